"""A simulated robot in the same process, behind ``RobotInterface``, stepped in simulated time.

``InProcessRobot`` wraps a ``MotorPlant`` (a physics simulation with joint torques in and sensor readings out;
the lab's ``cafe_mpc_lab.sim.motor_plant.MujocoMotorPlant``) and acts as the robot's low level does: the
motors apply the last command with their PD law at every physics step (``robot_io.motors``), and a state is
published every ``1 / state_rate_hz`` seconds. Its ``clock`` is the plant's time: ``clock.sleep_until(t)``
steps the physics up to ``t``, so a deployment (``cafe_mpc.deploy``) runs against it deterministically, as
fast as the machine goes, with its start-up checks and safety logic exactly as on the wire. ``outages``
drop the states published inside the given windows (a link that stops delivering), to test the reaction to
link loss without a network.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from cafe_mpc.robot_io.interface import (
    Clock,
    JointCommand,
    LinkHealth,
    LinkMonitor,
    RobotInterface,
    RobotState,
)
from cafe_mpc.robot_io.motors import motor_torques


class MotorPlant(Protocol):
    """A simulated robot at the motor level (joint order of its ``Robot``)."""

    timestep: float
    """Physics step, s."""
    torque_limits: np.ndarray
    """Motor saturation, Nm."""

    @property
    def time(self) -> float:
        """Simulated time, s."""
        ...

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint angles and rates now (the motors' own encoders)."""
        ...

    def step(self, torques: np.ndarray) -> None:
        """One physics step with ``torques`` applied."""
        ...

    def sense(self, out: RobotState) -> None:
        """What the robot's sensors report now, into ``out`` (readings, foot forces; ``robot_time``)."""
        ...


class PlantClock(Clock):
    """The plant's simulated time; ``sleep_until`` steps the physics (``InProcessRobot.advance``)."""

    def __init__(self, robot: InProcessRobot) -> None:
        self._robot = robot

    def now(self) -> float:
        return self._robot.plant.time

    def sleep_until(self, t: float) -> None:
        self._robot.advance(t)


class InProcessRobot(RobotInterface):
    """``RobotInterface`` over a ``MotorPlant`` in simulated time (module docstring).

    ``state_rate_hz``: how often the robot publishes its state; ``outages``: ``(start, duration)`` windows
    (s of plant time) in which every state is lost.
    """

    def __init__(
        self,
        plant: MotorPlant,
        n_joints: int,
        n_feet: int,
        state_rate_hz: float = 500.0,
        outages: Sequence[tuple[float, float]] = (),
    ) -> None:
        if state_rate_hz <= 0:
            raise ValueError(f"state_rate_hz must be positive, got {state_rate_hz}")
        self.plant = plant
        self.n_joints = n_joints
        self.clock = PlantClock(self)
        self.state_period = 1.0 / state_rate_hz
        self.outages = tuple((float(start), float(start) + float(length)) for start, length in outages)
        self.monitor = LinkMonitor()
        self._command = JointCommand.zeros(n_joints)
        self._torques = np.zeros(n_joints)
        self._sensed = RobotState.zeros(n_joints, n_feet)
        self._state = RobotState.zeros(n_joints, n_feet)
        self._have_state = False
        self._published = 0
        self._next_state = plant.time
        self._sent = 0

    @property
    def commands_sent(self) -> int:
        return self._sent

    def open(self) -> None:
        """Nothing to connect."""

    def close(self) -> None:
        """Nothing to release."""

    def advance(self, t: float) -> None:
        """Step the physics to ``t`` (the motors on the last command), publishing states on the way."""
        plant = self.plant
        half_step = 0.5 * plant.timestep
        while plant.time + half_step < t:
            if plant.time + half_step >= self._next_state:
                self._publish()
            q, dq = plant.joint_state()
            plant.step(motor_torques(self._command, q, dq, plant.torque_limits, self._torques))
        if plant.time + half_step >= self._next_state:
            self._publish()

    def _publish(self) -> None:
        plant = self.plant
        self._next_state += self.state_period
        self._published += 1
        now = plant.time
        if any(start <= now < end for start, end in self.outages):
            return
        plant.sense(self._sensed)
        self._sensed.received = now
        self._sensed.readings.time = now
        self._sensed.sequence = self.monitor.received + 1
        self.monitor.arrived(now, self._published)
        self._have_state = True

    def read(self) -> RobotState | None:
        if not self._have_state:
            return None
        state, sensed = self._state, self._sensed
        state.readings.copy_from(sensed.readings)
        np.copyto(state.foot_forces, sensed.foot_forces)
        state.received, state.robot_time, state.sequence = sensed.received, sensed.robot_time, sensed.sequence
        return state

    def write(self, command: JointCommand) -> None:
        self._command.copy_from(command)
        self._sent += 1

    def health(self) -> LinkHealth:
        return self.monitor.health(self.plant.time)
