"""Single-rigid-body (SRB) dynamics of the tail plan (paper Sec. IV-B, Eqs. (29), (30)).

State (``SRBState``, ``nx = 13``, ``ndx = 12``), without Euler angles:

    x = [c (world position, 3), quaternion (x, y, z, w), c_dot (world linear velocity, 3), omega (body, 3)]
    tangent = [dc (world), dtheta (body-frame rotation, R ⊕ dtheta = R exp(dtheta)), dc_dot, domega]

Control: the world-frame foot forces ``u = [f_FL, f_FR, f_HL, f_HR]`` (``3 n_feet``). Foot positions
``p_j`` and contact flags ``s_j`` are per-knot parameters (from the reference, Raibert footholds), neither
state nor control. Continuous dynamics (29):

    c_ddot    = sum_j s_j f_j / m - g
    omega_dot = I^-1 (-omega x I omega + R' sum_j s_j (p_j - c) x f_j)

and one explicit Euler step (30) on the manifold (everything evaluated at ``x_k``):
``c+ = c + c_dot dt``, ``R+ = R exp(omega dt)``, ``c_dot+ = c_dot + c_ddot dt``,
``omega+ = omega + omega_dot dt``. Jacobians are analytic (numpy; no finite differences).

The SRB position ``c`` is the base-frame origin (the WB -> SRB map (31), (32) keeps the base pose), which
for the Mini Cheetah is the trunk's centre of mass; the legs' mass is lumped into ``m`` and ``I``.
``srb_parameters(robot)`` computes ``m`` and ``I`` from the robot's model (legs lumped at the standing pose,
rotor masses added); ``SRBParameters(mass, inertia)`` sets them explicitly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from cafe_mpc.core.contacts import N_FEET
from cafe_mpc.core.interfaces import CompiledStateOperations, StateManifold, own_operations
from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.dynamics.srb_kernels import (
    srb_difference,
    srb_difference_jacobian_product,
    srb_difference_jacobian_product_stacked,
    srb_integrate,
    srb_step,
    srb_step_jacobians,
)
from cafe_mpc.robots.robot import Robot


def quaternion_to_rotation(quaternion: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion ``(x, y, z, w)``."""
    return pin.Quaternion(quaternion).toRotationMatrix()


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` of quaternions stored ``(x, y, z, w)``."""
    ax, ay, az, aw = a.tolist()
    bx, by, bz, bw = b.tolist()
    return np.array(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ]
    )


SRB_OPERATIONS = CompiledStateOperations(
    srb_integrate, srb_difference, srb_difference_jacobian_product_stacked
)
"""``SRBState``'s compiled operations (``dynamics.srb_kernels``)."""


class SRBState(StateManifold):
    """``[c, quaternion, c_dot, omega]`` on ``R^3 x SO(3) x R^3 x R^3`` (see the module docstring)."""

    nx = 13
    ndx = 12

    def __init__(self) -> None:
        self.compiled = SRB_OPERATIONS if own_operations(self, SRBState) else None

    def zero(self) -> np.ndarray:
        x = np.zeros(13)
        x[6] = 1.0
        return x

    def check(self, x: np.ndarray, name: str = "x") -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if x.shape != (13,):
            raise ValueError(f"{name} must have shape (13,) = [c, quat xyzw, c_dot, omega], got {x.shape}")
        return x

    def integrate(self, x: np.ndarray, dx: np.ndarray) -> np.ndarray:
        out = np.empty(13)
        srb_integrate(x, dx, out)
        return out

    def integrate_into(self, x: np.ndarray, dx: np.ndarray, out: np.ndarray) -> None:
        srb_integrate(x, dx, out)

    def difference(self, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
        out = np.empty(12)
        srb_difference(x0, x1, out)
        return out

    def difference_into(self, x0: np.ndarray, x1: np.ndarray, out: np.ndarray) -> None:
        srb_difference(x0, x1, out)

    def jacobian_difference(self, x0: np.ndarray, x1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        error = quaternion_to_rotation(x0[3:7]).T @ quaternion_to_rotation(x1[3:7])
        jlog = pin.Jlog3(error)
        j0 = -np.eye(12)
        j1 = np.eye(12)
        j0[3:6, 3:6] = -jlog @ error.T
        j1[3:6, 3:6] = jlog
        return j0, j1

    def difference_jacobian_product(
        self, x0: np.ndarray, x1: np.ndarray, matrix: np.ndarray, out: np.ndarray
    ) -> None:
        """Only the rotation rows differ from the identity: ``out[3:6] = Jlog3(R0' R1) @ matrix[3:6]``."""
        srb_difference_jacobian_product(x0, x1, matrix, out)

    def jacobian_integrate(self, x: np.ndarray, dx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        j0 = np.eye(12)
        j1 = np.eye(12)
        j0[3:6, 3:6] = pin.exp3(dx[3:6]).T
        j1[3:6, 3:6] = pin.Jexp3(dx[3:6])
        return j0, j1


@dataclass(frozen=True)
class SRBParameters:
    """Mass and body-frame inertia of the single rigid body of Eq. (29).

    No defaults: they belong to a robot. ``srb_parameters(robot)`` computes them from the robot's own model
    (legs lumped, rotors included; for the Mini Cheetah 8.912 kg, as the CAFE-MPC authors'); a test may give
    any positive mass and inertia.
    """

    mass: float
    inertia: tuple[tuple[float, ...], ...]
    gravity: float = GRAVITY
    n_feet: int = N_FEET

    def __post_init__(self) -> None:
        if not (math.isfinite(self.mass) and self.mass > 0):
            raise ValueError(f"SRB mass must be positive, got {self.mass}")
        if self.n_feet < 1:
            raise ValueError(f"the SRB needs at least one foot, got n_feet = {self.n_feet}")
        inertia = self.inertia_matrix
        if inertia.shape != (3, 3) or not np.allclose(inertia, inertia.T):
            raise ValueError("SRB inertia must be a symmetric 3 x 3 matrix")
        if np.any(np.linalg.eigvalsh(inertia) <= 0):
            raise ValueError("SRB inertia must be positive definite")

    @property
    def inertia_matrix(self) -> np.ndarray:
        inertia = np.asarray(self.inertia, dtype=float)
        return np.diag(inertia) if inertia.shape == (3,) else inertia


def lumped_inertia(robot: Robot, q: np.ndarray | None = None) -> pin.Inertia:
    """Every body of the planning model lumped at configuration ``q`` (default: the standing pose), plus a
    point mass ``robot.rotor_mass`` at each actuated joint, as one ``pin.Inertia`` in the base frame (base at
    the origin, level): ``.mass``, ``.lever`` (centre of mass) and ``.inertia`` (about the centre of mass).

    The rotors' own rotational inertia (about 6e-5 kg m^2 each on the Mini Cheetah) is left out.
    """
    model = robot.model
    q = np.array(robot.q_standing if q is None else q, dtype=float)
    if q.shape != (model.nq,):
        raise ValueError(f"configuration must have shape ({model.nq},), got {q.shape}")
    q[:3] = 0.0
    q[3:7] = (0.0, 0.0, 0.0, 1.0)  # world frame = base frame
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    pin.ccrba(model, data, q, np.zeros(model.nv))  # composite inertia about the centre of mass: data.Ig
    lumped = pin.Inertia(data.Ig.mass, data.com[0].copy(), data.Ig.inertia.copy())
    if robot.rotor_mass > 0:
        for joint in range(2, model.njoints):  # 0: universe, 1: the floating base
            rotor = pin.Inertia(robot.rotor_mass, data.oMi[joint].translation.copy(), np.zeros((3, 3)))
            lumped = lumped + rotor
    return lumped


def srb_parameters(robot: Robot, q: np.ndarray | None = None) -> SRBParameters:
    """SRB mass and inertia of ``robot`` (``lumped_inertia``): the model's total mass plus the rotors, and
    the composite rigid-body inertia of the whole robot about its centre of mass, in the base frame."""
    lumped = lumped_inertia(robot, q)
    inertia = np.asarray(lumped.inertia, dtype=float)
    inertia = 0.5 * (inertia + inertia.T)
    return SRBParameters(
        float(lumped.mass), tuple(tuple(float(v) for v in row) for row in inertia), n_feet=robot.n_feet
    )


class SRBDynamicsData:
    """Workspace of ``SRBDynamics`` (one per knot)."""

    def __init__(self, n_feet: int = N_FEET) -> None:
        nu = 3 * n_feet
        self.x_next = np.zeros(13)
        self.Fx = np.zeros((12, 12))
        self.Fu = np.zeros((12, nu))
        self.linear_acceleration = np.zeros(3)
        self.angular_acceleration = np.zeros(3)
        self.rotation = np.eye(3)
        self.contact_mask = np.zeros(nu)  # contact flag of each force component
        self.active_forces = np.zeros(nu)  # s_j f_j
        self.lever_arms = np.zeros((n_feet, 3))  # p_j - c
        self.moment_map = np.zeros((3, nu))  # [[p_1 - c]x ... [p_n - c]x]: world moment = moment_map @ f
        self.body_moment = np.zeros(3)


class SRBDynamics:
    """Discrete SRB dynamics (29), (30) with time step ``dt``; immutable and shareable between knots."""

    def __init__(self, parameters: SRBParameters, dt: float = 0.05) -> None:
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"time step must be positive and finite, got {dt}")
        self.parameters = parameters
        self.dt = float(dt)
        self.state = SRBState()
        self.n_feet = self.parameters.n_feet
        self.nu = 3 * self.n_feet
        self.mass = self.parameters.mass
        self.inertia = self.parameters.inertia_matrix
        self.inertia_inverse = np.linalg.inv(self.inertia)
        self.gravity_vector = np.array([0.0, 0.0, -self.parameters.gravity])
        self._force_to_velocity = (self.dt / self.mass) * np.tile(np.eye(3), (1, self.n_feet))

    def create_data(self) -> SRBDynamicsData:
        data = SRBDynamicsData(self.n_feet)
        data.Fx[:] = np.eye(12)
        data.Fx[0:3, 6:9] = self.dt * np.eye(3)
        return data

    def calc(
        self,
        data: SRBDynamicsData,
        x: np.ndarray,
        u: np.ndarray,
        foot_positions: np.ndarray,
        contacts: np.ndarray,
    ) -> None:
        """Write ``data.x_next`` and the accelerations; ``contacts`` holds one flag per foot in {0, 1} as
        floats (one compiled call: ``dynamics/srb_kernels.srb_step``)."""
        finite = srb_step(
            x,
            u,
            foot_positions,
            contacts,
            self.mass,
            self.inertia,
            self.inertia_inverse,
            self.parameters.gravity,
            self.dt,
            data.x_next,
            data.rotation,
            data.active_forces,
            data.moment_map,
            data.body_moment,
            data.linear_acceleration,
            data.angular_acceleration,
        )
        if not finite:
            raise FloatingPointError("SRB dynamics: non-finite state, forces or footholds")

    def calc_diff(
        self,
        data: SRBDynamicsData,
        x: np.ndarray,
        u: np.ndarray,
        foot_positions: np.ndarray,
        contacts: np.ndarray,
    ) -> None:
        """Write ``data.Fx``, ``data.Fu`` (tangent Jacobians). Assumes ``calc`` ran with these arguments."""
        srb_step_jacobians(
            x,
            contacts,
            self.mass,
            self.inertia,
            self.inertia_inverse,
            self.dt,
            data.rotation,
            data.active_forces,
            data.moment_map,
            data.body_moment,
            data.Fx,
            data.Fu,
        )
