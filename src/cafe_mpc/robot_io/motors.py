"""What a robot's motor drivers do with a low-level command: the joint PD law plus feed-forward, saturated.

A Unitree motor (and most hobby-to-research actuators) runs ``tau + kp (q - q_j) + kd (dq - dq_j)`` at its
own rate (kHz) with the last command it received, and saturates at its torque limit. A simulated robot
applies the same law at every physics step (``robot_io.inprocess``, ``cafe-mpc sim-robot``).
"""

from __future__ import annotations

import numpy as np

from cafe_mpc.robot_io.interface import JointCommand


def motor_torques(
    command: JointCommand, q: np.ndarray, dq: np.ndarray, limits: np.ndarray, out: np.ndarray
) -> np.ndarray:
    """The joint torques the motors apply for ``command`` at joint angles ``q`` and rates ``dq``, clipped to
    ``limits`` (written into ``out``, returned)."""
    np.subtract(command.q, q, out=out)
    out *= command.kp
    out += command.kd * (command.dq - dq)
    out += command.tau
    np.clip(out, -limits, limits, out=out)
    return out
