"""The ``task`` block of acrobatic runs (issue 11, part 4) on synthetic logs, and its windows from a
composed reference."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cafe_mpc.config import VelocityCommand
from cafe_mpc.ocp.contact_schedule import get_gait
from cafe_mpc.reference.composition import ComposedReference
from cafe_mpc.reference.locomotion import LocomotionReference
from cafe_mpc.reference.trajectory import TrajectoryReference
from cafe_mpc.reference.trajectory_file import load_packaged_trajectory
from cafe_mpc.robots.robot import load_robot
from cafe_mpc_lab.report.task_metrics import (
    AcrobaticTask,
    body_floor_clearance,
    task_from_reference,
    task_metrics,
    task_summary,
)
from cafe_mpc_lab.sim.loop import SimulationLog

DT = 0.002
TASK = AcrobaticTask("roll", start=0.5, takeoff=0.83, touchdown=1.25, end=1.75)


def roll_log(robot, duration=3.6, final_roll=2.0 * math.pi, z_after=None) -> SimulationLog:
    """Stand, a roll by ``final_roll`` during the flight [0.83, 1.25) s with the base lifted, then stand."""
    n = round(duration / DT)
    log = SimulationLog.allocate(n, robot.nq, robot.nv, robot.nu, robot.n_feet)
    log.ticks = n
    log.time[:] = DT * np.arange(n)
    flight = (log.time >= TASK.takeoff) & (log.time < TASK.touchdown)
    rate = final_roll / (TASK.touchdown - TASK.takeoff)
    log.v[flight, 3] = rate
    roll = np.cumsum(log.v[:, 3]) * DT
    roll = np.concatenate([[0.0], roll[:-1]])  # the state at a tick integrates the rates before it
    log.q[:] = robot.q_standing
    log.q[:, 3] = np.sin(0.5 * roll)
    log.q[:, 6] = np.cos(0.5 * roll)
    phase = (log.time[flight] - TASK.takeoff) / (TASK.touchdown - TASK.takeoff)
    log.q[flight, 2] += 0.3 * np.sin(math.pi * phase)
    if z_after is not None:
        log.q[log.time >= TASK.touchdown, 2] = z_after
    log.contacts[:] = ~flight[:, None]
    log.torque_command[:] = 3.0
    return log


def test_a_clean_roll_succeeds(robot):
    metrics = task_metrics(robot, roll_log(robot), TASK, DT)
    assert metrics["success"] is True
    assert metrics["roll_turned_rad"] == pytest.approx(2.0 * math.pi, abs=1e-6)
    assert metrics["touchdown_s"] == pytest.approx(1.25) and metrics["all_feet_down_s"] == pytest.approx(1.25)
    assert metrics["landed"] and metrics["upright_after"] and metrics["stayed_up"]
    assert metrics["max_base_height_m"] == pytest.approx(robot.standing_height + 0.3, abs=1e-3)
    assert metrics["roll_motor_torque_limit_violations"] == 0
    assert "success" in metrics["criteria"] and "landed" in metrics["criteria"]


def test_short_roll_is_not_upright(robot):
    metrics = task_metrics(robot, roll_log(robot, final_roll=2.0 * math.pi - 0.5), TASK, DT)
    assert metrics["roll_turned_rad"] == pytest.approx(2.0 * math.pi - 0.5, abs=1e-6)
    assert metrics["landed"] and not metrics["upright_after"] and not metrics["success"]
    assert metrics["tilt_max_first_second_after_landing_rad"] == pytest.approx(0.5, abs=1e-3)


def test_knees_through_the_floor_is_not_a_landing(robot):
    metrics = task_metrics(robot, roll_log(robot, z_after=0.12), TASK, DT)
    assert metrics["lowest_knee_m"] < 0.0
    assert not metrics["landed"] and not metrics["success"]


def test_a_motor_limit_violation_during_the_roll_fails(robot):
    log = roll_log(robot)
    pushing = (log.time > 0.6) & (log.time < 0.62)
    log.torque_command[pushing, 2] = 30.0  # knee motor limit 26 Nm
    requested = log.torque_command.copy()
    metrics = task_metrics(robot, log, TASK, DT, requested=requested)
    assert metrics["roll_motor_torque_limit_violations"] == pushing.sum() > 0
    assert metrics["roll_requested_torque_limit_violations"] == pushing.sum()
    assert not metrics["success"]


def test_too_short_after_landing_and_no_flight(robot):
    short = task_metrics(robot, roll_log(robot, duration=2.5), TASK, DT)
    assert short["stayed_up"] is None and short["success"] is None  # ended 1.25 s after the touchdown
    assert short["unjudged"] == {"stayed_up": "the run ended 1.25 s after the touchdown; needs 2.0 s"}
    assert (
        short["success_reason"]
        == "cannot judge: stayed_up: the run ended 1.25 s after the touchdown; needs 2.0 s"
    )
    line = task_summary(short)
    assert line.startswith("task roll: success=None (roll 6.28 rad, apex ") and "cannot judge" in line
    before_touchdown = task_metrics(robot, roll_log(robot, duration=1.0), TASK, DT)
    assert before_touchdown["success"] is None and before_touchdown["landed"] is None
    assert set(before_touchdown["unjudged"]) == {"roll_turned", "landed", "upright_after", "stayed_up"}
    tilted = task_metrics(robot, roll_log(robot, duration=2.5, final_roll=2.0 * math.pi - 0.5), TASK, DT)
    assert tilted["success"] is False and tilted["failed_criteria"] == ["roll_turned", "upright_after"]
    assert "failed: roll_turned, upright_after" in task_summary(tilted)
    assert task_summary(task_metrics(robot, roll_log(robot), TASK, DT)).startswith(
        "task roll: success=True ("
    )
    log = roll_log(robot)
    log.contacts[:] = True
    metrics = task_metrics(robot, log, TASK, DT)
    assert metrics["touchdown_s"] is None and not metrics["landed"] and not metrics["success"]


def test_clearance_of_the_standing_robot(robot):
    clearance = body_floor_clearance(robot, robot.q_standing[None, :])
    assert clearance["trunk"][0] == pytest.approx(robot.standing_height - 0.05, abs=1e-6)
    assert 0.05 < clearance["knee"][0] < 0.15 and 0.05 < clearance["thigh"][0] < 0.15


def test_clearance_of_a_model_file_robot():
    """A robot from a model file (the Go2: no ``trunk`` box, no leg capsules) is measured on its collision
    geoms and knee joints: positive standing, and the trunk below the floor when the base is sunk into it."""
    go2 = load_robot("go2")
    standing = go2.q_standing.copy()
    sunk = standing.copy()
    sunk[2] = 0.05
    clearance = body_floor_clearance(go2, np.stack([standing, sunk]))
    assert set(clearance) == {"trunk", "thigh", "knee"}
    assert 0.0 < clearance["knee"][0] < clearance["trunk"][0] < standing[2]
    assert clearance["trunk"][1] < 0.0 and clearance["knee"][1] < 0.0


def test_task_windows_from_a_composed_reference(robot):
    trajectory = load_packaged_trajectory("barrel-roll", robot)
    stand = LocomotionReference(robot, get_gait("stand"), [VelocityCommand()])
    roll = TrajectoryReference(robot, trajectory)
    composed = ComposedReference([(stand, 0.5), (roll, 1.25)], robot.nq, robot.nv, robot.nu, robot.n_feet)
    task = task_from_reference(composed)
    assert (task.start, task.takeoff, task.touchdown, task.end) == pytest.approx((0.5, 0.83, 1.25, 1.75))
    assert task_from_reference(stand) is None and task_from_reference(None) is None


def test_planar_angle_follows_a_flip_through_the_whole_turn():
    """A backward flip about the body y axis: the planar pitch reaches -2 pi (the ZYX pitch folds at
    +-pi/2 and never passes -pi/2); roll and yaw are the ZYX angles."""
    from scipy.spatial.transform import Rotation

    from cafe_mpc_lab.report.task_plots import planar_angle

    turn = np.linspace(0.0, -2.0 * np.pi, 200)
    flip = Rotation.from_rotvec(np.outer(turn, [0.0, 1.0, 0.0])).as_quat()
    np.testing.assert_allclose(planar_angle(flip, 1), turn, atol=1e-9)
    assert np.min(Rotation.from_quat(flip).as_euler("ZYX")[:, 1]) >= -0.5 * np.pi - 1e-9
    tilted = Rotation.from_euler("ZYX", np.column_stack([0.3 * turn / turn[-1], 0.1 * np.ones(200), turn]))
    np.testing.assert_allclose(planar_angle(tilted.as_quat(), 0), turn, atol=1e-9)
    np.testing.assert_allclose(planar_angle(tilted.as_quat(), 2), 0.3 * turn / turn[-1], atol=1e-9)
