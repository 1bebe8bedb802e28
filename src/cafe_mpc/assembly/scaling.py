"""A run's settings carried to its robot (``scaling: robot``; the laws: ``robots.scaling``).

The builders read the config's tuned values as the reference robot's and pass them through the scale
``run_scale(config, robot)`` (in the ``RunContext`` they are given): gait phase durations (``scaled_gait``),
swing height, Raibert gain and foothold box (the reference); the CAFE problem's horizons, cost weights and
SRB force weight (``planners.cafe.setup``); the Baumgarte rates of the whole-body knots and the VWBC, the
minimum base height, PD and template swing gains (the registries' builders); the fall height (the lab).
"""

from __future__ import annotations

from cafe_mpc.config import RunConfig
from cafe_mpc.ocp.contact_schedule import GaitCycle, get_gait
from cafe_mpc.robots.robot import Robot
from cafe_mpc.robots.scaling import IDENTITY, RobotScale, robot_scale


def run_scale(config: RunConfig, robot: Robot) -> RobotScale:
    """The robot's scale, or the identity with ``scaling: none``."""
    return robot_scale(robot) if config.scaling == "robot" else IDENTITY


def scaled_gait(name: str, scale: RobotScale) -> GaitCycle:
    """The library gait with every phase duration times the Froude time scale."""
    gait = get_gait(name)
    if scale.time == 1.0:
        return gait
    return GaitCycle(gait.name, tuple((flags, duration * scale.time) for flags, duration in gait.cycle))
