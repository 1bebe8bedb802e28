"""The bound's height in closed loop against what its plans aim at (fixed latency, deterministic).

Runs the ``bound`` preset (fixed latency unless overridden) and prints, from ``START`` seconds on: the
mean base height and its standard deviation, the mean of the highest point of each gait cycle, and over the
MPC plans that took effect the mean planned height of their first three knots and the mean of their
whole-body apex. BENCHMARKS.md (issue 19) uses it to compare where plans start and take effect.

Usage::

    python benchmarks/bound_height.py --set mpc.fixed_latency=0.01 --set mpc.delay_compensation=false
    python benchmarks/bound_height.py --duration 5 --set gait.start_stance=0.21
"""

from __future__ import annotations

import argparse

import numpy as np

from cafe_mpc.config import load_config
from cafe_mpc.planners.cafe.planner import RecedingHorizonMpc
from cafe_mpc_lab.experiments.run import simulate_run

START = 1.5
"""s: the start of the window (after the gait's start and its command ramp)."""
CYCLE = 0.4
"""s: the bound's gait cycle."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=5.0)
    parser.add_argument("--set", action="append", default=[], help="config override (as cafe-mpc run)")
    arguments = parser.parse_args()
    config = load_config(
        "bound",
        [
            "output.plots=false",
            "mpc.latency=fixed",
            f"simulation.duration={arguments.duration}",
            *arguments.set,
        ],
    )
    planned: list[tuple[float, np.ndarray]] = []
    feedback = RecedingHorizonMpc.feedback

    def recording_feedback(self, t, q, v):
        plan = feedback(self, t, q, v)
        if plan is not None:
            planned.append((float(plan.times[0]), plan.xs[:, 2].copy()))
        return plan

    RecedingHorizonMpc.feedback = recording_feedback
    try:
        _, _, log = simulate_run(config)
    finally:
        RecedingHorizonMpc.feedback = feedback
    times, heights = log.time[: log.ticks], log.q[: log.ticks, 2]
    window = times > START
    cycles = np.arange(START, times[-1] - CYCLE, CYCLE)
    cycle_max = [heights[(times >= start) & (times < start + CYCLE)].max() for start in cycles]
    plans = [z for start, z in planned if start > START]
    print(f"fell: {log.fell}")
    print(
        f"base height from {START} s: mean {heights[window].mean():.4f} m, "
        f"std {heights[window].std():.4f} m, mean cycle maximum {np.mean(cycle_max):.4f} m"
    )
    if plans:
        print(
            f"plans ({len(plans)}): first three knots {np.mean([z[:3].mean() for z in plans]):.4f} m, "
            f"whole-body apex {np.mean([z.max() for z in plans]):.4f} m"
        )


if __name__ == "__main__":
    main()
