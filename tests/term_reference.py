"""The term-by-term whole-body knot evaluation that the fused knot replaced (test reference only).

``TermKnot`` evaluates the cost (18) and the barrier-priced constraints (26), (27) one term object at a time,
each with its own residual and dense Jacobian, summed into the knot's derivatives. The package's
``WholeBodyKnot`` computes the same quantities in one fused, compiled pass;
``tests/test_costs_constraints.py`` checks that both agree (cost, gradient, Gauss-Newton Hessian) and that
this reference matches finite differences term by term.
"""

from __future__ import annotations

import copy
from abc import ABC, abstractmethod
from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from cafe_mpc.config.weights import BaseError, WholeBodyWeights, leg_weights, weight_vector
from cafe_mpc.core.contacts import as_contact_flags, flags_to_string
from cafe_mpc.core.interfaces import ActionData, ActionModel
from cafe_mpc.dynamics.kinematics import FootKinematics
from cafe_mpc.dynamics.multibody_state import MultibodyState
from cafe_mpc.dynamics.whole_body import WholeBodyDynamics
from cafe_mpc.ocp.barrier import RelaxedBarrier
from cafe_mpc.ocp.constraints import BarrierParameters, WholeBodyConstraintSettings, friction_pyramid_matrix
from cafe_mpc.ocp.knots import WholeBodyReference
from cafe_mpc.robots.robot import Robot

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class CostTermData:
    """Residual and dense Jacobians of one term (preallocated)."""

    def __init__(self, dim: int, ndx: int, nu: int) -> None:
        self.r = np.zeros(dim)
        self.weighted_r = np.zeros(dim)
        self.Rx = np.zeros((dim, ndx))
        self.Ru = np.zeros((dim, nu))


class WholeBodyCostTerm(ABC):
    """``0.5 * r' diag(weights) r`` on the whole-body state (and control)."""

    name: str = ""
    dim: int
    weights: np.ndarray
    needs_control: bool = False
    position_legs: tuple[int, ...] = ()
    """Legs whose foot position (and position Jacobian) the term reads from the knot's kinematics."""
    velocity_legs: tuple[int, ...] = ()

    def create_data(self, ndx: int, nu: int) -> CostTermData:
        return CostTermData(self.dim, ndx, nu)

    @abstractmethod
    def calc(
        self, td: CostTermData, kd: TermKnotData, x: np.ndarray, u: np.ndarray, ref: WholeBodyReference
    ) -> float:
        """Write ``td.r`` and return ``0.5 r' W r`` (not yet scaled by the time step)."""

    @abstractmethod
    def calc_diff(
        self, td: CostTermData, kd: TermKnotData, x: np.ndarray, u: np.ndarray, ref: WholeBodyReference
    ) -> None:
        """Write ``td.Rx`` / ``td.Ru``. Assumes ``calc`` ran first."""

    def residual_jacobians(self, td: CostTermData) -> tuple[np.ndarray, np.ndarray]:
        """Dense ``(Rx, Ru)`` after ``calc_diff`` (for tests and diagnostics, not the hot path)."""
        return td.Rx, td.Ru

    def accumulate(self, td: CostTermData, kd: TermKnotData, scale: float) -> None:
        """Add ``scale * (Rx' W r, Rx' W Rx, ...)`` to the knot's derivatives (dense default)."""
        scaled_weights = self.weights * scale
        weighted_r = scaled_weights * td.r
        kd.Lx += td.Rx.T @ weighted_r
        weighted_rx = scaled_weights[:, None] * td.Rx
        kd.Lxx += td.Rx.T @ weighted_rx
        if self.needs_control:
            kd.Lu += td.Ru.T @ weighted_r
            weighted_ru = scaled_weights[:, None] * td.Ru
            kd.Luu += td.Ru.T @ weighted_ru
            kd.Lux += td.Ru.T @ weighted_rx


class StateTrackingCost(WholeBodyCostTerm):
    """``||x ⊖ x_ref||^2_W`` (first two terms of Eq. (18)).

    ``base_error`` chooses the base residual:

    * ``"tangent"``: ``state.difference(x_ref, x)``; the base part is the SE(3) logarithm of the relative
      pose, i.e. the position error in the *reference's base frame* (coupled with rotation), and the base
      velocity error in base-frame coordinates;
    * ``"world"``: base position error ``p - p_ref`` and linear velocity error ``R v - R_ref v_ref`` in the
      world frame (the paper's ``c``, ``c_dot``), orientation error ``log3(R_ref' R)`` and angular-velocity
      error in body coordinates. Same first-order behaviour near a level reference; the weights keep their
      world meaning (height, vertical speed) when the reference rolls or pitches far (barrel roll).
    """

    name = "state"

    def __init__(self, model: pin.Model, weights: np.ndarray, base_error: BaseError = "tangent") -> None:
        if base_error not in ("tangent", "world"):
            raise ValueError(f"base_error must be 'tangent' or 'world', got {base_error!r}")
        self.model = model
        self.nq, self.nv = model.nq, model.nv
        self.dim = 2 * model.nv
        self.weights = weight_vector(weights, self.dim, "state weights")
        self.base_error = base_error
        nv = self.nv
        # Rows/columns whose Jacobian is not the identity: the base pose (0:6) always, the base velocity
        # (nv:nv+6) too in "world" mode; ``base_jacobian`` is the 12 x 12 block on [0:6, nv:nv+6].
        self._base = np.r_[0:6, nv : nv + 6]
        identity_mask = np.ones(self.dim)
        identity_mask[0:6] = 0.0
        if base_error == "world":
            identity_mask[nv : nv + 6] = 0.0
        self._identity_weights = self.weights * identity_mask
        self._identity_mask = identity_mask
        self._base_weights = self.weights[self._base]

    def create_data(self, ndx: int, nu: int) -> CostTermData:
        td = CostTermData(self.dim, ndx, nu)
        td.base_jacobian = np.zeros((12, 12))  # rows/columns self._base
        td.base_jacobian[6:, 6:] = np.eye(6)
        return td

    def calc(self, td, kd, x, u, ref) -> float:
        nq, nv = self.nq, self.nv
        x_ref = ref.state
        r = td.r
        if self.base_error == "tangent":
            r[:nv] = pin.difference(self.model, x_ref[:nq], x[:nq])
            np.subtract(x[nq:], x_ref[nq:], out=r[nv:])
        else:
            rotation = kd.base_rotation
            rotation_ref = pin.Quaternion(x_ref[3:7]).toRotationMatrix()
            td.rotation_ref = rotation_ref
            td.rotation_error = rotation_ref.T @ rotation
            np.subtract(x[0:3], x_ref[0:3], out=r[0:3])
            r[3:6] = pin.log3(td.rotation_error)
            np.subtract(x[7:nq], x_ref[7:nq], out=r[6:nv])
            np.subtract(x[nq + 3 :], x_ref[nq + 3 :], out=r[nv + 3 :])
            r[nv : nv + 3] = rotation @ x[nq : nq + 3] - rotation_ref @ x_ref[nq : nq + 3]
        np.multiply(self.weights, r, out=td.weighted_r)
        return 0.5 * float(np.dot(td.weighted_r, r))

    def calc_diff(self, td, kd, x, u, ref) -> None:
        nq = self.nq
        jac = td.base_jacobian
        if self.base_error == "tangent":
            jac[:6, :6] = pin.dDifference(self.model, ref.state[:nq], x[:nq], pin.ArgumentPosition.ARG1)[
                :6, :6
            ]
        else:
            rotation = kd.base_rotation
            jac[0:3, 0:3] = rotation
            jac[3:6, 3:6] = pin.Jlog3(td.rotation_error)
            jac[6:9, 3:6] = -rotation @ pin.skew(x[nq : nq + 3])
            jac[6:9, 6:9] = rotation

    def residual_jacobians(self, td: CostTermData) -> tuple[np.ndarray, np.ndarray]:
        rx = np.eye(self.dim)
        rx[np.ix_(self._base, self._base)] = td.base_jacobian
        return rx, td.Ru

    def accumulate(self, td, kd, scale) -> None:
        nv = self.nv
        weighted = td.weighted_r  # W r (from calc)
        jac = td.base_jacobian
        # Identity-Jacobian part: gradient W r, Hessian diag(W).
        kd.Lx += scale * (weighted * self._identity_mask)
        kd.Lxx.reshape(-1)[:: self.dim + 1] += scale * self._identity_weights
        if self.base_error == "tangent":
            pose_jacobian = jac[:6, :6]
            kd.Lx[0:6] += pose_jacobian.T @ (scale * weighted[0:6])
            kd.Lxx[0:6, 0:6] += pose_jacobian.T @ ((scale * self._base_weights[:6])[:, None] * pose_jacobian)
            return
        base_gradient = jac.T @ (scale * weighted[self._base])
        kd.Lx[0:6] += base_gradient[:6]
        kd.Lx[nv : nv + 6] += base_gradient[6:]
        hessian = jac.T @ ((scale * self._base_weights)[:, None] * jac)
        kd.Lxx[0:6, 0:6] += hessian[:6, :6]
        kd.Lxx[0:6, nv : nv + 6] += hessian[:6, 6:]
        kd.Lxx[nv : nv + 6, 0:6] += hessian[6:, :6]
        kd.Lxx[nv : nv + 6, nv : nv + 6] += hessian[6:, 6:]


class SwingFootPositionCost(WholeBodyCostTerm):
    """``||S (p - p_ref)||^2_Wp`` on the swing feet (third term of Eq. (18)); world-frame foot positions."""

    name = "swing_foot_position"

    def __init__(self, legs: Sequence[int], weights: np.ndarray, nv: int) -> None:
        self.position_legs = tuple(legs)
        self.legs = self.position_legs
        self.nv = nv
        self.dim = 3 * len(self.legs)
        per_leg = leg_weights(weights, 4, "swing foot position weights").reshape(4, 3)
        self.weights = per_leg[list(self.legs)].reshape(-1)

    def calc(self, td, kd, x, u, ref) -> float:
        kin = kd.kinematics
        for row, leg in enumerate(self.legs):
            np.subtract(kin.positions[leg], ref.foot_positions[leg], out=td.r[3 * row : 3 * row + 3])
        np.multiply(self.weights, td.r, out=td.weighted_r)
        return 0.5 * float(np.dot(td.weighted_r, td.r))

    def calc_diff(self, td, kd, x, u, ref) -> None:
        kin = kd.kinematics
        for row, leg in enumerate(self.legs):
            td.Rx[3 * row : 3 * row + 3, : self.nv] = kin.position_jacobians[leg]

    def accumulate(self, td, kd, scale) -> None:
        nv = self.nv
        jac = td.Rx[:, :nv]
        kd.Lx[:nv] += jac.T @ (scale * td.weighted_r)
        kd.Lxx[:nv, :nv] += jac.T @ ((scale * self.weights)[:, None] * jac)


class SwingFootVelocityCost(WholeBodyCostTerm):
    """``||S (pdot - pdot_ref)||^2_Wpdot`` on the swing feet (fourth term of Eq. (18)); world frame."""

    name = "swing_foot_velocity"

    def __init__(self, legs: Sequence[int], weights: np.ndarray, nv: int) -> None:
        self.velocity_legs = tuple(legs)
        self.legs = self.velocity_legs
        self.nv = nv
        self.dim = 3 * len(self.legs)
        per_leg = leg_weights(weights, 4, "swing foot velocity weights").reshape(4, 3)
        self.weights = per_leg[list(self.legs)].reshape(-1)

    def calc(self, td, kd, x, u, ref) -> float:
        kin = kd.kinematics
        for row, leg in enumerate(self.legs):
            np.subtract(kin.velocities[leg], ref.foot_velocities[leg], out=td.r[3 * row : 3 * row + 3])
        np.multiply(self.weights, td.r, out=td.weighted_r)
        return 0.5 * float(np.dot(td.weighted_r, td.r))

    def calc_diff(self, td, kd, x, u, ref) -> None:
        kin, nv = kd.kinematics, self.nv
        for row, leg in enumerate(self.legs):
            td.Rx[3 * row : 3 * row + 3, :nv] = kin.velocity_dq[leg]
            td.Rx[3 * row : 3 * row + 3, nv:] = kin.position_jacobians[leg]


class TorqueRegularisationCost(WholeBodyCostTerm):
    """``||u - u_ref||^2_R`` (last term of Eq. (18); ``u_ref`` is zero unless the reference sets one)."""

    name = "torque"
    needs_control = True

    def __init__(self, weights: np.ndarray) -> None:
        self.weights = weight_vector(weights, 12, "torque weights")
        self.dim = 12
        self._flat_diagonal = np.arange(12) * 13

    def create_data(self, ndx: int, nu: int) -> CostTermData:
        td = CostTermData(self.dim, ndx, nu)
        td.Ru[:] = np.eye(self.dim)
        return td

    def calc(self, td, kd, x, u, ref) -> float:
        np.subtract(u, ref.torque, out=td.r)
        np.multiply(self.weights, td.r, out=td.weighted_r)
        return 0.5 * float(np.dot(td.weighted_r, td.r))

    def calc_diff(self, td, kd, x, u, ref) -> None:
        pass  # Ru is the identity (set at creation)

    def accumulate(self, td, kd, scale) -> None:
        kd.Lu += scale * td.weighted_r
        kd.Luu.reshape(-1)[self._flat_diagonal] += scale * self.weights


def whole_body_cost_terms(
    model: pin.Model,
    stance: Sequence[bool],
    weights: WholeBodyWeights,
    with_torque: bool,
    base_error: BaseError = "tangent",
) -> list[WholeBodyCostTerm]:
    """The terms of Eq. (18) for a knot with these stance flags (terms whose weights are all zero are left
    out; the torque term only on running knots)."""
    swing_legs = [leg for leg in range(4) if not stance[leg]]
    nu = model.nv - 6
    terms: list[WholeBodyCostTerm] = []
    if np.any(weights.state_weights(nu) > 0):
        terms.append(StateTrackingCost(model, weights.state_weights(nu), base_error))
    if swing_legs:
        position_weights = weights.foot_position_weights(4)
        if np.any(position_weights.reshape(4, 3)[swing_legs] > 0):
            terms.append(SwingFootPositionCost(swing_legs, position_weights, model.nv))
        velocity_weights = weights.foot_velocity_weights(4)
        if np.any(velocity_weights.reshape(4, 3)[swing_legs] > 0):
            terms.append(SwingFootVelocityCost(swing_legs, velocity_weights, model.nv))
    if with_torque and np.any(weights.torque_weights(nu) > 0):
        terms.append(TorqueRegularisationCost(weights.torque_weights(nu)))
    return terms


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
    def calc(self, cd: InequalityData, kd: TermKnotData, x: np.ndarray, u: np.ndarray) -> None:
        """Write ``cd.g``."""

    @abstractmethod
    def calc_diff(self, cd: InequalityData, kd: TermKnotData, x: np.ndarray, u: np.ndarray) -> None:
        """Write ``cd.Gx``/``cd.Gu`` (where not constant). Assumes ``calc`` ran first."""

    def accumulate(
        self, cd: InequalityData, kd: TermKnotData, d1: np.ndarray, d2: np.ndarray, scale: float
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
    """``z_base - h_min >= 0`` (settings facts). ``d z / d(base linear tangent) = R[2, :]``."""

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


class FrictionPyramid(WholeBodyInequality):
    """Inner friction pyramid and unilateral force (26) on every stance foot's KKT force, the unilateral
    row raised to ``minimum_normal_force``."""

    name = "friction"
    needs_control = True
    needs_forces = True

    def __init__(
        self, n_contacts: int, mu: float, barrier: BarrierParameters, minimum_normal_force: float = 0.0
    ) -> None:
        self.n_contacts = n_contacts
        self.mu = float(mu)
        self.dim = 5 * n_contacts
        self.barrier = barrier
        self.matrix = np.kron(np.eye(n_contacts), friction_pyramid_matrix(self.mu))
        self.offset = np.zeros(self.dim)
        self.offset[::5] = minimum_normal_force

    def calc(self, cd, kd, x, u) -> None:
        np.matmul(self.matrix, kd.dynamics.forces, out=cd.g)
        cd.g -= self.offset

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
            FrictionPyramid(
                n_contacts,
                settings.friction_coefficient,
                settings.friction_barrier,
                settings.minimum_normal_force,
            )
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


class TermKnotData(ActionData):
    """Per-knot workspace: dynamics data (its ``x_next``/``Fx``/``Fu`` are this data's), foot kinematics,
    base rotation, cost/constraint term data and the stacked barrier."""

    def __init__(self, model: TermKnot) -> None:
        super().__init__(model)
        ndx, nu = model.state.ndx, model.nu
        self.dynamics = model.dynamics.create_data() if model.dynamics is not None else None
        if self.dynamics is not None:
            self.x_next = self.dynamics.x_next
            self.Fx = self.dynamics.Fx
            self.Fu = self.dynamics.Fu
        self.kinematics = model.kinematics.create_data()
        self.base_rotation = np.eye(3)
        self.cost_datas = [term.create_data(ndx, nu) for term in model.costs]
        self.cost_values = np.zeros(len(model.costs))
        self.barrier = model.barrier.create_data()
        self.constraint_datas = [
            constraint.create_data(self.barrier.g[rows], ndx, nu)
            for constraint, rows in zip(model.constraints, model.constraint_rows, strict=True)
        ]
        self.last_x = np.full(model.state.nx, np.nan)
        self.last_u = np.full(nu, np.nan)
        self.layout = model.layout


class TermKnot(ActionModel):
    """Whole-body knot: ``x+ = f(x, tau)`` (Eqs. (19)-(23)), cost (18) and barrier-penalised (26), (27).

    Args:
        robot: the robot.
        dynamics: the phase dynamics (sets ``nu = 12`` and the time step), or ``None`` for a terminal knot.
        costs: cost terms (weights: ``cafe_mpc.config.weights``), summed, times ``dt`` on running knots.
        constraints: inequality terms (``cafe_mpc.ocp.constraints``); ``eps B(g)``, times ``dt`` if running.
        reference: this knot's mutable reference.
        stance: stance flags of a terminal knot (a running knot takes the dynamics').
    """

    def __init__(
        self,
        robot: Robot,
        dynamics: WholeBodyDynamics | None,
        costs: Sequence[WholeBodyCostTerm],
        constraints: Sequence[WholeBodyInequality],
        reference: WholeBodyReference,
        stance: Sequence[bool] | None = None,
    ) -> None:
        self.robot = robot
        self.dynamics = dynamics
        self.state = dynamics.state if dynamics is not None else MultibodyState(robot.model)
        self.next_state = self.state
        self.nu = dynamics.nu if dynamics is not None else 0
        self.cost_scale = dynamics.dt if dynamics is not None else 1.0
        if dynamics is not None:
            self.stance = dynamics.stance
            if stance is not None and as_contact_flags(stance) != dynamics.stance:
                raise ValueError("stance flags differ from the dynamics' stance flags")
        else:
            if stance is None:
                raise ValueError("a terminal whole-body knot needs its phase's stance flags")
            self.stance = as_contact_flags(stance)
        self.costs = tuple(costs)
        self.constraints = tuple(constraints)
        for term in (*self.costs, *self.constraints):
            if dynamics is None and (
                getattr(term, "needs_control", False) or getattr(term, "needs_forces", False)
            ):
                raise ValueError(f"term {term.name!r} needs a control/forces: not allowed on a terminal knot")
            if getattr(term, "needs_forces", False) and term.n_contacts != dynamics.n_contacts:
                raise ValueError(
                    f"term {term.name!r} expects {term.n_contacts} contacts, "
                    f"the dynamics has {dynamics.n_contacts}"
                )
        self.kinematics = FootKinematics(
            robot,
            position_legs=sorted({leg for term in self.costs for leg in term.position_legs}),
            velocity_legs=sorted({leg for term in self.costs for leg in term.velocity_legs}),
        )
        rows, start = [], 0
        for constraint in self.constraints:
            rows.append(slice(start, start + constraint.dim))
            start += constraint.dim
        self.constraint_rows = tuple(rows)
        self.barrier = BarrierStack(
            np.concatenate([np.full(c.dim, c.barrier.delta) for c in self.constraints] or [np.zeros(0)]),
            np.concatenate([np.full(c.dim, c.barrier.eps) for c in self.constraints] or [np.zeros(0)]),
        )
        self.layout = object()
        """Identity token shared by every knot made from this one with ``with_reference``: a data object
        created by one of them can be reused by any other (``data.layout is knot.layout``)."""
        self._needs_rotation = any(
            getattr(term, "base_error", "tangent") == "world" for term in self.costs
        ) or any(constraint.name == "base_height" for constraint in self.constraints)
        self.reference = self._check_reference(reference)

    def _check_reference(self, reference: WholeBodyReference) -> WholeBodyReference:
        if not isinstance(reference, WholeBodyReference):
            raise ValueError(f"reference must be a WholeBodyReference, got {type(reference).__name__}")
        if reference.state.shape != (self.state.nx,):
            raise ValueError(
                f"reference state must have shape ({self.state.nx},), got {reference.state.shape}"
            )
        return reference

    def __repr__(self) -> str:
        kind = f"dt={self.cost_scale}" if self.dynamics is not None else "terminal"
        return f"WholeBodyKnot({flags_to_string(self.stance)}, {kind})"

    def with_reference(self, reference: WholeBodyReference) -> TermKnot:
        """A knot sharing everything with this one except the reference."""
        knot = copy.copy(self)
        knot.reference = self._check_reference(reference)
        return knot

    def create_data(self) -> TermKnotData:
        return TermKnotData(self)

    def _check_sizes(self, x: np.ndarray, u: np.ndarray) -> None:
        if x.shape != (self.state.nx,):
            raise ValueError(f"{self!r}: x must have shape ({self.state.nx},), got {x.shape}")
        if u.shape != (self.nu,):
            raise ValueError(f"{self!r}: u must have shape ({self.nu},), got {u.shape}")

    def calc(self, data: TermKnotData, x: np.ndarray, u: np.ndarray) -> None:
        self._check_sizes(x, u)
        nq = self.state.nq
        if self.dynamics is not None:
            self.dynamics.calc(data.dynamics, x, u)
        if self._needs_rotation:
            data.base_rotation = pin.Quaternion(x[3:7]).toRotationMatrix()
        if not self.kinematics.empty:
            self.kinematics.calc(data.kinematics, x[:nq], x[nq:])
        reference = self.reference
        cost = 0.0
        for index, (term, term_data) in enumerate(zip(self.costs, data.cost_datas, strict=True)):
            value = term.calc(term_data, data, x, u, reference)
            data.cost_values[index] = value
            cost += value
        cost *= self.cost_scale
        if self.constraints:
            for constraint, constraint_data in zip(self.constraints, data.constraint_datas, strict=True):
                constraint.calc(constraint_data, data, x, u)
            cost += self.cost_scale * self.barrier.evaluate(data.barrier)
            data.constraint_violation = max(0.0, -float(data.barrier.g.min()))
        else:
            data.constraint_violation = 0.0
        data.cost = cost
        data.last_x[:] = x
        data.last_u[:] = u

    def calc_diff(self, data: TermKnotData, x: np.ndarray, u: np.ndarray) -> None:
        if not (np.array_equal(x, data.last_x) and np.array_equal(u, data.last_u)):
            self.calc(data, x, u)  # keep the forward pass consistent with (x, u)
        nq = self.state.nq
        if self.dynamics is not None:
            self.dynamics.calc_diff(data.dynamics, x, u)
        if not self.kinematics.empty:
            self.kinematics.calc_diff(data.kinematics, x[:nq], x[nq:])
        data.Lx.fill(0.0)
        data.Lxx.fill(0.0)
        if self.nu:
            data.Lu.fill(0.0)
            data.Luu.fill(0.0)
            data.Lux.fill(0.0)
        reference, scale = self.reference, self.cost_scale
        for term, term_data in zip(self.costs, data.cost_datas, strict=True):
            term.calc_diff(term_data, data, x, u, reference)
            term.accumulate(term_data, data, scale)
        barrier = data.barrier
        for constraint, constraint_data, rows in zip(
            self.constraints, data.constraint_datas, self.constraint_rows, strict=True
        ):
            constraint.calc_diff(constraint_data, data, x, u)
            constraint.accumulate(constraint_data, data, barrier.d1[rows], barrier.d2[rows], scale)


def term_knot(
    robot: Robot,
    stance,
    weights: WholeBodyWeights,
    constraints,
    reference,
    dt=0.01,
    base_error: BaseError = "tangent",
    running=True,
) -> TermKnot:
    """The term-by-term knot with the same content as a factory's fused ``WholeBodyKnot``."""
    stance = as_contact_flags(stance)
    costs = whole_body_cost_terms(robot.model, stance, weights, with_torque=running, base_error=base_error)
    inequalities = whole_body_inequalities(robot, stance, constraints, running) if constraints else []
    dynamics = WholeBodyDynamics(robot, stance, dt) if running else None
    return TermKnot(robot, dynamics, costs, inequalities, reference, stance=stance)
