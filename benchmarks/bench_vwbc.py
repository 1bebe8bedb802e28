"""Benchmark of the VWBC QP (34): solve time per tick and solver iterations with and without warm start.

Synthetic plans (``cafe_mpc.low_level.synthetic``) around the standing pose with all four feet in stance
(``standing``) and with a diagonal pair in stance (``trot``, FL + HR); the state drifts a little from tick
to tick (configuration random walk + noisy velocity), as consecutive 500 Hz ticks do. ``disturbed`` is the
standing plan with ten times the velocity noise, so that friction-pyramid constraints become active.

For every solver (ProxQP always, DAQP when installed) and warm-start mode: the histogram of iterations,
the median / 99th percentile of the solver call and of the whole tick (assembly + solve) in ms, the share
of one-iteration ticks and fallbacks. ProxQP counts proximal augmented-Lagrangian iterations, DAQP counts
active-set changes (comparable to the paper's qpOASES numbers). The Riccati controller (33) is scored on
the same states for friction-pyramid violations.

``--detection``: what contact detection (``stance_source: detected``) adds to a tick. The default VWBC with
the plan's stance, with the detected stance (flat ground) and, blind (a ground plane), with the detector's
static force estimate and with its momentum observer (the default off flat ground), on the same states, in
interleaved rounds; the median of the per-round ratios of the median tick times to the plan's stance, and
every variant's median / p99.

    .venv/bin/python benchmarks/bench_vwbc.py [--ticks 400] [--json]
    .venv/bin/python benchmarks/bench_vwbc.py --detection [--rounds 15]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import platform
import sys
import time

import numpy as np
import pinocchio as pin

from cafe_mpc.config import ContactDetectionSettings, VWBCSettings
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.low_level.contact_dynamics import FrictionConeScorer
from cafe_mpc.low_level.riccati import RiccatiController
from cafe_mpc.low_level.synthetic import synthetic_plan
from cafe_mpc.low_level.vwbc import VWBCController
from cafe_mpc.robots.robot import load_robot

SCENARIOS = {
    "standing": {"stance": (True, True, True, True), "v_scale": 0.03},
    "trot": {"stance": (True, False, False, True), "v_scale": 0.03},
    "disturbed": {"stance": (True, True, True, True), "v_scale": 0.3},
}
MODES = {"proxqp": ("plan", "previous", "equality", "none"), "daqp": ("plan", "previous", "none")}


def states(robot, ticks: int, v_scale: float, seed: int = 0):
    """Nearby measured states: slowly drifting configuration error, noisy (low-passed) velocity."""
    rng = np.random.default_rng(seed)
    dq, v = np.zeros(robot.nv), np.zeros(robot.nv)
    for _ in range(ticks):
        dq = 0.98 * dq + 0.002 * rng.normal(size=robot.nv)
        v = 0.9 * v + v_scale * rng.normal(size=robot.nv)
        yield pin.integrate(robot.model, robot.q_standing, dq), v.copy()


def run(robot, plan, scenario: dict, solver: str, mode: str, ticks: int) -> dict:
    vwbc = VWBCController(robot, VWBCSettings(solver=solver, warm_start=mode))
    for i, (q, v) in enumerate(states(robot, ticks, scenario["v_scale"])):
        vwbc.compute(0.002 * i, Measurement.of_state(q, v, scenario["stance"]), plan)
    stats = vwbc.statistics()
    histogram = stats["qp_iterations_histogram"]
    total = sum(histogram.values())
    return {
        "solver": stats["solver"],
        "warm_start": mode,
        "iterations_histogram": {str(k): n for k, n in histogram.items()},
        "iterations_mean": sum(k * n for k, n in histogram.items()) / total,
        "one_iteration_share": histogram.get(1, 0) / total,
        "at_most_3_iterations_share": sum(n for k, n in histogram.items() if k <= 3) / total,
        "solve_ms_median": stats["qp_solve_time_ms_median"],
        "solve_ms_p99": stats["qp_solve_time_ms_p99"],
        "tick_ms_median": stats["tick_time_ms_median"],
        "tick_ms_p99": stats["tick_time_ms_p99"],
        "fallbacks": stats["fallbacks"],
        "friction_cone_violations": stats["friction_cone_violations"],
    }


def riccati_violations(robot, plan, scenario: dict, ticks: int) -> int:
    riccati = RiccatiController(robot)
    scorer = FrictionConeScorer(robot)
    stance = np.array(scenario["stance"])
    for i, (q, v) in enumerate(states(robot, ticks, scenario["v_scale"])):
        scorer.score(q, v, riccati.compute(0.002 * i, Measurement.of_state(q, v, stance), plan), stance)
    return scorer.violations


def detection_cost(robot, ticks: int, rounds: int) -> dict:
    """Tick times of the default VWBC with the plan's and with the detected stance (trot scenario),
    measured in alternating rounds in this process (module docstring)."""
    scenario = SCENARIOS["trot"]
    plan = synthetic_plan(robot, stance=np.array(scenario["stance"]), knots=20, seed=1)
    measured = [
        Measurement.of_state(q, v, scenario["stance"]) for q, v in states(robot, ticks, scenario["v_scale"])
    ]
    detected = VWBCSettings(stance_source="detected")
    controllers = {
        "plan": VWBCController(robot, VWBCSettings(stance_source="plan")),
        "detected": VWBCController(robot, detected),
        "blind_static": VWBCController(
            robot, detected, detection=ContactDetectionSettings(force_estimate="static"), ground_plane=True
        ),
        "blind_momentum": VWBCController(
            robot, detected, detection=ContactDetectionSettings(force_estimate="momentum"), ground_plane=True
        ),
    }
    ticks_ms: dict[str, list[float]] = {source: [] for source in controllers}
    ratios: dict[str, list[float]] = {source: [] for source in controllers if source != "plan"}
    for _ in range(rounds):
        medians = {}
        for source, vwbc in controllers.items():
            vwbc.reset()
            times = np.empty(ticks)
            for i, measurement in enumerate(measured):
                start = time.perf_counter()
                vwbc.compute(0.002 * i, measurement, plan)
                times[i] = time.perf_counter() - start
            ticks_ms[source].extend(1e3 * times)
            medians[source] = float(np.median(times))
        for source in ratios:
            ratios[source].append(medians[source] / medians["plan"])
    return {
        "ticks": ticks,
        "rounds": rounds,
        **{f"ratio_{source}_to_plan_median": float(np.median(values)) for source, values in ratios.items()},
        **{
            f"{source}_tick_ms": {
                "median": float(np.median(values)),
                "p99": float(np.percentile(values, 99)),
            }
            for source, values in ticks_ms.items()
        },
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=400, help="ticks per run (default 400)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    parser.add_argument("--detection", action="store_true", help="what contact detection adds to a tick")
    parser.add_argument("--rounds", type=int, default=15, help="interleaved rounds of --detection")
    args = parser.parse_args(argv)
    robot = load_robot("mini_cheetah")
    if args.detection:
        cost = detection_cost(robot, args.ticks, args.rounds)
        cost["machine"] = {"python": platform.python_version(), "processor": platform.machine()}
        print(json.dumps(cost, indent=2))
        return 0
    solvers = ["proxqp"] + (["daqp"] if importlib.util.find_spec("daqp") else [])
    results: dict = {
        "machine": {"python": platform.python_version(), "processor": platform.machine()},
        "ticks": args.ticks,
        "scenarios": {},
    }
    for name, scenario in SCENARIOS.items():
        plan = synthetic_plan(robot, stance=np.array(scenario["stance"]), knots=20, seed=1)
        runs = [run(robot, plan, scenario, s, m, args.ticks) for s in solvers for m in MODES[s]]
        results["scenarios"][name] = {
            "stance": list(scenario["stance"]),
            "velocity_noise": scenario["v_scale"],
            "riccati_friction_cone_violations": riccati_violations(robot, plan, scenario, args.ticks),
            "runs": runs,
        }
    if args.json:
        json.dump(results, sys.stdout, indent=2)
        print()
        return 0
    for name, scenario in results["scenarios"].items():
        print(
            f"\n{name}: stance {scenario['stance']}, velocity noise {scenario['velocity_noise']}, "
            f"{args.ticks} ticks; Riccati cone violations {scenario['riccati_friction_cone_violations']}"
        )
        print(
            f"  {'solver':<30} {'warm':<9} {'iter mean':>9} {'1 it':>6} {'<=3':>6} "
            f"{'solve med/p99 ms':>17} {'tick med/p99 ms':>16} {'fb':>3} {'cone':>4}  histogram"
        )
        for r in scenario["runs"]:
            print(
                f"  {r['solver']:<30} {r['warm_start']:<9} {r['iterations_mean']:9.2f} "
                f"{r['one_iteration_share']:6.1%} {r['at_most_3_iterations_share']:6.1%} "
                f"{r['solve_ms_median']:8.3f}/{r['solve_ms_p99']:.3f} "
                f"{r['tick_ms_median']:7.3f}/{r['tick_ms_p99']:.3f} {r['fallbacks']:3d} "
                f"{r['friction_cone_violations']:4d}  {r['iterations_histogram']}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
