"""The backward sweep of MS-iLQR on the ``bench solver`` problem: microseconds per sweep and per knot.

The 25-knot whole-body trot problem of ``cafe_mpc_lab.bench.problems`` is solved once; then its last
linearisation is swept backward repeatedly (``MSiLQRSolver.backward``, Eqs. (8)-(10), (16)), and the
two matrix products of one knot (``S F`` and ``F' S F``, the compiled kernel's BLAS calls) are timed alone.
Medians over rounds; compare against the iteration time ``cafe-mpc bench solver`` reports.

Usage::

    python benchmarks/bench_backward.py
"""

from __future__ import annotations

import time

import numpy as np
from numba import njit

from cafe_mpc.robots.robot import load_robot
from cafe_mpc.solver import MSiLQRSolver, SolverOptions
from cafe_mpc_lab.bench.problems import TROT_CYCLE, whole_body_problem


@njit(cache=True)
def _products(S: np.ndarray, F: np.ndarray, H: np.ndarray, SF: np.ndarray, Q: np.ndarray) -> None:
    np.dot(S, F, SF)
    np.dot(F.T, SF, Q)
    Q += H


def _median_us(function, calls: int, rounds: int = 7) -> float:
    samples = []
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(calls):
            function()
        samples.append((time.perf_counter() - start) / calls)
    return float(np.median(samples)) * 1e6


def main() -> None:
    robot = load_robot("mini_cheetah")
    peer = whole_body_problem(robot, TROT_CYCLE)
    solver = MSiLQRSolver(SolverOptions(max_iterations=10, max_al_iterations=1))
    solver.solve(peer.problem, peer.initial_xs, peer.initial_us)
    workspace = solver.workspace
    knots = sum(work.horizon for work in workspace.phases)

    def sweep() -> None:
        solver.backward()

    work = workspace.phases[0]
    S, F, H = work.S[1].copy(), work.F[0].copy(), work.H[0].copy()
    SF, Q = np.zeros_like(work.SF), np.zeros_like(work.Q)

    def products() -> None:
        _products(S, F, H, SF, Q)

    for function in (sweep, products):
        _median_us(function, 50, rounds=1)
    per_sweep = _median_us(sweep, 200)
    per_knot = per_sweep / knots
    print(f"backward sweep: {per_sweep:.0f} us per sweep, {per_knot:.1f} us per knot ({knots} knots)")
    print(f"S F and F' S F of one knot (F {F.shape[0]} x {F.shape[1]}): {_median_us(products, 5000):.2f} us")


if __name__ == "__main__":
    main()
