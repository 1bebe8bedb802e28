"""The start-up checks: nothing is commanded until the robot's state says it is safe to.

Each check raises ``StartupRefused`` with one line that says what is wrong and what was measured:

* ``check_link``: states arrive at ``min_link_rate_hz`` or more (measured over ``link_window``);
* ``check_joints``: every joint reads inside its position limits (``joint_range_tolerance`` beyond them is
  accepted): a joint outside means a wrong mapping, offset or calibration, or a robot in a pose it cannot
  stand up from;
* ``check_upright``: the IMU says the trunk is within ``max_start_tilt`` of upright (not on its side or
  upside down).
"""

from __future__ import annotations

import numpy as np

from cafe_mpc.robot_io.interface import LinkHealth, RobotState
from cafe_mpc.robots.robot import Robot


class StartupRefused(RuntimeError):
    """The robot's state does not allow starting (one line: what and the value measured)."""


def tilt_of(quaternion_xyzw: np.ndarray) -> float:
    """Angle (rad) between the trunk's z axis and the vertical, from the base-to-world quaternion."""
    x, y = float(quaternion_xyzw[0]), float(quaternion_xyzw[1])
    norm = float(np.dot(quaternion_xyzw, quaternion_xyzw))
    return float(np.arccos(np.clip(1.0 - 2.0 * (x * x + y * y) / norm, -1.0, 1.0)))


def check_link(health: LinkHealth, min_rate_hz: float, where: str) -> None:
    if health.rate_hz < min_rate_hz:
        raise StartupRefused(
            f"the robot's state arrives at {health.rate_hz:.0f} Hz on {where}, below the "
            f"{min_rate_hz:.0f} Hz the controller needs ({health.received} received, {health.lost} lost)"
        )


def check_joints(state: RobotState, robot: Robot, tolerance: float) -> None:
    q = state.readings.joint_positions
    outside = [
        f"{name} at {value:.3f} rad (range {lower:.3f} to {upper:.3f})"
        for name, value, lower, upper in zip(
            robot.joint_names, q, robot.position_lower, robot.position_upper, strict=True
        )
        if not lower - tolerance <= value <= upper + tolerance
    ]
    if outside:
        raise StartupRefused(
            f"joint outside its range: {'; '.join(outside)} (check the robot file's hardware mapping and the "
            "robot's pose)"
        )


def check_upright(state: RobotState, max_tilt: float) -> None:
    tilt = tilt_of(state.readings.orientation)
    if tilt > max_tilt:
        raise StartupRefused(
            f"the IMU says the trunk is tilted {np.degrees(tilt):.0f} degrees from upright (at most "
            f"{np.degrees(max_tilt):.0f} accepted): put the robot on its feet"
            + (" (it reads upside down)" if tilt > 0.5 * np.pi else "")
        )
