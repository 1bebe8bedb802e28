"""Packaged trajectories for other robots: a run picks the trajectory solved for its own robot
(``<stem>.<robot>.npz``), a robot without one gets one clear error saying how to make it, the Go2's and
Go1's backflips are feasible, planar and within their robots' limits, the Go1's backflip optimisation
lowers its defect in its first iterations, and the Go2's in-place barrel roll and the Go1's backflip turn
and land in closed loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cafe_mpc.assembly import load_run_config
from cafe_mpc.reference.trajectory_file import (
    TrajectoryFileError,
    load_packaged_trajectory,
    packaged_trajectory_path,
    packaged_trajectory_robots,
)
from cafe_mpc.robots.robot import load_robot
from cafe_mpc.trajopt.multiphase import check_trajectory
from cafe_mpc.trajopt.presets import load_task
from cafe_mpc.trajopt.retarget import resolve_task
from cafe_mpc_lab.experiments.run import run

BACKFLIP_TORQUE_FRACTIONS = {"go1": 0.8, "go2": 0.75}
"""The torque margins the shipped per-robot backflips were solved with (``constraints.torque_limit_fraction``;
docs/tasks.md, "Backflip on other robots")."""

BACKFLIP_EARLIER_PLAN = [
    "initial.position=[0.0, 0.0, 0.2383]",
    "initial.joint_positions=[0.0, -1.0, 2.0]",
    "constraints.friction_coefficient=0.6",
    "integration=explicit",
]
"""The task settings the shipped Go1 and Go2 backflips were solved with: the Mini Cheetah's earlier start,
nominal friction and body-frame step (its own backflip now plans from its standing pose, at the controller's
friction 0.4, with the world-frame step; docs/tasks.md, "Backflip from the standing pose")."""


def test_the_barrel_roll_resolves_the_trajectory_of_the_runs_robot():
    assert packaged_trajectory_path("barrel-roll", "go2").name == "barrel_roll.go2.npz"
    assert packaged_trajectory_path("barrel-roll", "mini_cheetah").name == "barrel_roll.npz"
    assert packaged_trajectory_robots("barrel-roll") == ["mini_cheetah", "go1", "go2"]
    go2 = load_robot("go2")
    trajectory = load_packaged_trajectory("barrel-roll", go2)
    assert trajectory.robot == "go2" and trajectory.xs.shape[1] == go2.nq + go2.nv
    assert trajectory.phase_contacts == ("FS", "FR-HR", "FT", "FS", "FT", "FS")
    with pytest.raises(
        TrajectoryFileError, match=r"shipped for mini_cheetah, go1, go2, not 'aliengo'.*robot=aliengo"
    ):
        load_packaged_trajectory("barrel-roll", load_robot("aliengo"))


@pytest.mark.slow
def test_closed_loop_go2_barrel_roll_takes_off_rolls_and_lands():
    """Fixed latency (20 ms, deterministic), VWBC, 2.4 s on the Go2: take-off, roll, landing and the second
    after it (about 12 s)."""
    config = load_run_config(
        "barrel-roll", ["robot=go2", "mpc.latency=fixed", "simulation.duration=2.4", "output.plots=false"]
    )
    result = run(config, None)
    task = result.metrics["task"]
    assert not result.metrics["fell"]
    assert task["max_base_height_m"] > 0.4
    assert task["roll_turned_rad"] >= 2.0 * math.pi - 0.3
    assert task["landed"] and task["upright_after"]
    assert task["roll_motor_torque_limit_violations"] == 0


@pytest.mark.parametrize("robot_name", sorted(BACKFLIP_TORQUE_FRACTIONS))
def test_shipped_backflip_of_another_robot_is_planar_and_within_its_limits(robot_name):
    """The backflip solved for the Go1 / Go2: picked for its robot, defects <= 1e-3 under the planning model,
    torques within its share of the limits (+0.2 Nm for the relaxed barrier), joint speeds within the
    robot's limits at every knot the motors drive (the post-impact knot is reported apart: docs/tasks.md),
    -2 pi about the pitch axis at the landing and a planar flip (roll and yaw under 0.05 rad: before the
    task's lateral weights the Go2's optimum rolled -0.56 and yawed +0.58 rad), made from the current task
    with the settings it was solved with."""
    robot = load_robot(robot_name)
    assert packaged_trajectory_path("backflip", robot_name).name == f"backflip.{robot_name}.npz"
    assert set(BACKFLIP_TORQUE_FRACTIONS) <= set(packaged_trajectory_robots("backflip"))
    trajectory = load_packaged_trajectory("backflip", robot)
    assert trajectory.robot == robot_name
    check = check_trajectory(robot, trajectory)
    assert check.max_defect <= 1e-3
    fraction = f"constraints.torque_limit_fraction={BACKFLIP_TORQUE_FRACTIONS[robot_name]}"
    task = resolve_task(
        load_task("backflip", [f"robot={robot_name}", fraction, *BACKFLIP_EARLIER_PLAN]), robot
    )
    assert np.all(np.abs(trajectory.us) <= np.asarray(task.constraints.torque_limits(robot)) + 0.2)
    assert check.driven_joint_speed_ratio <= 1.0
    assert check.post_impact_knots == [round(check.landing_time / trajectory.dt)]
    assert check.rotation_at_landing[1] == pytest.approx(-2.0 * math.pi, abs=0.1)
    assert abs(check.total_rotation[0]) < 0.05 and abs(check.total_rotation[2]) < 0.05
    assert check.min_leg_joint_height >= 0.0
    shipped_task = load_task(str(packaged_trajectory_path("backflip", robot_name).with_suffix(".yaml")))
    assert shipped_task == task


@pytest.mark.slow
def test_closed_loop_go1_backflip_takes_off_flips_and_lands():
    """Fixed latency (20 ms, deterministic), VWBC, 1.7 s on the Go1 with its own backflip: the push, the
    flip and the landing on four feet (the run ends before the upright criterion's second)."""
    config = load_run_config(
        "backflip", ["robot=go1", "mpc.latency=fixed", "simulation.duration=1.7", "output.plots=false"]
    )
    result = run(config, None)
    task = result.metrics["task"]
    assert not result.metrics["fell"]
    assert task["max_base_height_m"] > 0.5
    assert task["rotation_turned_rad"] <= -2.0 * math.pi + 0.3
    assert task["landed"]
    assert task["roll_motor_torque_limit_violations"] == 0
