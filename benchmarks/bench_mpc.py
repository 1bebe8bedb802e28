"""Closed-loop MPC timing per gait: per-iteration and per-solve times (median, p99), real-time factor.

Runs each gait preset as ``cafe-mpc run`` does (CAFE-MPC S4 + VWBC, full MuJoCo plant), without writing
files, and prints a markdown table for BENCHMARKS.md. Timing is wall clock on this machine: run it alone
(no other simulation on the machine), e.g.

    .venv/bin/python benchmarks/bench_mpc.py --duration 4 --gaits trot pace bound pronk flying-trot
"""

from __future__ import annotations

import argparse
import json
import platform

import numpy as np

from cafe_mpc.config import load_config
from cafe_mpc.experiments.run import run_metrics, simulate_run


def bench_gait(preset: str, duration: float, overrides: list[str]) -> dict:
    config = load_config(preset, [f"simulation.duration={duration}", "output.plots=false", *overrides])
    robot, controller, log = simulate_run(config)
    metrics = run_metrics(config, robot, controller, log)
    statistics = controller.statistics
    iterations = np.asarray(statistics.iteration_times) * 1e3
    solves = np.asarray(statistics.solve_times) * 1e3
    return {
        "gait": preset,
        "fell": bool(log.fell),
        "vx_mean": metrics["vx_mean"],
        "solves": statistics.solves,
        "iterations_per_solve": float(np.mean(statistics.iterations)),
        "iteration_ms_median": float(np.median(iterations)),
        "iteration_ms_p99": float(np.percentile(iterations, 99)),
        "solve_ms_median": float(np.median(solves)),
        "solve_ms_p99": float(np.percentile(solves, 99)),
        "real_time_factor": metrics["real_time_factor"],
        "qp_solve_ms_median": metrics["wbc"].get("qp_solve_time_ms_median"),
        "qp_solve_ms_p99": metrics["wbc"].get("qp_solve_time_ms_p99"),
    }


def main() -> None:
    formatter = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=formatter)
    parser.add_argument("--duration", type=float, default=4.0, help="simulated seconds per gait")
    parser.add_argument("--gaits", nargs="+", default=["trot", "pace", "bound", "pronk", "flying-trot"])
    parser.add_argument("--set", dest="overrides", action="append", default=[], help="config override")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    args = parser.parse_args()
    rows = [bench_gait(gait, args.duration, args.overrides) for gait in args.gaits]
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    print(f"{platform.processor() or platform.machine()}, {args.duration} s simulated per gait\n")
    print(
        "| gait | fell | vx mean (m/s) | iterations / solve | iteration ms median / p99 "
        "| solve ms median / p99 | real-time factor | VWBC QP ms median / p99 |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['gait']} | {r['fell']} | {r['vx_mean']:.3f} | {r['iterations_per_solve']:.2f} "
            f"| {r['iteration_ms_median']:.1f} / {r['iteration_ms_p99']:.1f} "
            f"| {r['solve_ms_median']:.1f} / {r['solve_ms_p99']:.1f} | {r['real_time_factor']:.2f} "
            f"| {r['qp_solve_ms_median']:.3f} / {r['qp_solve_ms_p99']:.3f} |"
        )


if __name__ == "__main__":
    main()
