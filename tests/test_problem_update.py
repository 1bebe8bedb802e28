"""The problem update in place equals a problem built afresh, and its references are the sampled ones.

``CafeProblemBuilder.build`` keeps its knots, phases and problems between updates and writes the sampled
references into stacked storage whose rows the knots read. A persistent builder is taken through a run of
updates (contact changes, the SRB tail's switches, the running roll's segments and weight sets). At every
update each knot's reference is compared with the one written plainly, knot by knot, from the reference
sampled at the same times (``expected_references``: the per-knot construction of the CAFE problem,
Sec. IV-D); at several updates the whole problem is compared field by field with the one a new builder makes
at the same time from the same state and reference. The comparisons are exact: both sides sample the same
reference at the same times.
"""

from __future__ import annotations

import numpy as np
import pytest

from cafe_mpc.assembly import load_run_config, resolve
from cafe_mpc.assembly.references import build_reference
from cafe_mpc.config import MpcSettings, VelocityCommand
from cafe_mpc.core.contacts import touchdown_flags
from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.dynamics.transition import whole_body_to_srb_state
from cafe_mpc.ocp.contact_schedule import get_gait
from cafe_mpc.ocp.knots import SRBModelFactory, WholeBodyModelFactory
from cafe_mpc.planners.base import update_solve_options
from cafe_mpc.planners.cafe import problem as problem_module
from cafe_mpc.planners.cafe.problem import BuiltProblem, CafeProblemBuilder, ModelSchedule, WarmStart
from cafe_mpc.planners.cafe.setup import build_problem
from cafe_mpc.reference.base import ReferenceWindow, switches_inside
from cafe_mpc.reference.locomotion import LocomotionReference
from cafe_mpc.solver import MSiLQRSolver

REFERENCE_FIELDS = ("state", "foot_positions", "foot_velocities", "torque", "contacts", "forces")


def _knot_summary(model) -> tuple:
    """What identifies a knot besides its reference: its type, stance, duration and weights."""
    dynamics = getattr(model, "dynamics", None)
    weights = getattr(model, "weights", None)
    return (
        type(model).__name__,
        getattr(model, "stance", None),
        getattr(dynamics, "dt", None),
        repr(weights) if weights is not None else None,
    )


def assert_same_problem(persistent: BuiltProblem, fresh: BuiltProblem) -> None:
    """Exactly the same problem: phases, knots, references, reset maps' presence, targets, x0."""
    np.testing.assert_array_equal(persistent.problem.x0, fresh.problem.x0)
    assert len(persistent.phases) == len(fresh.phases)
    for info_a, info_b in zip(persistent.phases, fresh.phases, strict=True):
        assert (info_a.kind, info_a.stance, info_a.entered_by_impact, info_a.first_knot) == (
            info_b.kind,
            info_b.stance,
            info_b.entered_by_impact,
            info_b.first_knot,
        )
        np.testing.assert_array_equal(info_a.times, info_b.times)
        np.testing.assert_array_equal(info_a.contacts, info_b.contacts)
        if info_b.fractions is not None:
            np.testing.assert_array_equal(info_a.fractions, info_b.fractions)
    for phase_a, phase_b in zip(persistent.problem.phases, fresh.problem.phases, strict=True):
        assert (phase_a.name, phase_a.dt, phase_a.horizon) == (phase_b.name, phase_b.dt, phase_b.horizon)
        assert (phase_a.reset_map is None) == (phase_b.reset_map is None)
        assert (phase_a.switching_constraint is None) == (phase_b.switching_constraint is None)
        models_a = [*phase_a.running_models, phase_a.terminal_model]
        models_b = [*phase_b.running_models, phase_b.terminal_model]
        for k, (a, b) in enumerate(zip(models_a, models_b, strict=True)):
            assert _knot_summary(a) == _knot_summary(b), f"{phase_a.name} knot {k}"
            for name in REFERENCE_FIELDS:
                if hasattr(b.reference, name):
                    np.testing.assert_array_equal(
                        getattr(a.reference, name), getattr(b.reference, name), err_msg=f"{phase_a.name} {k}"
                    )
    np.testing.assert_array_equal(persistent.srb_forces, fresh.srb_forces)
    np.testing.assert_array_equal(persistent.torque_reference, fresh.torque_reference)


def expected_references(
    builder: CafeProblemBuilder, t: float, reference
) -> tuple[list[list[dict]], np.ndarray]:
    """Per phase, per knot (the terminal last): the reference each knot must hold, written plainly from the
    reference sampled at the problem's times (whole-body knots: their row, terminal torque target zero; SRB
    knots: the projection (32) of their row, per-foot stance fractions over their interval, foothold and
    force (28) of the row where the foot's first stance inside it starts); and the whole-body knots' torque
    references."""
    robot = builder.robot
    wb_times, srb_times, tail = builder.knot_times(t, reference)
    n_w, n_s = len(wb_times) - 1, max(len(srb_times) - 1, 0)
    times = np.concatenate([wb_times, srb_times, np.asarray(tail, dtype=float)])
    window = ReferenceWindow(len(times), robot.nq, robot.nv, robot.nu, robot.n_feet)
    window.set_times(times, joint_rows=n_w + 1)
    reference.sample(window)
    state, positions, velocities = window.state, window.foot_positions, window.foot_velocities
    stance = window.stance.tolist()
    phases, first = [], 0
    for k in range(1, n_w + 1):
        if k == n_w or stance[k] != stance[first]:
            knots = [
                {
                    "state": state[i],
                    "foot_positions": positions[i],
                    "foot_velocities": velocities[i],
                    "torque": window.torque[i],
                }
                for i in range(first, k)
            ]
            knots.append(
                {
                    "state": state[k],
                    "foot_positions": positions[k],
                    "foot_velocities": velocities[k],
                    "torque": np.zeros(robot.nu),
                }
            )
            phases.append(knots)
            first = k
    torque_reference = window.torque[: n_w + 1].copy()
    if not n_s:
        return phases, torque_reference
    offset, n_feet = n_w + 1, robot.n_feet
    knots = []
    for j in range(n_s):
        a, b = float(srb_times[j]), float(srb_times[j + 1])
        starts = [(a, offset + j)] + [(s, offset + n_s + 1 + i) for i, s in enumerate(tail) if a < s < b]
        fractions = np.zeros(n_feet)
        feet, forces = positions[offset + j].copy(), window.forces[offset + j].copy()
        found = [False] * n_feet
        for index, (start, row) in enumerate(starts):
            end = starts[index + 1][0] if index + 1 < len(starts) else b
            fractions += window.stance[row] * ((end - start) / (b - a))
            for foot in range(n_feet):
                if window.stance[row, foot] and not found[foot]:
                    feet[foot], forces[foot] = positions[row, foot], window.forces[row, foot]
                    found[foot] = True
        fractions[fractions < 1e-9] = 0.0
        fractions[fractions > 1.0 - 1e-9] = 1.0
        name = reference.weight_sets[int(window.weight_set[offset + j])]
        ratio = builder.weight_factories[name][1].weight / (robot.total_mass * GRAVITY)
        knots.append(
            {
                "state": whole_body_to_srb_state(state[offset + j]),
                "foot_positions": feet,
                "contacts": fractions,
                "forces": (forces * ratio).reshape(-1),
            }
        )
    last = offset + n_s
    knots.append(
        {
            "state": whole_body_to_srb_state(state[last]),
            "foot_positions": positions[last],
            "contacts": window.stance[last].astype(float),
        }
    )
    phases.append(knots)
    return phases, torque_reference


def assert_expected_references(built: BuiltProblem, expected: tuple[list[list[dict]], np.ndarray]) -> None:
    expected, torque_reference = expected
    np.testing.assert_array_equal(built.torque_reference, torque_reference)
    for before, info in zip(built.phases[:-1], built.phases[1:], strict=True):
        after = info.stance if info.kind == "whole_body" else tuple(info.contacts[0].tolist())
        assert info.entered_by_impact == any(touchdown_flags(before.stance, after))
    assert len(built.problem.phases) == len(expected)
    for phase, knots in zip(built.problem.phases, expected, strict=True):
        models = [*phase.running_models, phase.terminal_model]
        assert len(models) == len(knots)
        for k, (model, fields) in enumerate(zip(models, knots, strict=True)):
            for name, value in fields.items():
                np.testing.assert_array_equal(
                    getattr(model.reference, name), value, err_msg=f"{phase.name} knot {k}: {name}"
                )


def _builder(
    robot, schedule: str, touchdown_on_reference: bool = False, touchdown_below_floor: bool = False
) -> CafeProblemBuilder:
    return CafeProblemBuilder(
        WholeBodyModelFactory(robot),
        SRBModelFactory(robot=robot),
        ModelSchedule.named(schedule),
        touchdown_on_reference=touchdown_on_reference,
        touchdown_below_floor=touchdown_below_floor,
    )


def _trot_case(robot):
    commands = [VelocityCommand(start=0.0, vx=0.6, yaw_rate=0.3)]
    reference = LocomotionReference(robot, get_gait("trot"), commands)
    return (lambda: _builder(robot, "S4")), reference, np.arange(0.0, 1.2, 0.013)


def _running_roll_case(robot):
    config = load_run_config("running-barrel-roll", ["simulation.duration=4"])
    reference = build_reference(resolve(config, robot))
    roll_start = reference.segments[1].start
    # through the end of the pace, the roll (its own weight set) and back into the pace
    times = np.arange(roll_start - 0.4, roll_start + 1.6, 0.02)
    return (lambda: build_problem(resolve(config, robot))), reference, times


@pytest.mark.parametrize("spare_slots", [problem_module.SPARE_SLOTS, -10])
@pytest.mark.parametrize("case", ["trot", "running-barrel-roll"])
def test_problem_updated_in_place_equals_a_fresh_one(robot, monkeypatch, case, spare_slots):
    """``spare_slots = -10``: the stacked rows end ten slots before the horizon does, so that the knots past
    them (written knot by knot: a horizon with many switches inside) are exercised too."""
    monkeypatch.setattr(problem_module, "SPARE_SLOTS", spare_slots)
    make_builder, reference, times = (_trot_case if case == "trot" else _running_roll_case)(robot)
    persistent = make_builder()
    x = robot.x_standing.copy()
    compared, structures, weight_sets = 0, set(), set()
    for index, t in enumerate(times):
        t = float(t)
        x[0] = 0.8 * t  # the measured state moves along: the re-anchored reference changes every update
        reference.update(t, x[: robot.nq], x[robot.nq :])
        built = persistent.build(t, x, reference)
        assert_expected_references(built, expected_references(persistent, t, reference))
        structures.add(tuple((info.kind, info.stance, len(info.times)) for info in built.phases))
        weight_sets.update(persistent.window.weight_set.tolist())
        if index % 9 == 4 or index == len(times) - 1:
            assert_same_problem(built, make_builder().build(t, x, reference))
            compared += 1
    assert compared >= 5
    assert len(structures) > 5  # the phases moved through the horizon
    if case == "running-barrel-roll":
        assert weight_sets == {0, 1}  # both the pace's and the roll's weight sets were built


def test_problem_objects_come_back_when_the_knots_do(robot):
    """The same knots give the same ``Phase`` and problem objects (validated once); a problem built again
    gets its own new ``x0`` and leaves the earlier ``x0`` array as it was."""
    builder = _builder(robot, "S2")
    reference = LocomotionReference(robot, get_gait("trot"), [VelocityCommand(start=0.0, vx=0.5)])
    reference.update(0.0, robot.q_standing, np.zeros(robot.nv))
    first = builder.build(0.5, robot.x_standing, reference)
    x0 = first.problem.x0
    other = robot.x_standing.copy()
    other[0] += 0.1
    second = builder.build(0.5, other, reference)
    assert second.problem is first.problem
    assert all(a is b for a, b in zip(first.problem.phases, second.problem.phases, strict=True))
    np.testing.assert_array_equal(x0, robot.x_standing)
    np.testing.assert_array_equal(second.problem.x0, other)
    third = builder.build(0.51, other, reference)
    assert third.problem is not second.problem


@pytest.mark.parametrize("gait", ["trot", "bound", "flying_pace"])
def test_locomotion_switch_times_equal_those_of_the_whole_schedule(robot, gait):
    """``LocomotionReference.switch_times`` looks only at the cached schedule's switches between ``t0`` and
    ``t1``: the same as ``switches_inside`` of all of them, for windows on and off the switch times."""
    reference = LocomotionReference(robot, get_gait(gait), [VelocityCommand(start=0.0, vx=0.5)])
    reference.update(0.0, robot.q_standing, np.zeros(robot.nv))
    for t0 in np.arange(0.0, 2.0, 0.0125):
        for length in (0.05, 0.3, 0.95):
            t0, t1 = float(t0), float(t0 + length)
            expected = switches_inside(reference.schedule(t0, t1).switch_times(), t0, t1)
            assert reference.switch_times(t0, t1) == expected


def test_composed_reference_joins_equal_those_made_without_kept_poses(robot):
    """The running roll's composed reference keeps its stored trajectory's poses between re-joins; the
    offsets and signs after each update equal those of a re-join that samples them again (re-joined at every
    update: ``join: measured``; the preset joins fixed)."""
    config = load_run_config("running-barrel-roll", ["simulation.duration=4", "reference.join=measured"])
    reference = build_reference(resolve(config, robot))
    x = robot.x_standing.copy()
    roll_start = reference.segments[1].start
    for t in np.arange(roll_start - 0.6, roll_start + 1.6, 0.1):
        x[0], x[1] = 0.8 * t, 0.01 * t
        reference.update(float(t), x[: robot.nq], x[robot.nq :])
        kept = [(segment.offset, segment.sign) for segment in reference.segments]
        reference._trajectory_poses.clear()
        reference._resolve_offsets(reference.segment_at(float(t)))
        assert [(segment.offset, segment.sign) for segment in reference.segments] == kept


def test_warm_start_reusing_its_buffers_equals_a_new_one(robot):
    """One ``WarmStart`` along receding-horizon updates (its guess arrays are reused buffers) gives the
    guesses a new ``WarmStart`` gives at every update: states, controls, roll-out masks, AL parameters."""
    builder = _builder(robot, "S2")
    reference = LocomotionReference(robot, get_gait("bound"), [VelocityCommand(start=0.0, vx=0.5)])
    reference.update(0.0, robot.q_standing, np.zeros(robot.nv))
    warm_start = WarmStart()
    solver = MSiLQRSolver(update_solve_options(MpcSettings(latency="fixed")))
    x, previous = robot.x_standing.copy(), (None, None)
    rollouts = 0
    for i in range(10):
        built = builder.build(0.03 * i, x, reference)
        guess = warm_start.guess(built, *previous)
        expected = WarmStart().guess(built, *previous)
        for name in ("xs", "us", "rollout"):
            for a, b in zip(getattr(guess, name), getattr(expected, name), strict=True):
                np.testing.assert_array_equal(a, b)
        assert guess.penalties == expected.penalties
        rollouts += sum(int(mask.sum()) for mask in guess.rollout)
        result = solver.solve(
            built.problem,
            guess.xs,
            guess.us,
            guess.rollout,
            initial_multipliers=guess.multipliers,
            initial_penalties=guess.penalties,
        )
        previous = (built, result)
        x = result.phases[0].xs[min(3, len(result.phases[0].xs) - 1)].copy()
    assert rollouts > 0  # roll-out knots came and went: the reused masks were cleared


@pytest.mark.parametrize("on_reference", [True, False])
@pytest.mark.parametrize("raised", [0.0, 0.25])
def test_touchdown_constraint_height_follows_the_reference(robot, raised, on_reference):
    """With ``mpc.touchdown_surface: reference`` Eq. (25) puts a touchdown on the surface the reference's
    feet land on: the spin's trajectory lifted by ``raised`` (a box top) lands at that height, and on the
    floor exactly at 0 (the presets' heights); with ``floor`` (the default off the height map) always at 0."""
    from dataclasses import replace

    from cafe_mpc.reference.trajectory import TrajectoryReference
    from cafe_mpc.reference.trajectory_file import load_packaged_trajectory

    spin = load_packaged_trajectory("spin", robot)
    xs = spin.xs.copy()
    xs[:, 2] += raised
    lifted = replace(spin, xs=xs)
    reference = TrajectoryReference(robot, lifted, weight_set="regular", hold_weight_set="regular")
    builder = _builder(robot, "S4", touchdown_on_reference=on_reference)
    touchdown_time = float(spin.switching_times[2])  # flight -> landing
    heights = []
    for t0 in (touchdown_time - 0.2, touchdown_time - 0.07):
        built = builder.build(t0, xs[0], reference)
        constraints = [phase.switching_constraint for phase in built.problem.phases]
        touchdowns = [c for c in constraints if c is not None and len(c.legs) == robot.n_feet]
        assert len(touchdowns) == 1
        heights.append(touchdowns[0].surface_heights.copy())
    for surface in heights:
        if raised == 0.0 or not on_reference:
            assert np.all(surface == 0.0) and not np.any(np.signbit(surface))
        else:
            np.testing.assert_allclose(surface, raised, atol=1e-12)


@pytest.mark.parametrize("raised", [0.25, -0.1])
def test_touchdown_on_the_lower_surface_reaches_below_the_floor_only(robot, raised):
    """``mpc.touchdown_surface: lower``: Eq. (25) lands a foot at the lower of the reference's foothold
    height and the floor: a trajectory lowered 10 cm (a blind descent's footholds under the estimator's
    floor) lands 10 cm down, one raised onto a 25 cm box top lands on the floor (met early, as with
    ``floor``)."""
    from dataclasses import replace

    from cafe_mpc.reference.trajectory import TrajectoryReference
    from cafe_mpc.reference.trajectory_file import load_packaged_trajectory

    spin = load_packaged_trajectory("spin", robot)
    xs = spin.xs.copy()
    xs[:, 2] += raised
    reference = TrajectoryReference(
        robot, replace(spin, xs=xs), weight_set="regular", hold_weight_set="regular"
    )
    builder = _builder(robot, "S4", touchdown_on_reference=True, touchdown_below_floor=True)
    touchdown_time = float(spin.switching_times[2])  # flight -> landing
    built = builder.build(touchdown_time - 0.07, xs[0], reference)
    constraints = [phase.switching_constraint for phase in built.problem.phases]
    touchdowns = [c for c in constraints if c is not None and len(c.legs) == robot.n_feet]
    assert len(touchdowns) == 1
    np.testing.assert_allclose(touchdowns[0].surface_heights, min(raised, 0.0), atol=1e-12)
