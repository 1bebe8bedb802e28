"""Per-knot cost of dynamics + derivatives (``calc`` + ``calc_diff``), ours vs Crocoddyl.

For each phase type (flight, 1, 2, 4 stance feet, impact, SRB) prints the median wall time of one
``calc`` + ``calc_diff`` of:

* ``dynamics``: the bare dynamics (``WholeBodyDynamics``, explicit Euler; ``ImpactReset``; ``SRBDynamics``);
* ``semi_implicit``: the same with Crocoddyl's integration scheme;
* ``knot``: the full knot (dynamics + cost (18)/(28) + barrier constraints), what the solver calls;
* ``crocoddyl``: ``DifferentialActionModelContactFwdDynamics`` (``ContactModel3D``, ``LOCAL_WORLD_ALIGNED``,
  gains [0, 10], empty cost) in ``IntegratedActionModelEuler``, same robot, same states, same run.

Usage: ``python benchmarks/bench_dynamics.py [--robot mini_cheetah] [--repeats 2000] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from collections.abc import Callable

import numpy as np
import pinocchio as pin

from cafe_mpc.dynamics.impact import ImpactReset
from cafe_mpc.dynamics.srb import SRBDynamics, SRBState, srb_parameters
from cafe_mpc.dynamics.whole_body import WholeBodyDynamics
from cafe_mpc.ocp.knots import SRBModelFactory, WholeBodyModelFactory
from cafe_mpc.robots.robot import Robot, load_robot

STANCES = {
    "flight": (False, False, False, False),
    "1 stance": (True, False, False, False),
    "2 stance": (True, False, False, True),
    "4 stance": (True, True, True, True),
}


def median_microseconds(function: Callable[[], None], repeats: int, warmup: int = 50) -> float:
    """Median of ``repeats`` individually timed calls, in microseconds."""
    for _ in range(warmup):
        function()
    samples = []
    clock = time.perf_counter_ns
    for _ in range(repeats):
        start = clock()
        function()
        samples.append(clock() - start)
    return statistics.median(samples) / 1e3


def crocoddyl_action(robot: Robot, stance: tuple[bool, ...], dt: float):
    from cafe_mpc_lab.bench.crocoddyl_peer import crocoddyl_contact_action

    return crocoddyl_contact_action(robot, stance, dt)


def run(robot_name: str, repeats: int) -> dict:
    robot = load_robot(robot_name)
    rng = np.random.default_rng(0)
    q = pin.integrate(robot.model, robot.q_standing, 0.05 * rng.standard_normal(robot.nv))
    x = np.concatenate([q, 0.2 * rng.standard_normal(robot.nv)])
    u = rng.standard_normal(12)
    dt = 0.01
    factory = WholeBodyModelFactory(robot)
    results: dict[str, dict[str, float | None]] = {}
    for name, stance in STANCES.items():
        row: dict[str, float | None] = {}
        for scheme, column in (("explicit", "dynamics"), ("semi_implicit", "semi_implicit")):
            dynamics = WholeBodyDynamics(robot, stance, dt, integration=scheme)
            data = dynamics.create_data()
            row[column] = median_microseconds(
                lambda d=data, m=dynamics: (m.calc(d, x, u), m.calc_diff(d, x, u)), repeats
            )
        knot = factory.running_knot(stance)
        knot_data = knot.create_data()
        row["knot"] = median_microseconds(
            lambda k=knot, d=knot_data: (k.calc(d, x, u), k.calc_diff(d, x, u)), repeats
        )
        try:
            action = crocoddyl_action(robot, stance, dt)
            action_data = action.createData()
            row["crocoddyl"] = median_microseconds(
                lambda a=action, d=action_data: (a.calc(d, x, u), a.calcDiff(d, x, u)), repeats
            )
        except ImportError:
            row["crocoddyl"] = None
        results[name] = row

    impact = ImpactReset(robot, STANCES["4 stance"])
    impact_data = impact.create_data()
    results["impact (4 feet)"] = {
        "dynamics": median_microseconds(
            lambda: (impact.calc(impact_data, x), impact.calc_diff(impact_data, x)), repeats
        )
    }

    srb_state = SRBState()
    xs = srb_state.integrate(srb_state.zero(), 0.1 * rng.standard_normal(12))
    xs[2] = 0.25
    feet = robot.foot_positions(robot.q_standing)
    contacts = np.array([1.0, 0.0, 0.0, 1.0])
    forces = 20.0 * rng.standard_normal(12)
    srb = SRBDynamics(srb_parameters(robot), dt=0.05)
    srb_data = srb.create_data()
    srb_factory = SRBModelFactory(robot=robot)
    srb_knot = srb_factory.running_knot(srb_factory.reference(xs, feet, (1, 0, 0, 1)))
    srb_knot_data = srb_knot.create_data()
    results["SRB"] = {
        "dynamics": median_microseconds(
            lambda: (
                srb.calc(srb_data, xs, forces, feet, contacts),
                srb.calc_diff(srb_data, xs, forces, feet, contacts),
            ),
            repeats,
        ),
        "knot": median_microseconds(
            lambda: (srb_knot.calc(srb_knot_data, xs, forces), srb_knot.calc_diff(srb_knot_data, xs, forces)),
            repeats,
        ),
    }
    return {
        "robot": robot_name,
        "repeats": repeats,
        "unit": "microseconds (median of calc + calc_diff)",
        "python": platform.python_version(),
        "pinocchio": pin.__version__,
        "results": results,
    }


def print_table(report: dict) -> None:
    columns = ("dynamics", "semi_implicit", "knot", "crocoddyl")
    print(f"robot {report['robot']}, {report['repeats']} repeats, {report['unit']}")
    print(f"{'phase':<16}" + "".join(f"{c:>15}" for c in columns))
    for name, row in report["results"].items():
        cells = "".join(f"{row[c]:>15.1f}" if row.get(c) is not None else f"{'-':>15}" for c in columns)
        print(f"{name:<16}{cells}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="mini_cheetah")
    parser.add_argument("--repeats", type=int, default=2000)
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    arguments = parser.parse_args()
    report = run(arguments.robot, arguments.repeats)
    if arguments.json:
        print(json.dumps(report, indent=2))
    else:
        print_table(report)


if __name__ == "__main__":
    main()
