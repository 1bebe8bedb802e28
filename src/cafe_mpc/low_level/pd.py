"""Joint PD control toward a fixed pose with a static gravity feed-forward: the first controller.

``tau = tau_ff + kp (q_des - q) - kd qdot`` where ``tau_ff`` balances gravity at the target pose with the
weight shared equally by the stance feet (``dynamics.statics.static_stance_torques``). Needs no plan, so it
is also a closed-loop ``Controller`` on its own (standing), and the MPC loop's last-resort fallback.
"""

from __future__ import annotations

import numpy as np

from cafe_mpc.config import PDSettings
from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import KnotPlan
from cafe_mpc.dynamics.statics import static_stance_torques
from cafe_mpc.robots.robot import Robot
from cafe_mpc.robots.scaling import IDENTITY, RobotScale


class PDController(LowLevelController[KnotPlan]):
    """PD on the actuated joints toward ``q_target`` (standing pose by default), clamped to the torque
    limits. The plan, if any, is ignored. ``settings``: gains and feed-forward (the ``pd`` section;
    ``config.PDSettings``), whose gains (the reference robot's) ``scale`` carries to the robot
    (``robots.scaling``: the torque scale, times the time scale for the damping)."""

    def __init__(
        self,
        robot: Robot,
        settings: PDSettings | None = None,
        scale: RobotScale = IDENTITY,
        q_target: np.ndarray | None = None,
    ) -> None:
        settings = settings or PDSettings()
        self.robot = robot
        self.kp, self.kd = scale.stiffness(settings.kp), scale.damping(settings.kd)
        self.q_target = (robot.q_standing if q_target is None else np.asarray(q_target, float)).copy()
        self.feedforward = (
            static_stance_torques(robot, self.q_target)
            if settings.gravity_feedforward
            else np.zeros(robot.nu)
        )
        self.limits = robot.torque_limits
        self._joints_q = slice(robot.nq - robot.nu, robot.nq)
        self._joints_v = slice(robot.nv - robot.nu, robot.nv)
        self._torques = np.zeros(robot.nu)
        self.last_request = np.zeros(robot.nu)

    def reset(self) -> None:
        self._torques[:] = 0.0
        self.last_request[:] = 0.0

    def compute(self, t: float, measurement: Measurement, plan: KnotPlan | None = None) -> np.ndarray:
        np.subtract(self.q_target[self._joints_q], measurement.q[self._joints_q], out=self._torques)
        self._torques *= self.kp
        self._torques -= self.kd * measurement.v[self._joints_v]
        self._torques += self.feedforward
        self.last_request[:] = self._torques
        np.clip(self._torques, -self.limits, self.limits, out=self._torques)
        return self._torques

    def statistics(self) -> dict:
        return {}
