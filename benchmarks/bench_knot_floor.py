"""A whole-body knot's evaluation and linearisation against the floor: Pinocchio's own calls on it.

For a running knot of each stance type (the presets' weights and constraints; swing feet priced), the median
wall time of ``calc`` + ``calc_diff`` at a new point, next to the median of the Pinocchio calls that knot
cannot do without (the floor): contact dynamics (``constraintDynamics`` or ``aba``) and their derivatives,
``integrate`` and ``dIntegrate`` of the step, the joint Jacobians and the swing feet's placements (their
velocities and all their derivatives come from those in compiled code), ``difference``/``dDifference`` of
the state residual. Everything between them is
Python and compiled glue. Calls are timed one by one (medians), interleaved between the packages, so a
load change on a shared machine hits all columns alike.

Usage: ``python benchmarks/bench_knot_floor.py [--baseline PACKAGE_DIR] [--repeats 3000] [--json]``
(``PACKAGE_DIR`` from ``benchmarks/make_baseline.sh COMMIT``: another commit's code in the same process).
"""

from __future__ import annotations

import argparse
import importlib
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

STANCES = {
    "trot (2 stance, 2 swing feet)": (True, False, False, True),
    "4 stance": (True, True, True, True),
    "1 stance (3 swing feet)": (True, False, False, False),
    "flight (4 swing feet)": (False, False, False, False),
}


def knot_and_floor(package: str, stance: tuple[bool, ...]):
    """``(full, floor)``: callables evaluating and linearising one knot of ``package`` at a fresh point, and
    the bare Pinocchio calls of the same work."""
    robots = importlib.import_module(f"{package}.robots.robot")
    knots = importlib.import_module(f"{package}.ocp.knots")
    statics = importlib.import_module(f"{package}.dynamics.statics")
    robot = robots.load_robot("mini_cheetah")
    factory = knots.WholeBodyModelFactory(robot)
    knot = factory.running_knot(stance)
    data = knot.create_data()
    rng = np.random.default_rng(0)
    x = robot.x_standing.copy()
    x[robot.nq :] = rng.normal(scale=0.3, size=robot.nv)
    u = statics.static_stance_torques(robot, robot.q_standing, stance) if any(stance) else np.zeros(robot.nu)
    model, nq = robot.model, robot.nq
    q, v = x[:nq], x[nq:]
    tau = np.zeros(robot.nv)
    tau[6:] = u
    dynamics, dynamics_data = knot.dynamics, data.dynamics
    pinocchio_data, kinematics_data = model.createData(), model.createData()
    step = v * dynamics.dt
    swing = [leg for leg in range(4) if not stance[leg]]
    swing_frames = [robot.foot_frame_ids[leg] for leg in swing]
    reference = robot.q_standing

    def full() -> None:
        data.last_x[0] = np.nan  # a new point: calc_diff must not find calc's results stale
        knot.calc(data, x, u)
        knot.calc_diff(data, x, u)

    def floor() -> None:
        if any(stance):
            pin.constraintDynamics(
                model,
                dynamics_data.pinocchio,
                q,
                v,
                tau,
                dynamics.contact_models,
                dynamics_data.contact_datas,
                dynamics_data.proximal,
            )
            pin.computeConstraintDynamicsDerivatives(
                model, dynamics_data.pinocchio, dynamics.contact_models, dynamics_data.contact_datas
            )
        else:
            pin.aba(model, pinocchio_data, q, v, tau, pin.Convention.WORLD)
            pin.computeABADerivatives(model, pinocchio_data)
        pin.integrate(model, q, step)
        pin.dIntegrate(model, q, step)
        pin.difference(model, reference, q)
        pin.dDifference(model, reference, q, pin.ArgumentPosition.ARG1)
        if swing:
            pin.computeJointJacobians(model, kinematics_data, q)
            for frame_id in swing_frames:
                pin.updateFramePlacement(model, kinematics_data, frame_id)

    return full, floor


def median_us(function, repeats: int) -> float:
    samples = []
    clock = time.perf_counter_ns
    for _ in range(repeats):
        start = clock()
        function()
        samples.append(clock() - start)
    return statistics.median(samples) / 1e3


def run(packages: list[str], repeats: int) -> dict:
    rows = []
    for name, stance in STANCES.items():
        callables = {package: knot_and_floor(package, stance) for package in packages}
        for full, floor in callables.values():
            for _ in range(200):
                full()
                floor()
        samples: dict[str, list[float]] = {f"{p}:{kind}": [] for p in packages for kind in ("knot", "floor")}
        for _ in range(5):  # interleaved blocks
            for package, (full, floor) in callables.items():
                samples[f"{package}:knot"].append(median_us(full, repeats // 5))
                samples[f"{package}:floor"].append(median_us(floor, repeats // 5))
        row = {"stance": name}
        for key, values in samples.items():
            row[key] = float(np.median(values))
        rows.append(row)
    return {"date": time.strftime("%Y-%m-%d %H:%M"), "packages": packages, "repeats": repeats, "rows": rows}


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--baseline", help="another commit's package directory (make_baseline.sh)")
    parser.add_argument("--repeats", type=int, default=3000)
    parser.add_argument("--json", action="store_true")
    arguments = parser.parse_args()
    packages = ["cafe_mpc"]
    if arguments.baseline:
        path = Path(arguments.baseline).resolve()
        sys.path.insert(0, str(path.parent))
        packages.insert(0, path.name)
    result = run(packages, arguments.repeats)
    if arguments.json:
        print(json.dumps(result, indent=1))
        return
    header = " | ".join(f"{p} knot | {p} floor" for p in packages)
    print(f"{result['date']}: median microseconds of calc + calc_diff (knot) and Pinocchio's calls (floor)")
    print(f"| stance | {header} |")
    print("|---|" + "---|" * (2 * len(packages)))
    for row in rows_of(result):
        print(row)


def rows_of(result: dict) -> list[str]:
    lines = []
    for row in result["rows"]:
        cells = []
        for package in result["packages"]:
            cells += [f"{row[f'{package}:knot']:.1f}", f"{row[f'{package}:floor']:.1f}"]
        lines.append(f"| {row['stance']} | " + " | ".join(cells) + " |")
    return lines


if __name__ == "__main__":
    main()
