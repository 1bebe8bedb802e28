"""Heuristic locomotion reference (Sec. VI-A): command integration, Raibert footholds, Bezier swings."""

import math

import numpy as np
import pinocchio as pin
import pytest

from cafe_mpc.ocp.contact_schedule import get_gait
from cafe_mpc.reference.locomotion import (
    LocomotionReference,
    VelocityCommand,
    cubic_bezier_blend,
    validate_command,
    yaw_from_quaternion,
)


def test_base_integrates_commands_with_yaw_rate(robot):
    reference = LocomotionReference(
        robot, get_gait("trot"), [VelocityCommand(start=0.0, vx=0.5, vy=0.0, yaw_rate=0.5)]
    )
    reference.update(0.0, robot.q_standing, np.zeros(robot.nv))
    q, v = reference.base_state(2.0)
    assert yaw_from_quaternion(q[3:7]) == pytest.approx(1.0)
    # closed form: a circle of radius vx / yaw_rate = 1 m
    assert q[0] == pytest.approx(math.sin(1.0), abs=1e-9)
    assert q[1] == pytest.approx(1.0 - math.cos(1.0), abs=1e-9)
    assert v[0] == 0.5 and v[5] == 0.5 and q[2] == robot.standing_height


def test_commands_switch_in_time(robot):
    commands = [
        VelocityCommand(start=0.0, vx=0.0),
        VelocityCommand(start=1.0, vx=0.8),
        VelocityCommand(start=2.0, vx=0.0, vy=0.3),
    ]
    reference = LocomotionReference(robot, get_gait("trot"), commands)
    reference.update(0.0, robot.q_standing, np.zeros(robot.nv))
    assert reference.base_state(0.5)[1][0] == 0.0
    assert reference.base_state(1.5)[1][0] == 0.8
    q, v = reference.base_state(3.0)
    assert q[0] == pytest.approx(0.8) and q[1] == pytest.approx(0.3) and v[1] == 0.3


def test_swing_feet_follow_bezier_and_land_on_raibert_footholds(robot):
    reference = LocomotionReference(
        robot, get_gait("trot"), [VelocityCommand(start=0.0, vx=0.5)], swing_height=0.06
    )
    reference.update(0.0, robot.q_standing, np.zeros(robot.nv))
    times = np.arange(0.0, 0.5, 0.01)
    stance, positions, velocities = reference.feet(times)
    assert stance[0].tolist() == [True, False, False, True]
    fr = 1
    apex = positions[:25, fr, 2].max()
    assert apex == pytest.approx(robot.foot_radius + 0.06, abs=1e-3)
    # lands where the Raibert heuristic says: hip at mid-stance (0.25 + 0.125 s) plus velocity feedback
    landing = positions[30, fr]
    expected_x = robot.foothold_offsets[fr, 0] + 0.5 * 0.375 + 0.03 * (0.0 - 0.5)
    assert landing[0] == pytest.approx(expected_x, abs=1e-9)
    assert landing[2] == pytest.approx(robot.foot_radius)
    # velocities are the time derivative of the positions (finite differences, swing only)
    numeric = np.gradient(positions[:25, fr], times[:25], axis=0)
    assert np.allclose(numeric[2:-2], velocities[2:-2, fr][: len(numeric) - 4], atol=0.05)
    # stance feet do not move
    assert np.allclose(positions[:25, 0], positions[0, 0])


def test_footholds_are_clamped_to_a_box_about_the_hip(robot):
    reference = LocomotionReference(
        robot, get_gait("bound"), [VelocityCommand(start=0.0, vx=2.5)], foothold_box=(0.05, 0.05)
    )
    reference.update(0.0, robot.q_standing, np.zeros(robot.nv))
    foothold = reference.foothold(0, 0.2, 0.1)
    nominal = reference.hip_xy(0.2, 0)
    assert abs(foothold[0] - nominal[0]) <= 0.05 + 1e-12


def test_normal_force_reference_shares_the_weight(robot):
    reference = LocomotionReference(robot, get_gait("trot"), [VelocityCommand()])
    forces = reference.normal_forces(np.array([[True, False, False, True], [False] * 4]))
    assert forces[0, :, 2].sum() == pytest.approx(robot.total_mass * 9.81)
    assert np.all(forces[1] == 0.0)


def test_bezier_blend():
    assert cubic_bezier_blend(0.0) == (0.0, 0.0)
    assert cubic_bezier_blend(1.0) == (1.0, 0.0)
    assert cubic_bezier_blend(0.5)[0] == pytest.approx(0.5)


@pytest.mark.parametrize(
    ("command", "message"),
    [
        (VelocityCommand(start=0.0, vx=10.0), "vx = 10"),
        (VelocityCommand(start=0.0, vx=0.5, vy=2.0), "vy = 2"),
        (VelocityCommand(start=0.0, vx=0.5, height=0.6), "height = 0.6"),
        (VelocityCommand(start=0.0, vx=0.5, yaw_rate=9.0), "yaw_rate = 9"),
    ],
)
def test_out_of_range_commands_are_rejected(robot, command, message):
    with pytest.raises(ValueError, match=message):
        validate_command(command, robot)


def test_feet_after_a_touchdown_between_anchor_and_query_stand_on_its_foothold(robot):
    """A window that starts after a touchdown (the SRB tail's) must see that swing's foothold, not where the
    foot stood before it lifted off (the bug put SRB stance feet up to 0.4 m away)."""
    reference = LocomotionReference(robot, get_gait("trot"), [VelocityCommand(start=0.0, vx=0.5)])
    reference.update(0.1, robot.q_standing, np.zeros(robot.nv))  # FR is swinging until 0.25 s
    _, whole, _ = reference.feet(np.arange(0.1, 0.4, 0.01))
    _, tail, _ = reference.feet(np.array([0.3, 0.35]))
    landed = whole[20, 1]  # FR at 0.3 s, from the window that contains its touchdown
    np.testing.assert_allclose(tail[0, 1], landed, atol=1e-12)
    assert landed[0] - robot.foot_positions(robot.q_standing)[1, 0] > 0.05  # it stepped forward
    # stance flags of a gait with an initial stand
    standing_first = LocomotionReference(robot, get_gait("bound"), [VelocityCommand()], start_stance=0.2)
    assert standing_first.stance_at(0.1) == (True, True, True, True)
    assert standing_first.stance_at(0.25) == get_gait("bound").flags_at(0.05)
    assert get_gait("bound").support_factor == pytest.approx(1.0)
    assert get_gait("trot").support_factor == pytest.approx(0.5)


def test_leg_inverse_kinematics_reaches_feet_and_matches_rates(robot):
    from cafe_mpc.dynamics.leg_inverse_kinematics import LegInverseKinematics

    ik = LegInverseKinematics(robot)
    base = robot.q_standing[:7].copy()
    feet = robot.foot_positions(robot.q_standing)
    joints, _, error = ik.solve(base, feet)
    np.testing.assert_allclose(joints, robot.q_standing[7:], atol=1e-6)
    assert error < 1e-5
    # moved feet are reached; joint rates are the derivative of the solution along a foot motion
    target = feet + np.array([0.04, -0.01, 0.03])
    velocity = np.tile([0.2, 0.1, -0.3], (4, 1))
    base_velocity = np.array([0.3, 0.0, 0.0, 0.0, 0.0, 0.1])
    joints, rates, error = ik.solve(base, target, None, base_velocity, velocity)
    q = robot.q_standing.copy()
    q[7:] = joints
    np.testing.assert_allclose(robot.foot_positions(q), target, atol=1e-5)
    dt = 1e-6
    moved_base = np.concatenate([base[:3] + dt * base_velocity[:3], base[3:7]])
    moved_base[3:7] = pin.Quaternion(pin.exp3(dt * base_velocity[3:]) @ np.eye(3)).coeffs()
    later, _, _ = ik.solve(moved_base, target + dt * velocity, joints)
    np.testing.assert_allclose((later - joints) / dt, rates, atol=1e-3)


def test_holding_the_path_turns_the_heading_back_toward_the_commanded_line(robot):
    """Trot at 0.5 m/s straight ahead from the origin: measured 1 s later 0.1 m left of the line with the
    commanded heading, a reference that holds its path (``path_gain`` 1 rad/m) heads 0.1 rad to the right,
    at most ``path_heading_limit`` for a larger error, and a reference that dead-reckons keeps the measured
    heading."""

    gait = get_gait("trot")
    q = robot.q_standing.copy()
    v = np.zeros(robot.nv)

    def heading_after(offset: float, gain: float) -> float:
        reference = LocomotionReference(
            robot, gait, [VelocityCommand(vx=0.5)], path_gain=gain, path_heading_limit=0.2
        )
        reference.update(0.0, q, v)
        moved = q.copy()
        moved[:2] += (0.5, offset)
        reference.update(1.0, moved, v)
        return reference.anchor_yaw

    assert heading_after(0.1, 1.0) == pytest.approx(-0.1)
    assert heading_after(-0.1, 1.0) == pytest.approx(0.1)
    assert heading_after(1.0, 1.0) == pytest.approx(-0.2)
    assert heading_after(0.1, 0.0) == pytest.approx(0.0)


def test_a_path_anchor_places_the_base_reference_and_footholds_on_the_line(robot):
    """Trot at 0.5 m/s from the origin, measured 1 s later 0.04 m left of the line: with ``path_anchor`` 1
    the reference's base and the next footholds sit on the line (the footholds 0.04 m right of where the
    measurement alone puts them; the stance feet stay where they stand), with 0.5 halfway, and without it
    at the measurement; a path anchor without a path is refused."""

    gait = get_gait("trot")
    q = robot.q_standing.copy()
    v = np.zeros(robot.nv)

    def after(offset: float, anchor: float) -> tuple[float, np.ndarray]:
        reference = LocomotionReference(
            robot, gait, [VelocityCommand(vx=0.5)], path_gain=1.0, path_heading_limit=0.0, path_anchor=anchor
        )
        reference.update(0.0, q, v)
        moved = q.copy()
        moved[:2] += (0.5, offset)
        reference.update(1.0, moved, v)
        xy, _ = reference.base_pose(1.2)
        _, positions, _ = reference.feet(np.linspace(1.0, 1.5, 51))
        return float(xy[1]), positions[..., 1]

    base_on_line, feet_on_line = after(0.04, 1.0)
    base_measured, feet_measured = after(0.04, 0.0)
    base_halfway, _ = after(0.04, 0.5)
    assert base_on_line == pytest.approx(0.0, abs=1e-9)
    assert base_measured == pytest.approx(0.04, abs=1e-9)
    assert base_halfway == pytest.approx(0.02, abs=1e-9)
    assert after(0.0, 1.0)[0] == pytest.approx(0.0, abs=1e-9)
    shift = feet_on_line - feet_measured  # the swings move toward their new footholds, which moved 0.04 m
    assert shift.min() == pytest.approx(-0.04, abs=1e-6)
    assert shift.max() <= 1e-9
    with pytest.raises(ValueError, match="path_anchor"):
        LocomotionReference(robot, gait, [VelocityCommand(vx=0.5)], path_anchor=0.5)


def test_a_foot_on_the_ground_before_its_touchdown_advances_the_gaits_clock(robot):
    """Pronk (0.1 s stance, 0.2 s flight): measured standing (every foot on the ground) 50 ms before the
    planned touchdown, the reference's clock jumps 50 ms ahead so that its stance starts now; 10 ms before
    (under the 15 ms lead) or in the middle of the flight (outside the 80 ms window) it keeps its clock, and
    without touchdown events it never moves."""

    gait = get_gait("pronk")
    stance, flight = gait.cycle[0][1], gait.cycle[1][1]
    touchdown = stance + flight  # the second stance's planned start (cycle start 0)
    events = (0.015, 0.08, 0.02)
    q = robot.q_standing.copy()
    v = np.zeros(robot.nv)

    def measured_at(t: float, events=events) -> LocomotionReference:
        reference = LocomotionReference(robot, gait, [VelocityCommand()], touchdown_events=events)
        reference.update(t, q, v)
        return reference

    early = measured_at(touchdown - 0.05)
    assert early.phase_advances == 1 and early.phase_advance_total == pytest.approx(0.05)
    assert early.stance_at(touchdown - 0.05 + 1e-6) == (True, True, True, True)
    assert early.switch_times(touchdown - 0.05, touchdown + 0.5)[0] == pytest.approx(
        touchdown - 0.05 + stance
    )
    assert measured_at(touchdown - 0.01).phase_advances == 0
    assert measured_at(stance + 0.05).phase_advances == 0
    assert measured_at(touchdown - 0.05, events=None).phase_advances == 0
    lifted = q.copy()
    lifted[2] += 0.05  # every foot 5 cm above the ground: in flight, as planned
    reference = LocomotionReference(robot, gait, [VelocityCommand()], touchdown_events=events)
    reference.update(touchdown - 0.05, lifted, v)
    assert reference.phase_advances == 0
