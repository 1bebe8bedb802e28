"""Robustness to timing: problems built at any start time, warm starts by time, the real-time iteration's
prepare/feedback split and the low level's zero-order hold."""

from dataclasses import replace

import numpy as np
import pytest

from cafe_mpc.config import VelocityCommand
from cafe_mpc.core.plan import interval_at
from cafe_mpc.ocp.contact_schedule import get_gait
from cafe_mpc.ocp.knots import SRBModelFactory, WholeBodyModelFactory
from cafe_mpc.planners.cafe.plan import Plan
from cafe_mpc.planners.cafe.planner import MpcSettings, RecedingHorizonMpc
from cafe_mpc.planners.cafe.problem import CafeProblemBuilder, ModelSchedule
from cafe_mpc.planners.time_grid import TIME_QUANTUM, PiecewiseTrajectory, grid_times
from cafe_mpc.reference.base import Reference
from cafe_mpc.reference.locomotion import LocomotionReference


def _builder(robot, schedule=None):
    schedule = schedule or ModelSchedule.named("S4")
    return CafeProblemBuilder(WholeBodyModelFactory(robot), SRBModelFactory(robot=robot), schedule)


def _reference(robot, gait, start_stance=0.0):
    reference = LocomotionReference(
        robot, get_gait(gait), [VelocityCommand(start=0.0, vx=0.5)], start_stance=start_stance
    )
    reference.update(0.0, robot.q_standing, np.zeros(robot.nv))
    return reference


# ------------------------------------------------------------------------------------------ knot grid
def test_grid_times_put_later_knots_on_the_absolute_grid_and_split_at_switches():
    times = grid_times(0.026, 5, 0.01)
    np.testing.assert_allclose(times, [0.026, 0.03, 0.04, 0.05, 0.06, 0.07])
    times = grid_times(0.026, 5, 0.01, switches=[0.0413, 0.05, 0.0504, 0.2])
    np.testing.assert_allclose(times, [0.026, 0.03, 0.04, 0.0413, 0.05, 0.06, 0.07])  # 0.0504 is 0.05
    np.testing.assert_allclose(grid_times(0.02, 3, 0.01), [0.02, 0.03, 0.04, 0.05])
    np.testing.assert_allclose(grid_times(0.28, 2, 0.05, first_min=0.025), [0.28, 0.35, 0.4])


@pytest.mark.parametrize("gait", ["bound", "pronk", "flying_trot"])
@pytest.mark.parametrize("t0", [0.2, 0.226, 0.254, 0.3331])
def test_a_problem_built_at_any_start_time_has_its_switches_at_the_references_times(robot, gait, t0):
    reference = _reference(robot, gait)
    built = _builder(robot).build(t0, robot.x_standing, reference)
    whole_body = [info for info in built.phases if info.kind == "whole_body"]
    end = whole_body[-1].times[-1]
    expected = reference.switch_times(t0, end)
    ends = [float(info.times[-1]) for info in whole_body[:-1]]
    np.testing.assert_allclose(ends, expected, atol=1e-9)
    for info in whole_body:  # knots after the first sit on the 10 ms grid (or on a switch)
        for t in info.times[1:]:
            on_grid = abs(t / 0.01 - round(t / 0.01)) < 1e-6
            assert on_grid or min(abs(t - s) for s in expected) < 1e-9
        for k, t in enumerate(info.times[:-1]):
            assert reference.stance_at(float(t) + 1e-6) == info.stance, (k, t)
    assert whole_body[0].times[0] == t0


def test_srb_knots_stand_for_the_share_of_their_interval_in_stance(robot):
    """A switch inside an SRB interval: per-foot stance fractions carry the schedule's impulse, and a foot
    that lands inside the interval stands on the foothold it lands on."""
    reference = _reference(robot, "bound", start_stance=0.23)  # switches at 0.23 + 0.1 k: off the 50 ms grid
    built = _builder(robot).build(0.226, robot.x_standing, reference)
    srb = built.phases[-1]
    times, fractions = srb.times, srb.fractions
    assert np.all((fractions >= 0.0) & (fractions <= 1.0))
    assert np.any((fractions > 0.01) & (fractions < 0.99))
    for j in range(len(times) - 1):
        a, b = float(times[j]), float(times[j + 1])
        samples = np.linspace(a, b, 2001)[:-1] + 0.5 * (b - a) / 2000
        expected = np.mean([reference.stance_at(float(t)) for t in samples], axis=0)
        np.testing.assert_allclose(fractions[j], expected, atol=2e-3)
        knot = built.problem.phases[-1].running_models[j]
        np.testing.assert_allclose(knot.reference.contacts, fractions[j])
        assert np.all(knot.reference.foot_positions[fractions[j] > 0, 2] < 0.05)  # on the floor


def test_reference_switch_times_match_a_scan_of_their_stance(robot):
    reference = _reference(robot, "bound", start_stance=0.2)
    for t0, t1 in ((0.0, 0.7), (0.13, 0.91), (2.3, 3.9)):
        np.testing.assert_allclose(
            reference.switch_times(t0, t1), Reference.switch_times(reference, t0, t1), atol=2e-6
        )


# ----------------------------------------------------------------------------------------- warm start
def test_a_warm_start_shifted_off_the_grid_is_the_interpolated_previous_solution(robot):
    """The previous solution, as a function of time, evaluated at the new knots: the state interpolated
    between the two knots around each new knot time, the control of the interval containing it."""
    mpc = RecedingHorizonMpc(
        robot, _reference(robot, "trot"), _builder(robot), MpcSettings(latency="fixed", warm_up=0.0)
    )
    assert mpc.update(0.0, robot.q_standing, np.zeros(robot.nv)) is not None
    previous, solution = mpc.previous
    t_new = 0.026  # 2.6 knots later: not a multiple of the knot spacing
    built = mpc.builder.build(t_new, robot.x_standing, mpc.reference)
    guess = mpc.warm_start.guess(built, previous, solution)
    old_info, old = previous.phases[0], solution.phases[0]
    manifold = previous.problem.phases[0].state
    trajectory = PiecewiseTrajectory(old_info.times, old.xs, old.us, manifold.difference, manifold.integrate)
    info = built.phases[0]
    assert info.stance == old_info.stance
    checked = 0
    for k, t in enumerate(info.times[:-1]):
        if not old_info.times[0] <= t <= old_info.times[-1]:
            continue
        np.testing.assert_allclose(guess.xs[0][k], trajectory.state_at(float(t)), atol=1e-12)
        np.testing.assert_allclose(guess.us[0][k], trajectory.control_at(float(t)), atol=1e-12)
        checked += 1
    assert checked >= 5
    # the first new knot (0.026) lies between the old knots at 0.02 and 0.03: a true interpolation
    a, b = np.searchsorted(old_info.times, t_new) - 1, np.searchsorted(old_info.times, t_new)
    alpha = (t_new - old_info.times[a]) / (old_info.times[b] - old_info.times[a])
    expected = manifold.integrate(old.xs[a], alpha * manifold.difference(old.xs[a], old.xs[b]))
    np.testing.assert_allclose(guess.xs[0][0], expected, atol=1e-12)
    np.testing.assert_allclose(guess.us[0][0], old.us[a], atol=1e-12)


# ------------------------------------------------------------------------------ real-time iteration
def _started_mpc(robot, scheme, final_policy="relinearize"):
    settings = MpcSettings(latency="fixed", warm_up=0.0, scheme=scheme, final_policy=final_policy)
    mpc = RecedingHorizonMpc(
        robot, _reference(robot, "trot"), _builder(robot, ModelSchedule.named("S1")), settings
    )
    assert mpc.update(0.0, robot.q_standing, np.zeros(robot.nv)) is not None
    return mpc


@pytest.mark.parametrize("final_policy", ["relinearize", "shift"])
def test_prepare_and_feedback_at_the_predicted_state_give_the_one_phase_plan(robot, final_policy):
    one_phase = _started_mpc(robot, "one_phase", final_policy)
    rti = _started_mpc(robot, "rti", final_policy)
    t = 0.02
    predicted = rti.predict(t)
    np.testing.assert_allclose(predicted, one_phase.predict(t), atol=0.0)
    nq = robot.nq
    assert rti.prepare(t, predicted[:nq], predicted[nq:])
    plan = rti.feedback(t, predicted[:nq], predicted[nq:])
    expected = one_phase.update(t, predicted[:nq], predicted[nq:])
    for name in ("times", "xs", "us", "K", "Quu", "Qux", "Qu", "contacts", "forces"):
        np.testing.assert_allclose(getattr(plan, name), getattr(expected, name), atol=1e-9, err_msg=name)


def test_a_perturbed_measurement_moves_the_first_control_by_the_gain_times_the_deviation(robot):
    """Feedback phase (linear): the first control moves by exactly ``K_0 dx_0`` (``dx_0``: the measurement,
    projected onto the first phase's stance, minus the predicted state), which to first order is ``K_0``
    times the perturbation."""
    rti = _started_mpc(robot, "rti")
    t = 0.02
    predicted = rti.predict(t)
    nq = robot.nq
    assert rti.prepare(t, predicted[:nq], predicted[nq:])
    _, built, prepared, template = rti.prepared
    reference_plan = rti._plan(built, prepared)
    np.testing.assert_array_equal(template.us, reference_plan.us)  # the feedback keeps its gains
    gain = reference_plan.K[0]
    perturbation = np.zeros(2 * robot.nv)
    perturbation[2], perturbation[8] = 1e-5, -2e-5  # base height, third joint (q[7 + 2])
    q = predicted[:nq].copy()
    q[2] += perturbation[2]
    q[9] += perturbation[8]
    plan = rti.feedback(t, q, predicted[nq:])
    change = plan.us[0] - reference_plan.us[0]
    measured = np.concatenate([q, predicted[nq:]])
    rti._contact_consistent(measured, built.phases[0].stance)
    dx = built.problem.phases[0].state.difference(reference_plan.xs[0], measured)
    np.testing.assert_allclose(change, gain @ dx, atol=1e-12)
    first_order = gain @ perturbation
    assert np.linalg.norm(first_order) > 1e-6
    assert np.linalg.norm(change - first_order) < 0.1 * np.linalg.norm(first_order)


def test_the_real_time_iteration_needs_a_preparation_for_the_feedbacks_time(robot):
    rti = _started_mpc(robot, "rti")
    predicted = rti.predict(0.02)
    nq = robot.nq
    assert rti.prepare(0.02, predicted[:nq], predicted[nq:])
    failures = rti.statistics.failures
    assert rti.feedback(0.024, predicted[:nq], predicted[nq:]) is None  # no preparation for 0.024 s
    assert rti.statistics.failures == failures + 1
    with pytest.raises(RuntimeError, match="first solve"):
        RecedingHorizonMpc(robot, _reference(robot, "trot"), _builder(robot)).prepare(
            0.0, robot.q_standing, np.zeros(18)
        )


# ---------------------------------------------------------------------------------------- low level
def test_the_low_level_uses_the_knot_whose_interval_contains_the_time():
    times = np.array([0.026, 0.03, 0.04, 0.05])
    assert interval_at(times, 0.0) == 0
    assert interval_at(times, 0.026) == 0
    assert interval_at(times, 0.0299) == 0  # the nearest knot would be 0.03's
    assert interval_at(times, 0.03) == 1
    assert interval_at(times, 0.0351) == 1
    assert interval_at(times, 0.049) == 2
    assert interval_at(times, 0.07) == 3
    n = len(times)
    plan = Plan(
        times=times,
        xs=np.zeros((n + 1, 37)),
        us=np.zeros((n, 12)),
        K=np.zeros((n, 12, 36)),
        Qu=np.zeros((n, 12)),
        Quu=np.tile(np.eye(12), (n, 1, 1)),
        Qux=np.zeros((n, 12, 36)),
        contacts=np.ones((n, 4), dtype=bool),
        forces=np.zeros((n, 4, 3)),
        dt=np.array([0.004, 0.01, 0.01, 0.01]),
    )
    assert plan.knot_at(0.0399) == 1 and plan.knot_at(0.04) == 2
    # the feedback phase's plan: a new trajectory over the prepared gains, checked at the boundary
    moved = plan.with_trajectory(np.ones((n + 1, 37)), np.ones((n, 12)))
    assert moved.xs[0, 0] == 1.0 and plan.xs[0, 0] == 0.0 and moved.K is plan.K and moved.Qu is plan.Qu
    assert plan.with_trajectory(plan.xs, plan.us, np.ones((n, 12))).Qu[0, 0] == 1.0
    with pytest.raises(ValueError, match="needs"):
        plan.with_trajectory(np.zeros((n, 37)), plan.us)
    bad = plan.us.copy()
    bad[1, 3] = np.nan
    with pytest.raises(ValueError, match="us contains NaN"):
        plan.with_trajectory(plan.xs, bad)


def test_time_quantum_rounds_first_knots_to_few_durations(robot):
    builder = _builder(robot)
    reference = _reference(robot, "trot")
    for t0 in np.arange(0.2, 0.3, 0.002):
        builder.build(float(t0), robot.x_standing, reference)
    durations = {key[3] for key in builder._running}
    assert durations <= {round(d / TIME_QUANTUM) for d in (0.002, 0.004, 0.006, 0.008, 0.01)}


def test_the_update_clock_keeps_the_period_and_leaves_room_for_slow_preparations():
    from cafe_mpc.control.update_clock import PREPARATION_HISTORY, UpdateClock

    clock = UpdateClock(period=0.02, control_period=0.002)
    assert clock.next_update(0.1, 0.1007) == pytest.approx(0.12)  # one period, on a tick
    assert clock.next_update(0.1, 0.1193) == pytest.approx(0.12)  # no preparation recorded yet
    for duration in [0.005] * (PREPARATION_HISTORY - 3) + [0.05] * 3:
        clock.record_preparation(duration)
    assert clock.expected_preparation == pytest.approx(0.005)  # three slow ones do not set the pace
    assert clock.next_update(0.1, 0.101) == pytest.approx(0.12)
    for _ in range(PREPARATION_HISTORY):
        clock.record_preparation(0.031)
    assert clock.next_update(0.1, 0.101) == pytest.approx(0.132)  # 0.101 + 0.031, on the next tick
    assert clock.tick_at_or_after(0.1320000001) == pytest.approx(0.132)


# ------------------------------------------------------------------------------------ delay compensation
def test_the_delay_predictor_carries_the_planned_state_along_its_own_plan(robot):
    """A measurement on the plan, carried with the plan's own knots (step = their dt) across a touchdown,
    lands on the plan: the roll-out is the plan's dynamics (19)-(23), impacts (22) and Riccati law (33)."""
    from cafe_mpc.planners.base import first_solve_options
    from cafe_mpc.planners.cafe.prediction import DelayPredictor
    from cafe_mpc.solver import MSiLQRSolver

    builder = _builder(robot, ModelSchedule.named("S1"))
    settings = MpcSettings(latency="fixed", warm_up=0.0)
    mpc = RecedingHorizonMpc(robot, _reference(robot, "bound", start_stance=0.02), builder, settings)
    mpc.first_solver = MSiLQRSolver(replace(first_solve_options(), defect_tolerance=1e-10, max_iterations=60))
    mpc.first_solver.workspace = mpc.solver.workspace  # the planner's solvers share one workspace
    plan = mpc.update(0.0, robot.q_standing, np.zeros(robot.nv))
    assert plan is not None
    touchdowns = np.flatnonzero(np.any(plan.contacts[1:] & ~plan.contacts[:-1], axis=1)) + 1
    assert len(touchdowns), "the plan has a touchdown to carry across"
    end = touchdowns[0] + 2
    assert np.allclose(plan.dt[:end], plan.dt[0])
    predictor = DelayPredictor(robot, builder.whole_body)
    predictor.limits[:] = np.inf  # the cold plan asks for more than the limits at the touchdown: no clamp
    nq = robot.nq
    carried = predictor.carry(
        plan.xs[0][:nq], plan.xs[0][nq:], plan.times[0], plan.times[end], lambda t: plan
    )
    error = builder.whole_body.state.difference(plan.xs[end], carried)
    assert np.max(np.abs(error)) < 1e-8
    # and the roll-out moves: it is not the measurement handed back
    assert np.max(np.abs(builder.whole_body.state.difference(plan.xs[0], carried))) > 1e-2
    # off the plan, a knot's torque is the Riccati law (33) of the deviation, clamped to the limits
    predictor.limits[:] = robot.torque_limits
    measured = plan.xs[3].copy()
    measured[2] += 0.01  # 1 cm above the plan
    measured[nq + 2] -= 0.2  # falling 0.2 m/s faster
    carried = predictor.carry(
        measured[:nq], measured[nq:], plan.times[3], plan.times[4], lambda t: plan
    ).copy()
    deviation = builder.whole_body.state.difference(plan.xs[3], measured)
    torque = np.clip(plan.us[3] + plan.K[3] @ deviation, -robot.torque_limits, robot.torque_limits)
    assert np.max(np.abs(torque - plan.us[3])) > 0.1  # the feedback matters here
    dynamics = builder.whole_body.dynamics(tuple(bool(c) for c in plan.contacts[3]), float(plan.dt[3]))
    data = dynamics.create_data()
    dynamics.calc(data, measured, torque)
    np.testing.assert_allclose(carried, data.x_next, atol=1e-12)


@pytest.mark.parametrize(("latency", "first_knot"), [(0.03, 0.03), (0.025, 0.02)])
def test_a_compensated_plan_starts_from_the_measurement_carried_to_its_start(robot, latency, first_knot):
    """Delay compensation in the closed loop: an update measured at ``t`` is prepared for the last knot time
    at or before ``t + L`` (its first knot is whole and holds the time it takes effect) and its plan starts
    there from the measured state carried there along the plan in effect meanwhile."""
    from cafe_mpc.control.inline import InlineMpcLoop
    from cafe_mpc.core.measurement import Measurement
    from cafe_mpc.low_level.riccati import RiccatiController
    from cafe_mpc.planners.cafe.prediction import DelayPredictor

    period = 0.02
    builder = _builder(robot, ModelSchedule.named("S1"))
    controller = InlineMpcLoop(
        robot,
        RecedingHorizonMpc(
            robot,
            _reference(robot, "trot"),
            builder,
            MpcSettings(latency="fixed", fixed_latency=latency, warm_up=0.0, period=period),
        ),
        RiccatiController(robot),
    )
    assert controller.delay == latency
    q, v = robot.q_standing.copy(), np.zeros(robot.nv)
    contacts = np.ones(robot.n_feet, dtype=bool)
    controller.start(0.0, Measurement.of_state(q, v, contacts))
    cold = controller.plan
    assert controller.planner.prepared_time == pytest.approx(period + first_knot)
    q[2] += 0.01  # the next update's measurement: 1 cm above the plan
    v[0] = 0.1
    controller.compute(period, Measurement.of_state(q, v, contacts, period))
    (effective, measured_at, plan), *_ = controller.pending
    assert (effective, measured_at) == (pytest.approx(period + latency), pytest.approx(period))
    assert plan.start_time == pytest.approx(period + first_knot)
    assert plan.knot_at(effective) == 0
    expected = DelayPredictor(robot, builder.whole_body).carry(
        q, v, period, period + first_knot, lambda t: cold
    )
    np.testing.assert_allclose(plan.xs[0][: robot.nq], expected[: robot.nq], atol=1e-9)
    # the carried state is not the measured one: 20-30 ms at 0.1 m/s moved the base
    assert abs(expected[0] - q[0]) > 1e-3


def test_a_published_plan_keeps_its_gains_through_later_updates(robot):
    """The updates' results borrow the solver's policy arrays (``SolverOptions.copy_policy=False``); a plan
    must own its copies: the next preparation and feedback leave a published plan unchanged."""
    rti = _started_mpc(robot, "rti")
    nq = robot.nq
    predicted = rti.predict(0.02)
    assert rti.prepare(0.02, predicted[:nq], predicted[nq:])
    plan = rti.feedback(0.02, predicted[:nq], predicted[nq:])
    names = ("xs", "us", "K", "Qu", "Quu", "Qux", "forces")
    before = {name: getattr(plan, name).copy() for name in names}
    for t in (0.04, 0.06):
        predicted = rti.predict(t)
        assert rti.prepare(t, predicted[:nq], predicted[nq:])
        q = predicted[:nq].copy()
        q[:3] += 1e-3  # a measurement off the prediction: the feedback moves the trajectory
        later = rti.feedback(t, q, predicted[nq:])
        assert later is not None
    for name in names:
        np.testing.assert_array_equal(getattr(plan, name), before[name], err_msg=name)
