"""Our MuJoCo plant at the motor level: a simulated robot as its low-level interface sees it.

``MujocoMotorPlant`` is the ``robot_io.inprocess.MotorPlant`` a simulated robot runs (``cafe-mpc sim-robot``,
``robot_io.inprocess.InProcessRobot``): joint torques in (the motor law of ``robot_io.motors`` applied by the
caller at every physics step), the robot's own sensors out (the IMU's orientation, gyroscope and
accelerometer, the joint encoders and torques, ideal: ``sim.sensors.IdealSensors``), and the foot forces a
robot's foot sensors would give (the vertical contact force, N). It starts **lying**: joints at the robot
file's ``hardware.lying_pose``, settled on the floor with the motors damping, as a robot is powered on.
"""

from __future__ import annotations

import numpy as np

from cafe_mpc.robot_io.interface import JointCommand, RobotState
from cafe_mpc.robot_io.motors import motor_torques
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant
from cafe_mpc_lab.sim.sensors import IdealSensors


class MujocoMotorPlant:
    """``robot``'s MuJoCo plant behind the motor interface (module docstring). ``timestep``: physics step
    (None: the robot file's)."""

    def __init__(self, robot: Robot, timestep: float | None = None) -> None:
        if robot.hardware is None:
            raise ValueError(f"robot {robot.name!r} has no hardware section: no lying pose to start from")
        self.robot = robot
        self.plant = MujocoPlant(robot, timestep)
        self.model, self.data = self.plant.model, self.plant.data
        self.timestep = float(self.model.opt.timestep)
        self.torque_limits = np.array(self.plant.torque_limits, dtype=float)
        self.sensors = IdealSensors(self.model, robot.joint_names)
        self._torques = np.zeros(robot.nu)

    @property
    def time(self) -> float:
        return float(self.data.time)

    def lie_down(self, settle: float = 1.0) -> None:
        """Reset to the robot lying (module docstring): the lying pose just above the floor, then ``settle``
        s with the motors damping (robot file's ``hardware.stance_kd``)."""
        robot, data = self.robot, self.data
        q = np.array(robot.q_standing, dtype=float)
        q[3:7] = (0.0, 0.0, 0.0, 1.0)
        q[7:] = robot.hardware.lying_pose
        height = 0.0
        while True:  # the lowest base height at which nothing touches the floor
            q[2] = height
            self.plant.reset(q)
            if data.ncon == 0 or height > robot.standing_height:
                break
            height += 0.005
        damping = JointCommand.zeros(robot.nu)
        damping.kd[:] = robot.hardware.stance_kd
        for _ in range(round(settle / self.timestep)):
            self.step_command(damping)
        data.time = 0.0

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        return self.data.qpos[7:], self.data.qvel[6:]

    def step(self, torques: np.ndarray) -> None:
        self.plant.step(torques)

    def step_command(self, command: JointCommand) -> None:
        """One physics step with the motors applying ``command`` (``robot_io.motors.motor_torques``)."""
        q, dq = self.joint_state()
        self.plant.step(motor_torques(command, q, dq, self.torque_limits, self._torques))

    def sense(self, out: RobotState) -> None:
        self.sensors.read(self.data, out.readings)
        out.foot_forces[:] = self.plant.read_state().foot_forces[:, 2]
        out.robot_time = self.time

    def base_height(self) -> float:
        return float(self.data.qpos[2])

    def base_velocity(self) -> np.ndarray:
        """World-frame linear velocity of the base."""
        return np.array(self.data.qvel[:3])

    def base_position(self) -> np.ndarray:
        return np.array(self.data.qpos[:3])

    def tilt(self) -> float:
        """Angle between the trunk's z axis and the vertical (rad)."""
        _w, x, y, _z = self.data.qpos[3:7]
        return float(np.arccos(np.clip(1.0 - 2.0 * (x * x + y * y), -1.0, 1.0)))
