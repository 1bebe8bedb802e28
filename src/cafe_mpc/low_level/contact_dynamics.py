"""Contact dynamics (paper Eqs. (34b)-(34c)) and friction-cone scoring, shared by the VWBC and the reports.

``ContactDynamicsTerms`` evaluates Pinocchio's terms of the contact dynamics at a state (preallocated, reused
per tick); ``contact_forces_for_torque`` gives the contact forces a torque implies through them (KKT system,
``pin.forwardDynamics``), so that any controller's torque (the Riccati controller's, the VWBC's fallback's)
can be scored against the friction cone (``FrictionConeScorer``, ``friction_cone_violation``) the same way the
VWBC's QP forces are. Contact Jacobians and forces are in ``LOCAL_WORLD_ALIGNED`` at the foot frames (world
frame ground reaction forces, as in ``Plan.forces``).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from cafe_mpc.config import BAUMGARTE_ALPHA, CONE_TOLERANCE, DEFAULT_FRICTION
from cafe_mpc.robots.robot import Robot


def friction_cone_violation(forces: np.ndarray, mu: float) -> float:
    """Largest violation (N) of ``Fz >= 0`` and ``|Fx|, |Fy| <= mu Fz`` (34e)-(34f) over rows of ``forces``.

    ``forces`` is ``(n, 3)``; returns 0 for an empty set or forces inside the pyramid.
    """
    if len(forces) == 0:
        return 0.0
    fz = forces[:, 2]
    worst = max(
        float(np.max(-fz)),
        float(np.max(np.abs(forces[:, 0]) - mu * fz)),
        float(np.max(np.abs(forces[:, 1]) - mu * fz)),
    )
    return max(worst, 0.0)


class ContactDynamicsTerms:
    """Pinocchio terms of the contact dynamics (34b)-(34c) at ``(q, v)``; preallocated, reused per tick.

    After ``compute(q, v, stance)``: ``M`` (symmetric), ``h`` (Coriolis + gravity), ``Jc`` (``3 nc x nv``,
    linear foot Jacobians in ``LOCAL_WORLD_ALIGNED``) and ``drift = Jcdot v + alpha Jc v`` (so that (34c)
    reads ``Jc qdd = -drift``), for the stance feet in leg order.
    """

    def __init__(self, robot: Robot, alpha: float = BAUMGARTE_ALPHA) -> None:
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        self.alpha = float(alpha)
        nv = self.model.nv
        self.M = np.zeros((nv, nv))
        self.h = np.zeros(nv)
        self._J_all = np.zeros((3 * robot.n_feet, nv))
        self._drift_all = np.zeros(3 * robot.n_feet)
        self._zero_a = np.zeros(nv)
        self._lower = np.tril_indices(nv, -1)
        self.Jc = self._J_all[:0]
        self.drift = self._drift_all[:0]

    def compute(self, q: np.ndarray, v: np.ndarray, stance: np.ndarray) -> None:
        model, data = self.model, self.data
        self.M[:] = pin.crba(model, data, q)  # symmetric in pin 4 Python; mirror in case only triu is set
        self.M[self._lower] = self.M.T[self._lower]
        self.h[:] = pin.nonLinearEffects(model, data, q, v)
        pin.computeJointJacobians(model, data, q)
        pin.forwardKinematics(model, data, q, v, self._zero_a)
        pin.updateFramePlacements(model, data)
        row = 0
        for foot, frame_id in enumerate(self.robot.foot_frame_ids):
            if not stance[foot]:
                continue
            J = self._J_all[row : row + 3]
            J[:] = pin.getFrameJacobian(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED)[:3]
            accel = pin.getFrameClassicalAcceleration(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED)
            self._drift_all[row : row + 3] = accel.linear + self.alpha * (J @ v)
            row += 3
        self.Jc = self._J_all[:row]
        self.drift = self._drift_all[:row]


def contact_forces_for_torque(
    robot: Robot,
    q: np.ndarray,
    v: np.ndarray,
    tau: np.ndarray,
    stance: np.ndarray,
    alpha: float = BAUMGARTE_ALPHA,
    terms: ContactDynamicsTerms | None = None,
) -> np.ndarray:
    """World-frame contact forces (n_feet x 3, zero rows for swing feet) implied by joint torques ``tau``.

    Solves the KKT system of the contact dynamics (34b)-(34c) (``pin.forwardDynamics`` with the stance-foot
    Jacobian and drift ``Jcdot v + alpha Jc v``) — the forces the plant would need for the feet to follow the
    stabilised no-slip constraint. Used to score any controller's torque against the friction cone.
    """
    stance = np.asarray(stance, dtype=bool)
    forces = np.zeros((robot.n_feet, 3))
    if not stance.any():
        return forces
    terms = ContactDynamicsTerms(robot, alpha) if terms is None else terms
    terms.compute(q, v, stance)
    tau_full = np.zeros(robot.nv)
    tau_full[robot.nv - robot.nu :] = tau
    # KKT: [M Jc'; Jc 0] [qdd; -F] = [S' tau - h; -drift]  (computeAllTerms is called inside)
    pin.forwardDynamics(terms.model, terms.data, q, v, tau_full, terms.Jc, terms.drift, 0.0)
    forces[stance] = np.asarray(terms.data.lambda_c).reshape(-1, 3)
    return forces


class FrictionConeScorer:
    """Counts ticks whose torque implies a stance force outside the friction pyramid (any controller)."""

    def __init__(
        self,
        robot: Robot,
        mu: float = DEFAULT_FRICTION,
        alpha: float = BAUMGARTE_ALPHA,
        tolerance: float = CONE_TOLERANCE,
    ) -> None:
        self.robot = robot
        self.mu = float(mu)
        self.tolerance = float(tolerance)
        self.terms = ContactDynamicsTerms(robot, alpha)
        self.ticks = 0
        self.violations = 0

    def score(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray, stance: np.ndarray) -> bool:
        """Score one tick; returns True (and counts it) when the implied forces leave the cone."""
        forces = contact_forces_for_torque(self.robot, q, v, tau, stance, self.terms.alpha, terms=self.terms)
        self.ticks += 1
        violated = friction_cone_violation(forces[np.asarray(stance, bool)], self.mu) > self.tolerance
        self.violations += int(violated)
        return violated
