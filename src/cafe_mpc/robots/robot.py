"""The ``Robot``: planning model, feet, limits, standing pose and plant description of one quadruped.

A robot is a YAML file (``data/<name>.yaml``): either a parameter table from which the URDF is generated
(Mini Cheetah) or a pointer to an example-robot-data URDF plus the plant extras (Go1). Everything else in
the package takes a ``Robot`` and never hard-codes a robot.

Conventions used everywhere:

* leg order ``leg_names`` (``FL, FR, HL, HR``); contact flags, foot arrays and the 12 joint vectors
  (``[abad, hip, knee]`` per leg) follow it;
* planning configuration ``q = [base position (3), base quaternion (x, y, z, w), joints (12)]`` and
  velocity ``v = [base linear velocity (base frame), base angular velocity (base frame), joint rates]``,
  Pinocchio's free-flyer convention (``nq = 19``, ``nv = 18``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import pinocchio as pin
import yaml

from cafe_mpc.core.contacts import LEG_NAMES
from cafe_mpc.robots.description import PlantParameters, mjcf_from_model, urdf_from_parameters

DATA_DIR = Path(__file__).parent / "data"
JOINTS_PER_LEG = 3  # abad, hip, knee


class RobotLoadError(ValueError):
    """A robot file that does not load, with the reason."""


@dataclass(frozen=True, eq=False)
class Robot:
    """Immutable description of a quadruped for planning (Pinocchio) and simulation (MuJoCo)."""

    name: str
    model: pin.Model
    urdf: str
    leg_names: tuple[str, ...]
    foot_frame_names: tuple[str, ...]
    foot_frame_ids: tuple[int, ...]
    joint_names: tuple[str, ...]
    torque_limits: np.ndarray
    position_lower: np.ndarray
    position_upper: np.ndarray
    velocity_limits: np.ndarray
    q_standing: np.ndarray
    standing_height: float
    foothold_offsets: np.ndarray
    plant: PlantParameters
    rotor_mass: float = 0.0
    """Mass (kg) of each joint's rotor when the planning model does not hold it as a body (Mini Cheetah:
    the rotors sit at the joints; Go1's URDF has them as links, so 0 there). Counted in the SRB mass."""

    @property
    def nq(self) -> int:
        return self.model.nq

    @property
    def nv(self) -> int:
        return self.model.nv

    @property
    def nu(self) -> int:
        return self.model.nv - 6

    @property
    def n_feet(self) -> int:
        return len(self.foot_frame_ids)

    @property
    def total_mass(self) -> float:
        """Mass of the planning model's bodies (without ``rotor_mass``)."""
        return float(sum(inertia.mass for inertia in self.model.inertias))

    @property
    def foot_radius(self) -> float:
        """Height of a planning foot (sphere centre) above the floor when it touches down."""
        return self.plant.foot_radius

    @property
    def x_standing(self) -> np.ndarray:
        """Standing state ``[q, v]`` with zero velocity."""
        return np.concatenate([self.q_standing, np.zeros(self.nv)])

    @cached_property
    def mjcf(self) -> str:
        """MJCF text of the MuJoCo plant (same kinematics/inertias plus the plant extras)."""
        return mjcf_from_model(
            self.model,
            list(self.foot_frame_ids),
            self.plant,
            self.position_lower,
            self.position_upper,
            self.name,
        )

    def foot_positions(self, q: np.ndarray) -> np.ndarray:
        """World positions of the feet (n_feet x 3, leg order) at ``q`` (allocates; not hot path)."""
        data = self.model.createData()
        pin.framesForwardKinematics(self.model, data, q)
        return np.array([data.oMf[i].translation.copy() for i in self.foot_frame_ids])

    def hip_positions(self) -> np.ndarray:
        """Positions of the first joint of each leg in the base frame (n_feet x 3, leg order)."""
        positions = []
        for frame_id in self.foot_frame_ids:
            joint_id = self.model.frames[frame_id].parentJoint
            while self.model.parents[joint_id] != 1:
                joint_id = self.model.parents[joint_id]
            positions.append(self.model.jointPlacements[joint_id].translation.copy())
        return np.array(positions)

    def summary(self) -> dict:
        """Masses, limits and feet as plain data (for ``cafe-mpc robot NAME --json``)."""
        bodies = {
            self.model.names[j]: float(self.model.inertias[j].mass) for j in range(1, self.model.njoints)
        }
        return {
            "name": self.name,
            "total_mass": self.total_mass,
            "rotor_mass": self.rotor_mass,
            "body_masses": bodies,
            "nq": self.nq,
            "nv": self.nv,
            "leg_names": list(self.leg_names),
            "foot_frames": list(self.foot_frame_names),
            "joint_names": list(self.joint_names),
            "torque_limits": self.torque_limits.tolist(),
            "motor_torque_limits": self.plant.motor_torque_limits.tolist(),
            "position_lower": self.position_lower.tolist(),
            "position_upper": self.position_upper.tolist(),
            "velocity_limits": self.velocity_limits.tolist(),
            "standing_height": self.standing_height,
            "q_standing": self.q_standing.tolist(),
            "armature": self.plant.armature.tolist(),
            "foot_radius": self.plant.foot_radius,
        }


def _per_leg(values: list[float] | None, default: np.ndarray, key: str) -> np.ndarray:
    """Per-joint values from 3 (one per joint kind, every leg) or one per joint (``len(default)``)."""
    if values is None:
        return default.copy()
    n_joints = len(default)
    array = np.asarray(values, dtype=float)
    if array.shape == (JOINTS_PER_LEG,):
        array = np.tile(array, n_joints // JOINTS_PER_LEG)
    if array.shape != (n_joints,) or not np.all(np.isfinite(array)) or np.any(array <= 0):
        raise RobotLoadError(
            f"{key}: expected {JOINTS_PER_LEG} (per joint kind) or {n_joints} positive numbers, got {values}"
        )
    return array


def _standing_configuration(
    model: pin.Model,
    foot_frame_ids: tuple[int, ...],
    height: float,
    foot_radius: float,
    joint_guess: np.ndarray,
    foot_xy: np.ndarray,
) -> np.ndarray:
    """Joint angles that put the feet at ``foot_xy`` on the floor with the base at ``height`` (level).

    Damped Gauss-Newton on the four foot positions (a few iterations; construction time only).
    """
    q = pin.neutral(model)
    q[2] = height
    q[7:] = joint_guess
    data = model.createData()
    targets = np.column_stack([foot_xy, np.full(len(foot_frame_ids), foot_radius)])
    for _ in range(100):
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        errors, rows = [], []
        for foot, frame_id in enumerate(foot_frame_ids):
            errors.append(data.oMf[frame_id].translation - targets[foot])
            jacobian = pin.getFrameJacobian(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED)[:3, 6:]
            rows.append(jacobian)
        error = np.concatenate(errors)
        if np.linalg.norm(error) < 1e-10:
            break
        jacobian = np.vstack(rows)
        step = np.linalg.solve(jacobian.T @ jacobian + 1e-8 * np.eye(model.nv - 6), jacobian.T @ error)
        q[7:] -= step
    else:
        raise RobotLoadError(f"standing pose: feet cannot reach the floor at height {height} m")
    return q


def _load_table(path: Path) -> dict:
    try:
        with open(path) as handle:
            table = yaml.safe_load(handle)
    except (OSError, yaml.YAMLError) as error:
        raise RobotLoadError(f"robot file {path}: {error}") from error
    if not isinstance(table, dict):
        raise RobotLoadError(f"robot file {path}: expected a mapping at the top level")
    return table


def robot_file(name_or_path: str) -> Path:
    """Resolve a robot name (``mini_cheetah``, ``go1``) or a path to a robot YAML file."""
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml"):
        if not path.is_file():
            raise RobotLoadError(f"robot file {path} does not exist")
        return path
    candidate = DATA_DIR / f"{name_or_path.replace('-', '_')}.yaml"
    if not candidate.is_file():
        known = sorted(p.stem for p in DATA_DIR.glob("*.yaml"))
        raise RobotLoadError(f"unknown robot {name_or_path!r}; known robots: {', '.join(known)}")
    return candidate


def load_robot(name_or_path: str = "mini_cheetah") -> Robot:
    """Build a ``Robot`` from a robot name or a robot YAML file."""
    table = _load_table(robot_file(name_or_path))
    try:
        return _build_robot(table)
    except KeyError as error:
        raise RobotLoadError(f"robot {table.get('name', name_or_path)!r}: missing key {error}") from error


def _build_robot(table: dict) -> Robot:
    name = str(table["name"])
    leg_names = tuple(table.get("leg_names", LEG_NAMES))
    if sorted(leg_names) != sorted(LEG_NAMES):
        raise RobotLoadError(f"robot {name!r}: leg_names must be a permutation of {LEG_NAMES}")
    source = table.get("source", "parameters")
    geometry, joints, plant_table, standing = (
        table["geometry"],
        table["joints"],
        table["plant"],
        table["standing"],
    )
    if source == "parameters":
        urdf = urdf_from_parameters(table)
        foot_frames = tuple(f"{leg}_foot" for leg in leg_names)
        joint_names = tuple(f"{leg}_{kind}" for leg in leg_names for kind in ("abad", "hip", "knee"))
    elif source == "example-robot-data":
        import example_robot_data

        try:
            loaded = example_robot_data.load(table["example_robot_data_name"])
        except Exception as error:  # the loader raises many types for a missing robot
            raise RobotLoadError(f"robot {name!r}: example-robot-data cannot load it: {error}") from error
        with open(loaded.urdf if hasattr(loaded, "urdf") else loaded.model_path) as handle:
            urdf = handle.read()
        foot_frames = tuple(table["foot_frames"])
        joint_names = tuple(table["joint_names"])
    else:
        raise RobotLoadError(f"robot {name!r}: unknown source {source!r} (parameters | example-robot-data)")
    try:
        model = pin.buildModelFromXML(urdf, pin.JointModelFreeFlyer())
    except Exception as error:  # Pinocchio raises RuntimeError/ValueError on bad URDF
        raise RobotLoadError(f"robot {name!r}: Pinocchio cannot parse the URDF: {error}") from error
    model.name = name
    n_legs = len(leg_names)
    n_joints = JOINTS_PER_LEG * n_legs
    if model.nq != 7 + n_joints or model.nv != 6 + n_joints:
        raise RobotLoadError(
            f"robot {name!r}: expected a floating base and {n_joints} revolute joints "
            f"({JOINTS_PER_LEG} per leg), got nv = {model.nv}"
        )
    model_joint_names = tuple(model.names[j] for j in range(2, model.njoints))
    if model_joint_names != joint_names:
        raise RobotLoadError(
            f"robot {name!r}: joint order {model_joint_names} does not follow the leg order {joint_names}"
        )
    foot_ids = []
    for frame in foot_frames:
        if not model.existFrame(frame):
            raise RobotLoadError(f"robot {name!r}: foot frame {frame!r} not in the model")
        foot_ids.append(model.getFrameId(frame))
    urdf_torque = np.array(model.effortLimit[6:], dtype=float)
    urdf_velocity = np.array(model.velocityLimit[6:], dtype=float)
    urdf_position = np.array(model.upperPositionLimit[7:], dtype=float)
    torque_limits = _per_leg(joints.get("torque_limits"), urdf_torque, "joints.torque_limits")
    velocity_limits = _per_leg(joints.get("velocity_limits"), urdf_velocity, "joints.velocity_limits")
    position_upper = _per_leg(joints.get("position_limits"), np.abs(urdf_position), "joints.position_limits")
    if source != "parameters" and joints.get("position_limits") is None:
        position_lower = np.array(model.lowerPositionLimit[7:], dtype=float)
        position_upper = np.array(model.upperPositionLimit[7:], dtype=float)
    else:
        position_lower = -position_upper
    plant = PlantParameters(
        motor_torque_limits=_per_leg(
            plant_table.get("motor_torque_limits"), torque_limits, "plant.motor_torque_limits"
        ),
        armature=_per_leg(plant_table["armature"], np.zeros(n_joints), "plant.armature"),
        joint_damping=float(plant_table["joint_damping"]),
        joint_friction=float(plant_table["joint_friction"]),
        floor_friction=float(plant_table["floor_friction"]),
        timestep=float(plant_table["timestep"]),
        foot_radius=float(geometry["foot_radius"]),
        body_box=tuple(float(v) for v in geometry["body_box"]),
    )
    if plant.timestep <= 0 or plant.foot_radius <= 0 or plant.floor_friction <= 0:
        raise RobotLoadError(
            f"robot {name!r}: plant timestep, foot radius and floor friction must be positive"
        )
    if bool(joints.get("rotor_inertia_in_model", False)):
        model.armature[6:] = plant.armature  # reflected rotor inertia, in CRBA/ABA and their derivatives
    offsets = np.asarray(standing["foothold_offsets"], dtype=float)
    if offsets.shape != (n_legs, 2):
        raise RobotLoadError(f"robot {name!r}: standing.foothold_offsets must be {n_legs} (x, y) pairs")
    height = float(standing["height"])
    guess = np.tile(np.asarray(standing["joint_guess"], dtype=float), n_legs)
    rotor_mass = float(table.get("inertia", {}).get("rotor_mass", 0.0))
    if not (np.isfinite(rotor_mass) and rotor_mass >= 0):
        raise RobotLoadError(f"robot {name!r}: inertia.rotor_mass must be a non-negative number")
    q_standing = _standing_configuration(model, tuple(foot_ids), height, plant.foot_radius, guess, offsets)
    # Keep position limits honest with the standing pose (it must be inside them).
    if np.any(q_standing[7:] < position_lower) or np.any(q_standing[7:] > position_upper):
        raise RobotLoadError(f"robot {name!r}: the standing pose violates the joint position limits")
    return Robot(
        name=name,
        model=model,
        urdf=urdf,
        leg_names=leg_names,
        foot_frame_names=foot_frames,
        foot_frame_ids=tuple(foot_ids),
        joint_names=joint_names,
        torque_limits=torque_limits,
        position_lower=position_lower,
        position_upper=position_upper,
        velocity_limits=velocity_limits,
        q_standing=q_standing,
        standing_height=height,
        foothold_offsets=offsets,
        plant=plant,
        rotor_mass=rotor_mass,
    )
