"""What an MPC preparation asks of the OS's memory in closed loop: page faults, solver data made inside it.

A preparation that writes memory the OS has not mapped yet (a knot's data made inside the update, a
workspace's knots used for the first time) takes a page fault per 4 kB page: a few hundred in one update
on a take-off. This runs a preset in closed loop (the simulator and the 500 Hz low level between the
updates, as a run has them) and records, per preparation, the minor and major page faults of the thread
that ran it (``getrusage(RUSAGE_THREAD)``), the solver data objects and impact maps it created, and its wall
and thread CPU time.

Usage::

    python benchmarks/update_memory.py --preset spin                       # fixed 20 ms latency
    python benchmarks/update_memory.py --preset spin --set mpc.latency=measured
    python benchmarks/update_memory.py --preset spin --json

Fault counts depend on the kernel and the allocator, not on the machine's load; the times do (run it on an
idle machine for those).
"""

from __future__ import annotations

import argparse
import json
import resource
import time

import numpy as np

from cafe_mpc.config import load_config
from cafe_mpc.planners.cafe.planner import RecedingHorizonMpc
from cafe_mpc.solver import workspace
from cafe_mpc_lab.experiments.run import simulate_run


def measure(preset: str, overrides: list[str]) -> dict:
    rows: list[tuple[float, float, float, int, int, int, int]] = []
    inside = {"data": 0}
    prepare, get = RecedingHorizonMpc.prepare, workspace._DataPool.get
    planners: list[RecedingHorizonMpc] = []

    def counting_get(self, owner, create):
        def make():
            inside["data"] += 1
            return create()

        return get(self, owner, make)

    def measured_prepare(self, t, q, v):
        if not planners:
            planners.append(self)
        projections = len(self._projections)
        inside["data"] = 0
        workspace._DataPool.get = counting_get
        before = resource.getrusage(resource.RUSAGE_THREAD)
        wall, cpu = time.perf_counter(), time.thread_time()
        try:
            return prepare(self, t, q, v)
        finally:
            wall, cpu = time.perf_counter() - wall, time.thread_time() - cpu
            after = resource.getrusage(resource.RUSAGE_THREAD)
            workspace._DataPool.get = get
            rows.append(
                (
                    t,
                    wall * 1e3,
                    cpu * 1e3,
                    after.ru_minflt - before.ru_minflt,
                    after.ru_majflt - before.ru_majflt,
                    inside["data"],
                    len(self._projections) - projections,
                )
            )

    RecedingHorizonMpc.prepare = measured_prepare
    try:
        config = load_config(preset, ["mpc.latency=fixed", "output.plots=false", *overrides])
        _, _, log = simulate_run(config)
    finally:
        RecedingHorizonMpc.prepare = prepare
    table = np.array(rows)
    later = table[1:]  # the first preparation after the clock started reads its plan for the first time
    faulted = later[later[:, 3] > 10]
    return {
        "preset": preset,
        "overrides": overrides,
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "fell": bool(log.fell),
        "preparations": len(table),
        "minor_faults": {
            "first": int(table[0, 3]),
            "later_total": int(later[:, 3].sum()),
            "later_max": int(later[:, 3].max()),
            "later_over_10": len(faulted),
            "times_over_10": [round(float(t), 3) for t in faulted[:, 0]],
        },
        "major_faults": int(table[:, 4].sum()),
        "data_created_inside": int(table[:, 5].sum()),
        "impact_maps_created_inside": int(table[:, 6].sum()),
        "wall_ms": {"median": float(np.median(table[:, 1])), "p99": float(np.percentile(table[:, 1], 99))},
        "cpu_ms": {"median": float(np.median(table[:, 2])), "p99": float(np.percentile(table[:, 2], 99))},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", default="spin")
    parser.add_argument("--set", action="append", default=[], help="config override (after fixed latency)")
    parser.add_argument("--json", action="store_true")
    arguments = parser.parse_args()
    result = measure(arguments.preset, arguments.set)
    if arguments.json:
        print(json.dumps(result, indent=1))
        return
    faults = result["minor_faults"]
    wall, cpu = result["wall_ms"], result["cpu_ms"]
    print(
        f"{result['preset']} {' '.join(result['overrides'])}: {result['preparations']} preparations, "
        f"fell {result['fell']}; minor page faults: first {faults['first']}, "
        f"the rest {faults['later_total']} (largest {faults['later_max']}, "
        f"{faults['later_over_10']} over 10: "
        f"{faults['times_over_10']}); major {result['major_faults']}; solver data made inside "
        f"{result['data_created_inside']}, impact maps {result['impact_maps_created_inside']}; wall ms "
        f"median {wall['median']:.2f} p99 {wall['p99']:.2f}, CPU ms median {cpu['median']:.2f} p99 "
        f"{cpu['p99']:.2f}"
    )


if __name__ == "__main__":
    main()
