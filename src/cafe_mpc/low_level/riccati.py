"""Riccati feedback controller (paper Eq. (33)): ``tau = tau*_k + K_k (x ⊖ x*_k)``, clamped.

The baseline low-level controller and the fallback of the VWBC. ``k`` is the plan knot whose interval holds
the current time. The torque is clamped to the robot's limits (the paper's controller is not; the number of
ticks the unclamped command exceeded the limits is counted in ``limit_violations`` and the unclamped
torque of the last tick is ``last_request``).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.planners.cafe.plan import Plan, riccati_torque
from cafe_mpc.robots.robot import Robot


def state_error(
    model: pin.Model, q: np.ndarray, v: np.ndarray, x_plan: np.ndarray, out: np.ndarray | None = None
) -> np.ndarray:
    """``x ⊖ x*`` in the tangent space at ``x* = x_plan`` (the solver's convention):
    ``[pin.difference(q*, q), v - v*]``, written into ``out`` (``2 nv``) when given."""
    nq, nv = model.nq, model.nv
    out = np.empty(2 * nv) if out is None else out
    out[:nv] = pin.difference(model, x_plan[:nq], q)
    np.subtract(v, x_plan[nq:], out=out[nv:])
    return out


class RiccatiController(LowLevelController[Plan]):
    """Eq. (33) on the plan passed to ``compute``."""

    def __init__(self, robot: Robot, clamp: bool = True) -> None:
        self.robot = robot
        self.model = robot.model
        self.clamp = clamp
        self.limits = robot.torque_limits
        self.limit_violations = 0
        self.ticks = 0
        self._dx = np.zeros(2 * robot.nv)
        self._torques = np.zeros(robot.nu)
        self.last_request = np.zeros(robot.nu)
        """The last ``compute``'s torque before clamping (what Eq. (33) asked for; Fig. 9 plots it)."""

    def reset(self) -> None:
        self.limit_violations = 0
        self.ticks = 0
        self.last_request[:] = 0.0

    def state_error(self, q: np.ndarray, v: np.ndarray, x_plan: np.ndarray) -> np.ndarray:
        """``x ⊖ x*`` (``state_error``) into this controller's buffer."""
        return state_error(self.model, q, v, x_plan, self._dx)

    def torques_at(self, t: float, q: np.ndarray, v: np.ndarray, plan: Plan) -> np.ndarray:
        """Unclamped Riccati torques (Eq. (33)) at the plan knot whose interval holds ``t``."""
        k = plan.knot_at(t)
        return riccati_torque(plan, k, self.state_error(q, v, plan.xs[k]), self._torques)

    def compute(self, t: float, measurement: Measurement, plan: Plan | None) -> np.ndarray:
        if plan is None:
            raise RuntimeError("RiccatiController needs a plan")
        torques = self.torques_at(t, measurement.q, measurement.v, plan)
        self.last_request[:] = torques
        self.ticks += 1
        if np.any(np.abs(torques) > self.limits):
            self.limit_violations += 1
            if self.clamp:
                np.clip(torques, -self.limits, self.limits, out=torques)
        return torques

    def statistics(self) -> dict:
        """``torque_limit_violations``: ticks whose unclamped torque (33) exceeded a limit."""
        return {"ticks": self.ticks, "torque_limit_violations": self.limit_violations}
