"""Metrics of a run, written to ``metrics.json``."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from cafe_mpc.robots.robot import Robot
from cafe_mpc.sim.loop import SimulationLog


def roll_pitch_yaw(quaternions_xyzw: np.ndarray) -> np.ndarray:
    """Unwrapped (roll, pitch, yaw) of base quaternions (N x 4, x y z w), for plots and metrics only."""
    if len(quaternions_xyzw) == 0:
        return np.zeros((0, 3))
    angles = Rotation.from_quat(quaternions_xyzw).as_euler("ZYX")[:, ::-1]
    return np.unwrap(angles, axis=0)


def base_metrics(robot: Robot, log: SimulationLog, control_period: float) -> dict:
    """The metrics every run reports: fall, timing, base height, torque use."""
    sim_time = float(log.ticks * control_period)
    heights = log.q[:, 2]
    angles = roll_pitch_yaw(log.q[:, 3:7])
    limits = robot.torque_limits
    over_limit = np.any(np.abs(log.torque_command) > limits + 1e-9, axis=1)
    return {
        "fell": bool(log.fell),
        "fall_time_s": log.fall_time,
        "fall_reason": log.fall_reason,
        "sim_time_s": sim_time,
        "wall_time_s": float(log.wall_time),
        "real_time_factor": float(sim_time / log.wall_time) if log.wall_time > 0 else None,
        "control_ticks": int(log.ticks),
        "base_height_mean": float(np.mean(heights)) if len(heights) else None,
        "base_height_min": float(np.min(heights)) if len(heights) else None,
        "base_height_max": float(np.max(heights)) if len(heights) else None,
        "roll_abs_max_rad": float(np.max(np.abs(angles[:, 0]))) if len(angles) else None,
        "pitch_abs_max_rad": float(np.max(np.abs(angles[:, 1]))) if len(angles) else None,
        "base_displacement_xy_m": (log.q[-1, :2] - log.q[0, :2]).tolist() if log.ticks else None,
        "torque_abs_max_nm": float(np.max(np.abs(log.torque_command))) if log.ticks else None,
        "torque_limit_ticks": int(np.sum(over_limit)),
    }
