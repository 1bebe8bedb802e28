"""Robot descriptions generated from one parameter table.

* ``urdf_from_parameters`` turns a parameter table (``data/mini_cheetah.yaml``) into the URDF that
  Pinocchio loads as the planning model (floating base + 12 revolute joints, point feet).
* ``mjcf_from_model`` turns any Pinocchio quadruped model (generated or loaded from example-robot-data)
  plus the table's ``plant`` section into the MJCF of the MuJoCo plant. Kinematics and inertias are read
  from the Pinocchio model, so the two cannot drift apart; the plant ADDS what the planning model lacks:
  rotor armature, joint damping and dry friction, torque saturation, foot spheres, elliptic friction cones.
"""

from __future__ import annotations

from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import numpy as np
import pinocchio as pin

from cafe_mpc.core.physics import GRAVITY

LEG_SIGNS = {"FL": (1.0, 1.0), "FR": (1.0, -1.0), "HL": (-1.0, 1.0), "HR": (-1.0, -1.0)}
JOINT_KINDS = ("abad", "hip", "knee")


def _fmt(values: np.ndarray | list[float] | tuple[float, ...]) -> str:
    return " ".join(f"{float(v):.10g}" for v in values)


def _mirrored_inertia(entry: dict, side: float) -> tuple[float, np.ndarray, dict[str, float]]:
    """Mass, com and inertia of a left-side link mirrored to ``side`` (+1 left, -1 right) about y."""
    com = np.array(entry["com"], dtype=float)
    com[1] *= side
    inertia = dict(entry["inertia"])
    inertia["xy"] = inertia["xy"] * side
    inertia["yz"] = inertia["yz"] * side
    return float(entry["mass"]), com, inertia


def _urdf_inertial(mass: float, com: np.ndarray, inertia: dict[str, float]) -> str:
    return (
        f'    <inertial><origin xyz="{_fmt(com)}" rpy="0 0 0"/><mass value="{mass:.10g}"/>'
        f'<inertia ixx="{inertia["xx"]:.10g}" iyy="{inertia["yy"]:.10g}" izz="{inertia["zz"]:.10g}" '
        f'ixy="{inertia["xy"]:.10g}" ixz="{inertia["xz"]:.10g}" iyz="{inertia["yz"]:.10g}"/></inertial>\n'
    )


def urdf_from_parameters(table: dict) -> str:
    """URDF of a Mini-Cheetah-like quadruped from a parameter table (see ``data/mini_cheetah.yaml``).

    Joints are named ``{leg}_{abad|hip|knee}``, foot frames ``{leg}_foot`` (at the foot sphere centre).
    The floating base is added by the loader (``pin.JointModelFreeFlyer``), not in the URDF.
    """
    geometry, inertia, joints = table["geometry"], table["inertia"], table["joints"]
    lines = [f'<?xml version="1.0"?>\n<robot name="{table["name"]}">\n']
    body = inertia["body"]
    lines.append('  <link name="body">\n')
    lines.append(_urdf_inertial(body["mass"], np.array(body["com"], float), body["inertia"]))
    lines.append("  </link>\n")
    for leg in table["leg_names"]:
        front, side = LEG_SIGNS[leg]
        abad_xyz = np.array(geometry["abad_position"], float) * np.array([front, side, 1.0])
        origins = [
            abad_xyz,
            np.array([0.0, side * geometry["abad_link_length"], 0.0]),
            np.array([0.0, side * geometry["knee_offset_y"], -geometry["thigh_length"]]),
        ]
        parents = ["body", f"{leg}_abad_link", f"{leg}_thigh"]
        children = [f"{leg}_abad_link", f"{leg}_thigh", f"{leg}_shank"]
        link_inertias = [inertia["abad"], inertia["thigh"], inertia["shank"]]
        for j, kind in enumerate(JOINT_KINDS):
            limit_q = joints["position_limits"][j]
            mass, com, link_inertia = _mirrored_inertia(link_inertias[j], side)
            lines.append(f'  <link name="{children[j]}">\n')
            lines.append(_urdf_inertial(mass, com, link_inertia))
            lines.append("  </link>\n")
            lines.append(
                f'  <joint name="{leg}_{kind}" type="revolute"><parent link="{parents[j]}"/>'
                f'<child link="{children[j]}"/><origin xyz="{_fmt(origins[j])}" rpy="0 0 0"/>'
                f'<axis xyz="{_fmt(joints["axes"][j])}"/>'
                f'<limit lower="{-limit_q:.10g}" upper="{limit_q:.10g}" '
                f'effort="{joints["torque_limits"][j]:.10g}" velocity="{joints["velocity_limits"][j]:.10g}"/>'
                "</joint>\n"
            )
        lines.append(f'  <link name="{leg}_foot"/>\n')
        lines.append(
            f'  <joint name="{leg}_foot_fixed" type="fixed"><parent link="{leg}_shank"/>'
            f'<child link="{leg}_foot"/>'
            f'<origin xyz="0 0 {-geometry["shank_length"]:.10g}" rpy="0 0 0"/></joint>\n'
        )
    lines.append("</robot>\n")
    return "".join(lines)


@dataclass(frozen=True)
class PlantParameters:
    """What the MuJoCo plant has and the planning model lacks (per-joint arrays in model joint order).

    ``joint_damping`` and ``joint_friction`` are one value for every joint (generated plants) or one per joint
    (model-file robots: the robot file's, or the model file's own); ``body_box`` is the trunk's collision box
    of a generated plant (a model file brings its own trunk geoms; None there).
    """

    motor_torque_limits: np.ndarray
    armature: np.ndarray
    joint_damping: float | np.ndarray
    joint_friction: float | np.ndarray
    floor_friction: float
    timestep: float
    foot_radius: float
    body_box: tuple[float, float, float] | None


def _revolute_axis(model: pin.Model, joint_id: int) -> np.ndarray:
    """Rotation axis (in the joint frame) of a one-dof revolute joint, read from its motion subspace."""
    joint = model.joints[joint_id]
    data = joint.createData()
    joint.calc(data, np.zeros(model.nq))
    subspace = np.array(data.S).reshape(6, -1)
    if subspace.shape[1] != 1 or np.linalg.norm(subspace[:3, 0]) > 1e-12:
        raise ValueError(f"joint {model.names[joint_id]!r} is not a 1-dof revolute joint")
    return subspace[3:, 0]


def mjcf_from_model(
    model: pin.Model,
    foot_frame_ids: list[int],
    plant: PlantParameters,
    position_lower: np.ndarray,
    position_upper: np.ndarray,
    name: str,
) -> str:
    """MJCF of the plant, built from a Pinocchio model with a free-flyer root (joint 1).

    Body frames coincide with Pinocchio joint frames, so MuJoCo's joint order equals Pinocchio's
    (depth-first) and inertias are copied exactly. Contacts: foot spheres and the trunk box against the
    floor only (no self-collision); elliptic cones; torque saturation through actuator ``ctrlrange``.
    """
    if model.joints[1].shortname() != "JointModelFreeFlyer":
        raise ValueError("the planning model needs a free-flyer root joint")
    children: dict[int, list[int]] = {j: [] for j in range(model.njoints)}
    for j in range(2, model.njoints):
        children[model.parents[j]].append(j)
    feet_by_joint: dict[int, list[int]] = {}
    for frame_id in foot_frame_ids:
        feet_by_joint.setdefault(model.frames[frame_id].parentJoint, []).append(frame_id)

    def inertial(joint_id: int) -> str:
        inertia = model.inertias[joint_id]
        if inertia.mass <= 0.0:
            return ""
        moment = np.array(inertia.inertia)
        full = [moment[0, 0], moment[1, 1], moment[2, 2], moment[0, 1], moment[0, 2], moment[1, 2]]
        return (
            f'<inertial pos="{_fmt(inertia.lever)}" mass="{inertia.mass:.10g}" fullinertia="{_fmt(full)}"/>'
        )

    out: list[str] = []

    def body(joint_id: int, depth: int) -> None:
        pad = "  " * depth
        placement = model.jointPlacements[joint_id]
        quat = pin.Quaternion(placement.rotation)
        joint_name = model.names[joint_id]
        index = joint_id - 2
        out.append(
            f'{pad}<body name={quoteattr(joint_name + "_body")} pos="{_fmt(placement.translation)}" '
            f'quat="{_fmt([quat.w, quat.x, quat.y, quat.z])}">\n'
        )
        out.append(f"{pad}  {inertial(joint_id)}\n")
        lower, upper = float(position_lower[index]), float(position_upper[index])
        out.append(
            f'{pad}  <joint name={quoteattr(joint_name)} type="hinge" '
            f'axis="{_fmt(_revolute_axis(model, joint_id))}" '
            f'range="{lower:.10g} {upper:.10g}" limited="true" armature="{plant.armature[index]:.10g}" '
            f'damping="{plant.joint_damping:.10g}" frictionloss="{plant.joint_friction:.10g}"/>\n'
        )
        for child in children[joint_id]:
            child_pos = model.jointPlacements[child].translation
            out.append(
                f'{pad}  <geom type="capsule" size="0.012" fromto="0 0 0 {_fmt(child_pos)}" '
                f'contype="0" conaffinity="0" group="1" rgba="0.3 0.3 0.35 1"/>\n'
            )
        for frame_id in feet_by_joint.get(joint_id, []):
            foot_pos = model.frames[frame_id].placement.translation
            out.append(
                f'{pad}  <geom type="capsule" size="0.01" fromto="0 0 0 {_fmt(foot_pos)}" '
                f'contype="0" conaffinity="0" group="1" rgba="0.3 0.3 0.35 1"/>\n'
            )
            out.append(
                f'{pad}  <geom name={quoteattr(model.frames[frame_id].name)} type="sphere" '
                f'size="{plant.foot_radius:.10g}" pos="{_fmt(foot_pos)}" contype="0" conaffinity="1" '
                f'condim="3" friction="{plant.floor_friction:.10g} 0.005 0.0001" rgba="0.1 0.1 0.1 1"/>\n'
            )
            out.append(
                f"{pad}  <site name={quoteattr(model.frames[frame_id].name + '_site')} "
                f'pos="{_fmt(foot_pos)}"/>\n'
            )
        for child in children[joint_id]:
            body(child, depth + 1)
        out.append(f"{pad}</body>\n")

    box = np.array(plant.body_box) / 2.0
    out.append(f'<mujoco model="{name}">\n')
    out.append('  <compiler angle="radian" autolimits="true"/>\n')
    out.append(
        f'  <option timestep="{plant.timestep:.10g}" integrator="implicitfast" cone="elliptic" '
        f'impratio="1" gravity="0 0 {-GRAVITY:g}"/>\n'
    )
    out.append('  <visual><global offwidth="640" offheight="480"/></visual>\n')
    out.append("  <asset>\n")
    out.append(
        '    <texture name="grid" type="2d" builtin="checker" rgb1="0.55 0.6 0.65" rgb2="0.45 0.5 0.55" '
        'width="256" height="256"/>\n'
    )
    out.append('    <material name="grid" texture="grid" texrepeat="8 8" reflectance="0.1"/>\n')
    out.append("  </asset>\n")
    out.append("  <worldbody>\n")
    out.append('    <light pos="0 0 3" dir="0 0 -1" directional="true"/>\n')
    out.append(
        f'    <geom name="floor" type="plane" size="0 0 0.05" material="grid" contype="1" conaffinity="1" '
        f'condim="3" friction="{plant.floor_friction:.10g} 0.005 0.0001"/>\n'
    )
    out.append('    <body name="base" pos="0 0 0.5">\n')
    out.append(f"      {inertial(1)}\n")
    out.append('      <freejoint name="root"/>\n')
    out.append(
        f'      <geom name="trunk" type="box" size="{_fmt(box)}" contype="0" conaffinity="1" '
        'rgba="0.75 0.2 0.2 1"/>\n'
    )
    out.append('      <site name="imu" pos="0 0 0"/>\n')
    for child in children[1]:
        body(child, 3)
    out.append("    </body>\n  </worldbody>\n  <actuator>\n")
    for j in range(2, model.njoints):
        limit = float(plant.motor_torque_limits[j - 2])
        out.append(
            f"    <motor name={quoteattr(model.names[j] + '_motor')} joint={quoteattr(model.names[j])} "
            f'gear="1" ctrlrange="{-limit:.10g} {limit:.10g}" ctrllimited="true"/>\n'
        )
    out.append("  </actuator>\n</mujoco>\n")
    return "".join(out)
