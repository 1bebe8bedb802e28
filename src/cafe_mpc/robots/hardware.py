"""The real robot behind a robot file: which interface speaks to its motors and how its motors map to joints.

A robot file's optional ``hardware`` section (docs/robots.md, docs/deploy.md)::

    hardware:
      interface: unitree-dds             # the robot_io implementation that speaks to it
      motors: [FR_hip_joint, ...]        # the joint each motor slot drives, in the robot's motor order
      joint_signs: [1, 1, 1]             # joint angle = sign x motor angle + offset (3: per joint kind,
      joint_offsets: [0, 0, 0]           #   or one per joint; rad); defaults 1 and 0
      lying_pose: [0.0, 1.36, -2.65]     # joint angles the robot lies in, rad (where it stands up from and
                                         #   lies down to)
      stance_kp: 60.0                    # motor PD gains (Nm/rad, Nm s/rad) of the stand-up, the hold, the
      stance_kd: 5.0                     #   damped stance and the lie-down

Robots without the section have ``Robot.hardware`` None: nothing else changes. The values are read and
checked here once (``read_hardware``); ``robot_io`` applies them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

HARDWARE_KEYS = frozenset(
    {"interface", "motors", "joint_signs", "joint_offsets", "lying_pose", "stance_kp", "stance_kd"}
)
JOINTS_PER_KIND = 3  # abad (hip), hip (thigh), knee (calf): per-kind values repeat for every leg


class HardwareError(ValueError):
    """A robot file's ``hardware`` section that does not fit its robot (one line, naming the key)."""


@dataclass(frozen=True, eq=False)
class HardwareSpec:
    """A robot's motors as its low-level interface numbers them (``hardware`` section, module docstring).

    ``motor_of_joint[j]`` is the motor slot driving joint ``j`` (robot joint order); a motor angle ``m``
    reads as the joint angle ``joint_signs[j] * m + joint_offsets[j]`` (rates and torques: times the sign).
    """

    interface: str
    motor_joints: tuple[str, ...]
    """The joint of each motor slot, in the interface's motor order."""
    motor_of_joint: np.ndarray
    joint_signs: np.ndarray
    joint_offsets: np.ndarray
    lying_pose: np.ndarray
    stance_kp: float
    stance_kd: float

    @property
    def n_motors(self) -> int:
        return len(self.motor_joints)


def _per_joint(values: object, n_joints: int, key: str, default: float | None = None) -> np.ndarray:
    """One finite value per joint from 3 (one per joint kind, every leg) or ``n_joints`` values."""
    if values is None:
        if default is None:
            raise HardwareError(f"hardware.{key} is required")
        return np.full(n_joints, float(default))
    try:
        array = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise HardwareError(f"hardware.{key}: expected numbers, got {values!r}") from None
    if array.shape == (JOINTS_PER_KIND,):
        array = np.tile(array, n_joints // JOINTS_PER_KIND)
    if array.shape != (n_joints,) or not np.all(np.isfinite(array)):
        raise HardwareError(
            f"hardware.{key}: expected {JOINTS_PER_KIND} (per joint kind) or {n_joints} finite numbers, "
            f"got {values!r}"
        )
    return array


def _gain(section: dict, key: str) -> float:
    value = section.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or value < 0:
        raise HardwareError(f"hardware.{key}: expected a non-negative number, got {value!r}")
    return float(value)


def read_hardware(
    section: object,
    joint_names: tuple[str, ...],
    position_lower: np.ndarray,
    position_upper: np.ndarray,
) -> HardwareSpec | None:
    """The ``HardwareSpec`` of a robot file's ``hardware`` section (None without one), checked against the
    robot's joints and position limits; ``HardwareError`` names the key that does not fit."""
    if section is None:
        return None
    if not isinstance(section, dict):
        raise HardwareError(f"hardware must be a mapping of keys to values, got {section!r}")
    unknown = sorted(set(section) - HARDWARE_KEYS)
    if unknown:
        raise HardwareError(f"hardware: unknown keys {unknown}; keys: {sorted(HARDWARE_KEYS)}")
    interface = section.get("interface")
    if not isinstance(interface, str) or not interface:
        raise HardwareError(f"hardware.interface: expected an interface name, got {interface!r}")
    motors = section.get("motors")
    if not isinstance(motors, list) or not all(isinstance(m, str) for m in motors):
        raise HardwareError("hardware.motors: expected the joint names of the motor slots, in motor order")
    missing = [joint for joint in joint_names if joint not in motors]
    unknown_joints = [motor for motor in motors if motor not in joint_names]
    if missing or unknown_joints or len(set(motors)) != len(motors):
        raise HardwareError(
            f"hardware.motors: needs each of the robot's joints once (missing {missing}, not joints of the "
            f"robot {unknown_joints})"
        )
    n_joints = len(joint_names)
    signs = _per_joint(section.get("joint_signs"), n_joints, "joint_signs", default=1.0)
    if not np.all(np.abs(signs) == 1.0):
        raise HardwareError(f"hardware.joint_signs: each sign must be 1 or -1, got {signs.tolist()}")
    offsets = _per_joint(section.get("joint_offsets"), n_joints, "joint_offsets", default=0.0)
    lying = _per_joint(section.get("lying_pose"), n_joints, "lying_pose")
    outside = [
        joint
        for joint, value, low, high in zip(joint_names, lying, position_lower, position_upper, strict=True)
        if not low <= value <= high
    ]
    if outside:
        raise HardwareError(f"hardware.lying_pose: outside the position limits of {', '.join(outside)}")
    return HardwareSpec(
        interface=interface,
        motor_joints=tuple(motors),
        motor_of_joint=np.array([motors.index(joint) for joint in joint_names]),
        joint_signs=signs,
        joint_offsets=offsets,
        lying_pose=lying,
        stance_kp=_gain(section, "stance_kp"),
        stance_kd=_gain(section, "stance_kd"),
    )
