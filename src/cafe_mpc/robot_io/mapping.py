"""Joints <-> motor slots: order, signs and zero offsets of a robot's motors (its robot file's ``hardware``).

A motor angle ``m`` reads as the joint angle ``sign * m + offset``; rates and torques are multiplied by the
sign; gains are the same on both sides. The ``*_into`` methods write into the caller's arrays (motor arrays
have one entry per motor slot of the message; slots without a joint are left as they are).
"""

from __future__ import annotations

import numpy as np

from cafe_mpc.robots.hardware import HardwareSpec
from cafe_mpc.robots.robot import Robot


class MotorMapping:
    """The motor slots of ``robot``'s joints (``Robot.hardware``); ``ValueError`` for a robot without a
    ``hardware`` section."""

    def __init__(self, robot: Robot) -> None:
        if robot.hardware is None:
            raise ValueError(
                f"robot {robot.name!r} has no hardware section in its robot file (docs/deploy.md): "
                "nothing says how its motors map to its joints"
            )
        spec: HardwareSpec = robot.hardware
        self.spec = spec
        self.slots = np.asarray(spec.motor_of_joint, dtype=np.intp)
        """Motor slot of each joint (robot joint order)."""
        self.signs = np.asarray(spec.joint_signs, dtype=float)
        self.offsets = np.asarray(spec.joint_offsets, dtype=float)
        self.n_joints = len(self.slots)

    def joint_positions_into(self, motor_q: np.ndarray, out: np.ndarray) -> None:
        """Joint angles from motor angles (the motor slots' values)."""
        np.multiply(motor_q[self.slots], self.signs, out=out)
        out += self.offsets

    def joint_rates_into(self, motor_values: np.ndarray, out: np.ndarray) -> None:
        """Joint rates or torques from motor rates or torques."""
        np.multiply(motor_values[self.slots], self.signs, out=out)

    def motor_positions_into(self, joint_q: np.ndarray, out: np.ndarray) -> None:
        """Motor angles for joint angles, written into the joints' slots of ``out``."""
        out[self.slots] = (joint_q - self.offsets) * self.signs

    def motor_rates_into(self, joint_values: np.ndarray, out: np.ndarray) -> None:
        """Motor rates or torques for joint rates or torques, into the joints' slots of ``out``."""
        out[self.slots] = joint_values * self.signs

    def motor_gains_into(self, joint_gains: np.ndarray, out: np.ndarray) -> None:
        """Gains (the same on both sides), into the joints' slots of ``out``."""
        out[self.slots] = joint_gains
