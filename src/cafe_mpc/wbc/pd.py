"""Joint PD control toward a fixed pose with a static gravity feed-forward: the first controller.

``tau = tau_ff + kp (q_des - q) - kd qdot`` where ``tau_ff`` balances gravity at the target pose with the
weight shared equally by the stance feet (``S tau = g(q) - Jc^T F``, the joint rows of the static
equilibrium). Also the safe last-resort fallback of the MPC controllers (damping toward standing).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from cafe_mpc.robots.robot import Robot
from cafe_mpc.sim.plant import PlantState


def static_stance_torques(
    robot: Robot, q: np.ndarray, stance: np.ndarray | None = None, force_per_foot: float | None = None
) -> np.ndarray:
    """Joint torques that hold configuration ``q`` with a vertical force on each stance foot (leg gravity
    included): by default the weight split over the stance feet (static balance); gaits with flight phases
    pass their average stance force (``force_per_foot``, N)."""
    stance = np.ones(4, dtype=bool) if stance is None else np.asarray(stance, dtype=bool)
    if stance.shape != (4,) or not stance.any():
        raise ValueError("static_stance_torques needs 4 stance flags with at least one foot on the ground")
    model = robot.model
    data = model.createData()
    gravity = pin.computeGeneralizedGravity(model, data, q)
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    weight = robot.total_mass * 9.81 / stance.sum() if force_per_foot is None else float(force_per_foot)
    contact_term = np.zeros(model.nv)
    for foot, frame_id in enumerate(robot.foot_frame_ids):
        if stance[foot]:
            jacobian = pin.getFrameJacobian(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED)[:3]
            contact_term += jacobian.T @ np.array([0.0, 0.0, weight])
    return (gravity - contact_term)[6:]


class PDController:
    """PD on the 12 joints toward ``q_target`` (standing pose by default), clamped to the torque limits."""

    def __init__(
        self,
        robot: Robot,
        kp: float = 60.0,
        kd: float = 1.5,
        q_target: np.ndarray | None = None,
        gravity_feedforward: bool = True,
    ) -> None:
        if kp < 0 or kd < 0:
            raise ValueError(f"PD gains must be non-negative, got kp={kp}, kd={kd}")
        self.robot = robot
        self.kp, self.kd = float(kp), float(kd)
        self.q_target = (robot.q_standing if q_target is None else np.asarray(q_target, float)).copy()
        self.feedforward = (
            static_stance_torques(robot, self.q_target) if gravity_feedforward else np.zeros(12)
        )
        self.limits = robot.torque_limits
        self._torques = np.zeros(robot.nu)

    def reset(self, state: PlantState) -> None:
        self._torques[:] = 0.0

    def compute(self, t: float, state: PlantState) -> np.ndarray:
        np.subtract(self.q_target[7:], state.q[7:], out=self._torques)
        self._torques *= self.kp
        self._torques -= self.kd * state.v[6:]
        self._torques += self.feedforward
        np.clip(self._torques, -self.limits, self.limits, out=self._torques)
        return self._torques
