"""The compiled sampling of the references agrees with straightforward versions.

``LocomotionReference.sample`` and ``sample_feet`` run compiled kernels (``reference.kernels``) over all knots
at once; here every field is rebuilt knot by knot from the reference's public pieces (``stance_at``,
``base_state``, ``support_factor``, ``stance_torque``, ``_swings``, ``foothold``, the Bezier swing of
``kernels.sample_foot``) and compared, across command ramps with a yaw rate (the quadrature path), an
initial stand, a gait switch, re-anchoring, and windows with times before the anchor and out of order. The
stored trajectory's compiled ``sample`` is compared with its ``sample_python``, and a composition (offset,
re-joined, with a weight-set override) with the composition written plainly.
"""

import math

import numpy as np
import pytest

from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.ocp.contact_schedule import get_gait
from cafe_mpc.reference.base import STANCE_TIME_EPS, ReferenceWindow
from cafe_mpc.reference.composition import ComposedReference, quaternion_multiply, yaw_quaternion
from cafe_mpc.reference.kernels import sample_foot
from cafe_mpc.reference.locomotion import LocomotionReference, VelocityCommand
from cafe_mpc.reference.trajectory import TrajectoryReference
from cafe_mpc.reference.trajectory_file import load_packaged_trajectory

TOLERANCE = 1e-12
JOINT_TOLERANCE = 1e-8
"""The joint angles and rates are leg inverse kinematics of the base and feet: a last-bit difference of a
base pose (the straightforward ``base_state`` rounds its 2 x 2 rotation products as numpy does) moves them
by the conditioning of the legs' Jacobians times that."""


def straightforward_feet(reference: LocomotionReference, times: np.ndarray) -> tuple[np.ndarray, ...]:
    """Stance, foot positions and velocities at ``times``: per foot, its swings and Raibert footholds in
    Python, then the Bezier swing of ``sample_foot``."""
    n, n_feet = len(times), reference.robot.n_feet
    stance = np.zeros((n, n_feet), dtype=bool)
    positions, velocities = np.zeros((n, n_feet, 3)), np.zeros((n, n_feet, 3))
    t0, t1 = min(float(times[0]), reference.anchor_time), float(max(times[-1], times[0]))
    for foot in range(n_feet):
        start_position = reference.stance_positions[foot]
        swings = reference._swings(foot, t0, t1)
        liftoffs = np.array([swing[0] for swing in swings])
        touchdowns = np.array([swing[1] for swing in swings])
        starts, ends = np.zeros((len(swings), 3)), np.zeros((len(swings), 3))
        for j, (liftoff, touchdown, stance_duration) in enumerate(swings):
            lifted = liftoff <= reference.anchor_time
            starts[j] = reference.liftoff_positions[foot] if lifted else start_position
            ends[j] = reference.foothold(foot, touchdown, stance_duration)
            start_position = ends[j]
        sample_foot(
            times,
            liftoffs,
            touchdowns,
            starts,
            ends,
            reference.stance_positions[foot],
            reference.swing_height,
            foot,
            stance,
            positions,
            velocities,
        )
    return stance, positions, velocities


def straightforward_sample(reference: LocomotionReference, times: np.ndarray) -> dict[str, np.ndarray]:
    """Every field of ``LocomotionReference.sample`` knot by knot from the public pieces."""
    robot = reference.robot
    nq = robot.nq
    _, positions, velocities = straightforward_feet(reference, times)
    state = np.zeros((len(times), nq + robot.nv))
    stance = np.zeros((len(times), robot.n_feet), dtype=bool)
    torque = np.zeros((len(times), robot.nu))
    forces = np.zeros((len(times), robot.n_feet, 3))
    for i, t in enumerate(times.tolist()):
        q, v = reference.base_state(t)
        state[i, :nq], state[i, nq:] = q, v
        stance[i] = reference.stance_at(t + STANCE_TIME_EPS)
        factor = reference.support_factor(t)
        torque[i] = reference.stance_torque(tuple(stance[i]), factor)
        forces[i, :, 2] = stance[i] * factor * reference.mass * GRAVITY
    joints, rates, _ = reference.inverse_kinematics.solve_batch(
        state[:, :7], positions, None, state[:, nq : nq + 6], velocities
    )
    state[:, 7:nq], state[:, nq + 6 :] = joints, rates
    return {
        "state": state,
        "stance": stance,
        "torque": torque,
        "forces": forces,
        "foot_positions": positions,
        "foot_velocities": velocities,
    }


def measured_state(robot, t: float) -> tuple[np.ndarray, np.ndarray]:
    """A plausible measured state at ``t``: the standing pose moved, turned and rocked a little."""
    q = robot.q_standing.copy()
    yaw, roll = 0.3 * t, 0.05 * np.sin(3.0 * t)
    q[0], q[1], q[2] = 0.4 * t, 0.1 * np.sin(t), q[2] - 0.01 * np.cos(5.0 * t)
    half_yaw, half_roll = 0.5 * yaw, 0.5 * roll
    q[3:7] = [
        np.sin(half_roll) * np.cos(half_yaw),
        np.sin(half_roll) * np.sin(half_yaw),
        np.cos(half_roll) * np.sin(half_yaw),
        np.cos(half_roll) * np.cos(half_yaw),
    ]
    q[7:] += 0.05 * np.sin(np.arange(robot.nu) + 7.0 * t)
    v = 0.1 * np.cos(np.arange(robot.nv) + t)
    return q, v


@pytest.mark.parametrize("switch", [False, True, "restart"])
def test_compiled_sample_matches_the_straightforward_one(robot, switch):
    commands = [
        VelocityCommand(start=0.0, vx=0.5, yaw_rate=0.4),
        VelocityCommand(start=0.9, vx=0.2, vy=0.2, yaw_rate=-0.6, height=0.25),
        VelocityCommand(start=1.6, vx=0.6),
    ]
    reference = LocomotionReference(robot, get_gait("trot"), commands, start_stance=0.3, command_ramp=0.4)
    if switch:
        reference.set_gait(0.8, "pace")
        reference.set_gait(1.5, "bound")
    window = ReferenceWindow(80, robot.nq, robot.nv, robot.nu, robot.n_feet)
    for t in np.arange(0.0, 2.6, 0.13):
        if switch == "restart" and abs(t - 1.04) < 1e-6:  # held by the safe ladder, then taken back
            reference.restart_gait(float(t), math.inf)
        if switch == "restart" and abs(t - 1.56) < 1e-6:
            reference.restart_gait(float(t), 0.3)
        q, v = measured_state(robot, float(t))
        reference.update(float(t), q, v)
        whole_body = t + np.concatenate([[0.0, 0.004], 0.004 + 0.01 * np.arange(1, 40)])
        tail = whole_body[-1] + 0.05 * np.arange(1, 9)
        times = np.concatenate([t - 0.03 + np.zeros(1), whole_body, tail, [t + 0.2, t + 0.45]])
        for window_times in (times, times[1:], np.full(3, t + 0.1)):
            window.set_times(window_times)
            reference.sample(window)
            expected = straightforward_sample(reference, window.times.copy())
            nq = robot.nq
            joints = np.r_[7:nq, nq + 6 : nq + robot.nv]
            others = np.setdiff1d(np.arange(nq + robot.nv), joints)
            for name, values in expected.items():
                got = getattr(window, name)
                if name == "state":
                    np.testing.assert_allclose(
                        got[:, joints], values[:, joints], rtol=0, atol=JOINT_TOLERANCE
                    )
                    got, values = got[:, others], values[:, others]
                np.testing.assert_allclose(got, values, rtol=0, atol=TOLERANCE, err_msg=f"{name} at t = {t}")
            assert np.all(window.weight_set == 0)


def test_feet_match_the_straightforward_version(robot):
    reference = LocomotionReference(robot, get_gait("bound"), [VelocityCommand(vx=0.8, yaw_rate=0.5)])
    for t in (0.0, 0.37, 0.81):
        q, v = measured_state(robot, t)
        reference.update(t, q, v)
        times = t + np.linspace(-0.05, 0.9, 57)
        for got, expected in zip(reference.feet(times), straightforward_feet(reference, times), strict=True):
            np.testing.assert_allclose(got, expected, rtol=0, atol=TOLERANCE)


def windows_over(reference_end: float, capacity: int = 90) -> list[np.ndarray]:
    """Windows of MPC-like times (a fractional first knot, 0.01 s knots, a 0.05 s tail, two switch times
    out of order) from before a reference's start to past its end."""
    windows = []
    for t in np.arange(-0.2, reference_end + 0.3, 0.0737):
        whole_body = t + np.concatenate([[0.0, 0.0043], 0.0043 + 0.01 * np.arange(1, 55)])
        tail = whole_body[-1] + 0.05 * np.arange(1, 9)
        times = np.concatenate([whole_body, tail, [t + 0.21, t + 0.13]])
        windows.append(np.maximum(times[:capacity], 0.0))
    return windows


def fields(window: ReferenceWindow) -> dict[str, np.ndarray]:
    names = ("stance", "state", "torque", "forces", "foot_positions", "foot_velocities", "weight_set")
    return {name: getattr(window, name).copy() for name in names}


def test_compiled_trajectory_sample_matches_the_python_one(robot):
    trajectory = load_packaged_trajectory("barrel-roll", robot)
    reference = TrajectoryReference(
        robot, trajectory, start=0.3, weight_set="barrel_roll", hold_weight_set="a"
    )
    compiled = ReferenceWindow(90, robot.nq, robot.nv, robot.nu, robot.n_feet)
    python = ReferenceWindow(90, robot.nq, robot.nv, robot.nu, robot.n_feet)
    knots = 0.3 + trajectory.times - trajectory.times[0]
    for times in [*windows_over(reference.end_time), knots[:90], knots[-60:] + 1e-12, knots[:40] - 1e-9]:
        compiled.set_times(times)
        python.set_times(times)
        reference.sample(compiled)
        reference.sample_python(python)
        for name, values in fields(python).items():
            np.testing.assert_allclose(getattr(compiled, name), values, rtol=0, atol=TOLERANCE, err_msg=name)


def composed_sample_python(reference, window: ReferenceWindow) -> None:
    """``ComposedReference.sample`` written plainly: the owner segment of each time by ``segment_at``, each
    segment's rows sampled in its own time and placed by numpy (``quaternion_multiply``)."""
    times = window.times
    local = ReferenceWindow(window.capacity, reference.nq, reference.nv, reference.nu, reference.n_feet)
    owner = np.array([reference.segment_at(float(t)) for t in times])
    for index in np.unique(owner):
        segment = reference.segments[int(index)]
        rows = np.flatnonzero(owner == index)
        local.set_times(times[rows] - segment.start)
        segment.reference.sample(local)
        state = local.state.copy()
        x, y, yaw = segment.offset or (0.0, 0.0, 0.0)
        c, s = np.cos(yaw), np.sin(yaw)
        px, py = state[:, 0].copy(), state[:, 1].copy()
        state[:, 0], state[:, 1] = c * px - s * py + x, s * px + c * py + y
        state[:, 3:7] = quaternion_multiply(yaw_quaternion(yaw), state[:, 3:7]) * segment.sign
        rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        window.state[rows] = state
        window.stance[rows] = local.stance
        window.torque[rows] = local.torque
        window.forces[rows] = local.forces @ rotation.T
        window.foot_positions[rows] = local.foot_positions @ rotation.T + np.array([x, y, 0.0])
        window.foot_velocities[rows] = local.foot_velocities @ rotation.T
        names = segment.reference.weight_sets if segment.weight_set is None else (segment.weight_set,)
        mapping = np.array([reference.weight_sets.index(name) for name in names])
        window.weight_set[rows] = mapping[local.weight_set if segment.weight_set is None else 0]


def test_compiled_composition_matches_the_plain_one(robot):
    trajectory = load_packaged_trajectory("barrel-roll", robot)
    pace = LocomotionReference(robot, get_gait("pace"), [VelocityCommand(vx=0.6, yaw_rate=0.3)])
    roll = TrajectoryReference(robot, trajectory)
    after = LocomotionReference(robot, get_gait("trot"), [VelocityCommand(vx=0.4)], start_stance=0.2)
    composed = ComposedReference(
        [(pace, 1.0), (roll, roll.end_time), (after, None)],
        robot.nq,
        robot.nv,
        robot.nu,
        robot.n_feet,
        offsets=[(0.2, -0.1, 0.4), None, None],
        weight_sets=[None, None, "after"],
        rejoin=True,
    )
    compiled = ReferenceWindow(90, robot.nq, robot.nv, robot.nu, robot.n_feet)
    plain = ReferenceWindow(90, robot.nq, robot.nv, robot.nu, robot.n_feet)
    for times in windows_over(composed.segments[-1].start + 0.5):
        t = float(times[0])
        q, v = measured_state(robot, t)
        composed.update(t, q, v)
        compiled.set_times(times)
        plain.set_times(times)
        composed.sample(compiled)
        composed_sample_python(composed, plain)
        for name, values in fields(plain).items():
            np.testing.assert_allclose(getattr(compiled, name), values, rtol=0, atol=TOLERANCE, err_msg=name)


def test_joint_rows_leave_the_other_fields_and_the_first_rows_unchanged(robot):
    """``ReferenceWindow.joint_rows``: the first rows' joints as with all rows, the later rows at the
    nominal joints with zero rates, every other field as with all rows (also through a composition)."""
    trajectory = load_packaged_trajectory("barrel-roll", robot)
    for make in (
        lambda: LocomotionReference(robot, get_gait("trot"), [VelocityCommand(vx=0.5, yaw_rate=0.2)]),
        lambda: ComposedReference(
            [
                (LocomotionReference(robot, get_gait("pace"), [VelocityCommand(vx=0.4)]), 0.6),
                (TrajectoryReference(robot, trajectory), None),
            ],
            robot.nq,
            robot.nv,
            robot.nu,
            robot.n_feet,
        ),
    ):
        full_reference, partial_reference = make(), make()
        full = ReferenceWindow(80, robot.nq, robot.nv, robot.nu, robot.n_feet)
        partial = ReferenceWindow(80, robot.nq, robot.nv, robot.nu, robot.n_feet)
        nq = robot.nq
        joints = np.r_[7:nq, nq + 6 : nq + robot.nv]
        for times in windows_over(1.0)[::3]:
            q, v = measured_state(robot, float(times[0]))
            full_reference.update(float(times[0]), q, v)
            partial_reference.update(float(times[0]), q, v)
            rows = 40
            full.set_times(times)
            partial.set_times(times, joint_rows=rows)
            assert partial.joint_rows == rows and full.joint_rows == len(times)
            full_reference.sample(full)
            partial_reference.sample(partial)
            expected = fields(full)
            got = fields(partial)
            np.testing.assert_array_equal(got["state"][:rows], expected["state"][:rows])
            tail = np.setdiff1d(np.arange(nq + robot.nv), joints)
            np.testing.assert_array_equal(got["state"][rows:, tail], expected["state"][rows:, tail])
            for name in ("stance", "torque", "forces", "foot_positions", "foot_velocities", "weight_set"):
                np.testing.assert_array_equal(got[name], expected[name], err_msg=name)
            if isinstance(partial_reference, LocomotionReference):  # after the rows: nominal joints, no rates
                nominal = np.tile(robot.q_standing[7:], (len(times) - rows, 1))
                np.testing.assert_array_equal(got["state"][rows:, 7:nq], nominal)
                assert not got["state"][rows:, nq + 6 :].any()
