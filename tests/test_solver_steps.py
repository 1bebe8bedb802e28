"""``MSiLQRSolver``'s public steps: ``prepare``, ``linearize``, ``backward`` and ``try_step`` are the pieces
``solve`` is made of, and give bit for bit what ``solve`` gives.

``prepare`` (the real-time iteration's preparation) is a solve without iterations; ``prepare`` followed by
``try_step`` with the step ``solve``'s line search accepted is ``solve``'s first iteration; ``linearize`` and
``backward`` at a solution give the policy ``solve`` returned with it.
"""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np
import pytest

from cafe_mpc.core.interfaces import MultiPhaseProblem, Phase
from cafe_mpc.solver import MSiLQRSolver, SolverOptions, SweepOutcome
from cafe_mpc_lab.bench.problems import TROT_CYCLE, whole_body_problem
from toy_models import BounceReset, PointMassFlight, TouchdownConstraint


def bounce() -> tuple[MultiPhaseProblem, list[np.ndarray], list[np.ndarray]]:
    """A fall onto the ground (touchdown constraint, Eq. (2)), a bounce (reset map) and a rebound, with a
    guess that misses the touchdown (the augmented-Lagrangian update has work to do)."""
    flight = Phase([PointMassFlight(0.02)] * 20, PointMassFlight(None), name="flight")
    flight.switching_constraint = TouchdownConstraint()
    flight.reset_map = BounceReset(restitution=0.7)
    rebound = Phase([PointMassFlight(0.02)] * 20, PointMassFlight(None, target_height=0.4), name="rebound")
    problem = MultiPhaseProblem(x0=np.array([1.0, 0.0]), phases=[flight, rebound])
    rng = np.random.default_rng(2)
    xs = [np.column_stack([np.linspace(1.0, 0.3, 21), -np.ones(21)]), 0.1 * rng.standard_normal((21, 2))]
    us = [np.zeros((20, 1)), 0.1 * rng.standard_normal((20, 1))]
    return problem, xs, us


def trot(robot) -> tuple[MultiPhaseProblem, list[np.ndarray], list[np.ndarray]]:
    """Two whole-body trot phases with an impact between them (compiled free-flyer operations)."""
    peer = whole_body_problem(robot, TROT_CYCLE)
    return peer.problem, peer.initial_xs, peer.initial_us


def assert_same_result(a, b) -> None:
    """Every array and number of two results equal bit for bit (timings aside)."""
    for name in ("cost", "augmented_cost", "defect_max", "defect_l1", "switching_violation", "status"):
        assert getattr(a, name) == getattr(b, name), name
    assert (a.converged, a.policy_valid) == (b.converged, b.policy_valid)
    for first, second in zip(a.phases, b.phases, strict=True):
        for field in fields(first):
            x, y = getattr(first, field.name), getattr(second, field.name)
            if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
                np.testing.assert_array_equal(x, y, err_msg=field.name)
            else:
                assert x == y, field.name


@pytest.mark.parametrize("case", ["bounce", "trot"])
def test_prepare_is_a_solve_without_iterations(robot, case: str) -> None:
    problem, xs, us = bounce() if case == "bounce" else trot(robot)
    options = SolverOptions(max_iterations=0, max_al_iterations=2)
    solved = MSiLQRSolver(options).solve(problem, xs, us)
    preparing = MSiLQRSolver(replace(options, max_iterations=5, final_backward_pass=False))
    prepared = preparing.prepare(problem, xs, us)
    assert_same_result(solved, prepared)
    assert prepared.policy_valid and prepared.statistics.iterations == 0
    if case == "bounce":  # the guess misses the touchdown: both updated the multipliers twice
        assert solved.switching_violation > options.switching_tolerance
        assert prepared.statistics.al_iterations == 2
        assert prepared.phases[0].penalty == pytest.approx(options.al_initial_penalty * 25.0)
    # and the feedback embeds a measured state into either the same way
    x0 = problem.x0 + 1e-3
    other = MSiLQRSolver(options)
    assert_same_result(
        other.feedback(other.solve(problem, xs, us), x0, 1.0), preparing.feedback(prepared, x0, 1.0)
    )


@pytest.mark.parametrize("case", ["bounce", "trot"])
def test_prepare_then_try_step_is_the_first_iteration(robot, case: str) -> None:
    """The backward sweep of ``prepare`` and the trial roll-out of the accepted step (Eqs. (11)-(13), (15))
    give the trajectory ``solve``'s first iteration accepted (no multiplier update in either)."""
    problem, xs, us = bounce() if case == "bounce" else trot(robot)
    options = SolverOptions(max_iterations=1, max_al_iterations=1, switching_tolerance=np.inf)
    result = MSiLQRSolver(replace(options, final_policy="shift")).solve(problem, xs, us)
    (alpha,), (mode,) = result.statistics.step_sizes, result.statistics.forward_modes
    assert alpha > 0.0 and mode in ("hybrid", "nonlinear")
    solver = MSiLQRSolver(options)
    solver.prepare(problem, xs, us)
    totals = solver.try_step(alpha, nonlinear=mode == "nonlinear")
    assert (totals.cost, totals.defect_l1, totals.defect_max) == (
        result.cost,
        result.defect_l1,
        result.defect_max,
    )
    for work, phase in zip(solver.workspace.phases, result.phases, strict=True):
        np.testing.assert_array_equal(work.xs_try, phase.xs)
        np.testing.assert_array_equal(work.us_try, phase.us)
        np.testing.assert_array_equal(work.defects_try, phase.defects)
        assert not np.array_equal(work.xs_try, work.xs)  # the nominal stayed the guess


def test_linearize_and_backward_at_a_solution_give_its_policy(robot) -> None:
    problem, xs, us = trot(robot)
    solver = MSiLQRSolver(SolverOptions(max_iterations=3, max_al_iterations=1, final_policy="relinearize"))
    result = solver.solve(problem, xs, us)
    assert result.policy_valid
    for work in solver.workspace.phases:
        work.K[:] = np.nan
        work.k[:] = np.nan
    solver.linearize()
    assert solver.backward() == SweepOutcome.OK
    for work, phase in zip(solver.workspace.phases, result.phases, strict=True):
        for name in ("K", "k", "Qu", "Quu", "Qux", "S", "s"):
            np.testing.assert_array_equal(getattr(work, name), getattr(phase, name), err_msg=name)


def test_the_steps_need_a_problem_and_the_nominal_in_the_data() -> None:
    solver = MSiLQRSolver()
    for step in (solver.linearize, solver.backward, lambda: solver.try_step(1.0)):
        with pytest.raises(RuntimeError, match="solve or prepare"):
            step()
    problem, xs, us = bounce()
    solver.prepare(problem, xs, us)
    solver.linearize()
    solver.try_step(0.5)
    with pytest.raises(RuntimeError, match="not at the nominal"):
        solver.linearize()
    solver.prepare(problem, xs, us)
    solver.linearize()
