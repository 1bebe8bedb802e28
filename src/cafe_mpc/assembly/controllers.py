"""The closed-loop controller of a run config: PD standing, or a planner's MPC loop over its low level.

Each builder turns config sections into objects once, through the registries (``planners.registry``: the
``planner`` key; ``low_level.registry``: the ``wbc`` key), from the run's ``RunContext``
(``assembly.context``: robot, scale, torque limits):

* ``build_planner``: the planner the config names (CAFE-MPC, Sec. IV and VI; the template baseline, Sec.
  VII-C) tracking the run's reference (``assembly.references``, Sec. VI-A) with the ``mpc`` section's
  receding-horizon settings;
* ``build_low_level``: what follows the plan at the control rate: the planner's own low level (the
  template's stance ``J' F`` / swing PD), else the one ``wbc`` names (PD standing, Riccati feedback (33), the
  VWBC QP (34));
* ``build_controller``: the closed loop in simulated time (``control.mpc_loop.CafeMpcController``, one
  MPC worker, fixed or measured latency) over the low level, or the PD controller alone (a ``wbc`` that
  follows no plan);
* ``build_realtime_controller``: the MPC in its own process against the wall clock (``control.realtime``;
  the process builds its planner with ``realtime_mpc``);
* ``build_estimator`` / ``build_sensing_controller``: the state estimator, and a controller behind it, for
  runs that read the robot's sensors.

A builder that is given a ``low_level`` uses it (the experiment harness passes one wrapped in its recorder);
otherwise it builds ``build_low_level``'s. Every setting the library rejects becomes a ``ConfigError``
naming its section.
"""

from __future__ import annotations

import functools

import numpy as np

from cafe_mpc.assembly.context import run_context
from cafe_mpc.assembly.references import build_reference
from cafe_mpc.config import ConfigError, RunConfig
from cafe_mpc.control.mpc_loop import CafeMpcController
from cafe_mpc.control.realtime import RealtimeMpcController
from cafe_mpc.core.controller import Controller, LowLevelController
from cafe_mpc.estimation.controller import SensingController
from cafe_mpc.estimation.estimator import StateEstimator
from cafe_mpc.low_level import registry as low_levels
from cafe_mpc.low_level.registry import LOW_LEVELS
from cafe_mpc.planners.base import Planner
from cafe_mpc.planners.registry import PLANNERS
from cafe_mpc.reference.base import Reference
from cafe_mpc.robots.robot import Robot, load_robot

RunController = LowLevelController | CafeMpcController | RealtimeMpcController
"""What a run config builds: a low level that runs alone (PD standing), or an MPC loop in simulated or
wall-clock time."""


def runs_alone(config: RunConfig) -> bool:
    """Whether the config's ``wbc`` follows no plan and drives the robot by itself, with no planner (PD
    standing)."""
    return not LOW_LEVELS.get(config.wbc).needs_plan


def low_level_name(config: RunConfig) -> str:
    """How a run's records name its low level: the planner's name when its slice brings its own (the
    template's), else ``wbc``."""
    return config.planner if PLANNERS.get(config.planner).low_level is not None else config.wbc


def build_planner(config: RunConfig, robot: Robot, reference: Reference | None = None) -> Planner:
    """The planner of a run (``planner``): tracking ``reference`` (default: the config's, Sec. VI-A), with
    the ``mpc`` section's receding-horizon settings."""
    planner = PLANNERS.get(config.planner)
    if reference is None:
        reference = build_reference(config, robot)
    return planner.build(run_context(config, robot), reference)


def build_low_level(config: RunConfig, robot: Robot) -> LowLevelController:
    """The low-level controller of a run: the planner's own (``planner: template``), else the one named by
    ``wbc`` (PD, Riccati (33) or VWBC (34)), with the run's torque limits and friction."""
    return low_levels.build_low_level(run_context(config, robot), PLANNERS.get(config.planner))


def build_controller(
    config: RunConfig, robot: Robot, low_level: LowLevelController | None = None
) -> LowLevelController | CafeMpcController:
    """The closed-loop controller of ``config`` in simulated time (fixed or measured latency): the low level
    alone when it follows no plan (``wbc: pd``), or the planner's MPC loop over ``low_level`` (default:
    ``build_low_level``'s)."""
    if runs_alone(config):
        return LOW_LEVELS.get(config.wbc).build(run_context(config, robot))
    if low_level is None:
        low_level = build_low_level(config, robot)
    mpc = build_planner(config, robot)
    return CafeMpcController(
        robot,
        mpc.reference,
        mpc.builder,
        low_level,
        mpc=mpc,
        control_period=1.0 / config.simulation.control_rate_hz,
    )


def realtime_mpc(config_data: dict) -> Planner:
    """Builds the planner inside the real-time mode's MPC process, from the run config as plain data
    (picklable): its own robot model, reference and solver; measured latency, so the solve keeps the
    wall-clock budget."""
    config = RunConfig.model_validate(config_data)
    robot = load_robot(config.robot)
    config = config.model_copy(update={"mpc": config.mpc.model_copy(update={"latency": "measured"})})
    return build_planner(config, robot)


def build_realtime_controller(
    config: RunConfig, robot: Robot, low_level: LowLevelController | None = None
) -> RealtimeMpcController:
    """The planner against the wall clock: in its own process (``control.realtime``, built there by
    ``realtime_mpc``), ``low_level`` (default: ``build_low_level``'s) here. Close it (``with``) to stop the
    process."""
    if runs_alone(config):
        raise ConfigError(
            f"simulation.realtime needs an MPC run (a wbc that follows a plan), not wbc: {config.wbc}"
        )
    planner = PLANNERS.get(config.planner)
    run = run_context(config, robot)
    factory = functools.partial(realtime_mpc, config.model_dump(mode="json"))
    if low_level is None:
        low_level = build_low_level(config, robot)
    controller = RealtimeMpcController(
        robot,
        factory,
        low_level,
        config.mpc.period,
        planner.plan_format(run),
        control_period=run.control_period,
        scheme=config.mpc.scheme,
    )
    controller.reference = build_reference(config, robot)  # for the run's report (gait stance)
    return controller


def build_estimator(config: RunConfig, robot: Robot) -> StateEstimator:
    """The state estimator of a run (``kinematic_kf``: IMU attitude + leg-kinematics Kalman filter)."""
    try:
        return StateEstimator(robot, config.kinematic_kf)
    except ValueError as error:
        raise ConfigError(f"kinematic_kf: {error}") from error


def build_sensing_controller(
    config: RunConfig,
    robot: Robot,
    inner: Controller,
    position_xy: tuple[float, float] = (0.0, 0.0),
    capacity: int | None = None,
) -> SensingController:
    """``inner`` behind the state estimator (``estimator: kinematic_kf``): the closed loop hands it sensor
    readings, the estimator turns them into the measurement ``inner`` gets (``estimation.controller``).
    ``position_xy``: where the robot is placed (the estimator's odometry origin); ``capacity``: ticks of
    estimates to preallocate (default: the run's)."""
    estimator = build_estimator(config, robot)
    if capacity is None:
        capacity = int(np.ceil(config.simulation.duration * config.simulation.control_rate_hz)) + 2
    return SensingController(inner, estimator, capacity=capacity, position_xy=position_xy)
