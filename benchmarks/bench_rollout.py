"""The line search's roll-out of MS-iLQR on the ``bench solver`` problem: microseconds per knot and trial.

The 25-knot whole-body trot problem of ``cafe_mpc_lab.bench.problems`` is solved once and swept backward
at its solution; then one trial step is rolled out repeatedly (``MSiLQRSolver.try_step``, Eqs. (11)-(13)
through the impact, Eq. (15)), with the hybrid roll-out (every knot shooting: Eq. (12)) and the nonlinear one
(Eq. (13) everywhere), against the knots' ``calc`` alone at the same points (what the roll-out cannot do
without). Interleaved rounds, medians; compare with Crocoddyl's ``forwardPass`` per knot.

Usage::

    python benchmarks/bench_rollout.py
"""

from __future__ import annotations

import time

import numpy as np

from cafe_mpc.robots.robot import load_robot
from cafe_mpc.solver import MSiLQRSolver, SolverOptions
from cafe_mpc_lab.bench.problems import TROT_CYCLE, whole_body_problem


def main(rounds: int = 15, calls: int = 20) -> None:
    robot = load_robot("mini_cheetah")
    peer = whole_body_problem(robot, TROT_CYCLE)
    solver = MSiLQRSolver(SolverOptions(max_iterations=10, max_al_iterations=1))
    solver.solve(peer.problem, peer.initial_xs, peer.initial_us)
    workspace = solver.workspace
    solver.linearize()
    solver.backward()
    knots = sum(work.horizon for work in workspace.phases)

    def calcs() -> None:
        for work in workspace.phases:
            xs, us = work.xs_try, work.us_try
            for k, (model, data) in enumerate(zip(work.models, work.running_data, strict=True)):
                model.calc(data, xs[k], us[k])

    functions = {
        "roll-out, hybrid (Eq. (12))": lambda: solver.try_step(0.5, False),
        "roll-out, nonlinear (Eq. (13))": lambda: solver.try_step(0.5, True),
        "the knots' calc alone": calcs,
    }
    samples: dict[str, list[float]] = {name: [] for name in functions}
    for function in functions.values():
        function()
    for _ in range(rounds):
        for name, function in functions.items():
            start = time.perf_counter()
            for _ in range(calls):
                function()
            samples[name].append((time.perf_counter() - start) / calls / knots * 1e6)
    for name, values in samples.items():
        print(f"{name:<32} {np.median(values):6.2f} us per knot ({knots} knots)")


if __name__ == "__main__":
    main()
