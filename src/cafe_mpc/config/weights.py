"""Cost weights of the whole-body and SRB knots (paper Eqs. (18) and (28)) and the authors' weight sets.

Every cost term of a knot is ``0.5 * r' W r`` with a residual ``r(x, u)`` and a diagonal weight ``W``; a
running knot multiplies the sum by its time step (``0.5 * dx' W dx * dt``, docs/settings.md). A weight set
(``WholeBodyWeights``, ``SRBWeights``) is the settings of those diagonals, written as in the authors' code:
base weights in the order ``[x, y, z, yaw, pitch, roll]``, joint weights one for all joints or one per
joint, foot weights ``(x, y, z)`` for every leg or one triple per leg. Each set gives its diagonals in the
knots' tangent order ``[lin x, y, z, ang x (roll), y (pitch), z (yaw)]`` (``state_weights``, ...), sized
for the robot they are used with (its joint and foot counts: ``check_counts``, which the assembly runs
against the run's robot). The run config's ``costs`` and ``reference.costs`` sections are these models.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from cafe_mpc.config.loading import StrictModel

BASE_WEIGHT_ORDER = ("x", "y", "z", "yaw", "pitch", "roll")
"""Order of the six base weights in the authors' code and in ``WholeBodyWeights``/``SRBWeights``."""

BaseError = Literal["tangent", "world"]
"""Whole-body base residual: tangent-space difference, or world-frame position, ``log3(R_ref' R)`` and
world-frame linear velocity (``ocp.knots.WholeBodySettings.base_error``)."""

Weights = float | tuple[float, ...]
"""A scalar (every joint / axis) or a tuple: one per joint; or x y z shared by the legs, or 3 per leg."""
BaseWeights = tuple[float, float, float, float, float, float]
"""Six base weights in ``BASE_WEIGHT_ORDER``."""


def base_weights_to_tangent(weights: Sequence[float]) -> np.ndarray:
    """``[x, y, z, yaw, pitch, roll]`` -> ``[x, y, z, roll, pitch, yaw]`` (tangent order: linear, then angular
    about the body x (roll), y (pitch) and z (yaw) axes)."""
    w = np.asarray(weights, dtype=float)
    if w.shape != (6,):
        raise ValueError(f"base weights need 6 values {BASE_WEIGHT_ORDER}, got shape {w.shape}")
    return np.array([w[0], w[1], w[2], w[5], w[4], w[3]])


def weight_vector(value: float | Sequence[float], size: int, name: str) -> np.ndarray:
    """A scalar or ``size`` weights -> ``size`` weights (``ValueError`` naming ``name`` for another shape or a
    negative or non-finite weight)."""
    array = np.asarray(value, dtype=float)
    if array.ndim == 0:
        array = np.full(size, float(array))
    if array.shape != (size,):
        raise ValueError(f"{name}: expected a scalar or {size} values, got shape {array.shape}")
    _check_values(array, value, name)
    return array


def leg_weights(value: float | Sequence[float], n_feet: int, name: str) -> np.ndarray:
    """3 weights (x, y, z) shared by the legs, or 3 per leg -> ``3 n_feet`` (leg-major)."""
    array = np.asarray(value, dtype=float)
    if array.ndim == 0:
        array = np.full(3, float(array))
    if array.shape == (3,):
        array = np.tile(array, n_feet)
    return weight_vector(array, 3 * n_feet, name)


def _check_values(array: np.ndarray, value, name: str) -> None:
    if not np.all(np.isfinite(array)) or np.any(array < 0):
        raise ValueError(f"{name}: weights must be finite and non-negative, got {value}")


def _check_shape(value: Weights, name: str, per_foot: bool = False) -> None:
    """What a weight can be checked for without its robot: finite and non-negative, and for foot weights
    a whole number of (x, y, z) triples (the counts: ``check_counts``)."""
    array = np.asarray(value, dtype=float)
    if array.ndim > 1 or array.size == 0:
        raise ValueError(f"{name}: expected a scalar or a list of values, got {value}")
    if per_foot and array.ndim == 1 and array.size % 3:
        raise ValueError(f"{name}: expected x, y, z for every leg or 3 per leg, got {array.size} values")
    _check_values(array, value, name)


class WholeBodyWeights(StrictModel):
    """Weights of the whole-body cost (18) (docs/settings.md: "Cost"; running cost is ``0.5 dx' W dx dt``).

    ``base_position``/``base_velocity`` are in ``BASE_WEIGHT_ORDER``; joint and torque weights are scalars
    (all joints) or one per joint (12 on the Mini Cheetah); foot weights are 3 (x, y, z, every leg) or 3 per
    leg and apply to swing feet.
    """

    base_position: BaseWeights = Field(
        (0.0, 0.0, 10.0, 1.0, 2.0, 2.0),
        description="base position and orientation: x, y, z, yaw, pitch, roll",
    )
    base_velocity: BaseWeights = Field(
        (2.0, 2.0, 2.0, 1.0, 2.0, 2.0),
        description="base linear and angular velocity: x, y, z, yaw, pitch, roll",
    )
    joint_position: Weights = Field(1.0, description="joint angles: one value or one per joint")
    joint_velocity: Weights = Field(0.01, description="joint rates: one value or one per joint")
    torque: Weights = Field(
        0.1, description="torque (regularised toward the gait's stance torques): one value or one per joint"
    )
    swing_foot_position: Weights = Field(
        (10.0, 10.0, 10.0),
        description="swing-foot position against the reference's swing: x, y, z (or 3 per leg)",
    )
    swing_foot_velocity: Weights = Field(
        (2.0, 2.0, 2.0), description="swing-foot velocity: x, y, z (or 3 per leg)"
    )

    @model_validator(mode="after")
    def _shapes(self) -> WholeBodyWeights:
        """Every weight finite and non-negative, the base ones six (``ValueError`` naming the field); the
        per-joint and per-leg counts are the robot's (``check_counts``)."""
        for name in ("base_position", "base_velocity"):
            weight_vector(getattr(self, name), 6, name)
        for name in ("joint_position", "joint_velocity", "torque"):
            _check_shape(getattr(self, name), name)
        for name in ("swing_foot_position", "swing_foot_velocity"):
            _check_shape(getattr(self, name), name, per_foot=True)
        return self

    def check_counts(self, n_joints: int, n_feet: int) -> None:
        """``ValueError`` naming the field when a per-joint or per-leg weight does not fit a robot with
        ``n_joints`` joints and ``n_feet`` feet."""
        self.state_weights(n_joints)
        self.torque_weights(n_joints)
        self.foot_position_weights(n_feet)
        self.foot_velocity_weights(n_feet)

    def state_weights(self, n_joints: int) -> np.ndarray:
        """``2 (6 + n_joints)`` weights in tangent order: base (6), joints, base velocity (6), joint
        velocities."""
        return np.concatenate(
            [
                base_weights_to_tangent(weight_vector(self.base_position, 6, "base_position")),
                weight_vector(self.joint_position, n_joints, "joint_position"),
                base_weights_to_tangent(weight_vector(self.base_velocity, 6, "base_velocity")),
                weight_vector(self.joint_velocity, n_joints, "joint_velocity"),
            ]
        )

    def torque_weights(self, n_joints: int) -> np.ndarray:
        return weight_vector(self.torque, n_joints, "torque")

    def foot_position_weights(self, n_feet: int) -> np.ndarray:
        """``3 n_feet`` weights (leg-major, x y z per leg)."""
        return leg_weights(self.swing_foot_position, n_feet, "swing_foot_position")

    def foot_velocity_weights(self, n_feet: int) -> np.ndarray:
        return leg_weights(self.swing_foot_velocity, n_feet, "swing_foot_velocity")

    @classmethod
    def regular_running(cls) -> WholeBodyWeights:
        """The authors' "regular" running set (docs/settings.md)."""
        return cls()

    @classmethod
    def regular_terminal(cls) -> WholeBodyWeights:
        """The authors' terminal set: base [0, 0, 1, 1, 1, 1], velocities 1, joints 0.5, joint speeds 0.01,
        no torque; vertical swing-foot speed weight 1 (the "touchdown foot speed" term), no foot position."""
        return cls(
            base_position=(0.0, 0.0, 1.0, 1.0, 1.0, 1.0),
            base_velocity=(1.0, 1.0, 1.0, 1.0, 1.0, 1.0),
            joint_position=0.5,
            joint_velocity=0.01,
            torque=0.0,
            swing_foot_position=0.0,
            swing_foot_velocity=(0.0, 0.0, 1.0),
        )

    @classmethod
    def zero(cls) -> WholeBodyWeights:
        """No cost at all (the terminal of an intermediate phase: its state is priced by later phases)."""
        return cls(
            base_position=(0.0,) * 6,
            base_velocity=(0.0,) * 6,
            joint_position=0.0,
            joint_velocity=0.0,
            torque=0.0,
            swing_foot_position=0.0,
            swing_foot_velocity=0.0,
        )

    @classmethod
    def barrel_roll_running(cls) -> WholeBodyWeights:
        """The authors' barrel-roll set (docs/settings.md): foot terms off."""
        return cls(
            base_position=(0.0, 0.0, 15.0, 5.0, 5.0, 5.0),
            base_velocity=(2.0, 2.0, 10.0, 2.0, 2.0, 2.0),
            joint_position=2.5,
            joint_velocity=1.2,
            torque=0.5,
            swing_foot_position=0.0,
            swing_foot_velocity=0.0,
        )

    @classmethod
    def barrel_roll_terminal(cls) -> WholeBodyWeights:
        running = cls.barrel_roll_running()
        return cls(
            base_position=running.base_position,
            base_velocity=running.base_velocity,
            joint_position=running.joint_position,
            joint_velocity=running.joint_velocity,
            torque=0.0,
            swing_foot_position=0.0,
            swing_foot_velocity=0.0,
        )


class SRBWeights(StrictModel):
    """Weights of the SRB cost (28): base tracking (``BASE_WEIGHT_ORDER``) and GRF regularisation."""

    base_position: BaseWeights = Field(
        (0.0, 0.0, 10.0, 1.0, 2.0, 2.0),
        description="base position and orientation: x, y, z, yaw, pitch, roll",
    )
    base_velocity: BaseWeights = Field(
        (2.0, 2.0, 2.0, 1.0, 2.0, 2.0),
        description="base linear and angular velocity: x, y, z, yaw, pitch, roll",
    )
    force: Weights = Field(
        0.01, description="GRF regularisation: one value, x y z shared by the feet, or 3 per foot"
    )

    @model_validator(mode="after")
    def _shapes(self) -> SRBWeights:
        """Every weight finite and non-negative, the base ones six (``ValueError`` naming the field); the
        per-foot count is the robot's (``check_counts``)."""
        self.state_weights()
        _check_shape(self.force, "force", per_foot=True)
        return self

    def check_counts(self, n_feet: int) -> None:
        """``ValueError`` naming the field when the force weights do not fit a robot with ``n_feet`` feet."""
        self.force_weights(n_feet)

    def state_weights(self) -> np.ndarray:
        """12 weights in the SRB tangent order ``[position, rotation (roll, pitch, yaw), linear velocity,
        angular velocity (roll, pitch, yaw rates)]``."""
        position = base_weights_to_tangent(weight_vector(self.base_position, 6, "base_position"))
        velocity = base_weights_to_tangent(weight_vector(self.base_velocity, 6, "base_velocity"))
        return np.concatenate([position, velocity])

    def force_weights(self, n_feet: int) -> np.ndarray:
        """``3 n_feet`` weights (foot-major, x y z per foot)."""
        return leg_weights(self.force, n_feet, "force")

    @classmethod
    def regular_running(cls) -> SRBWeights:
        """The SRB tail's running set: the authors' code's (its ``SRB_Tracking_Cost``; docs/settings.md) with
        the height weight 500 instead of 50: pitch 10, roll 5, velocities (2, 3, 3), angular rates 0.5, GRF
        regularisation 0.01.

        The tail has nothing but this weight to hold its height (the whole body also has its joints'
        posture), and the GRF regularisation, in newtons, prices what height changes: a bounding tail keeps
        its body from pitching with horizontal forces that shrink as it stands taller (0.19 / h of the
        vertical one for a stance pair 0.19 m from the centre of mass). With height 50 the tail's plans rode
        3-4 cm above the 0.25 m reference (0.28-0.29 m mean over its knots, fixed 50 ms) and pulled the
        whole-body plan up with them through the tail's value function, so the bound's height depended on
        little else: 0.258-0.281 m with where the updates fell relative to its contact switches (a whole-
        body height weight of 30 instead of 10 moved it by 1 mm). With 500 the bound rides at 0.240-0.260 m
        at every latency from 0 to 60 ms and period from 15 to 40 ms (BENCHMARKS.md, issue 19).

        Not the whole-body base weights either (paper Eq. (28) takes them from ``W_q``): with those (height
        10, angular rates 2) the bound rode at 0.32-0.34 m and the pace at 0.29 m."""
        return cls(
            base_position=(0.0, 0.0, 500.0, 0.0, 10.0, 5.0),
            base_velocity=(2.0, 3.0, 3.0, 0.5, 0.5, 0.5),
            force=0.01,
        )

    @classmethod
    def regular_terminal(cls) -> SRBWeights:
        """Half the running state weights, no GRF term (the authors' code's proportion)."""
        return cls(
            base_position=(0.0, 0.0, 250.0, 0.0, 5.0, 2.5),
            base_velocity=(1.0, 1.5, 1.5, 0.25, 0.25, 0.25),
            force=0.0,
        )

    @classmethod
    def from_whole_body(cls, weights: WholeBodyWeights, force: float = 0.01) -> SRBWeights:
        """Same base weights as a whole-body set (Eq. (28): the base components of ``Wq``, ``Wqdot``)."""
        return cls(base_position=weights.base_position, base_velocity=weights.base_velocity, force=force)
