"""MS-iLQR on nonlinear, hybrid, constrained and non-Euclidean toy problems."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from cafe_mpc.core.interfaces import ActionModel, MultiPhaseProblem, Phase
from cafe_mpc.ocp.barrier import RelaxedBarrier
from cafe_mpc.solver import MSiLQRSolver, SolverOptions, evaluate_trajectory
from cafe_mpc.solver.workspace import Workspace
from toy_models import (
    BounceReset,
    OrientationVelocityState,
    PendulumImpactReset,
    PendulumModel,
    PointMassFlight,
    RigidBodyAttitudeModel,
    TouchdownConstraint,
    quaternion_to_rotation,
    rotation_to_quaternion,
)

TIGHT = SolverOptions(max_iterations=200, defect_tolerance=1e-10)


def pendulum_problem(
    x0: np.ndarray, horizon: int = 40, dt: float = 0.05, **kwargs: object
) -> MultiPhaseProblem:
    model = PendulumModel(dt, **kwargs)
    return MultiPhaseProblem(x0=x0, phases=[Phase([model] * horizon, PendulumModel(None, **kwargs), dt=dt)])


def two_phase_pendulum(x0: np.ndarray) -> MultiPhaseProblem:
    """Two pendulum phases joined by a nonlinear reset map; targets differ so the reset matters."""
    first = Phase(
        [PendulumModel(0.05, target=1.0)] * 15, PendulumModel(None, target=1.0, terminal_weight=1.0)
    )
    first.reset_map = PendulumImpactReset()
    second = Phase(
        [PendulumModel(0.05, target=2.0)] * 15, PendulumModel(None, target=2.0, terminal_weight=10.0)
    )
    return MultiPhaseProblem(x0=x0, phases=[first, second])


# ------------------------------------------------------------------------------------------------------ tests
def test_infeasible_guess_converges_to_feasible_optimum() -> None:
    problem = pendulum_problem(np.array([0.2, 0.0]))
    rng = np.random.default_rng(0)
    horizon = problem.phases[0].horizon
    # Large random states on every shooting knot (defects of order 1-3) and random torques.
    initial_xs = [rng.uniform(-3.0, 3.0, size=(horizon + 1, 2))]
    initial_us = [rng.uniform(-2.0, 2.0, size=(horizon, 1))]
    assert evaluate_trajectory(problem, initial_xs, initial_us).defect_max > 1.0
    result = MSiLQRSolver(TIGHT).solve(problem, initial_xs, initial_us)
    assert result.converged, result.status
    assert result.defect_max < 1e-8
    assert np.all(np.isfinite(result.xs[0]))
    assert result.statistics.forward_modes[0] == "hybrid"  # Eq. (12) closes the defects first
    # The returned policy and Q-function belong to the returned trajectory: Qu ~ 0 at the optimum.
    assert result.policy_valid
    assert np.max(np.abs(result.phases[0].Qu)) < 1e-5
    assert np.max(np.abs(result.phases[0].k)) < 1e-4
    # Same optimum as single shooting from a zero guess (the problem has a clear swing-up solution).
    reference = MSiLQRSolver(TIGHT).solve(problem)
    assert reference.converged
    assert result.cost == pytest.approx(reference.cost, rel=1e-6)
    np.testing.assert_allclose(result.us[0], reference.us[0], atol=1e-4)
    # The terminal state is near the upright target.
    assert abs(result.xs[0][-1, 0] - np.pi) < 0.1


def test_wild_guess_does_not_stall_near_feasibility() -> None:
    """Regression: with only the hybrid roll-out, the L1 merit rejects every useful step once the defects are
    small (the linearisation remainders it creates exceed them: Maratos effect) and the solver stalls."""
    problem = pendulum_problem(np.array([0.2, 0.0]), dt=0.1)
    rng = np.random.default_rng(1)
    initial_xs = [rng.uniform(-10.0, 10.0, size=(41, 2))]
    initial_us = [rng.uniform(-2.0, 2.0, size=(40, 1))]
    result = MSiLQRSolver(TIGHT).solve(problem, initial_xs, initial_us)
    assert result.converged, result.status
    assert result.statistics.iterations < 60
    assert "nonlinear" in result.statistics.forward_modes
    assert result.cost == pytest.approx(MSiLQRSolver(TIGHT).solve(problem).cost, rel=1e-8)


def test_mixed_shooting_and_rollout_knots() -> None:
    problem = pendulum_problem(np.array([0.0, 0.0]), horizon=30)
    rng = np.random.default_rng(2)
    initial_xs = [rng.uniform(-1.0, 1.0, size=(31, 2))]
    rollout = [set(range(10, 20))]  # roll-out knots in the middle, shooting elsewhere
    result = MSiLQRSolver(TIGHT).solve(problem, initial_xs, None, rollout)
    assert result.converged, result.status
    assert result.defect_max < 1e-8
    assert result.phases[0].rollout_knots[10:20].all() and not result.phases[0].rollout_knots[20:].any()


def test_hybrid_bounce_meets_switching_constraint() -> None:
    dt = 0.02
    flight = Phase([PointMassFlight(dt)] * 20, PointMassFlight(None), name="flight")
    flight.switching_constraint = TouchdownConstraint()
    flight.reset_map = BounceReset(restitution=0.7)
    rebound = Phase(
        [PointMassFlight(dt)] * 20,
        PointMassFlight(None, target_height=0.4, terminal_weight=1000.0, terminal_velocity_weight=1.0),
        name="rebound",
    )
    problem = MultiPhaseProblem(x0=np.array([1.0, 0.0]), phases=[flight, rebound])
    # Without the constraint the mass would still be 0.2 m up after free fall: the AL loop has work to do.
    free_fall = evaluate_trajectory(problem, [np.zeros((21, 2)), np.zeros((21, 2))], [np.zeros((20, 1))] * 2)
    assert free_fall.defect_max > 0.1
    solver = MSiLQRSolver(SolverOptions(switching_tolerance=1e-4))
    result = solver.solve(problem)
    assert result.converged, result.status
    assert result.statistics.al_iterations > 1
    # The augmented problem is LQ (linear dynamics and reset, quadratic cost, AL terms with the Gauss-Newton
    # Hessian sigma Hx'Hx): every inner solve takes one full step.
    assert result.statistics.iterations == result.statistics.al_iterations
    assert result.statistics.step_sizes == [1.0] * result.statistics.iterations
    touchdown = result.phases[0].xs[-1]
    assert abs(touchdown[0]) < 1e-3
    assert result.switching_violation < 1e-3
    assert touchdown[1] < 0.0  # falling at touchdown
    after_impact = result.phases[1].xs[0]
    np.testing.assert_allclose(after_impact, [touchdown[0], -0.7 * touchdown[1]], atol=1e-8)
    assert result.phases[0].multiplier is not None and result.phases[0].penalty >= 20.0
    assert result.phases[1].xs[-1, 0] == pytest.approx(0.4, abs=0.05)
    # Warm start of the AL loop (as the MPC does): one AL iteration suffices.
    again = solver.solve(
        problem,
        result.xs,
        result.us,
        initial_multipliers=[p.multiplier for p in result.phases],
        initial_penalties=[p.penalty for p in result.phases],
    )
    assert again.converged and again.statistics.al_iterations == 1
    assert again.switching_violation < 1e-3


def test_a_time_budget_stop_still_updates_the_augmented_lagrangian() -> None:
    """The MPC's wall-clock stop must not freeze the touchdown multipliers and penalties: they warm-start the
    next update (a budget stop that skipped the AL update left them at their initial values forever)."""
    dt = 0.02
    flight = Phase([PointMassFlight(dt)] * 20, PointMassFlight(None), name="flight")
    flight.switching_constraint = TouchdownConstraint()
    flight.reset_map = BounceReset(restitution=0.7)
    rebound = Phase([PointMassFlight(dt)] * 20, PointMassFlight(None, target_height=0.4), name="rebound")
    problem = MultiPhaseProblem(x0=np.array([1.0, 0.0]), phases=[flight, rebound])
    options = SolverOptions(time_budget=1e-6, max_al_iterations=1, al_initial_penalty=20.0)
    result = MSiLQRSolver(options).solve(problem)
    assert result.status == "time_budget"
    phase = result.phases[0]
    assert result.switching_violation > options.al_update_threshold
    assert phase.penalty == pytest.approx(20.0 * options.al_penalty_growth)  # updated after the stop
    assert result.policy_valid  # the final backward sweep priced the updated AL terms


def test_torque_limit_through_relaxed_barrier() -> None:
    barrier = RelaxedBarrier(delta=0.01, eps=0.1)
    weights = {"torque_weight": 0.01, "terminal_weight": 10.0}
    problem = pendulum_problem(np.array([0.0, 0.0]), horizon=60, torque_limit=1.0, barrier=barrier, **weights)
    unconstrained = MSiLQRSolver(TIGHT).solve(pendulum_problem(np.array([0.0, 0.0]), horizon=60, **weights))
    assert np.max(np.abs(unconstrained.us[0])) > 2.0  # the limit would be violated without the barrier
    result = MSiLQRSolver(TIGHT).solve(problem)
    assert result.converged, result.status
    largest = np.max(np.abs(result.us[0]))
    assert largest > 0.95  # the limit is active
    assert result.inequality_violation < 1e-2
    assert largest < 1.0 + 1e-2


def test_value_gradient_matches_finite_differences() -> None:
    options = SolverOptions(max_iterations=300, defect_tolerance=1e-12, cost_change_tolerance=1e-14)
    x0 = np.array([0.3, -0.5])
    result = MSiLQRSolver(options).solve(two_phase_pendulum(x0))
    assert result.converged, result.status
    step = 1e-5
    gradient = np.zeros(2)
    for j in range(2):
        offset = np.zeros(2)
        offset[j] = step
        plus = MSiLQRSolver(options).solve(two_phase_pendulum(x0 + offset), result.xs, result.us)
        minus = MSiLQRSolver(options).solve(two_phase_pendulum(x0 - offset), result.xs, result.us)
        assert plus.converged and minus.converged
        gradient[j] = (plus.cost - minus.cost) / (2 * step)
    np.testing.assert_allclose(result.value_gradient, gradient, rtol=1e-5, atol=1e-7)


def test_a_result_without_the_value_function_has_the_same_policy() -> None:
    """``keep_value_function=False`` (the MPC's updates) leaves ``S``, ``s`` out of the result and nothing
    else: the same trajectory, gains and Q-function blocks; the value gradient says why it is missing."""
    x0 = np.array([0.3, -0.5])
    kept = MSiLQRSolver(SolverOptions(max_iterations=5)).solve(two_phase_pendulum(x0))
    lean = MSiLQRSolver(SolverOptions(max_iterations=5, keep_value_function=False)).solve(
        two_phase_pendulum(x0)
    )
    for mine, theirs in zip(lean.phases, kept.phases, strict=True):
        assert mine.S.shape[0] == 0 and mine.s.shape[0] == 0
        assert theirs.S.shape[0] == len(theirs.xs)
        for name in ("xs", "us", "K", "k", "Qu", "Quu", "Qux"):
            np.testing.assert_array_equal(getattr(mine, name), getattr(theirs, name), err_msg=name)
    with pytest.raises(ValueError, match="keep_value_function"):
        _ = lean.value_gradient


def test_a_result_that_borrows_the_policy_has_the_same_policy_until_the_next_solve() -> None:
    """``copy_policy=False`` (the MPC's updates): the result's ``K``, ``k``, ``Qu``, ``Quu``, ``Qux`` are the
    solver workspace's arrays, equal to an owning result's; the next solve overwrites them (an owning
    result keeps its own)."""
    x0 = np.array([0.3, -0.5])
    owning = MSiLQRSolver(SolverOptions(max_iterations=5)).solve(two_phase_pendulum(x0))
    solver = MSiLQRSolver(SolverOptions(max_iterations=5, copy_policy=False))
    borrowing = solver.solve(two_phase_pendulum(x0))
    names = ("K", "k", "Qu", "Quu", "Qux")
    for mine, theirs, work in zip(borrowing.phases, owning.phases, solver.workspace.phases, strict=True):
        for name in names:
            np.testing.assert_array_equal(getattr(mine, name), getattr(theirs, name), err_msg=name)
            assert getattr(mine, name) is getattr(work, name)
        assert not np.shares_memory(mine.xs, work.xs)  # the trajectory is always the result's own
    kept = [[getattr(phase, name).copy() for name in names] for phase in borrowing.phases]
    solver.solve(two_phase_pendulum(np.array([-0.4, 0.2])))
    changed = any(
        not np.array_equal(getattr(phase, name), before)
        for phase, arrays in zip(borrowing.phases, kept, strict=True)
        for name, before in zip(names, arrays, strict=True)
    )
    assert changed


TRAJECTORY_FIELDS = ("xs", "us", "defects", "rollout_knots", "switching_value", "multiplier", "forces")


def _trajectory_arrays(result) -> list[np.ndarray]:
    return [
        getattr(phase, name)
        for phase in result.phases
        for name in TRAJECTORY_FIELDS
        if getattr(phase, name) is not None
    ]


def test_lent_results_are_the_owning_ones_and_never_change_while_held() -> None:
    """``lend_results=True`` (the MPC's updates): the results of ``solve`` and ``feedback`` equal an owning
    solver's bit for bit, share no memory with the workspace, stay unchanged through later solves and
    feedbacks while they are held, and their buffers are reused once they are dropped. The default
    results own their arrays (no base array)."""
    first_x0, second_x0 = np.array([0.3, -0.5]), np.array([-0.4, 0.2])
    owner = MSiLQRSolver(SolverOptions(max_iterations=5))
    lender = MSiLQRSolver(SolverOptions(max_iterations=5, lend_results=True))
    owned = owner.solve(two_phase_pendulum(first_x0))
    lent = lender.solve(two_phase_pendulum(first_x0))
    assert all(array.base is None for array in _trajectory_arrays(owned))
    workspace_arrays = [
        getattr(work, name)
        for work in lender.workspace.phases
        for name in ("xs", "xs_try", "us", "us_try", "defects", "defects_try", "rollout", "multiplier")
    ]
    for mine, theirs in zip(_trajectory_arrays(lent), _trajectory_arrays(owned), strict=True):
        np.testing.assert_array_equal(mine, theirs)
        assert mine.base is not None  # rows of a lent buffer
        assert not any(np.shares_memory(mine, work) for work in workspace_arrays)
    embedded_x0 = first_x0 + np.array([0.01, -0.02])
    owned_feedback = owner.feedback(owned, embedded_x0, feedforward=0.5)
    lent_feedback = lender.feedback(lent, embedded_x0, feedforward=0.5)
    for mine, theirs in zip(lent_feedback.phases, owned_feedback.phases, strict=True):
        for name in ("xs", "us", "k", "Qu"):
            np.testing.assert_array_equal(getattr(mine, name), getattr(theirs, name), err_msg=name)
    held = [array.copy() for array in _trajectory_arrays(lent) + _trajectory_arrays(lent_feedback)]
    later = lender.solve(two_phase_pendulum(second_x0))
    lender.feedback(later, second_x0, feedforward=1.0)
    for array, before in zip(_trajectory_arrays(lent) + _trajectory_arrays(lent_feedback), held, strict=True):
        np.testing.assert_array_equal(array, before)
    buffers = {id(array.base) for array in _trajectory_arrays(lent)}
    del lent, lent_feedback, later, array, mine, theirs  # nothing refers to the lent rows any more
    again = lender.solve(two_phase_pendulum(second_x0))
    assert {id(array.base) for array in _trajectory_arrays(again)} <= buffers


def random_rotation(rng: np.random.Generator, scale: float) -> np.ndarray:
    return pin.exp3(scale * rng.standard_normal(3))


def test_quaternion_state_uses_manifold_operations() -> None:
    rng = np.random.default_rng(7)
    inertia = np.diag([0.06, 0.22, 0.27])
    target = random_rotation(rng, 1.0)
    dt, horizon = 0.05, 30
    model = RigidBodyAttitudeModel(dt, target, inertia)
    problem = MultiPhaseProblem(
        x0=np.concatenate([rotation_to_quaternion(np.eye(3)), [0.5, -0.3, 0.2]]),
        phases=[Phase([model] * horizon, RigidBodyAttitudeModel(None, target, inertia))],
    )
    state = OrientationVelocityState()
    # Infeasible guess: random orientations (up to about 2 rad from identity) and velocities on every
    # shooting knot. (Much wilder guesses can end in another local minimum that crosses log3's cut locus.)
    initial_xs = [
        np.array([state.integrate(state.zero(), 0.6 * rng.standard_normal(6)) for _ in range(horizon + 1)])
    ]
    assert evaluate_trajectory(problem, initial_xs, [np.zeros((horizon, 3))]).defect_max > 0.5
    result = MSiLQRSolver(TIGHT).solve(problem, initial_xs)
    assert result.converged, result.status
    assert result.defect_max < 1e-8
    single_shooting = MSiLQRSolver(TIGHT).solve(problem)
    assert single_shooting.converged
    assert result.cost == pytest.approx(single_shooting.cost, rel=1e-8)
    xs = result.xs[0]
    np.testing.assert_allclose(np.linalg.norm(xs[:, :4], axis=1), 1.0, atol=1e-12)
    final_error = pin.log3(target.T @ quaternion_to_rotation(xs[-1, :4]))
    assert np.linalg.norm(final_error) < 0.1
    # Roll the optimal controls out: the states must be reproduced (defects really are zero).
    data = model.create_data()
    x = problem.x0.copy()
    for k in range(horizon):
        model.calc(data, x, result.us[0][k])
        x = data.x_next.copy()
        np.testing.assert_allclose(state.difference(xs[k + 1], x), 0.0, atol=1e-7)


def test_non_finite_trial_steps_are_rejected() -> None:
    class Fragile(PendulumModel):
        """Cost becomes NaN for large torques, as a model evaluated outside its domain would."""

        def calc(self, data, x, u):  # type: ignore[override]
            super().calc(data, x, u)
            if self.dt is not None and abs(u[0]) > 3.0:
                data.cost = float("nan")

    model = Fragile(0.05)
    problem = MultiPhaseProblem(np.array([0.0, 0.0]), [Phase([model] * 40, PendulumModel(None))])
    result = MSiLQRSolver(SolverOptions(max_iterations=50)).solve(problem)
    assert np.isfinite(result.cost)
    assert np.all(np.isfinite(result.us[0])) and np.max(np.abs(result.us[0])) <= 3.0
    assert max(result.statistics.line_search_steps) > 1  # NaN trials were tried and rejected


def test_workspace_is_reused_and_warm_start_is_cheap() -> None:
    problem = pendulum_problem(np.array([0.1, 0.0]))
    solver = MSiLQRSolver(TIGHT)
    first = solver.solve(problem)
    data_ids = [id(d) for d in solver.workspace.phases[0].running_data]
    second = solver.solve(problem, first.xs, first.us)
    assert [id(d) for d in solver.workspace.phases[0].running_data] == data_ids
    assert second.converged and second.statistics.iterations <= 1
    assert second.cost == pytest.approx(first.cost, rel=1e-10)
    # A result never aliases the workspace.
    second.xs[0][:] = 0.0
    assert np.any(solver.workspace.phases[0].xs != 0.0)


def _bounce(n_flight: int, n_rebound: int) -> MultiPhaseProblem:
    flight = Phase([PointMassFlight(0.02)] * n_flight, PointMassFlight(None), name="flight")
    flight.switching_constraint = TouchdownConstraint()
    flight.reset_map = BounceReset(restitution=0.7)
    rebound = Phase(
        [PointMassFlight(0.02)] * n_rebound, PointMassFlight(None, target_height=0.4), name="rebound"
    )
    return MultiPhaseProblem(x0=np.array([1.0, 0.0]), phases=[flight, rebound])


def test_a_workspace_serving_phases_of_changing_shapes_solves_as_a_new_one() -> None:
    """Phase workspaces move between phases of other lengths, with and without a reset map and a switching
    constraint (their views of each length and their arrays of each shape are kept, holding the values of
    an earlier phase): every solve equals a new solver's, bit for bit."""
    options = SolverOptions(max_iterations=6, max_al_iterations=2)
    solver = MSiLQRSolver(options)
    names = ("xs", "us", "K", "k", "Qu", "Quu", "Qux", "S", "s", "defects", "multiplier", "switching_value")
    for lengths in ((20, 20), (10, 30), (30, 10), (20, 20), (10, 30), (30, 10)):
        mine = solver.solve(_bounce(*lengths))
        new = MSiLQRSolver(options).solve(_bounce(*lengths))
        assert mine.cost == new.cost and mine.statistics.iterations == new.statistics.iterations
        for a, b in zip(mine.phases, new.phases, strict=True):
            for name in names:
                if getattr(b, name) is not None:
                    np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_data_pool_gives_one_data_per_occurrence_and_the_same_ones_again() -> None:
    """A model object used several times in a problem gets one data object per occurrence; a later problem
    with the same objects (in another order of phases) gets the same data objects back, none new."""
    workspace = Workspace()
    shared = PendulumModel(0.05, target=1.0)
    terminal = PendulumModel(None, target=1.0, terminal_weight=1.0)
    long_phase, short_phase = Phase([shared] * 6, terminal), Phase([shared] * 3, terminal)
    workspace.setup(MultiPhaseProblem(x0=np.zeros(2), phases=[long_phase]))
    first = [id(data) for data in workspace.phases[0].running_data]
    assert len(set(first)) == 6
    workspace.setup(MultiPhaseProblem(x0=np.zeros(2), phases=[short_phase]))
    assert [id(data) for data in workspace.phases[0].running_data] == first[:3]
    workspace.setup(MultiPhaseProblem(x0=np.zeros(2), phases=[long_phase]))
    assert [id(data) for data in workspace.phases[0].running_data] == first


def test_time_budget_and_options_are_respected() -> None:
    problem = pendulum_problem(np.array([0.0, 0.0]), horizon=60)
    result = MSiLQRSolver(SolverOptions(max_iterations=3, max_al_iterations=1)).solve(problem)
    assert result.statistics.iterations == 3 and result.status == "max_iterations" and not result.converged
    assert len(result.statistics.iteration_times) == 3
    budget = MSiLQRSolver(SolverOptions(time_budget=1e-6)).solve(problem)
    assert budget.status == "time_budget" and budget.statistics.iterations == 1


def test_the_time_budget_counts_from_budget_start() -> None:
    """A caller's work before the solve (an MPC's problem build) is inside the budget: with ``budget_start``
    10 s back a 5 s budget is spent after the first iteration; from the call it lasts three."""
    import time

    problem = pendulum_problem(np.array([0.0, 0.0]), horizon=60)
    options = SolverOptions(max_iterations=3, max_al_iterations=1, time_budget=5.0)
    fresh = MSiLQRSolver(options).solve(problem)
    assert fresh.statistics.iterations == 3 and fresh.status == "max_iterations"
    late = MSiLQRSolver(options).solve(problem, budget_start=time.perf_counter() - 10.0)
    assert late.statistics.iterations == 1 and late.status == "time_budget" and late.policy_valid


def test_bad_inputs_raise() -> None:
    problem = pendulum_problem(np.array([0.0, 0.0]), horizon=5)
    solver = MSiLQRSolver()
    with pytest.raises(ValueError):
        solver.solve(problem, [np.zeros((4, 2))])
    with pytest.raises(ValueError):
        solver.solve(problem, [np.full((6, 2), np.nan)])
    with pytest.raises(ValueError):
        solver.solve(problem, rollout_knots=[[7]])


def _check_model_derivatives(model: ActionModel, x: np.ndarray, u: np.ndarray) -> None:
    """Finite-difference check of a toy model (test-only; the solver itself never differentiates)."""
    state, eps = model.state, 1e-6
    data = model.create_data()
    model.calc(data, x, u)
    model.calc_diff(data, x, u)
    x_next, cost = data.x_next.copy(), data.cost
    Fx, Lx = data.Fx.copy(), data.Lx.copy()
    for j in range(state.ndx):
        dx = np.zeros(state.ndx)
        dx[j] = eps
        probe = model.create_data()
        model.calc(probe, state.integrate(x, dx), u)
        assert (probe.cost - cost) / eps == pytest.approx(Lx[j], rel=1e-4, abs=1e-5)
        if model.nu:
            column = model.next_state.difference(x_next, probe.x_next) / eps
            np.testing.assert_allclose(column, Fx[:, j], rtol=1e-4, atol=1e-5)
    for j in range(model.nu):
        du = np.zeros(model.nu)
        du[j] = eps
        probe = model.create_data()
        model.calc(probe, x, u + du)
        np.testing.assert_allclose(
            model.next_state.difference(x_next, probe.x_next) / eps, data.Fu[:, j], atol=1e-5
        )
        assert (probe.cost - cost) / eps == pytest.approx(data.Lu[j], rel=1e-4, abs=1e-5)


def test_toy_model_derivatives() -> None:
    rng = np.random.default_rng(3)
    target = random_rotation(rng, 1.0)
    inertia = np.diag([0.06, 0.22, 0.27])
    x = OrientationVelocityState().integrate(OrientationVelocityState().zero(), rng.standard_normal(6))
    _check_model_derivatives(RigidBodyAttitudeModel(0.05, target, inertia), x, rng.standard_normal(3))
    _check_model_derivatives(RigidBodyAttitudeModel(None, target, inertia), x, np.zeros(0))
    barrier = RelaxedBarrier(delta=0.02, eps=0.05)
    pendulum = PendulumModel(0.05, torque_limit=1.0, barrier=barrier)
    _check_model_derivatives(pendulum, np.array([0.4, -0.3]), np.array([0.5]))
    _check_model_derivatives(pendulum, np.array([0.4, -0.3]), np.array([1.01]))


def test_shift_policy_matches_the_relinearized_one_to_first_order() -> None:
    """``final_policy="shift"`` returns the same trajectory as ``"relinearize"`` with one linearisation less;
    its Q-function gradient, moved to the new plan to first order, agrees with the one linearised there."""
    problem = pendulum_problem(np.array([0.3, 0.0]))
    start = MSiLQRSolver(SolverOptions(max_iterations=2, max_al_iterations=1)).solve(problem)
    results, calls = {}, {}
    for policy in ("relinearize", "shift"):
        solver = MSiLQRSolver(SolverOptions(max_iterations=1, max_al_iterations=1, final_policy=policy))
        results[policy] = solver.solve(problem, start.xs, start.us)
        calls[policy] = results[policy].statistics.linearizations
    relinearized, shifted = results["relinearize"], results["shift"]
    assert calls == {"relinearize": 2, "shift": 1}
    assert shifted.policy_valid and relinearized.policy_valid
    np.testing.assert_allclose(shifted.xs[0], relinearized.xs[0], atol=1e-12)
    # the shifted gradient is much closer to the one linearised at the new plan than the unshifted one
    unshifted = np.abs(start.phases[0].Qu - relinearized.phases[0].Qu).max()
    gap = np.abs(shifted.phases[0].Qu - relinearized.phases[0].Qu).max()
    assert gap < 0.5 * unshifted
    np.testing.assert_allclose(shifted.phases[0].Quu, relinearized.phases[0].Quu, rtol=0.05, atol=1e-6)


def test_bad_final_policy_is_rejected() -> None:
    with pytest.raises(ValueError, match="final_policy"):
        SolverOptions(final_policy="sometimes")
