"""The start of every gait preset, old (steps, no stand for trot and pace) against new (as shipped: a 0.2 s
stand, then the command ramped in over 0.5 s): the sideways lurch in the first 0.5 s and the tracking over
the whole run and from 0.5 s. Measured latency, as the presets; run it alone on the machine:

    .venv/bin/python benchmarks/bench_start.py --duration 10
    .venv/bin/python benchmarks/bench_start.py --gaits trot pace --duration 2 --set mpc.latency=fixed
"""

from __future__ import annotations

import argparse
import json
import os

import numpy as np

from cafe_mpc.config import load_config
from cafe_mpc_lab.experiments.run import run_metrics, simulate_run
from cafe_mpc_lab.report.metrics import body_rates

OLD = {"trot": ["gait.start_stance=0"], "pace": ["gait.start_stance=0"]}
"""What the old start differs in besides the ramp (the other gaits already stood for 0.2 s)."""


def start_row(gait: str, label: str, duration: float, overrides: list[str]) -> dict:
    extra = ["gait.command_ramp=0", *OLD.get(gait, [])] if label == "old" else []
    config = load_config(gait, [f"simulation.duration={duration}", *extra, *overrides])
    load = os.getloadavg()[0]
    run, controller, log = simulate_run(config)
    metrics = run_metrics(run, controller, log)
    heading, yaw_rate, _ = body_rates(log.q, log.v)
    first = log.time < 0.5
    mpc = metrics["mpc"] or {}
    return {
        "gait": gait,
        "start": label,
        "fell": metrics["fell"],
        "vy_abs_max_first_0.5s": float(np.max(np.abs(heading[first, 1]))),
        "yaw_rate_abs_max_first_0.5s": float(np.max(np.abs(yaw_rate[first]))),
        "roll_rate_abs_max_first_0.5s": float(np.max(np.abs(log.v[first, 3]))),
        "vx_rms_error_whole": metrics["vx_rms_error"],
        "vx_mean_whole": metrics["vx_mean"],
        "vx_mean_steady": metrics["steady_state"]["vx_mean"],
        "pitch_rms_steady": metrics["steady_state"]["pitch_rms"],
        "update_ms_median": mpc.get("update_ms_median"),
        "update_ms_p99": mpc.get("update_ms_p99"),
        "load_average": round(load, 2),
    }


def table(rows: list[dict]) -> str:
    lines = [
        "| gait | start | fell | max abs vy, first 0.5 s (m/s) | max abs yaw rate, first 0.5 s (rad/s) | "
        "max abs roll rate, first 0.5 s (rad/s) | vx RMS error, whole run (m/s) | "
        "vx mean, whole run / from 0.5 s (m/s) | pitch RMS from 0.5 s (rad) | update median / p99 (ms) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['gait']} | {r['start']} | {'yes' if r['fell'] else 'no'} | "
            f"{r['vy_abs_max_first_0.5s']:.3f} | "
            f"{r['yaw_rate_abs_max_first_0.5s']:.3f} | {r['roll_rate_abs_max_first_0.5s']:.2f} | "
            f"{r['vx_rms_error_whole']:.3f} | {r['vx_mean_whole']:.3f} / {r['vx_mean_steady']:.3f} | "
            f"{r['pitch_rms_steady']:.3f} | {r['update_ms_median']:.1f} / {r['update_ms_p99']:.1f} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--duration", type=float, default=10.0, help="simulated seconds per run")
    parser.add_argument("--gaits", nargs="+", default=["trot", "pace", "bound", "pronk", "flying-trot"])
    parser.add_argument("--set", dest="overrides", action="append", default=[], help="config override")
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    args = parser.parse_args()
    rows = [
        start_row(g, label, args.duration, args.overrides) for g in args.gaits for label in ("old", "new")
    ]
    print(json.dumps(rows, indent=2) if args.json else table(rows))


if __name__ == "__main__":
    main()
