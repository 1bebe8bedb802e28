"""Whole-body constraints (paper Eqs. (25)-(27)) and their relaxed-barrier treatment (Sec. III-B-2).

Inequalities ``g(x, u) >= 0`` of a knot become the cost ``eps * B(g)`` (``RelaxedBarrier``; times the
knot's time step on running knots) with Gauss-Newton Hessian ``G' diag(eps B'') G``, and their worst
violation is reported in ``ActionData.constraint_violation``:

* friction pyramid with unilateral force (26) on the stance-foot forces, ``[fz - fz_min, mu fz -+ fx,
  mu fz -+ fy]`` (``fz_min = minimum_normal_force``, 0 in (26): a stance foot planned at no load floats
  just above the floor of a compliant plant and cannot push at once when its load is asked for);
  the forces are outputs of the KKT dynamics, so ``G = P dF/d(x, u)`` uses the dynamics derivatives;
* torque limits (27a), joint position limits (27b), joint speed limits (27c), as boxes
  ``[upper - z, z - lower]``;
* minimum base height ``z_base - h_min`` (settings facts).

The touchdown condition (25), ``p_z - foot_radius - h_c = 0`` for the feet that touch down at the end of a
phase, is an equality on the phase's last state (``SwitchingConstraint``) for the solver's augmented
Lagrangian.

All constraints of a knot share one ``BarrierStack`` (concatenated ``g`` with per-row ``delta``/``eps``),
evaluated once per ``calc`` into preallocated arrays.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from cafe_mpc.config import DEFAULT_FRICTION
from cafe_mpc.core.contacts import as_contact_flags
from cafe_mpc.core.interfaces import ConstraintData, SwitchingConstraint
from cafe_mpc.dynamics.multibody_state import MultibodyState
from cafe_mpc.robots.robot import Robot

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


@dataclass(frozen=True)
class BarrierParameters:
    """``delta`` (switch to the quadratic extension) and weight ``eps`` of a relaxed barrier."""

    delta: float
    eps: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.delta) and self.delta > 0):
            raise ValueError(f"barrier delta must be positive, got {self.delta}")
        if not (math.isfinite(self.eps) and self.eps >= 0):
            raise ValueError(f"barrier eps must be non-negative, got {self.eps}")


@dataclass(frozen=True)
class WholeBodyConstraintSettings:
    """Which whole-body inequalities are on, their bounds and barrier parameters (settings facts).

    Limits default to the robot's (``torque_limits``, ``position_lower/upper``, ``velocity_limits``); the
    joint-speed barrier parameters are not in the facts and reuse the joint-limit ones.
    """

    friction_cone: bool = True
    friction_coefficient: float = DEFAULT_FRICTION
    torque_limits: bool = True
    joint_position_limits: bool = True
    joint_velocity_limits: bool = True
    minimum_base_height: float | None = 0.20
    minimum_normal_force: float = 0.0
    """N; the least normal force of every stance foot (the pyramid's unilateral row, ``fz >= fz_min``)."""
    friction_barrier: BarrierParameters = field(default_factory=lambda: BarrierParameters(0.2, 0.05))
    torque_barrier: BarrierParameters = field(default_factory=lambda: BarrierParameters(1.0, 0.01))
    # eps below is 10x (joints) and 100x (height) smaller than the published values: -ln g has a non-zero
    # gradient at the reference, and with eps = 0.1 the minimum-height barrier lifted the standing base
    # from 0.25 m to 0.33 m in closed loop (the terminal knot, not scaled by dt, pulls hardest).
    joint_position_barrier: BarrierParameters = field(default_factory=lambda: BarrierParameters(0.1, 0.01))
    joint_velocity_barrier: BarrierParameters = field(default_factory=lambda: BarrierParameters(0.1, 0.01))
    base_height_barrier: BarrierParameters = field(default_factory=lambda: BarrierParameters(0.01, 0.001))
    torque_limit_values: tuple[float, ...] | None = None
    """Override of the robot's torque limits (12 values, symmetric)."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.friction_coefficient) and self.friction_coefficient > 0):
            raise ValueError(f"friction coefficient must be positive, got {self.friction_coefficient}")
        if not (math.isfinite(self.minimum_normal_force) and self.minimum_normal_force >= 0):
            raise ValueError(f"minimum normal force must be finite and >= 0, got {self.minimum_normal_force}")
        if self.minimum_base_height is not None and not math.isfinite(self.minimum_base_height):
            raise ValueError("minimum base height must be finite or None")
        if self.torque_limit_values is not None and len(self.torque_limit_values) != 12:
            raise ValueError("torque_limit_values needs 12 values")

    @classmethod
    def unconstrained(cls) -> WholeBodyConstraintSettings:
        return cls(
            friction_cone=False,
            torque_limits=False,
            joint_position_limits=False,
            joint_velocity_limits=False,
            minimum_base_height=None,
        )


def friction_pyramid_matrix(mu: float) -> np.ndarray:
    """Rows ``[fz, mu fz - fx, mu fz + fx, mu fz - fy, mu fz + fy]`` of Eq. (26) (unilateral first)."""
    return np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, mu], [1.0, 0.0, mu], [0.0, -1.0, mu], [0.0, 1.0, mu]])


# --------------------------------------------------------------------------------------------------
# Touchdown (switching) constraint
# --------------------------------------------------------------------------------------------------


class TouchdownData(ConstraintData):
    def __init__(self, constraint: TouchdownFootHeight) -> None:
        super().__init__(constraint)
        self.pinocchio = constraint.model.createData()


class TouchdownFootHeight(SwitchingConstraint):
    """Eq. (25): ``p_z(foot) - foot_radius - h_c = 0`` for each foot that touches down at the phase end.

    ``surface_heights`` (one per constrained foot, world z of the contact surface) is a mutable parameter
    (set it in place when the terrain estimate changes).
    """

    def __init__(
        self, robot: Robot, touchdown: Sequence[bool], surface_height: float | Sequence[float] = 0.0
    ) -> None:
        touchdown = as_contact_flags(touchdown, "touchdown flags")
        self.legs = tuple(leg for leg in range(4) if touchdown[leg])
        if not self.legs:
            raise ValueError("a touchdown constraint needs at least one foot touching down")
        self.model = robot.model
        self.frame_ids = tuple(robot.foot_frame_ids[leg] for leg in self.legs)
        self.state = MultibodyState(robot.model)
        self.dim = len(self.legs)
        self.foot_radius = robot.foot_radius
        self.surface_heights = np.broadcast_to(np.asarray(surface_height, dtype=float), (self.dim,)).copy()

    def create_data(self) -> TouchdownData:
        return TouchdownData(self)

    def calc(self, data: TouchdownData, x: np.ndarray) -> None:
        pd = data.pinocchio
        pin.forwardKinematics(self.model, pd, x[: self.model.nq])
        for row, frame_id in enumerate(self.frame_ids):
            data.value[row] = pin.updateFramePlacement(self.model, pd, frame_id).translation[2]
        data.value -= self.foot_radius
        data.value -= self.surface_heights

    def calc_diff(self, data: TouchdownData, x: np.ndarray) -> None:
        pd, nv = data.pinocchio, self.model.nv
        pin.computeJointJacobians(self.model, pd, x[: self.model.nq])
        for row, frame_id in enumerate(self.frame_ids):
            data.Hx[row, :nv] = pin.getFrameJacobian(self.model, pd, frame_id, LWA)[2]
