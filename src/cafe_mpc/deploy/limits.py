"""The limits every command to the robot is held to, whatever produced it (stand-up, MPC, lie-down).

``CommandLimiter.apply(command, q, dq)`` changes the command in place, per joint:

* **gains**: ``kp`` in ``[0, max_kp]``, ``kd`` in ``[0, max_kd]``;
* **position**: the commanded angle inside the position limits, ``position_margin`` in from each; a joint
  measured beyond that range gets no feed-forward torque pushing it further out;
* **velocity**: the commanded rate within the velocity limits; a joint measured faster than its limit gets
  no feed-forward torque speeding it up;
* **torque**: the feed-forward torque within the torque limits (the smaller of the controller's and the
  motors');
* **rate of change**: the feed-forward torque moves at most ``max_torque_rate`` x period per tick, and a
  commanded angle held by a stiffness moves at most its velocity limit x period.

``clamps`` counts the ticks each limit changed a command (the deployment's summary reports them).
"""

from __future__ import annotations

import numpy as np

from cafe_mpc.deploy.settings import DeploySettings
from cafe_mpc.robot_io.interface import JointCommand
from cafe_mpc.robots.robot import Robot

LIMITS = ("gains", "position", "velocity", "torque", "rate")


class CommandLimiter:
    """Holds commands to ``robot``'s limits and the settings' (module docstring); ``period``: s between
    commands."""

    def __init__(self, robot: Robot, settings: DeploySettings, period: float) -> None:
        self.torque = np.minimum(robot.torque_limits, robot.plant.motor_torque_limits)
        margin = settings.position_margin
        self.lower = robot.position_lower + margin
        self.upper = robot.position_upper - margin
        self.velocity = np.asarray(robot.velocity_limits, dtype=float)
        self.max_kp, self.max_kd = settings.max_kp, settings.max_kd
        self.torque_step = settings.max_torque_rate * period
        self.position_step = self.velocity * period
        self.clamps = dict.fromkeys(LIMITS, 0)
        self._previous = JointCommand.zeros(len(self.torque))
        self._has_previous = False
        self._scratch = np.zeros(len(self.torque))

    def reset(self) -> None:
        """Forget the previous command (the next one is not rate-limited against it)."""
        self._has_previous = False

    def _clip(self, values: np.ndarray, low, high, limit: str) -> None:
        scratch = self._scratch
        np.clip(values, low, high, out=scratch)
        if not np.array_equal(scratch, values):
            self.clamps[limit] += 1
            np.copyto(values, scratch)

    def apply(self, command: JointCommand, q: np.ndarray, dq: np.ndarray) -> JointCommand:
        """Hold ``command`` to the limits at the measured joint angles ``q`` and rates ``dq`` (in place)."""
        self._clip(command.kp, 0.0, self.max_kp, "gains")
        self._clip(command.kd, 0.0, self.max_kd, "gains")
        self._clip(command.q, self.lower, self.upper, "position")
        self._clip(command.dq, -self.velocity, self.velocity, "velocity")
        tau = command.tau
        outward = ((q > self.upper) & (tau > 0.0)) | ((q < self.lower) & (tau < 0.0))
        if np.any(outward):
            tau[outward] = 0.0
            self.clamps["position"] += 1
        speeding = (np.abs(dq) > self.velocity) & (tau * dq > 0.0)
        if np.any(speeding):
            tau[speeding] = 0.0
            self.clamps["velocity"] += 1
        self._clip(tau, -self.torque, self.torque, "torque")
        previous = self._previous
        if self._has_previous:
            limited = False
            delta = tau - previous.tau
            if np.any(np.abs(delta) > self.torque_step):
                np.clip(delta, -self.torque_step, self.torque_step, out=delta)
                np.add(previous.tau, delta, out=tau)
                limited = True
            held = (command.kp > 0.0) & (previous.kp > 0.0)
            delta = command.q - previous.q
            too_fast = held & (np.abs(delta) > self.position_step)
            if np.any(too_fast):
                np.clip(delta, -self.position_step, self.position_step, out=delta)
                command.q[too_fast] = previous.q[too_fast] + delta[too_fast]
                limited = True
            if limited:
                self.clamps["rate"] += 1
        previous.copy_from(command)
        self._has_previous = True
        return command
