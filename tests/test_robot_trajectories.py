"""Packaged trajectories for other robots: a run picks the trajectory solved for its own robot
(``<stem>.<robot>.npz``), a robot without one gets one clear error saying how to make it, and the Go2's
in-place barrel roll rolls and lands in closed loop."""

from __future__ import annotations

import math

import pytest

from cafe_mpc.assembly import load_run_config
from cafe_mpc.reference.trajectory_file import (
    TrajectoryFileError,
    load_packaged_trajectory,
    packaged_trajectory_path,
    packaged_trajectory_robots,
)
from cafe_mpc.robots.robot import load_robot
from cafe_mpc_lab.experiments.run import run


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
