"""The robot description: one table -> Pinocchio model and MuJoCo plant that agree."""

import numpy as np
import pinocchio as pin
import pytest

from cafe_mpc.robots.robot import LEG_NAMES, RobotLoadError, load_robot
from cafe_mpc_lab.sim.consistency import check_consistency


def test_mini_cheetah_planning_model(mini_cheetah):
    robot = mini_cheetah
    assert robot.model.nq == 19 and robot.model.nv == 18
    assert robot.total_mass == pytest.approx(8.252, abs=1e-9)
    assert robot.leg_names == LEG_NAMES
    assert robot.foot_frame_names == ("FL_foot", "FR_foot", "HL_foot", "HR_foot")
    assert robot.torque_limits.tolist() == [17.0] * 12
    assert robot.plant.motor_torque_limits[2] == 26.0
    # legs hang straight down at zero joint angles: foot under the hip at abad + thigh + shank lengths
    q = pin.neutral(robot.model)
    feet = robot.foot_positions(q)
    assert feet[0] == pytest.approx([0.19, 0.049 + 0.062 + 0.004, -0.209 - 0.195], abs=1e-12)
    assert feet[3] == pytest.approx([-0.19, -(0.049 + 0.062 + 0.004), -0.404], abs=1e-12)


def test_positive_hip_angle_swings_foot_forward(mini_cheetah):
    q = pin.neutral(mini_cheetah.model)
    q[7 + 1] = 0.3
    assert mini_cheetah.foot_positions(q)[0, 0] > 0.19 + 0.05


def test_standing_pose_puts_feet_on_floor(mini_cheetah):
    feet = mini_cheetah.foot_positions(mini_cheetah.q_standing)
    assert feet[:, 2] == pytest.approx([mini_cheetah.foot_radius] * 4, abs=1e-9)
    assert feet[:, :2] == pytest.approx(mini_cheetah.foothold_offsets, abs=1e-9)
    assert mini_cheetah.q_standing[2] == pytest.approx(0.25)


@pytest.mark.parametrize("name", ["mini_cheetah", "go1"])
@pytest.mark.slow
def test_pinocchio_and_mujoco_agree(name):
    result = check_consistency(load_robot(name), samples=4, seed=3)
    assert result["passed"], result
    assert result["mass_matrix_max_error"] < 1e-8


def test_plant_has_what_the_planning_model_lacks(mini_cheetah):
    import mujoco

    plant_model = mujoco.MjModel.from_xml_string(mini_cheetah.mjcf)
    assert plant_model.dof_armature[6:9] == pytest.approx([0.002268, 0.002268, 0.005484])
    assert np.all(plant_model.dof_damping[6:] == 0.01)
    assert np.all(plant_model.dof_frictionloss[6:] == 0.2)
    assert plant_model.actuator_ctrlrange[2].tolist() == [-26.0, 26.0]
    assert plant_model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    assert plant_model.geom("FL_foot").size[0] == pytest.approx(0.02)
    assert plant_model.geom("floor").friction[0] == pytest.approx(0.6)


def test_bad_robot_files_give_clear_errors(tmp_path):
    with pytest.raises(RobotLoadError, match="unknown robot"):
        load_robot("no_such_robot")
    broken = tmp_path / "broken.yaml"
    broken.write_text("name: broken\nsource: parameters\n")
    with pytest.raises(RobotLoadError, match="missing key"):
        load_robot(str(broken))
    not_yaml = tmp_path / "bad.yaml"
    not_yaml.write_text("name: [unclosed\n")
    with pytest.raises(RobotLoadError, match=r"bad\.yaml"):
        load_robot(str(not_yaml))


def test_planning_model_carries_the_rotor_inertia(robot):
    """The Mini Cheetah file sets ``rotor_inertia_in_model``: the Pinocchio model has the plant's armature on
    the 12 joints (none on the floating base), so the planned legs are as heavy as the plant's."""
    np.testing.assert_allclose(robot.model.armature[6:], robot.plant.armature)
    assert not robot.model.armature[:6].any()
