"""CAFE problem construction (Sec. IV-D), warm start (Fig. 5) and a short MPC closed loop."""

import itertools
from dataclasses import replace

import numpy as np
import pytest

from cafe_mpc.config import MpcSettings, VelocityCommand
from cafe_mpc.control.inline import InlineMpcLoop
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.dynamics.statics import static_stance_torques
from cafe_mpc.low_level.riccati import RiccatiController
from cafe_mpc.ocp.contact_schedule import get_gait
from cafe_mpc.ocp.knots import SRBModelFactory, WholeBodyModelFactory
from cafe_mpc.planners.base import first_solve_options, update_solve_options
from cafe_mpc.planners.cafe.planner import RecedingHorizonMpc
from cafe_mpc.planners.cafe.problem import CafeProblemBuilder, ModelSchedule, WarmStart
from cafe_mpc.reference.locomotion import LocomotionReference
from cafe_mpc.solver import MSiLQRSolver
from cafe_mpc_lab.sim.loop import SimulationOptions, simulate
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant


def _builder(robot, schedule):
    return CafeProblemBuilder(WholeBodyModelFactory(robot), SRBModelFactory(robot=robot), schedule)


def _reference(robot, gait, vx=0.5):
    reference = LocomotionReference(robot, get_gait(gait), [VelocityCommand(start=0.0, vx=vx)])
    reference.update(0.0, robot.q_standing, np.zeros(robot.nv))
    return reference


def test_phases_split_at_contact_changes_and_srb_tail(robot):
    built = _builder(robot, ModelSchedule.named("S4")).build(0.2, robot.x_standing, _reference(robot, "trot"))
    kinds = [(info.kind, info.stance, len(info.times) - 1) for info in built.phases]
    assert kinds == [
        ("whole_body", (True, False, False, True), 5),
        ("whole_body", (False, True, True, False), 20),
        ("srb", None, 8),
    ]
    assert built.phases[1].entered_by_impact
    # touchdown of FR and HL at t = 0.25: switching constraint on the first phase, impact reset
    assert built.problem.phases[0].switching_constraint is not None
    assert built.phases[2].times[0] == pytest.approx(0.45)


def test_schedule_s0_has_no_tail_and_bad_schedules_are_rejected(robot):
    built = _builder(robot, ModelSchedule.named("S0")).build(
        0.0, robot.x_standing, _reference(robot, "bound")
    )
    assert all(info.kind == "whole_body" for info in built.phases)
    assert [info.stance for info in built.phases][:2] == [(True, True, False, False), (False,) * 4]
    with pytest.raises(ValueError, match="shorter than one whole-body knot"):
        ModelSchedule(0.005, 0.5)
    with pytest.raises(ValueError, match="unknown model schedule"):
        ModelSchedule.named("S7")


def test_warm_start_shifts_by_time_and_rolls_out_after_impacts(robot):
    builder = _builder(robot, ModelSchedule.named("S2"))
    reference = _reference(robot, "trot")
    first = builder.build(0.0, robot.x_standing, reference)
    guess = WarmStart().guess(first, None, None)
    solution = MSiLQRSolver(update_solve_options(MpcSettings(latency="fixed"))).solve(
        first.problem, guess.xs, guess.us, guess.rollout
    )
    second = builder.build(0.02, solution.phases[0].xs[2], reference)
    shifted = WarmStart().guess(second, first, solution)
    # knot k of the new problem is knot k + 2 of the previous one
    assert np.allclose(shifted.xs[0][5], solution.phases[0].xs[7])
    assert np.allclose(shifted.us[0][5], solution.phases[0].us[7])
    # the appended phase entered through an impact gets roll-out knots (Fig. 5)
    assert second.phases[1].entered_by_impact
    assert shifted.rollout[1][1:].all() and not shifted.rollout[0].any()
    # the touchdown constraint of the same switch keeps its AL multiplier and penalty;
    # a new switch starts afresh
    assert first.phases[0].times[-1] == pytest.approx(second.phases[0].times[-1])
    np.testing.assert_array_equal(shifted.multipliers[0], solution.phases[0].multiplier)
    assert shifted.penalties[0] == solution.phases[0].penalty
    assert all(m is None for m in shifted.multipliers[2:])
    # appended knots take the knot's torque reference (the static torques of that phase's stance)
    appended = second.phases[1]
    np.testing.assert_allclose(
        shifted.us[1][-1], second.torque_reference[appended.first_knot + len(shifted.us[1]) - 1]
    )


def _mpc_updates(robot, builder_for, solver_for, updates=8, gait="trot"):
    """Receding-horizon updates (S2, 0.02 s apart, each from the previous plan's state at the new time);
    ``builder_for(i)``/``solver_for(i)`` choose the builder and solver of update ``i``."""
    reference = _reference(robot, gait)
    x, previous, results = robot.x_standing.copy(), None, []
    settings = MpcSettings(latency="fixed")  # no wall-clock budget: deterministic
    for i in range(updates):
        built = builder_for(i).build(0.02 * i, x, reference)
        guess = WarmStart().guess(built, *(previous or (None, None)))
        options = first_solve_options() if i == 0 else update_solve_options(settings)
        result = solver_for(i, options).solve(
            built.problem,
            guess.xs,
            guess.us,
            guess.rollout,
            initial_multipliers=guess.multipliers,
            initial_penalties=guess.penalties,
        )
        # the updates' results borrow the solver's policy arrays (``copy_policy=False``): keep the gains
        results.append(replace(result, phases=[replace(phase, K=phase.K.copy()) for phase in result.phases]))
        previous = (built, result)
        x = result.phases[0].xs[2].copy()
    return results


@pytest.mark.parametrize("gait", ["trot", "bound"])
def test_persistent_problem_equals_a_fresh_one_across_contact_changes(robot, gait):
    """Knots, their data and the solver workspace persist between updates (references written in place); the
    solutions equal those of problems and solvers built afresh at every update, across contact changes."""
    persistent_builder = _builder(robot, ModelSchedule.named("S2"))
    solvers = {}

    def persistent_solver(i, options):
        return solvers.setdefault(i == 0, MSiLQRSolver(options))

    persistent = _mpc_updates(robot, lambda i: persistent_builder, persistent_solver, gait=gait)
    fresh = _mpc_updates(
        robot,
        lambda i: _builder(robot, ModelSchedule.named("S2")),
        lambda i, options: MSiLQRSolver(options),
        gait=gait,
    )
    phase_counts = {len(result.phases) for result in persistent}
    assert len(phase_counts) > 1 or gait == "trot"  # the phase structure changes along the way
    for a, b in zip(persistent, fresh, strict=True):
        assert len(a.phases) == len(b.phases)
        for pa, pb in zip(a.phases, b.phases, strict=True):
            np.testing.assert_allclose(pa.xs, pb.xs, atol=1e-9)
            np.testing.assert_allclose(pa.us, pb.us, atol=1e-9)
            np.testing.assert_allclose(pa.K, pb.K, atol=1e-9 * max(1.0, np.abs(pb.K).max()))
        assert a.statistics.iterations == b.statistics.iterations
    # persistent knots: the second update already reuses the first one's knot objects and data
    built_a = persistent_builder.build(0.5, robot.x_standing, _reference(robot, gait))
    built_b = persistent_builder.build(0.5, robot.x_standing, _reference(robot, gait))
    assert built_a.problem.phases[0].running_models[0] is built_b.problem.phases[0].running_models[0]


@pytest.mark.parametrize("scheme", ["one_phase", "rti"])
def test_mpc_closed_loop_stands(robot, scheme):
    reference = LocomotionReference(robot, get_gait("stand"), [VelocityCommand()])
    controller = InlineMpcLoop(
        robot,
        RecedingHorizonMpc(
            robot,
            reference,
            _builder(robot, ModelSchedule.named("S1")),
            MpcSettings(period=0.02, latency="fixed", scheme=scheme),  # deterministic: 15 updates in 0.3 s
        ),
        RiccatiController(robot),
    )
    log = simulate(MujocoPlant(robot), controller, SimulationOptions(0.3))
    assert not log.fell
    statistics = controller.statistics
    assert len(statistics.latencies) == 14 and statistics.failures == 0  # the last plan acts at 0.3 s
    if scheme == "rti":  # the cold solve, then one preparation per update (the last one for t = 0.3 s)
        assert statistics.solves == 16 and len(statistics.prepare_times) == 15
        assert len(statistics.feedback_times) == 14
    else:
        assert statistics.solves == 15 and not statistics.prepare_times
    assert controller.statistics.fallback_ticks == 0
    assert np.all(np.isfinite(log.torque_command))
    assert abs(log.q[-1, 2] - robot.standing_height) < 0.02


class _RecordingRiccati(RiccatiController):
    def __init__(self, robot):
        super().__init__(robot)
        self.activations: list[tuple[float, float]] = []  # (plan start time, tick time it took effect)
        self.contacts: list[np.ndarray] = []  # the measured contacts of every tick

    def compute(self, t, measurement, plan):
        if not self.activations or self.activations[-1][0] != plan.start_time:
            self.activations.append((plan.start_time, t))
        self.contacts.append(measurement.contacts.copy())
        return super().compute(t, measurement, plan)


@pytest.mark.parametrize(("scheme", "compensated"), [("one_phase", False), ("rti", False), ("rti", True)])
@pytest.mark.parametrize("latency", [0.02, 0.05])
def test_plans_take_effect_after_their_latency(robot, latency, scheme, compensated):
    """Policy lag: each plan drives the robot from ``measurement + latency`` on. One-phase (one worker busy
    until its plan acts): the next update starts when the worker is free, at most once per period (0.05 s
    latency: updates 0.05 s apart). Real-time iteration: a fixed latency is a transport delay, updates stay
    one period apart and several plans may be in flight; with delay compensation each plan starts at the
    time it takes effect, without it at its measurement's time."""
    reference = LocomotionReference(robot, get_gait("stand"), [VelocityCommand()])
    low_level = _RecordingRiccati(robot)
    controller = InlineMpcLoop(
        robot,
        RecedingHorizonMpc(
            robot,
            reference,
            _builder(robot, ModelSchedule.named("S0")),
            MpcSettings(
                period=0.02,
                latency="fixed",
                fixed_latency=latency,
                scheme=scheme,
                delay_compensation=compensated,
            ),
        ),
        low_level,
    )
    log = simulate(MujocoPlant(robot), controller, SimulationOptions(0.2))
    assert not log.fell
    first, *later = low_level.activations
    assert first == (pytest.approx(0.0), pytest.approx(0.0))  # the cold solve runs before the clock starts
    assert len(later) >= 3
    offset = latency if compensated else 0.0  # the plan's start after its measurement
    for start, applied in later:
        assert applied == pytest.approx(start - offset + latency, abs=1e-9)
    starts = [start for start, _ in low_level.activations]
    spacing = max(latency, 0.02) if scheme == "one_phase" else 0.02
    np.testing.assert_allclose(np.diff(starts[1:]), spacing, atol=1e-9)
    assert starts[1] == pytest.approx(0.02 + offset)
    # latencies are recorded, one per plan that took effect
    np.testing.assert_allclose(controller.statistics.latencies, [0.0] + [latency] * len(later), atol=1e-9)
    # the low-level controller sees the plant's measured contacts on every tick
    assert len(low_level.contacts) == log.ticks
    np.testing.assert_array_equal(np.array(low_level.contacts), log.contacts)


@pytest.mark.realtime
def test_measured_latency_never_uses_a_plan_before_it_exists(robot):
    """Measured mode, one-phase: a plan takes effect at the first control tick after its update's real wall
    time, never earlier; while the worker is busy no other update starts; the latencies are recorded."""
    reference = LocomotionReference(robot, get_gait("stand"), [VelocityCommand()])
    low_level = _RecordingRiccati(robot)
    controller = InlineMpcLoop(
        robot,
        RecedingHorizonMpc(
            robot,
            reference,
            _builder(robot, ModelSchedule.named("S0")),
            MpcSettings(period=0.02, latency="measured", scheme="one_phase"),
        ),
        low_level,
    )
    log = simulate(MujocoPlant(robot), controller, SimulationOptions(0.3))
    assert not log.fell
    statistics = controller.statistics
    update_times = dict(zip(statistics.start_times, statistics.update_times, strict=True))
    for start, applied in low_level.activations[1:]:
        assert applied >= start + update_times[start] - 1e-12
        assert applied - (start + update_times[start]) < 0.002 + 1e-9  # the next 500 Hz tick
    starts = statistics.start_times
    for earlier, later in itertools.pairwise(starts[1:]):
        assert later >= earlier + max(0.02, update_times[earlier]) - 1e-9
    assert len(statistics.latencies) == len(low_level.activations)
    assert update_solve_options(controller.settings).time_budget == pytest.approx(0.018)


@pytest.mark.realtime
@pytest.mark.parametrize("compute_scale", [1.0, 3.0])
def test_measured_real_time_iteration_pays_its_feedback_and_its_preparations(robot, compute_scale):
    """Measured mode, real-time iteration: a plan takes effect at the first tick after its update time plus
    its feedback phase's wall time (times ``compute_scale``), later only when the worker was still preparing;
    the next update is prepared for a control tick at least one period later and at least the preparation's
    time after the plan (never for a time it cannot be ready by, so its measurement is never stale when the
    preparations take the same time each)."""
    reference = LocomotionReference(robot, get_gait("stand"), [VelocityCommand()])
    low_level = _RecordingRiccati(robot)
    controller = InlineMpcLoop(
        robot,
        RecedingHorizonMpc(
            robot,
            reference,
            _builder(robot, ModelSchedule.named("S0")),
            MpcSettings(period=0.02, latency="measured", compute_scale=compute_scale),
        ),
        low_level,
    )
    log = simulate(MujocoPlant(robot), controller, SimulationOptions(0.3))
    assert not log.fell
    statistics = controller.statistics
    feedbacks = statistics.feedback_times
    activations = low_level.activations[1:]
    assert len(feedbacks) >= len(activations) >= 1  # how many depends on the machine: no count asserted
    for (start, applied), feedback in zip(activations, feedbacks, strict=False):
        assert applied >= start + compute_scale * feedback - 1e-12
    starts = [start for start, _ in activations]
    assert np.all(np.diff(starts) >= 0.02 - 1e-9)
    ticks = np.asarray(starts) / 0.002
    np.testing.assert_allclose(ticks, np.round(ticks), atol=1e-6)  # updates on control ticks
    assert controller.scheme == "rti"


def test_torque_and_force_targets_carry_the_gaits_average_stance_load(robot):
    """Running knots regularise torque toward the torques that hold the gait's average stance force (not
    zero), and the SRB tail's GRF targets carry the same load: twice the trot's per foot when bounding."""
    builder = _builder(robot, ModelSchedule.named("S4"))
    weight = robot.total_mass * 9.81
    for gait, factor in (("trot", 0.5), ("bound", 1.0)):
        built = builder.build(0.0, robot.x_standing, _reference(robot, gait))
        first = built.problem.phases[0].running_models[0]
        stance = built.phases[0].stance
        expected = static_stance_torques(robot, robot.q_standing, stance, factor * weight)
        np.testing.assert_allclose(first.reference.torque, expected, atol=1e-12)
        assert np.abs(first.reference.torque).max() > 1.0
        vertical = built.srb_forces.reshape(len(built.srb_forces), 4, 3)[:, :, 2]
        stance_forces = vertical[vertical > 0]
        np.testing.assert_allclose(stance_forces, factor * builder.srb.weight)


@pytest.mark.parametrize("warm_up", [0.0, 1.0])
def test_warm_up_creates_the_solver_data_of_the_next_updates(robot, warm_up):
    """After the cold solve, ``warm_up`` seconds of updates find every knot's data already made: the updates
    of a trot start (new stance patterns entering the horizon) create none; without it they do."""
    reference = LocomotionReference(robot, get_gait("trot"), [VelocityCommand(vx=0.5)], start_stance=0.2)
    settings = MpcSettings(period=0.02, latency="fixed", warm_up=warm_up)
    planner = RecedingHorizonMpc(robot, reference, _builder(robot, ModelSchedule.named("S4")), settings)
    controller = InlineMpcLoop(robot, planner, RiccatiController(robot))
    state = Measurement.of_state(robot.q_standing, np.zeros(robot.nv), np.ones(robot.n_feet, dtype=bool))
    controller.start(0.0, state)
    pool = controller.planner.solver.workspace._data
    after_cold = len(pool)
    assert controller.planner.solver.workspace is controller.planner.first_solver.workspace
    for step in range(1, 26):  # 0.5 s of updates from the measured standing state
        controller.planner.update(0.02 * step, robot.q_standing, np.zeros(robot.nv))
    created = len(pool) - after_cold
    if warm_up > 0:
        assert controller.statistics.warm_up_time is not None
        assert created == 0
    else:
        assert created > 0
