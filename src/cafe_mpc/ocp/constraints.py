"""Whole-body constraints (paper Eqs. (25)-(27)) and their relaxed-barrier treatment (Sec. III-B-2).

Inequalities ``g(x, u) >= 0`` of a knot become the cost ``eps * B(g)`` (``RelaxedBarrier``; times the
knot's time step on running knots) with Gauss-Newton Hessian ``G' diag(eps B'') G``, and their worst
violation is reported in ``ActionData.constraint_violation``:

* friction pyramid with unilateral force (26) on the stance-foot forces, ``[fz, mu fz -+ fx, mu fz -+ fy]``;
  the forces are outputs of the KKT dynamics, so ``G = P dF/d(x, u)`` uses the dynamics derivatives;
* torque limits (27a), joint position limits (27b), joint speed limits (27c), as boxes
  ``[upper - z, z - lower]``;
* minimum base height ``z_base - h_min`` (docs/settings.md).

The touchdown condition (25), ``p_z - foot_radius - h_c = 0`` for the feet that touch down at the end of a
phase, is an equality on the phase's last state (``SwitchingConstraint``) for the solver's augmented
Lagrangian.

All constraints of a knot share one ``BarrierStack`` (concatenated ``g`` with per-row ``delta``/``eps``),
evaluated once per ``calc`` into preallocated arrays.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from cafe_mpc.core.contacts import as_contact_flags
from cafe_mpc.core.interfaces import ConstraintData, SwitchingConstraint
from cafe_mpc.dynamics.multibody_state import MultibodyState
from cafe_mpc.ocp.barrier import RelaxedBarrier
from cafe_mpc.robots.robot import Robot

if TYPE_CHECKING:
    from cafe_mpc.ocp.knots import WholeBodyKnotData

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
    """Which whole-body inequalities are on, their bounds and barrier parameters (docs/settings.md).

    Limits default to the robot's (``torque_limits``, ``position_lower/upper``, ``velocity_limits``); the
    joint-speed barrier parameters are not published and reuse the joint-limit ones.
    """

    friction_cone: bool = True
    friction_coefficient: float = 0.6
    torque_limits: bool = True
    joint_position_limits: bool = True
    joint_velocity_limits: bool = True
    minimum_base_height: float | None = 0.20
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


# --------------------------------------------------------------------------------------------------
# Barrier evaluation
# --------------------------------------------------------------------------------------------------


class BarrierData:
    """Concatenated constraint values and barrier derivatives of one knot."""

    def __init__(self, dim: int) -> None:
        self.g = np.zeros(dim)
        self.value = 0.0
        self.d1 = np.zeros(dim)  # eps * B'(g)
        self.d2 = np.zeros(dim)  # eps * B''(g)
        self._inside = np.zeros(dim, dtype=bool)
        self._safe = np.zeros(dim)
        self._z = np.zeros(dim)
        self._b = np.zeros(dim)
        self._work = np.zeros(dim)


class BarrierStack:
    """``sum_i eps_i B(g_i)`` with ``RelaxedBarrier``'s formula, evaluated with derivatives in one pass into
    preallocated arrays (the reference implementation allocates; this is the per-knot hot path)."""

    def __init__(self, deltas: np.ndarray, epsilons: np.ndarray) -> None:
        self.dim = len(deltas)
        if self.dim:
            self.reference = RelaxedBarrier(deltas, epsilons)  # validates; used by tests as ground truth
        self.delta = np.asarray(deltas, dtype=float)
        self.eps = np.asarray(epsilons, dtype=float)
        self._two_delta = 2.0 * self.delta
        self._inv_delta = 1.0 / self.delta if self.dim else self.delta
        self._outside_d2 = self.eps * self._inv_delta * self._inv_delta
        self._log_delta_plus_half = np.log(self.delta) + 0.5 if self.dim else self.delta

    def create_data(self) -> BarrierData:
        return BarrierData(self.dim)

    def evaluate(self, bd: BarrierData) -> float:
        """Write ``bd.d1``, ``bd.d2`` and return the barrier value for ``bd.g``."""
        if self.dim == 0:
            bd.value = 0.0
            return 0.0
        g, inside, safe, z, b, work = bd.g, bd._inside, bd._safe, bd._z, bd._b, bd._work
        np.greater(g, self.delta, out=inside)
        np.maximum(g, self.delta, out=safe)
        # Quadratic extension (g <= delta): 0.5 z^2 - 0.5 - ln(delta), z = (g - 2 delta) / delta.
        np.subtract(g, self._two_delta, out=z)
        z *= self._inv_delta
        np.multiply(z, z, out=b)
        b *= 0.5
        b -= self._log_delta_plus_half
        np.multiply(z, self._inv_delta, out=bd.d1)
        bd.d2[:] = self._outside_d2
        # Log branch (g > delta): -ln g, -1/g, 1/g^2.
        np.log(safe, out=work)
        np.negative(work, out=work)
        np.copyto(b, work, where=inside)
        np.reciprocal(safe, out=work)
        np.negative(work, out=safe)  # safe is free now: -1/g
        np.copyto(bd.d1, safe, where=inside)
        np.multiply(work, work, out=work)
        work *= self.eps
        np.copyto(bd.d2, work, where=inside)
        bd.d1 *= self.eps
        value = float(np.dot(self.eps, b))
        bd.value = value
        return value


# --------------------------------------------------------------------------------------------------
# Inequality terms
# --------------------------------------------------------------------------------------------------


class InequalityData:
    """``g`` (a view into the knot's stacked ``g``) and dense Jacobians ``Gx``, ``Gu`` (views into one
    ``G = [Gx | Gu]`` so that the Gauss-Newton Hessian takes one product)."""

    def __init__(self, g: np.ndarray, dim: int, ndx: int, nu: int) -> None:
        self.g = g
        self.G = np.zeros((dim, ndx + nu))
        self.Gx = self.G[:, :ndx]
        self.Gu = self.G[:, ndx:]


class WholeBodyInequality(ABC):
    """``g(x, u) >= 0`` on a whole-body knot, with its barrier parameters."""

    name: str = ""
    dim: int
    barrier: BarrierParameters
    needs_control: bool = False
    needs_forces: bool = False

    def create_data(self, g: np.ndarray, ndx: int, nu: int) -> InequalityData:
        return InequalityData(g, self.dim, ndx, nu)

    @abstractmethod
    def calc(self, cd: InequalityData, kd: WholeBodyKnotData, x: np.ndarray, u: np.ndarray) -> None:
        """Write ``cd.g``."""

    @abstractmethod
    def calc_diff(self, cd: InequalityData, kd: WholeBodyKnotData, x: np.ndarray, u: np.ndarray) -> None:
        """Write ``cd.Gx``/``cd.Gu`` (where not constant). Assumes ``calc`` ran first."""

    def accumulate(
        self, cd: InequalityData, kd: WholeBodyKnotData, d1: np.ndarray, d2: np.ndarray, scale: float
    ) -> None:
        """Add the barrier gradient ``G' d1`` and Gauss-Newton Hessian ``G' diag(d2) G`` times ``scale``."""
        if not self.needs_control:
            kd.Lx += cd.Gx.T @ (scale * d1)
            kd.Lxx += cd.Gx.T @ ((scale * d2)[:, None] * cd.Gx)
            return
        ndx = kd.Lx.shape[0]
        gradient = cd.G.T @ (scale * d1)
        hessian = cd.G.T @ ((scale * d2)[:, None] * cd.G)
        kd.Lx += gradient[:ndx]
        kd.Lu += gradient[ndx:]
        kd.Lxx += hessian[:ndx, :ndx]
        kd.Lux += hessian[ndx:, :ndx]
        kd.Luu += hessian[ndx:, ndx:]


class BoxConstraint(WholeBodyInequality):
    """``lower <= z <= upper`` on a contiguous block ``z`` of ``u`` or of ``x`` (Eq. (27)).

    ``g = [upper - z, z - lower]``. For ``x`` the block is ``x[coordinate_slice]`` with tangent columns
    ``tangent_slice`` (joint angles and rates have identity tangent maps).
    """

    def __init__(
        self,
        name: str,
        lower: np.ndarray,
        upper: np.ndarray,
        barrier: BarrierParameters,
        on_control: bool,
        coordinate_slice: slice,
        tangent_slice: slice,
        n_columns: int,
    ) -> None:
        self.name = name
        self.lower = np.asarray(lower, dtype=float)
        self.upper = np.asarray(upper, dtype=float)
        if self.lower.shape != self.upper.shape or np.any(self.lower >= self.upper):
            raise ValueError(f"{name}: need lower < upper element-wise")
        self.size = len(self.lower)
        self.dim = 2 * self.size
        self.barrier = barrier
        self.needs_control = on_control
        self.coordinate_slice = coordinate_slice
        self.tangent_slice = tangent_slice
        # Flat indices of the diagonal entries of Luu (control) or Lxx (state) this box touches.
        self._flat_diagonal = np.arange(n_columns)[tangent_slice] * (n_columns + 1)
        if len(self._flat_diagonal) != self.size:
            raise ValueError(f"{name}: the tangent slice does not match the {self.size} bounds")

    def create_data(self, g: np.ndarray, ndx: int, nu: int) -> InequalityData:
        cd = InequalityData(g, self.dim, ndx, nu)
        jacobian = cd.Gu if self.needs_control else cd.Gx
        eye = np.eye(self.size)
        jacobian[: self.size, self.tangent_slice] = -eye
        jacobian[self.size :, self.tangent_slice] = eye
        return cd

    def calc(self, cd, kd, x, u) -> None:
        z = (u if self.needs_control else x)[self.coordinate_slice]
        np.subtract(self.upper, z, out=cd.g[: self.size])
        np.subtract(z, self.lower, out=cd.g[self.size :])

    def calc_diff(self, cd, kd, x, u) -> None:
        pass  # constant Jacobian (set at creation)

    def accumulate(self, cd, kd, d1, d2, scale) -> None:
        m = self.size
        gradient = scale * (d1[m:] - d1[:m])
        curvature = scale * (d2[m:] + d2[:m])
        if self.needs_control:
            kd.Lu[self.tangent_slice] += gradient
            kd.Luu.reshape(-1)[self._flat_diagonal] += curvature
        else:
            kd.Lx[self.tangent_slice] += gradient
            kd.Lxx.reshape(-1)[self._flat_diagonal] += curvature


class MinimumBaseHeight(WholeBodyInequality):
    """``z_base - h_min >= 0`` (docs/settings.md). ``d z / d(base linear tangent) = R[2, :]``."""

    name = "base_height"
    dim = 1

    def __init__(self, minimum_height: float, barrier: BarrierParameters) -> None:
        self.minimum_height = float(minimum_height)
        self.barrier = barrier

    def calc(self, cd, kd, x, u) -> None:
        cd.g[0] = x[2] - self.minimum_height

    def calc_diff(self, cd, kd, x, u) -> None:
        cd.Gx[0, 0:3] = kd.base_rotation[2]

    def accumulate(self, cd, kd, d1, d2, scale) -> None:
        row = kd.base_rotation[2]
        kd.Lx[0:3] += (scale * float(d1[0])) * row
        kd.Lxx[0:3, 0:3] += ((scale * float(d2[0])) * row)[:, None] * row


def friction_pyramid_matrix(mu: float) -> np.ndarray:
    """Rows ``[fz, mu fz - fx, mu fz + fx, mu fz - fy, mu fz + fy]`` of Eq. (26) (unilateral first)."""
    return np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, mu], [1.0, 0.0, mu], [0.0, -1.0, mu], [0.0, 1.0, mu]])


class FrictionPyramid(WholeBodyInequality):
    """Inner friction pyramid and unilateral force (26) on every stance foot's KKT force."""

    name = "friction"
    needs_control = True
    needs_forces = True

    def __init__(self, n_contacts: int, mu: float, barrier: BarrierParameters) -> None:
        self.n_contacts = n_contacts
        self.mu = float(mu)
        self.dim = 5 * n_contacts
        self.barrier = barrier
        self.matrix = np.kron(np.eye(n_contacts), friction_pyramid_matrix(self.mu))

    def calc(self, cd, kd, x, u) -> None:
        np.matmul(self.matrix, kd.dynamics.forces, out=cd.g)

    def calc_diff(self, cd, kd, x, u) -> None:
        np.matmul(self.matrix, kd.dynamics.dforces_dx, out=cd.Gx)
        np.matmul(self.matrix, kd.dynamics.dforces_du, out=cd.Gu)


def whole_body_inequalities(
    robot: Robot, stance: Sequence[bool], settings: WholeBodyConstraintSettings, running: bool
) -> list[WholeBodyInequality]:
    """The inequalities of a whole-body knot: all of them on running knots, the state-only ones (joint
    position/speed limits, base height) on terminal knots."""
    stance = as_contact_flags(stance)
    nq, nv = robot.model.nq, robot.model.nv
    constraints: list[WholeBodyInequality] = []
    n_contacts = sum(stance)
    if running and settings.friction_cone and n_contacts:
        constraints.append(
            FrictionPyramid(n_contacts, settings.friction_coefficient, settings.friction_barrier)
        )
    if running and settings.torque_limits:
        limits = (
            np.asarray(settings.torque_limit_values, dtype=float)
            if settings.torque_limit_values is not None
            else robot.torque_limits
        )
        constraints.append(
            BoxConstraint(
                "torque_limits",
                -limits,
                limits,
                settings.torque_barrier,
                True,
                slice(0, 12),
                slice(0, 12),
                12,
            )
        )
    if settings.joint_position_limits:
        constraints.append(
            BoxConstraint(
                "joint_position_limits",
                robot.position_lower,
                robot.position_upper,
                settings.joint_position_barrier,
                False,
                slice(7, nq),
                slice(6, nv),
                2 * nv,
            )
        )
    if settings.joint_velocity_limits:
        constraints.append(
            BoxConstraint(
                "joint_velocity_limits",
                -robot.velocity_limits,
                robot.velocity_limits,
                settings.joint_velocity_barrier,
                False,
                slice(nq + 6, nq + nv),
                slice(nv + 6, 2 * nv),
                2 * nv,
            )
        )
    if settings.minimum_base_height is not None:
        constraints.append(MinimumBaseHeight(settings.minimum_base_height, settings.base_height_barrier))
    return constraints


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
