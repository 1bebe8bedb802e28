"""Stored-trajectory reference and composed references (issue 11, parts 1 and 3): the trajectory reference
reproduces the stored knots; compositions keep x, y, yaw and the roll count continuous across joins."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cafe_mpc.config import VelocityCommand
from cafe_mpc.ocp.contact_schedule import get_gait
from cafe_mpc.reference.base import ReferenceWindow
from cafe_mpc.reference.composition import ComposedReference, heading, quaternion_multiply, yaw_quaternion
from cafe_mpc.reference.locomotion import LocomotionReference
from cafe_mpc.reference.trajectory import TrajectoryReference, foot_states, quaternion_slerp
from cafe_mpc.reference.trajectory_file import load_packaged_trajectory


@pytest.fixture(scope="module")
def trajectory(robot):
    return load_packaged_trajectory("barrel-roll", robot)


def sample(reference, times, robot) -> ReferenceWindow:
    window = ReferenceWindow(len(times), robot.nq, robot.nv, robot.nu, robot.n_feet)
    window.set_times(np.asarray(times, dtype=float))
    reference.sample(window)
    return window


def quaternion_roll(quaternions: np.ndarray) -> np.ndarray:
    """Roll angle carried by sign-continuous quaternions (mostly about x): ``2 atan2(q_x, q_w)`` unwrapped
    with the double cover's period 4 pi (a jump of the quaternion's sign would show as a 2 pi jump)."""
    return np.unwrap(2.0 * np.arctan2(quaternions[:, 0], quaternions[:, 3]), period=4.0 * math.pi)


def test_trajectory_reference_reproduces_stored_knots(robot, trajectory):
    start = 0.37
    reference = TrajectoryReference(robot, trajectory, start=start)
    n = trajectory.n_knots
    window = sample(reference, start + trajectory.times - trajectory.times[0], robot)
    np.testing.assert_allclose(window.state, trajectory.xs, atol=1e-9)
    np.testing.assert_array_equal(window.stance[:n], trajectory.contacts.astype(bool))
    np.testing.assert_allclose(window.torque[:n], trajectory.us, atol=1e-12)
    np.testing.assert_allclose(window.forces[:n], trajectory.forces, atol=1e-12)
    feet, feet_velocity = foot_states(robot, trajectory.xs)
    np.testing.assert_allclose(window.foot_positions, feet, atol=1e-9)
    np.testing.assert_allclose(window.foot_velocities, feet_velocity, atol=1e-9)
    assert set(window.weight_set.tolist()) == {reference.weight_sets.index("barrel_roll")}
    for k in range(n):
        assert reference.stance_at(start + k * trajectory.dt + 1e-7) == tuple(
            trajectory.contacts[k].astype(bool)
        )
    assert reference.end_time == pytest.approx(start + 1.25)


def test_trajectory_reference_interpolates_on_the_manifold_and_holds_outside(robot, trajectory):
    reference = TrajectoryReference(robot, trajectory, weight_set="barrel_roll", hold_weight_set="regular")
    k = 45  # mid-flight, roll rate about 12 rad/s
    middle = sample(reference, [trajectory.times[k] + 0.5 * trajectory.dt], robot)
    q = middle.state[0, :19]
    assert np.linalg.norm(q[3:7]) == pytest.approx(1.0)
    half = np.zeros(4)
    quaternion_slerp(trajectory.xs[k, 3:7], trajectory.xs[k + 1, 3:7], 0.5, half)
    np.testing.assert_allclose(q[3:7], half)
    np.testing.assert_allclose(q[:3], 0.5 * (trajectory.xs[k, :3] + trajectory.xs[k + 1, :3]))
    assert middle.stance[0].tolist() == trajectory.contacts[k].astype(bool).tolist()
    before, after = sample(reference, [-0.3, 5.0], robot).state
    np.testing.assert_allclose(before[:19], trajectory.xs[0, :19])
    np.testing.assert_allclose(after[:19], trajectory.xs[-1, :19])
    assert not before[19:].any() and not after[19:].any()
    holds = sample(reference, [-0.3, 5.0], robot)
    assert holds.stance.all() and holds.weight_set.tolist() == [1, 1]
    # the hold's torque carries the weight split over the four feet
    assert holds.forces[:, :, 2].sum(axis=1) == pytest.approx([robot.total_mass * 9.81] * 2)


def test_trajectory_reference_rejects_a_flight_at_an_end(robot, trajectory):
    bad = load_packaged_trajectory("barrel-roll", robot)
    bad.contacts = bad.contacts.copy()
    bad.forces = bad.forces.copy()
    bad.contacts[110:] = 0
    bad.forces[110:] = 0.0
    bad.phase_contacts = (*bad.phase_contacts[:-1], "FT")
    with pytest.raises(ValueError, match="last interval is a flight"):
        TrajectoryReference(robot, bad)


def test_slerp_keeps_the_sign_of_the_first_quaternion():
    q0 = np.array([0.0, 0.0, 0.0, 1.0])
    q1 = -np.array([math.sin(0.05), 0.0, 0.0, math.cos(0.05)])  # the same small rotation, other sign
    out = np.zeros(4)
    quaternion_slerp(q0, q1, 0.5, out)
    assert out[3] > 0.99 and out[0] == pytest.approx(math.sin(0.025))


def test_composition_keeps_position_yaw_and_roll_count_continuous(robot, trajectory):
    rolls = [TrajectoryReference(robot, trajectory) for _ in range(2)]
    stand = LocomotionReference(robot, get_gait("stand"), [VelocityCommand()])
    composed = ComposedReference(
        [(rolls[0], 1.25), (rolls[1], 1.25), (stand, None)],
        robot.nq,
        robot.nv,
        robot.nu,
        robot.n_feet,
        offsets=[(1.0, 2.0, 0.7), None, None],
    )
    dt = 0.002
    times = np.arange(0.0, 3.0, dt)
    window = sample(composed, times, robot)
    q = window.state[:, :19]
    # placed by the first offset
    np.testing.assert_allclose(q[0, :2], [1.0, 2.0], atol=1e-9)
    assert heading(q[0, 3:7]) == pytest.approx(0.7)
    # no jump anywhere in x, y, heading, or in the quaternion's sign
    assert np.max(np.abs(np.diff(q[:, :2], axis=0))) < 0.01
    headings = np.unwrap([heading(row) for row in q[:, 3:7]])
    assert np.max(np.abs(np.diff(headings))) < 0.05
    assert np.min(np.sum(q[1:, 3:7] * q[:-1, 3:7], axis=1)) > 0.9
    # the roll count: two full turns, read from the quaternions and from the integrated body roll rate
    local = quaternion_multiply(yaw_quaternion(-0.7), q[:, 3:7])  # undo the heading
    roll = quaternion_roll(local)
    assert np.max(np.abs(np.diff(roll))) < 0.1
    assert roll[-1] == pytest.approx(4.0 * math.pi, abs=0.15)
    integrated = np.cumsum(window.state[:, robot.nq + 3]) * dt
    assert integrated[-1] == pytest.approx(4.0 * math.pi, abs=0.15)
    # after the second roll the quaternion is back on +q (2 x double cover); in between it was -q
    assert composed.segments[1].sign == -1.0 and composed.segments[2].sign == 1.0
    # feet follow the placement: the stand after the rolls stands where the second roll ended
    end_base = sample(composed, [2.49], robot).state[0, :2]
    stand_feet = sample(composed, [2.9], robot).foot_positions[0]
    assert np.linalg.norm(stand_feet[:, :2].mean(axis=0) - end_base) < 0.1


def test_composition_maps_weight_sets_and_passes_local_measurements(robot, trajectory):
    roll = TrajectoryReference(robot, trajectory, weight_set="barrel_roll", hold_weight_set="barrel_roll")
    stand = LocomotionReference(robot, get_gait("stand"), [VelocityCommand()])
    after = LocomotionReference(robot, get_gait("stand"), [VelocityCommand()])
    composed = ComposedReference(
        [(stand, 0.5), (roll, 1.25), (after, None)],
        robot.nq,
        robot.nv,
        robot.nu,
        robot.n_feet,
    )
    assert composed.weight_sets == ("regular", "barrel_roll")
    window = sample(composed, [0.1, 1.0, 2.5], robot)
    assert window.weight_set.tolist() == [0, 1, 0]
    assert composed.segment_at(1.0) == 1 and composed.stance_at(0.5 + 0.25) == (False, True, False, True)
    # a measurement during the last stand is passed in that segment's frame (offset and sign undone)
    last = composed.segments[2]
    x, y, yaw = composed.offset_of(2)
    measured = robot.q_standing.copy()
    measured[:2] = [x + 0.03, y - 0.02]
    measured[3:7] = -quaternion_multiply(yaw_quaternion(yaw), np.array([0.0, 0.0, 0.0, 1.0]))
    composed.update(2.0, measured, np.zeros(robot.nv))
    c, s = math.cos(yaw), math.sin(yaw)
    assert last.reference.anchor_xy == pytest.approx([0.03 * c - 0.02 * s, -0.02 * c - 0.03 * s], abs=1e-9)
    placed = sample(composed, [2.0], robot).state[0]
    np.testing.assert_allclose(placed[:2], measured[:2], atol=1e-9)
    assert np.dot(placed[3:7], measured[3:7]) > 0.999


def test_composition_rejects_bad_segments(robot, trajectory):
    roll = TrajectoryReference(robot, trajectory)
    with pytest.raises(ValueError, match="only the last one may be open-ended"):
        ComposedReference([(roll, None), (roll, 1.0)], robot.nq, robot.nv, robot.nu, robot.n_feet)
    with pytest.raises(ValueError, match="duration must be > 0"):
        ComposedReference([(roll, 0.0)], robot.nq, robot.nv, robot.nu, robot.n_feet)
    with pytest.raises(ValueError, match="offset must be finite"):
        ComposedReference(
            [(roll, None)], robot.nq, robot.nv, robot.nu, robot.n_feet, offsets=[(0, math.nan, 0)]
        )
