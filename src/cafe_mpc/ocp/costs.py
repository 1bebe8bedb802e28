"""Cost terms of the whole-body and SRB knots (paper Eqs. (18) and (28)) as residual x weight.

Every term is ``0.5 * r' W r`` with a residual ``r(x, u)`` and a diagonal weight ``W``; a running knot
multiplies the sum by its time step (``0.5 * dx' W dx * dt``, docs/settings.md). Derivatives are
Gauss-Newton: ``Lx = Rx' W r``, ``Lxx = Rx' W Rx`` (and the same for ``u``). Weight sets are data
(``WholeBodyWeights``, ``SRBWeights``), written in the authors' base order ``[x, y, z, yaw, pitch, roll]``
and mapped here to the tangent order ``[lin x, y, z, ang x (roll), y (pitch), z (yaw)]``.

Each term keeps its residual ``r`` and dense Jacobians ``Rx``, ``Ru`` in its data (tests compare them
with finite differences); the accumulation into the knot's ``Lx, Lu, Lxx, Luu, Lux`` exploits the sparsity
of each term. References are read from the knot's mutable reference object (see ``cafe_mpc.ocp.knots``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np
import pinocchio as pin

if TYPE_CHECKING:
    from cafe_mpc.ocp.knots import WholeBodyKnotData, WholeBodyReference

BASE_WEIGHT_ORDER = ("x", "y", "z", "yaw", "pitch", "roll")
"""Order of the six base weights in the authors' code and in ``WholeBodyWeights``/``SRBWeights``."""

BaseError = Literal["tangent", "world"]


def base_weights_to_tangent(weights: Sequence[float]) -> np.ndarray:
    """``[x, y, z, yaw, pitch, roll]`` -> ``[x, y, z, roll, pitch, yaw]`` (tangent order: linear, then angular
    about the body x (roll), y (pitch) and z (yaw) axes)."""
    w = np.asarray(weights, dtype=float)
    if w.shape != (6,):
        raise ValueError(f"base weights need 6 values {BASE_WEIGHT_ORDER}, got shape {w.shape}")
    return np.array([w[0], w[1], w[2], w[5], w[4], w[3]])


def _weight_vector(value: float | Sequence[float], size: int, name: str) -> np.ndarray:
    array = np.asarray(value, dtype=float)
    if array.ndim == 0:
        array = np.full(size, float(array))
    if array.shape != (size,):
        raise ValueError(f"{name}: expected a scalar or {size} values, got shape {array.shape}")
    if not np.all(np.isfinite(array)) or np.any(array < 0):
        raise ValueError(f"{name}: weights must be finite and non-negative, got {value}")
    return array


def _leg_weights(value: float | Sequence[float], name: str) -> np.ndarray:
    """3 weights (x, y, z) shared by the four legs, or 12 (per leg)."""
    array = np.asarray(value, dtype=float)
    if array.ndim == 0:
        array = np.full(3, float(array))
    if array.shape == (3,):
        array = np.tile(array, 4)
    return _weight_vector(array, 12, name)


@dataclass(frozen=True)
class WholeBodyWeights:
    """Weights of the whole-body cost (18) (docs/settings.md: "Cost"; running cost is ``0.5 dx' W dx dt``).

    ``base_position``/``base_velocity`` are in ``BASE_WEIGHT_ORDER``; joint and torque weights are scalars
    (all joints) or 12 values; foot weights are 3 (x, y, z, every leg) or 12 values and apply to swing feet.
    """

    base_position: tuple[float, ...] = (0.0, 0.0, 10.0, 1.0, 2.0, 2.0)
    base_velocity: tuple[float, ...] = (2.0, 2.0, 2.0, 1.0, 2.0, 2.0)
    joint_position: float | tuple[float, ...] = 1.0
    joint_velocity: float | tuple[float, ...] = 0.01
    torque: float | tuple[float, ...] = 0.1
    swing_foot_position: float | tuple[float, ...] = (10.0, 10.0, 10.0)
    swing_foot_velocity: float | tuple[float, ...] = (2.0, 2.0, 2.0)

    def __post_init__(self) -> None:
        self.state_weights()
        self.torque_weights()
        self.foot_position_weights()
        self.foot_velocity_weights()

    def state_weights(self) -> np.ndarray:
        """36 weights in tangent order: base (6), joints (12), base velocity (6), joint velocity (12)."""
        return np.concatenate(
            [
                base_weights_to_tangent(_weight_vector(self.base_position, 6, "base_position")),
                _weight_vector(self.joint_position, 12, "joint_position"),
                base_weights_to_tangent(_weight_vector(self.base_velocity, 6, "base_velocity")),
                _weight_vector(self.joint_velocity, 12, "joint_velocity"),
            ]
        )

    def torque_weights(self) -> np.ndarray:
        return _weight_vector(self.torque, 12, "torque")

    def foot_position_weights(self) -> np.ndarray:
        """12 weights (leg-major, x y z per leg)."""
        return _leg_weights(self.swing_foot_position, "swing_foot_position")

    def foot_velocity_weights(self) -> np.ndarray:
        return _leg_weights(self.swing_foot_velocity, "swing_foot_velocity")

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


@dataclass(frozen=True)
class SRBWeights:
    """Weights of the SRB cost (28): base tracking (``BASE_WEIGHT_ORDER``) and GRF regularisation."""

    base_position: tuple[float, ...] = (0.0, 0.0, 10.0, 1.0, 2.0, 2.0)
    base_velocity: tuple[float, ...] = (2.0, 2.0, 2.0, 1.0, 2.0, 2.0)
    force: float | tuple[float, ...] = 0.01

    def __post_init__(self) -> None:
        self.state_weights()
        self.force_weights()

    def state_weights(self) -> np.ndarray:
        """12 weights in the SRB tangent order ``[position, rotation (roll, pitch, yaw), linear velocity,
        angular velocity (roll, pitch, yaw rates)]``."""
        position = base_weights_to_tangent(_weight_vector(self.base_position, 6, "base_position"))
        velocity = base_weights_to_tangent(_weight_vector(self.base_velocity, 6, "base_velocity"))
        return np.concatenate([position, velocity])

    def force_weights(self) -> np.ndarray:
        return _leg_weights(self.force, "force")

    @classmethod
    def regular_running(cls) -> SRBWeights:
        return cls()

    @classmethod
    def regular_terminal(cls) -> SRBWeights:
        return cls(
            base_position=(0.0, 0.0, 1.0, 1.0, 1.0, 1.0),
            base_velocity=(1.0, 1.0, 1.0, 1.0, 1.0, 1.0),
            force=0.0,
        )

    @classmethod
    def from_whole_body(cls, weights: WholeBodyWeights, force: float = 0.01) -> SRBWeights:
        """Same base weights as a whole-body set (Eq. (28): the base components of ``Wq``, ``Wqdot``)."""
        return cls(base_position=weights.base_position, base_velocity=weights.base_velocity, force=force)


# --------------------------------------------------------------------------------------------------
# Whole-body cost terms
# --------------------------------------------------------------------------------------------------


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
        self, td: CostTermData, kd: WholeBodyKnotData, x: np.ndarray, u: np.ndarray, ref: WholeBodyReference
    ) -> float:
        """Write ``td.r`` and return ``0.5 r' W r`` (not yet scaled by the time step)."""

    @abstractmethod
    def calc_diff(
        self, td: CostTermData, kd: WholeBodyKnotData, x: np.ndarray, u: np.ndarray, ref: WholeBodyReference
    ) -> None:
        """Write ``td.Rx`` / ``td.Ru``. Assumes ``calc`` ran first."""

    def residual_jacobians(self, td: CostTermData) -> tuple[np.ndarray, np.ndarray]:
        """Dense ``(Rx, Ru)`` after ``calc_diff`` (for tests and diagnostics, not the hot path)."""
        return td.Rx, td.Ru

    def accumulate(self, td: CostTermData, kd: WholeBodyKnotData, scale: float) -> None:
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
        self.weights = _weight_vector(weights, self.dim, "state weights")
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
        leg_weights = _leg_weights(weights, "swing foot position weights").reshape(4, 3)
        self.weights = leg_weights[list(self.legs)].reshape(-1)

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
        leg_weights = _leg_weights(weights, "swing foot velocity weights").reshape(4, 3)
        self.weights = leg_weights[list(self.legs)].reshape(-1)

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
        self.weights = _weight_vector(weights, 12, "torque weights")
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
    terms: list[WholeBodyCostTerm] = []
    if np.any(weights.state_weights() > 0):
        terms.append(StateTrackingCost(model, weights.state_weights(), base_error))
    if swing_legs:
        position_weights = weights.foot_position_weights()
        if np.any(position_weights.reshape(4, 3)[swing_legs] > 0):
            terms.append(SwingFootPositionCost(swing_legs, position_weights, model.nv))
        velocity_weights = weights.foot_velocity_weights()
        if np.any(velocity_weights.reshape(4, 3)[swing_legs] > 0):
            terms.append(SwingFootVelocityCost(swing_legs, velocity_weights, model.nv))
    if with_torque and np.any(weights.torque_weights() > 0):
        terms.append(TorqueRegularisationCost(weights.torque_weights()))
    return terms
