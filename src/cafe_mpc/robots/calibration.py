"""The robot as its controller models it: the robot file's robot with what is known beyond the file.

A robot carries a payload, its links weigh a little more or less than the file says, its motors deliver a
little more or less torque per command than their datasheet. ``ModelCalibration`` holds those factors (the
run config's ``calibration`` section, resolved once in ``assembly.resolve``) and ``calibrated_robot`` builds
the ``Robot`` every part of the controller is built from:

* masses: the trunk's (``body_mass_scale``, times ``mass_scale``) and each leg link's (``link_mass_scales``,
  times ``mass_scale``) mass and rotational inertia scale together (same shape, other density), in the
  whole-body Pinocchio model itself, so that everything lumped or computed from it follows: the plan's
  whole-body knots (CRBA/ABA and their derivatives), the SRB tail's mass and inertia
  (``dynamics.srb.srb_parameters``), the reference's and the low level's weight, the statics of the stances;
  the rotors (``Robot.rotor_mass``) scale with ``mass_scale``;
* motors: ``torque_limits`` become ``strength x`` the file's, the torque a motor of that strength can
  deliver; the low level divides its torques by the strength before sending them
  (``low_level.motor_strength``).

The factors mean what the plant's deviations mean (``sim.randomization`` in the lab), so a controller told
the plant's factors models the plant exactly in mass and motors. Kinematics, joint limits and the standing
pose do not change; the robot's scale (``robots.scaling``) is measured on the file's robot, so a payload
changes no gait timing or tuned weight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin

from cafe_mpc.robots.robot import Robot


@dataclass(frozen=True)
class ModelCalibration:
    """Factors on the robot file's model (module docstring): one value for every joint or one per actuated
    joint (the robot's joint order) for the links and motors. The defaults change nothing."""

    mass_scale: float = 1.0
    body_mass_scale: float = 1.0
    link_mass_scales: float | tuple[float, ...] = 1.0
    motor_strength_scales: float | tuple[float, ...] = 1.0

    def __post_init__(self) -> None:
        for name in ("mass_scale", "body_mass_scale"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value}")

    def per_joint(self, name: str, n_joints: int) -> np.ndarray:
        """``link_mass_scales`` or ``motor_strength_scales`` as one positive factor per joint."""
        values = getattr(self, name)
        array = np.full(n_joints, float(values)) if np.isscalar(values) else np.asarray(values, dtype=float)
        if array.shape != (n_joints,) or not np.all(np.isfinite(array)) or np.any(array <= 0.0):
            raise ValueError(f"{name}: one positive factor or {n_joints} (one per joint), got {values!r}")
        return array

    @property
    def is_identity(self) -> bool:
        return all(
            np.all(np.asarray(value) == 1.0)
            for value in (
                self.mass_scale,
                self.body_mass_scale,
                self.link_mass_scales,
                self.motor_strength_scales,
            )
        )


def scaled_inertia(inertia: pin.Inertia, factor: float) -> pin.Inertia:
    """``inertia`` with its mass and its rotational inertia about the centre of mass times ``factor`` (the
    centre of mass kept)."""
    return pin.Inertia(
        float(inertia.mass) * factor, np.array(inertia.lever), np.array(inertia.inertia) * factor
    )


def calibrated_robot(robot: Robot, calibration: ModelCalibration) -> Robot:
    """``robot`` with ``calibration`` applied to its planning model, rotor mass and torque limits (module
    docstring); ``robot`` itself when the calibration is the identity. ``ValueError`` for factors that do
    not fit the robot."""
    links = calibration.per_joint("link_mass_scales", robot.nu)
    strength = calibration.per_joint("motor_strength_scales", robot.nu)
    if calibration.is_identity:
        return robot
    model = pin.Model(robot.model)
    root = 1  # joint 0 is the universe, 1 the floating base that carries the trunk
    model.inertias[root] = scaled_inertia(
        model.inertias[root], calibration.mass_scale * calibration.body_mass_scale
    )
    for index, name in enumerate(robot.joint_names):
        joint = model.getJointId(name)
        model.inertias[joint] = scaled_inertia(model.inertias[joint], calibration.mass_scale * links[index])
    return replace(
        robot,
        model=model,
        rotor_mass=robot.rotor_mass * calibration.mass_scale,
        torque_limits=np.asarray(robot.torque_limits, dtype=float) * strength,
    )
