"""Cost weights of the whole-body and SRB knots (paper Eqs. (18) and (28)) and the authors' weight sets.

Every cost term of a knot is ``0.5 * r' W r`` with a residual ``r(x, u)`` and a diagonal weight ``W``; a
running knot multiplies the sum by its time step (``0.5 * dx' W dx * dt``, docs/settings.md). A weight set
(``WholeBodyWeights``, ``SRBWeights``) is the settings of those diagonals, written as in the authors' code:
base weights in the order ``[x, y, z, yaw, pitch, roll]``, joint weights one for all joints or one per
joint, foot weights ``(x, y, z)`` for every leg or one triple per leg. Each set gives its diagonals in the
knots' tangent order ``[lin x, y, z, ang x (roll), y (pitch), z (yaw)]`` (``state_weights``, ...). The run
config's ``costs`` and ``reference.costs`` sections are these models.
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
"""A scalar (every joint / axis) or a tuple (12 per joint, or 3 x y z shared by the legs, or 12 per leg)."""
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
    if not np.all(np.isfinite(array)) or np.any(array < 0):
        raise ValueError(f"{name}: weights must be finite and non-negative, got {value}")
    return array


def leg_weights(value: float | Sequence[float], name: str) -> np.ndarray:
    """3 weights (x, y, z) shared by the four legs, or 12 (per leg) -> 12 (leg-major)."""
    array = np.asarray(value, dtype=float)
    if array.ndim == 0:
        array = np.full(3, float(array))
    if array.shape == (3,):
        array = np.tile(array, 4)
    return weight_vector(array, 12, name)


class WholeBodyWeights(StrictModel):
    """Weights of the whole-body cost (18) (docs/settings.md: "Cost"; running cost is ``0.5 dx' W dx dt``).

    ``base_position``/``base_velocity`` are in ``BASE_WEIGHT_ORDER``; joint and torque weights are scalars
    (all joints) or 12 values; foot weights are 3 (x, y, z, every leg) or 12 values and apply to swing feet.
    """

    base_position: BaseWeights = Field(
        (0.0, 0.0, 10.0, 1.0, 2.0, 2.0),
        description="base position and orientation: x, y, z, yaw, pitch, roll",
    )
    base_velocity: BaseWeights = Field(
        (2.0, 2.0, 2.0, 1.0, 2.0, 2.0),
        description="base linear and angular velocity: x, y, z, yaw, pitch, roll",
    )
    joint_position: Weights = Field(1.0, description="joint angles: one value or 12")
    joint_velocity: Weights = Field(0.01, description="joint rates: one value or 12")
    torque: Weights = Field(
        0.1, description="torque (regularised toward the gait's stance torques): one value or 12"
    )
    swing_foot_position: Weights = Field(
        (10.0, 10.0, 10.0), description="swing-foot position against the reference's swing: x, y, z (or 12)"
    )
    swing_foot_velocity: Weights = Field((2.0, 2.0, 2.0), description="swing-foot velocity: x, y, z (or 12)")

    @model_validator(mode="after")
    def _shapes(self) -> WholeBodyWeights:
        """Every weight of the right count, finite and non-negative (``ValueError`` naming the field)."""
        self.state_weights()
        self.torque_weights()
        self.foot_position_weights()
        self.foot_velocity_weights()
        return self

    def state_weights(self) -> np.ndarray:
        """36 weights in tangent order: base (6), joints (12), base velocity (6), joint velocity (12)."""
        return np.concatenate(
            [
                base_weights_to_tangent(weight_vector(self.base_position, 6, "base_position")),
                weight_vector(self.joint_position, 12, "joint_position"),
                base_weights_to_tangent(weight_vector(self.base_velocity, 6, "base_velocity")),
                weight_vector(self.joint_velocity, 12, "joint_velocity"),
            ]
        )

    def torque_weights(self) -> np.ndarray:
        return weight_vector(self.torque, 12, "torque")

    def foot_position_weights(self) -> np.ndarray:
        """12 weights (leg-major, x y z per leg)."""
        return leg_weights(self.swing_foot_position, "swing_foot_position")

    def foot_velocity_weights(self) -> np.ndarray:
        return leg_weights(self.swing_foot_velocity, "swing_foot_velocity")

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
    force: Weights = Field(0.01, description="GRF regularisation: one value, 3 shared by the feet, or 12")

    @model_validator(mode="after")
    def _shapes(self) -> SRBWeights:
        """Every weight of the right count, finite and non-negative (``ValueError`` naming the field)."""
        self.state_weights()
        self.force_weights()
        return self

    def state_weights(self) -> np.ndarray:
        """12 weights in the SRB tangent order ``[position, rotation (roll, pitch, yaw), linear velocity,
        angular velocity (roll, pitch, yaw rates)]``."""
        position = base_weights_to_tangent(weight_vector(self.base_position, 6, "base_position"))
        velocity = base_weights_to_tangent(weight_vector(self.base_velocity, 6, "base_velocity"))
        return np.concatenate([position, velocity])

    def force_weights(self) -> np.ndarray:
        return leg_weights(self.force, "force")

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
