"""Riccati feedback controller (paper Eq. (33)): ``tau = tau*_k + K_k (x ⊖ x*_k)``, clamped.

The baseline low-level controller and the fallback of the VWBC. ``k`` is the plan knot closest to the
current time. The torque is clamped to the robot's limits (the paper's controller is not; the number of
ticks the unclamped command exceeded the limits is counted in ``limit_violations``).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from cafe_mpc.mpc.plan import Plan
from cafe_mpc.robots.robot import Robot


class RiccatiController:
    """Eq. (33) on the latest ``Plan``; ``set_plan`` swaps plans between ticks."""

    def __init__(self, robot: Robot, clamp: bool = True) -> None:
        self.robot = robot
        self.model = robot.model
        self.clamp = clamp
        self.limits = robot.torque_limits
        self.plan: Plan | None = None
        self.limit_violations = 0
        self._dx = np.zeros(2 * robot.nv)
        self._torques = np.zeros(robot.nu)
        self.requested = np.zeros(robot.nu)
        """The last ``compute``'s torque before clamping (what Eq. (33) asked for; Fig. 9 plots it)."""

    def set_plan(self, plan: Plan) -> None:
        self.plan = plan

    def state_error(self, q: np.ndarray, v: np.ndarray, x_plan: np.ndarray) -> np.ndarray:
        """``x ⊖ x*`` in the tangent space at ``x*`` (the solver's convention)."""
        nq, nv = self.model.nq, self.model.nv
        self._dx[:nv] = pin.difference(self.model, x_plan[:nq], q)
        np.subtract(v, x_plan[nq:], out=self._dx[nv:])
        return self._dx

    def torques_at(self, t: float, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Unclamped Riccati torques (Eq. (33)) at the plan knot closest to ``t``."""
        if self.plan is None:
            raise RuntimeError("RiccatiController has no plan yet")
        k = self.plan.knot_at(t)
        dx = self.state_error(q, v, self.plan.xs[k])
        np.matmul(self.plan.K[k], dx, out=self._torques)
        self._torques += self.plan.us[k]
        return self._torques

    def compute(self, t: float, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        torques = self.torques_at(t, q, v)
        self.requested[:] = torques
        if np.any(np.abs(torques) > self.limits):
            self.limit_violations += 1
            if self.clamp:
                np.clip(torques, -self.limits, self.limits, out=torques)
        return torques
