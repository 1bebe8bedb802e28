"""``cafe-mpc bench mpc``: MPC update time in closed loop, per gait, with its breakdown.

Each gait preset runs as ``cafe-mpc run`` does (CAFE-MPC + VWBC, full MuJoCo plant, no files written), in the
preset's timing mode (measured latency by default: each plan acts after its real update time, so the loop
is what a robot would see). Reported per gait, medians and p99 over the updates after the cold first solve
(which runs before the clock starts): the MPC update (problem update + solve + plan), its parts (problem
update, linearisation, backward sweeps, line search), with the real-time iteration (``mpc.scheme: rti``,
the presets' default) its two phases (preparation before the measurement, feedback after it: the latency),
the time per MS-iLQR iteration, iterations per update, the plan latency, the knots of the last problem by
type, and whether the robot stayed up and tracked the speed. Wall-clock numbers: run it alone on
the machine (no other simulation), and read the numbers with the machine they came from.
"""

from __future__ import annotations

import platform

import numpy as np

from cafe_mpc.assembly.checks import load_run_config
from cafe_mpc_lab.experiments.run import run_metrics, simulate_run

DEFAULT_GAITS = ("trot", "bound")


def bench_gait(preset: str, duration: float, overrides: list[str]) -> dict:
    """One closed-loop run of ``preset``; its MPC timing and tracking."""
    config = load_run_config(preset, [f"simulation.duration={duration}", "output.plots=false", *overrides])
    run, controller, log = simulate_run(config)
    metrics = run_metrics(run, controller, log)
    mpc = metrics["mpc"]
    iterations = np.asarray(controller.statistics.iteration_times) * 1e3
    knots = {"whole_body": None, "srb": None}
    previous = getattr(controller.planner, "previous", None)
    if previous is not None and hasattr(previous[0], "phases"):
        for kind in knots:
            knots[kind] = sum(len(i.times) - 1 for i in previous[0].phases if getattr(i, "kind", "") == kind)
    return {
        "gait": preset,
        "timing_mode": metrics["timing"]["mode"],
        "scheme": metrics["timing"].get("scheme"),
        "prepare_ms_median": mpc.get("prepare_ms_median"),
        "prepare_ms_p99": mpc.get("prepare_ms_p99"),
        "feedback_ms_median": mpc.get("feedback_ms_median"),
        "feedback_ms_p99": mpc.get("feedback_ms_p99"),
        "knots": knots,
        "schedule": config.mpc.schedule,
        "fell": bool(log.fell),
        "vx_mean": metrics["steady_state"]["vx_mean"],  # from 0.5 s, as in the earlier tables
        "updates": mpc["solves"] - 1,
        "update_ms_median": mpc["update_ms_median"],
        "update_ms_p99": mpc["update_ms_p99"],
        "problem_update_ms_median": mpc["problem_update_ms_median"],
        "linearize_ms_median": mpc["linearize_ms_median"],
        "backward_ms_median": mpc["backward_ms_median"],
        "line_search_ms_median": mpc["line_search_ms_median"],
        "iteration_ms_median": float(np.median(iterations)) if iterations.size else None,
        "iteration_ms_p99": float(np.percentile(iterations, 99)) if iterations.size else None,
        "iterations_per_update": mpc["iterations_mean"],
        "time_budget_stops": mpc["time_budget_stops"],
        "latency_ms_median": mpc["latency_ms_median"],
        "latency_ms_p99": mpc["latency_ms_p99"],
        "rate_hz": mpc["rate_hz"],
        "first_solve_ms": mpc["first_solve_ms"],
        "real_time_factor": metrics["real_time_factor"],
    }


def run_mpc_benchmark(gaits: tuple[str, ...] = DEFAULT_GAITS, duration: float = 4.0, overrides=()) -> dict:
    """``bench_gait`` for each gait, with the machine it ran on."""
    rows = [bench_gait(gait, duration, list(overrides)) for gait in gaits]
    return {
        "machine": {
            "processor": platform.processor() or platform.machine(),
            "python": platform.python_version(),
        },
        "duration_s": duration,
        "overrides": list(overrides),
        "gaits": rows,
    }


def _number(value: float | None, digits: int = 1) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def format_report(result: dict) -> str:
    """A markdown table (for BENCHMARKS.md)."""
    lines = [
        f"{result['machine']['processor']}, {result['duration_s']} s simulated per gait",
        "",
        "| gait | timing, scheme | fell | vx mean from 0.5 s | update ms median / p99 "
        "| prepare ms median / p99 | feedback ms median / p99 "
        "| problem / linearise / backward / line search ms (median) "
        "| iteration ms | iterations / update | latency ms median / p99 | rate Hz |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in result["gaits"]:
        lines.append(
            f"| {row['gait']} | {row['timing_mode']}, {row['scheme']} | {row['fell']} "
            f"| {_number(row['vx_mean'], 3)} "
            f"| {_number(row['update_ms_median'])} / {_number(row['update_ms_p99'])} "
            f"| {_number(row['prepare_ms_median'])} / {_number(row['prepare_ms_p99'])} "
            f"| {_number(row['feedback_ms_median'], 2)} / {_number(row['feedback_ms_p99'], 2)} "
            f"| {_number(row['problem_update_ms_median'])} / {_number(row['linearize_ms_median'])} / "
            f"{_number(row['backward_ms_median'])} / {_number(row['line_search_ms_median'])} "
            f"| {_number(row['iteration_ms_median'], 2)} | {_number(row['iterations_per_update'], 2)} "
            f"| {_number(row['latency_ms_median'])} / {_number(row['latency_ms_p99'])} "
            f"| {_number(row['rate_hz'])} |"
        )
    return "\n".join(lines)
