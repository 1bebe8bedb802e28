"""What a run config resolves to before anything is built: the ``RunContext`` the registries' builders take.

``run_context(config, robot)``: the config, its robot, the robot's scale (``assembly.scaling.run_scale``) and
the torque limits the plan and the low level respect (``torque_limits_of``).
"""

from __future__ import annotations

import numpy as np

from cafe_mpc.assembly.scaling import run_scale
from cafe_mpc.config import RunConfig
from cafe_mpc.planners.base import RunContext
from cafe_mpc.robots.robot import Robot


def torque_limits_of(config: RunConfig, robot: Robot) -> np.ndarray:
    """The torque limits the plan and the low-level controller respect (``config.torque_limits``)."""
    if config.torque_limits == "motor":
        return np.asarray(robot.plant.motor_torque_limits, dtype=float).copy()
    return np.asarray(robot.torque_limits, dtype=float).copy()


def run_context(config: RunConfig, robot: Robot) -> RunContext:
    """The ``RunContext`` of ``config`` driving ``robot``."""
    return RunContext(config, robot, run_scale(config, robot), torque_limits_of(config, robot))
