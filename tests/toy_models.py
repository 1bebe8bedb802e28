"""Small test-only models for the MS-iLQR solver tests (not part of the package).

* linear-quadratic knots with affine dynamics and an affine reset that may change the state dimension;
* a pendulum (nonlinear, Euclidean) with an optional relaxed-barrier torque limit;
* a 1-D point mass in flight with a touchdown switching constraint and an impact reset;
* a rigid body with a unit-quaternion orientation (a non-Euclidean state manifold).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from cafe_mpc.core.interfaces import (
    ActionData,
    ActionModel,
    ConstraintData,
    EuclideanState,
    ResetData,
    ResetMap,
    StateManifold,
    SwitchingConstraint,
)
from cafe_mpc.ocp.barrier import RelaxedBarrier, constraint_violation


# ------------------------------------------------------------------------------------ linear-quadratic
class LinearQuadraticModel(ActionModel):
    """``x+ = A x + B u + c``; cost ``½x'Qx + q'x + ½u'Ru + r'u + u'N x`` (terminal if ``B`` is None)."""

    def __init__(
        self,
        Q: np.ndarray,
        q: np.ndarray,
        A: np.ndarray | None = None,
        B: np.ndarray | None = None,
        c: np.ndarray | None = None,
        R: np.ndarray | None = None,
        r: np.ndarray | None = None,
        N: np.ndarray | None = None,
    ) -> None:
        n = Q.shape[0]
        self.state = EuclideanState(n)
        self.next_state = self.state
        self.Q, self.q = Q, q
        self.terminal = B is None
        if B is None:
            self.nu = 0
            return
        self.nu = B.shape[1]
        self.A, self.B = A, B
        self.c = c if c is not None else np.zeros(n)
        self.R = R
        self.r = r if r is not None else np.zeros(self.nu)
        self.N = N if N is not None else np.zeros((self.nu, n))

    def calc(self, data: ActionData, x: np.ndarray, u: np.ndarray) -> None:
        data.cost = 0.5 * x @ self.Q @ x + self.q @ x
        if not self.terminal:
            data.cost += 0.5 * u @ self.R @ u + self.r @ u + u @ self.N @ x
            data.x_next[:] = self.A @ x + self.B @ u + self.c

    def calc_diff(self, data: ActionData, x: np.ndarray, u: np.ndarray) -> None:
        data.Lx[:] = self.Q @ x + self.q
        data.Lxx[:] = self.Q
        if not self.terminal:
            data.Lx += self.N.T @ u
            data.Lu[:] = self.R @ u + self.r + self.N @ x
            data.Luu[:] = self.R
            data.Lux[:] = self.N
            data.Fx[:] = self.A
            data.Fu[:] = self.B


class AffineReset(ResetMap):
    """``x+ = M x + m`` between Euclidean spaces of possibly different dimensions."""

    def __init__(self, M: np.ndarray, m: np.ndarray | None = None) -> None:
        self.state = EuclideanState(M.shape[1])
        self.next_state = EuclideanState(M.shape[0])
        self.M = M
        self.m = m if m is not None else np.zeros(M.shape[0])

    def calc(self, data: ResetData, x: np.ndarray) -> None:
        data.x_next[:] = self.M @ x + self.m

    def calc_diff(self, data: ResetData, x: np.ndarray) -> None:
        data.Px[:] = self.M


# ------------------------------------------------------------------------------------------------- pendulum
class PendulumModel(ActionModel):
    """Torque-driven pendulum ``[θ, ω]``, explicit Euler; ``θ = 0`` hangs down.

    Running cost ``dt * ½ (w_θ (θ - θ*)² + w_ω ω² + w_u u²)``, plus (optionally) the relaxed barrier of
    ``|u| <= torque_limit`` weighted by ``dt``. Terminal (``dt = None``): ``½ w_T ((θ - θ*)² + ω²)``.
    """

    def __init__(
        self,
        dt: float | None,
        target: float = np.pi,
        angle_weight: float = 1.0,
        velocity_weight: float = 0.1,
        torque_weight: float = 0.1,
        terminal_weight: float = 100.0,
        torque_limit: float | None = None,
        barrier: RelaxedBarrier | None = None,
        gravity_over_length: float = 9.81,
        damping: float = 0.1,
    ) -> None:
        self.state = EuclideanState(2)
        self.next_state = self.state
        self.nu = 0 if dt is None else 1
        self.dt = dt
        self.target = target
        self.weights = (angle_weight, velocity_weight, torque_weight, terminal_weight)
        self.torque_limit = torque_limit
        self.barrier = barrier
        self.g = gravity_over_length
        self.damping = damping

    def _limits(self, u: np.ndarray) -> np.ndarray:
        return np.array([self.torque_limit - u[0], self.torque_limit + u[0]])

    def calc(self, data: ActionData, x: np.ndarray, u: np.ndarray) -> None:
        w_angle, w_velocity, w_torque, w_terminal = self.weights
        error = x[0] - self.target
        if self.dt is None:
            data.cost = 0.5 * w_terminal * (error * error + x[1] * x[1])
            return
        dt = self.dt
        data.x_next[0] = x[0] + dt * x[1]
        data.x_next[1] = x[1] + dt * (-self.g * np.sin(x[0]) - self.damping * x[1] + u[0])
        data.cost = dt * 0.5 * (w_angle * error * error + w_velocity * x[1] * x[1] + w_torque * u[0] * u[0])
        if self.torque_limit is not None:
            g = self._limits(u)
            data.cost += dt * self.barrier.value(g)
            data.constraint_violation = constraint_violation(g)

    def calc_diff(self, data: ActionData, x: np.ndarray, u: np.ndarray) -> None:
        w_angle, w_velocity, w_torque, w_terminal = self.weights
        error = x[0] - self.target
        if self.dt is None:
            data.Lx[:] = w_terminal * np.array([error, x[1]])
            data.Lxx[:] = w_terminal * np.eye(2)
            return
        dt = self.dt
        data.Fx[:] = [[1.0, dt], [-dt * self.g * np.cos(x[0]), 1.0 - dt * self.damping]]
        data.Fu[:] = [[0.0], [dt]]
        data.Lx[:] = dt * np.array([w_angle * error, w_velocity * x[1]])
        data.Lxx[:] = dt * np.diag([w_angle, w_velocity])
        data.Lu[:] = dt * w_torque * u
        data.Luu[:] = dt * w_torque
        data.Lux[:] = 0.0
        if self.torque_limit is not None:
            _, gradient, hessian = self.barrier.derivatives(self._limits(u))
            dg_du = np.array([-1.0, 1.0])
            data.Lu += dt * (gradient @ dg_du)
            data.Luu += dt * (hessian @ (dg_du * dg_du))


class PendulumImpactReset(ResetMap):
    """A nonlinear reset between two pendulum phases: ``ω+ = e ω + β sin θ`` (θ unchanged)."""

    def __init__(self, restitution: float = 0.8, coupling: float = 0.3) -> None:
        self.state = EuclideanState(2)
        self.next_state = self.state
        self.restitution = restitution
        self.coupling = coupling

    def calc(self, data: ResetData, x: np.ndarray) -> None:
        data.x_next[0] = x[0]
        data.x_next[1] = self.restitution * x[1] + self.coupling * np.sin(x[0])

    def calc_diff(self, data: ResetData, x: np.ndarray) -> None:
        data.Px[:] = [[1.0, 0.0], [self.coupling * np.cos(x[0]), self.restitution]]


# ------------------------------------------------------------------------------------------------ 1-D hopper
class PointMassFlight(ActionModel):
    """Vertical point mass ``[h, v]`` with thrust ``u`` (acceleration), explicit Euler under gravity.

    Running cost ``dt * ½ w_u u²``; terminal (``dt = None``) ``½ w_T (h - h*)² + ½ w_v v²``.
    """

    def __init__(
        self,
        dt: float | None,
        thrust_weight: float = 1.0,
        target_height: float = 0.0,
        terminal_weight: float = 0.0,
        terminal_velocity_weight: float = 0.0,
        gravity: float = 9.81,
    ) -> None:
        self.state = EuclideanState(2)
        self.next_state = self.state
        self.nu = 0 if dt is None else 1
        self.dt = dt
        self.thrust_weight = thrust_weight
        self.target_height = target_height
        self.terminal_weight = terminal_weight
        self.terminal_velocity_weight = terminal_velocity_weight
        self.gravity = gravity

    def calc(self, data: ActionData, x: np.ndarray, u: np.ndarray) -> None:
        if self.dt is None:
            error = x[0] - self.target_height
            data.cost = 0.5 * (
                self.terminal_weight * error * error + self.terminal_velocity_weight * x[1] * x[1]
            )
            return
        dt = self.dt
        data.x_next[0] = x[0] + dt * x[1]
        data.x_next[1] = x[1] + dt * (u[0] - self.gravity)
        data.cost = dt * 0.5 * self.thrust_weight * u[0] * u[0]

    def calc_diff(self, data: ActionData, x: np.ndarray, u: np.ndarray) -> None:
        if self.dt is None:
            data.Lx[:] = [
                self.terminal_weight * (x[0] - self.target_height),
                self.terminal_velocity_weight * x[1],
            ]
            data.Lxx[:] = np.diag([self.terminal_weight, self.terminal_velocity_weight])
            return
        dt = self.dt
        data.Fx[:] = [[1.0, dt], [0.0, 1.0]]
        data.Fu[:] = [[0.0], [dt]]
        data.Lx[:] = 0.0
        data.Lxx[:] = 0.0
        data.Lu[:] = dt * self.thrust_weight * u
        data.Luu[:] = dt * self.thrust_weight
        data.Lux[:] = 0.0


class TouchdownConstraint(SwitchingConstraint):
    """``g(x) = h`` (height zero at touchdown, like the foot-height constraint (25))."""

    def __init__(self) -> None:
        self.state = EuclideanState(2)
        self.dim = 1

    def calc(self, data: ConstraintData, x: np.ndarray) -> None:
        data.value[0] = x[0]

    def calc_diff(self, data: ConstraintData, x: np.ndarray) -> None:
        data.Hx[:] = [[1.0, 0.0]]


class BounceReset(ResetMap):
    """Impact: ``v+ = -e v-``, height unchanged."""

    def __init__(self, restitution: float = 0.7) -> None:
        self.state = EuclideanState(2)
        self.next_state = self.state
        self.restitution = restitution

    def calc(self, data: ResetData, x: np.ndarray) -> None:
        data.x_next[0] = x[0]
        data.x_next[1] = -self.restitution * x[1]

    def calc_diff(self, data: ResetData, x: np.ndarray) -> None:
        data.Px[:] = [[1.0, 0.0], [0.0, -self.restitution]]


# -------------------------------------------------------------------------------------- quaternion rigid body
def quaternion_to_rotation(quaternion: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion stored as ``[x, y, z, w]``."""
    return pin.Quaternion(np.array(quaternion, dtype=float)).normalized().toRotationMatrix()


def rotation_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    return pin.Quaternion(rotation).coeffs().copy()


class OrientationVelocityState(StateManifold):
    """``SO(3) x R^3`` with the orientation as a unit quaternion: ``x = [qx, qy, qz, qw, ωx, ωy, ωz]``.

    Tangent ``[δθ, δω]`` with the right (body) perturbation ``R ⊕ δθ = R exp(δθ)``.
    """

    nx = 7
    ndx = 6

    def zero(self) -> np.ndarray:
        return np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])

    def integrate(self, x: np.ndarray, dx: np.ndarray) -> np.ndarray:
        rotation = quaternion_to_rotation(x[:4]) @ pin.exp3(dx[:3])
        return np.concatenate([rotation_to_quaternion(rotation), x[4:] + dx[3:]])

    def difference(self, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
        relative = quaternion_to_rotation(x0[:4]).T @ quaternion_to_rotation(x1[:4])
        return np.concatenate([pin.log3(relative), x1[4:] - x0[4:]])

    def jacobian_difference(self, x0: np.ndarray, x1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        relative = quaternion_to_rotation(x0[:4]).T @ quaternion_to_rotation(x1[:4])
        jlog = pin.Jlog3(relative)
        J0, J1 = -np.eye(6), np.eye(6)
        J0[:3, :3] = -jlog @ relative.T
        J1[:3, :3] = jlog
        return J0, J1

    def jacobian_integrate(self, x: np.ndarray, dx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Jx, Jdx = np.eye(6), np.eye(6)
        Jx[:3, :3] = pin.exp3(dx[:3]).T
        Jdx[:3, :3] = pin.Jexp3(dx[:3])
        return Jx, Jdx


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class RigidBodyAttitudeModel(ActionModel):
    """Torque-driven free rigid body: ``R+ = R exp(ω dt)``, ``ω+ = ω + dt I⁻¹ (τ - ω x Iω)``.

    Cost ``dt * ½ (w_R |log(R*' R)|² + w_ω |ω|² + w_τ |τ|²)``;
    terminal (``dt = None``) ``½ w_T (|log(R*' R)|² + |ω|²)``.
    """

    def __init__(
        self,
        dt: float | None,
        target_rotation: np.ndarray,
        inertia: np.ndarray,
        rotation_weight: float = 1.0,
        velocity_weight: float = 0.1,
        torque_weight: float = 0.1,
        terminal_weight: float = 50.0,
    ) -> None:
        self.state = OrientationVelocityState()
        self.next_state = self.state
        self.nu = 0 if dt is None else 3
        self.dt = dt
        self.target_rotation = target_rotation
        self.inertia = inertia
        self.inertia_inverse = np.linalg.inv(inertia)
        self.weights = (rotation_weight, velocity_weight, torque_weight, terminal_weight)

    def _rotation_error(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        relative = self.target_rotation.T @ quaternion_to_rotation(x[:4])
        return pin.log3(relative), relative

    def calc(self, data: ActionData, x: np.ndarray, u: np.ndarray) -> None:
        w_rotation, w_velocity, w_torque, w_terminal = self.weights
        error, _ = self._rotation_error(x)
        omega = x[4:]
        if self.dt is None:
            data.cost = 0.5 * w_terminal * (error @ error + omega @ omega)
            return
        dt = self.dt
        rotation = quaternion_to_rotation(x[:4]) @ pin.exp3(omega * dt)
        data.x_next[:4] = rotation_to_quaternion(rotation)
        data.x_next[4:] = omega + dt * self.inertia_inverse @ (u - np.cross(omega, self.inertia @ omega))
        data.cost = dt * 0.5 * (w_rotation * error @ error + w_velocity * omega @ omega + w_torque * u @ u)

    def calc_diff(self, data: ActionData, x: np.ndarray, u: np.ndarray) -> None:
        w_rotation, w_velocity, w_torque, w_terminal = self.weights
        error, relative = self._rotation_error(x)
        jlog = pin.Jlog3(relative)
        omega = x[4:]
        if self.dt is None:
            data.Lx[:3] = w_terminal * jlog.T @ error
            data.Lx[3:] = w_terminal * omega
            data.Lxx[:] = 0.0
            data.Lxx[:3, :3] = w_terminal * jlog.T @ jlog
            data.Lxx[3:, 3:] = w_terminal * np.eye(3)
            return
        dt = self.dt
        data.Fx[:] = 0.0
        data.Fx[:3, :3] = pin.exp3(omega * dt).T
        data.Fx[:3, 3:] = dt * pin.Jexp3(omega * dt)
        inertia_omega = self.inertia @ omega
        data.Fx[3:, 3:] = np.eye(3) - dt * self.inertia_inverse @ (
            skew(omega) @ self.inertia - skew(inertia_omega)
        )
        data.Fu[:] = 0.0
        data.Fu[3:, :] = dt * self.inertia_inverse
        data.Lx[:3] = dt * w_rotation * jlog.T @ error
        data.Lx[3:] = dt * w_velocity * omega
        data.Lxx[:] = 0.0
        data.Lxx[:3, :3] = dt * w_rotation * jlog.T @ jlog
        data.Lxx[3:, 3:] = dt * w_velocity * np.eye(3)
        data.Lu[:] = dt * w_torque * u
        data.Luu[:] = dt * w_torque * np.eye(3)
        data.Lux[:] = 0.0
