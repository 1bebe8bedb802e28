"""The closed-loop controller of a run config: PD standing, or a planner's MPC loop over its low level.

Each builder turns a run into objects once, through the registries (``planners.registry``: the ``planner``
key; ``low_level.registry``: the ``wbc`` key), from the run config resolved once against its robot
(``assembly.resolve``: the ``ResolvedRun`` with the robot, its scale, the scaled schedule and gaits, the
torque limits and the contact model):

* ``build_planner``: the planner the config names (CAFE-MPC, Sec. IV and VI; the template baseline, Sec.
  VII-C) tracking the run's reference (``assembly.references``, Sec. VI-A) with the ``mpc`` section's
  receding-horizon settings;
* ``build_low_level``: what follows the plan at the control rate: the planner's own low level (the
  template's stance ``J' F`` / swing PD), else the one ``wbc`` names (PD standing, Riccati feedback (33), the
  VWBC QP (34));
* ``build_mpc_loop``: the planner's MPC loop over the low level (``control.loop.MpcLoop``), ``inline``
  (``control.inline``: in simulated time, one MPC worker, fixed or measured latency) or in its own
  ``process`` against the wall clock (``control.process``; the process builds its planner with
  ``process_planner``), with the safe ladder of the ``recovery`` section and its balance controller;
* ``build_controller``: the closed loop of a run in simulated time: the inline MPC loop, or the low level
  alone when it follows no plan (``wbc: pd``);
* ``build_estimator`` / ``build_sensing_controller``: the state estimator, and a controller behind it and
  the sensing front end (``recovery.sensors``), for runs that read the robot's sensors.

A builder that is given a ``low_level`` uses it (the experiment harness passes one wrapped in its recorder);
otherwise it builds ``build_low_level``'s. Every setting the library rejects becomes a ``ConfigError``
naming its section.
"""

from __future__ import annotations

import functools

import numpy as np

from cafe_mpc.assembly.references import build_reference
from cafe_mpc.assembly.resolve import resolve
from cafe_mpc.config import ConfigError, RunConfig
from cafe_mpc.control.inline import InlineMpcLoop
from cafe_mpc.control.loop import MpcLoop
from cafe_mpc.control.process import ProcessMpcLoop
from cafe_mpc.core.controller import Controller, LowLevelController
from cafe_mpc.estimation.controller import SensingController
from cafe_mpc.estimation.estimator import StateEstimator
from cafe_mpc.low_level import registry as low_levels
from cafe_mpc.low_level.registry import LOW_LEVELS
from cafe_mpc.planners.base import Planner
from cafe_mpc.planners.registry import PLANNERS
from cafe_mpc.planners.resolved import ResolvedRun
from cafe_mpc.reference.base import Reference
from cafe_mpc.robots.robot import load_robot

RunController = LowLevelController | MpcLoop
"""What a run config builds: a low level that runs alone (PD standing), or an MPC loop (inline in simulated
time, or with the planner in its own process against the wall clock)."""


def runs_alone(config: RunConfig) -> bool:
    """Whether the config's ``wbc`` follows no plan and drives the robot by itself, with no planner (PD
    standing)."""
    return not LOW_LEVELS.get(config.wbc).needs_plan


def low_level_name(config: RunConfig) -> str:
    """How a run's records name its low level: the planner's name when its slice brings its own (the
    template's), else ``wbc``."""
    return config.planner if PLANNERS.get(config.planner).low_level is not None else config.wbc


def build_planner(run: ResolvedRun, reference: Reference | None = None) -> Planner:
    """The planner of a run (``planner``): tracking ``reference`` (default: the run's, Sec. VI-A), with the
    ``mpc`` section's receding-horizon settings."""
    planner = PLANNERS.get(run.config.planner)
    if reference is None:
        reference = build_reference(run)
    return planner.build(run, reference)


def build_low_level(run: ResolvedRun) -> LowLevelController:
    """The low-level controller of a run: the planner's own (``planner: template``), else the one named by
    ``wbc`` (PD, Riccati (33) or VWBC (34)), with the run's torque limits and contact model."""
    return low_levels.build_low_level(run, PLANNERS.get(run.config.planner))


def build_mpc_loop(
    run: ResolvedRun, mode: str = "inline", low_level: LowLevelController | None = None
) -> MpcLoop:
    """The planner's MPC loop over ``low_level`` (default: ``build_low_level``'s): ``inline`` (simulated or
    the caller's time, fixed or measured latency) or ``process`` (the planner in its own process against the
    wall clock; close it, ``with``, to stop the process). ``ConfigError`` when the config's ``wbc`` follows
    no plan (``wbc: pd`` stands without a planner), and for ``process`` with ``terrain: height_map`` (the
    process gets no maps)."""
    config = run.config
    if runs_alone(config):
        raise ConfigError(
            f"an MPC loop needs a low level that follows a plan (wbc: vwbc or riccati), not wbc: {config.wbc}"
        )
    if mode not in ("inline", "process"):
        raise ConfigError(f"mode must be 'inline' or 'process', got {mode!r}")
    if mode == "process" and config.terrain == "height_map":
        raise ConfigError(
            "terrain: 'height_map' runs with the MPC in the caller's loop only (mode 'inline'): the MPC "
            "process does not receive the maps, and its plans carry no map normal for the low level"
        )
    planner = PLANNERS.get(config.planner)
    if low_level is None:
        low_level = low_levels.build_low_level(run, planner)
    balance = low_levels.build_balance(run)  # the safe ladder's (control.plan_follower)
    damped = low_levels.build_damped(run)
    if mode == "inline":
        reference = build_reference(run)
        if run.terrain_map is not None and run.terrain_map.cone == "map":
            _cone_on_map(low_level, reference)
        return InlineMpcLoop(
            run.controller_robot,
            planner.build(run, reference),
            low_level,
            run.control_period,
            recovery=config.recovery,
            balance=balance,
            damped=damped,
        )
    loop = ProcessMpcLoop(
        run.controller_robot,
        functools.partial(process_planner, config.model_dump(mode="json")),
        low_level,
        planner.plan_format(run),
        config.mpc.period,
        control_period=run.control_period,
        scheme=config.mpc.scheme,
        recovery=config.recovery,
        balance=balance,
        damped=damped,
        lock_memory=config.simulation.realtime and config.simulation.lock_memory,
    )
    loop.reference = build_reference(run)  # for the run's report (gait stance)
    return loop


def _cone_on_map(low_level: LowLevelController, reference: Reference) -> None:
    """``terrain_map.cone: map``: the VWBC's pyramid about the reference's height map under the feet
    (``VWBC.cone_normal``, ``LocomotionReference.terrain_normal``), the VWBC found under the wrappers that
    record it (``inner``); a low level without a pyramid (Riccati) keeps none."""
    target = low_level
    while not hasattr(target, "cone_normal") and hasattr(target, "inner"):
        target = target.inner
    normal = getattr(reference, "terrain_normal", None)
    if hasattr(target, "cone_normal") and normal is not None:
        target.cone_normal = normal


def build_controller(run: ResolvedRun, low_level: LowLevelController | None = None) -> RunController:
    """The closed-loop controller of a run in simulated time (fixed or measured latency): the low level
    alone when it follows no plan (``wbc: pd``), or the planner's inline MPC loop over ``low_level``
    (default: ``build_low_level``'s)."""
    if runs_alone(run.config):
        return LOW_LEVELS.get(run.config.wbc).build(run)
    return build_mpc_loop(run, "inline", low_level)


def process_planner(config_data: dict) -> Planner:
    """Builds the planner inside the MPC process, from the run config as plain data (picklable): its own
    robot model, resolved run, reference and solver; measured latency, so the solve keeps the wall-clock
    budget."""
    config = RunConfig.model_validate(config_data)
    config = config.model_copy(update={"mpc": config.mpc.model_copy(update={"latency": "measured"})})
    return build_planner(resolve(config, load_robot(config.robot)))


def build_estimator(run: ResolvedRun) -> StateEstimator:
    """The state estimator of a run (``kinematic_kf``: IMU attitude + leg-kinematics Kalman filter); off
    flat ground (``run.ground_plane``) it does not drop stance feet for standing above z = 0."""
    try:
        return StateEstimator(run.controller_robot, run.config.kinematic_kf, flat_ground=not run.ground_plane)
    except ValueError as error:
        raise ConfigError(f"kinematic_kf: {error}") from error


def build_sensing_controller(
    run: ResolvedRun,
    inner: Controller,
    position_xy: tuple[float, float] = (0.0, 0.0),
    capacity: int | None = None,
) -> SensingController:
    """``inner`` behind the state estimator (``estimator: kinematic_kf``): the closed loop hands it sensor
    readings, the estimator turns them into the measurement ``inner`` gets (``estimation.controller``).
    ``position_xy``: where the robot is placed (the estimator's odometry origin); ``capacity``: ticks of
    estimates to preallocate (default: the run's)."""
    estimator = build_estimator(run)
    if capacity is None:
        simulation = run.config.simulation
        capacity = int(np.ceil(simulation.duration * simulation.control_rate_hz)) + 2
    return SensingController(
        inner, estimator, capacity=capacity, position_xy=position_xy, limits=run.config.recovery.sensors
    )
