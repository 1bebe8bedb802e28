"""What makes an MPC update fast must not change what it computes (issue 20)."""

from __future__ import annotations

import gc

import numpy as np
import pytest

from cafe_mpc.bench.problems import TROT_CYCLE, whole_body_problem
from cafe_mpc.mpc import collector
from cafe_mpc.solver import MSiLQRSolver, SolverOptions


def _solve(peer, **options):
    solver = MSiLQRSolver(SolverOptions(max_iterations=3, max_al_iterations=1, **options))
    return solver.solve(peer.problem, peer.initial_xs, peer.initial_us)


def test_threaded_and_fused_linearisations_equal_the_plain_one(robot) -> None:
    """``threads=2`` linearises on a pool (blocks of knots, no fused first linearisation); the result is the
    one of the single-threaded solve, whose first linearisation is fused with the evaluation, bit for bit."""
    peer = whole_body_problem(robot, TROT_CYCLE)
    single, threaded = _solve(peer), _solve(peer, threads=2)
    assert single.statistics.linearizations == threaded.statistics.linearizations == 4
    assert single.cost == threaded.cost
    for a, b in zip(single.phases, threaded.phases, strict=True):
        for name in ("xs", "us", "K", "k", "Quu", "Qux", "Qu"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_the_collector_is_paused_inside_and_restored_after() -> None:
    seen = []

    @collector.paused
    def update(fail: bool) -> None:
        seen.append(gc.isenabled())
        if fail:
            raise ValueError("failed update")

    was_enabled = gc.isenabled()
    try:
        gc.enable()
        update(False)
        assert gc.isenabled()
        with pytest.raises(ValueError):
            update(True)
        assert gc.isenabled()
        gc.disable()
        update(False)
        assert not gc.isenabled()  # a caller that had it off keeps it off
    finally:
        if was_enabled:
            gc.enable()
    assert seen == [False, False, False]
