"""Defaults that scale with the robot: the laws that carry settings tuned on one robot to another.

The published settings (gait timings, swing height, cost weights, gains, ...) were tuned on the
``REFERENCE_ROBOT`` (the Mini Cheetah). A run with ``scaling: robot`` (the default) reads every such setting
as a value *for the reference robot* and carries it to the run's robot by dimensional similarity, with three
characteristic scales of a robot:

* length ``L``: the mean leg length (thigh + shank, ``Robot.leg_length``; 0.404 m for the Mini Cheetah);
* mass ``m``: the whole robot, rotors included (``Robot.mass``; 8.912 kg);
* time ``T = sqrt(L / g)``: Froude similarity, so that a robot twice as long steps sqrt(2) times slower
  and two robots at the same Froude number ``v^2 / (g L)`` move alike.

With ``s_L = L / L_ref`` and ``s_m = m / m_ref`` (``RobotScale``), a setting with units
``m^a kg^b s^c`` scales by ``s_L^a s_m^b s_T^c`` where ``s_T = sqrt(s_L)``: gait phase durations and the
Raibert gain (s) by ``s_T``, swing height, foothold box, minimum base height and fall height (m) by ``s_L``,
the contact-stabilisation (Baumgarte) rates (1/s) by ``1 / s_T``, joint PD gains (Nm/rad, Nm s/rad) by the
torque scale ``s_m s_L`` (times ``s_T`` for the damping), force tolerances by ``s_m``.

Cost weights ``W`` of a term ``0.5 W r^2`` keep every term's share of the cost when the residual ``r`` is
measured in the robot's own units: ``W`` scales by ``1 / u^2`` where ``u`` is the residual's characteristic
scale (position ``s_L``, linear velocity ``s_L / s_T``, angular velocity ``1 / s_T``, torque ``s_m s_L``,
force ``s_m``; angles are dimensionless). Joint-space and orientation weights are therefore unchanged, a
torque weight falls with the square of the robot's ``m g L``, and the SRB inertia enters through the model
(``dynamics.srb.srb_parameters``), not through the weights. For the reference robot every factor is exactly 1.
``scaling: none`` uses every value as written. The laws are stated once more, with the numbers of the shipped
robots, in docs/robots.md.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.robots.robot import REFERENCE_ROBOT, Robot, load_robot


@dataclass(frozen=True)
class RobotScale:
    """A robot's length and mass relative to the reference robot (1, 1: the reference itself)."""

    length: float = 1.0
    mass: float = 1.0

    def __post_init__(self) -> None:
        if not (
            math.isfinite(self.length) and self.length > 0 and math.isfinite(self.mass) and self.mass > 0
        ):
            raise ValueError(f"robot scale needs positive length and mass factors, got {self}")

    @property
    def time(self) -> float:
        """Froude time scale ``sqrt(s_L)``."""
        return math.sqrt(self.length)

    @property
    def torque(self) -> float:
        """``m g L`` scale (torques, joint stiffness)."""
        return self.mass * self.length

    @property
    def is_identity(self) -> bool:
        return self.length == 1.0 and self.mass == 1.0

    def duration(self, seconds: float) -> float:
        return seconds * self.time

    def distance(self, metres: float) -> float:
        return metres * self.length

    def rate(self, per_second: float) -> float:
        return per_second / self.time

    def speed(self, metres_per_second: float | None) -> float | None:
        """A speed carried to the robot (length over time); ``None`` (a threshold that is off) stays off."""
        return None if metres_per_second is None else metres_per_second * self.length / self.time

    def force(self, newtons: float) -> float:
        return newtons * self.mass

    def stiffness(self, newton_metres_per_radian: float) -> float:
        return newton_metres_per_radian * self.torque

    def damping(self, newton_metre_seconds_per_radian: float) -> float:
        return newton_metre_seconds_per_radian * self.torque * self.time

    # weights of 0.5 W r^2 terms: W / u^2 with u the residual's characteristic scale
    @property
    def position_weight(self) -> float:
        return 1.0 / self.length**2

    @property
    def linear_velocity_weight(self) -> float:
        return 1.0 / self.length  # u = L / T = sqrt(L): u^2 = L

    @property
    def angular_velocity_weight(self) -> float:
        return self.length  # u = 1 / T: u^2 = 1 / L

    @property
    def torque_weight(self) -> float:
        return 1.0 / self.torque**2

    @property
    def force_weight(self) -> float:
        return 1.0 / self.mass**2

    def summary(self) -> dict:
        return {
            "length": self.length,
            "mass": self.mass,
            "time": self.time,
            "torque": self.torque,
        }


IDENTITY = RobotScale()


@functools.cache
def _reference() -> tuple[float, float]:
    reference = load_robot(REFERENCE_ROBOT)
    return reference.leg_length, reference.mass


def robot_scale(robot: Robot) -> RobotScale:
    """``robot``'s scale relative to ``REFERENCE_ROBOT`` (leg length and mass ratios)."""
    length, mass = _reference()
    return RobotScale(robot.leg_length / length, robot.mass / mass)


def reference_scales() -> dict:
    """The reference robot's name, leg length (m), mass (kg) and time scale sqrt(L / g) (s)."""
    length, mass = _reference()
    return {"robot": REFERENCE_ROBOT, "leg_length": length, "mass": mass, "time": math.sqrt(length / GRAVITY)}
