"""The closed-loop controller of a run config: PD standing, or an MPC (CAFE or template) over its low level.

Each builder turns config sections into objects once:

* ``build_mpc``: the CAFE-MPC planner (``mpc.receding_horizon.RecedingHorizonMpc``): the reference
  (``assembly.references``, Sec. VI-A), the CAFE problem with its model schedule (``assembly.problem``,
  Sec. IV-D) and the receding-horizon settings (the ``mpc`` section itself: ``config.MpcSettings``);
* ``build_template_mpc``: the template-MPC baseline (``mpc.template.TemplateMpc``, Sec. VII-C);
* ``build_low_level``: what follows the plan at the control rate: PD standing, Riccati feedback (33), the
  VWBC QP (34), or the template's stance ``J' F`` / swing PD;
* ``build_controller``: the closed loop in simulated time (``control.mpc_loop.CafeMpcController``, one
  MPC worker, fixed or measured latency) over the low level, or the PD controller alone;
* ``build_realtime_controller``: the MPC in its own process against the wall clock (``control.realtime``;
  the process builds its planner with ``realtime_mpc``);
* ``build_sensing_controller``: a controller behind the state estimator (``estimation.controller``), for
  runs that read the robot's sensors.

A builder that is given a ``low_level`` uses it (the experiment harness passes one wrapped in its recorder);
otherwise it builds ``build_low_level``'s. Every setting the library rejects becomes a ``ConfigError``
naming its section.
"""

from __future__ import annotations

import functools

import numpy as np

from cafe_mpc.assembly.problem import build_problem, run_schedule, torque_limits_of
from cafe_mpc.assembly.references import build_reference
from cafe_mpc.assembly.scaling import run_scale
from cafe_mpc.config import ConfigError, RunConfig
from cafe_mpc.control.mpc_loop import CafeMpcController
from cafe_mpc.control.realtime import RealtimeMpcController
from cafe_mpc.core.controller import Controller, LowLevelController
from cafe_mpc.estimation.controller import SensingController
from cafe_mpc.estimation.estimator import StateEstimator
from cafe_mpc.mpc.receding_horizon import RecedingHorizonMpc
from cafe_mpc.mpc.template import TemplateMpc, TemplateProblemBuilder, TemplateSettings, template_srb
from cafe_mpc.reference.base import Reference
from cafe_mpc.robots.robot import Robot, load_robot
from cafe_mpc.wbc.pd import PDController
from cafe_mpc.wbc.riccati import RiccatiController
from cafe_mpc.wbc.template_low_level import TemplateLowLevelController, TemplateLowLevelSettings
from cafe_mpc.wbc.vwbc import VWBCController, VWBCSettings

RunController = PDController | CafeMpcController | RealtimeMpcController
"""What a run config builds: PD standing, or an MPC loop in simulated or wall-clock time."""


def build_mpc(config: RunConfig, robot: Robot, reference: Reference | None = None) -> RecedingHorizonMpc:
    """The CAFE-MPC planner of a run: reference (Sec. VI-A; ``reference`` if given), CAFE problem builder
    with its model schedule (Sec. IV-D), receding-horizon settings."""
    if reference is None:
        reference = build_reference(config, robot)
    return RecedingHorizonMpc(robot, reference, build_problem(config, robot), config.mpc)


def build_template_mpc(config: RunConfig, robot: Robot, reference: Reference | None = None) -> TemplateMpc:
    """The template-MPC baseline (``planner: template``, paper Sec. VII-C): the SRB-only plan
    (``mpc.template``) of the CAFE run's reference and receding-horizon settings (period, latency,
    iterations)."""
    if reference is None:
        reference = build_reference(config, robot)
    parameters, com_offset = template_srb(robot)
    section = config.template
    try:
        settings = TemplateSettings(
            horizon=section.horizon,
            dt=section.dt,
            parameters=parameters,
            leg_torque_limits=section.leg_torque_limits,
            predict_latency=section.predict_latency,
            centroidal_state=section.centroidal_state,
            vertical_reference=section.vertical_reference,
            torque_limits=tuple(torque_limits_of(config, robot).tolist()),
            friction_coefficient=config.mpc.friction,
        )
    except ValueError as error:
        raise ConfigError(f"template: {error}") from error
    builder = TemplateProblemBuilder(robot, settings, com_offset)
    return TemplateMpc(robot, reference, builder, config.mpc)


def build_low_level(config: RunConfig, robot: Robot) -> LowLevelController:
    """The low-level controller of a run: the template's own (``planner: template``), else the one named by
    ``config.wbc`` (PD, Riccati (33) or VWBC (34)), with the run's torque limits and friction."""
    if config.planner == "template":
        scale = run_scale(config, robot)
        try:
            settings = TemplateLowLevelSettings(
                scale.stiffness(config.template.swing_kp), scale.damping(config.template.swing_kd)
            )
        except ValueError as error:
            raise ConfigError(f"template: {error}") from error
        return TemplateLowLevelController(robot, settings, torque_limits=torque_limits_of(config, robot))
    if config.wbc == "pd":
        return build_pd(config, robot)
    if config.wbc == "riccati":
        riccati = RiccatiController(robot)
        riccati.limits = torque_limits_of(config, robot)
        return riccati
    try:
        scale = run_scale(config, robot)
        defaults = VWBCSettings.model_fields  # the reference robot's, scaled to the run's robot
        vwbc_settings = VWBCSettings(
            **config.vwbc.model_dump(),
            mu=config.vwbc.friction if config.vwbc.friction is not None else config.mpc.friction,
            alpha=scale.rate(defaults["alpha"].default),
            cone_tolerance=scale.force(defaults["cone_tolerance"].default),
        )
    except ValueError as error:
        raise ConfigError(f"vwbc: {error}") from error
    return VWBCController(robot, vwbc_settings, torque_limits=torque_limits_of(config, robot))


def build_pd(config: RunConfig, robot: Robot) -> PDController:
    """Joint PD standing with the config's gains scaled to the robot (torque scale; damping also by time)."""
    scale = run_scale(config, robot)
    return PDController(
        robot,
        scale.stiffness(config.pd.kp),
        scale.damping(config.pd.kd),
        gravity_feedforward=config.pd.gravity_feedforward,
    )


def build_controller(
    config: RunConfig, robot: Robot, low_level: LowLevelController | None = None
) -> PDController | CafeMpcController:
    """The closed-loop controller of ``config`` in simulated time (fixed or measured latency): the PD
    controller alone (``wbc: pd``), or the CAFE or template MPC over ``low_level`` (default:
    ``build_low_level``'s)."""
    if config.wbc == "pd":
        return build_pd(config, robot)
    if low_level is None:
        low_level = build_low_level(config, robot)
    if config.planner == "template":
        mpc: RecedingHorizonMpc | TemplateMpc = build_template_mpc(config, robot)
    else:
        mpc = build_mpc(config, robot)
    return CafeMpcController(
        robot,
        mpc.reference,
        mpc.builder,
        low_level,
        mpc=mpc,
        control_period=1.0 / config.simulation.control_rate_hz,
    )


def realtime_mpc(config_data: dict) -> RecedingHorizonMpc:
    """Builds the MPC inside the real-time mode's MPC process, from the run config as plain data (picklable):
    its own robot model, reference and solver; measured latency, so the solve keeps the wall-clock budget."""
    config = RunConfig.model_validate(config_data)
    robot = load_robot(config.robot)
    config = config.model_copy(update={"mpc": config.mpc.model_copy(update={"latency": "measured"})})
    return build_mpc(config, robot)


def build_realtime_controller(
    config: RunConfig, robot: Robot, low_level: LowLevelController | None = None
) -> RealtimeMpcController:
    """CAFE-MPC against the wall clock: the MPC in its own process (``control.realtime``, built there by
    ``realtime_mpc``), ``low_level`` (default: ``build_low_level``'s) here. Close it (``with``) to stop the
    process."""
    if config.wbc == "pd":
        raise ConfigError("simulation.realtime needs an MPC run (wbc: vwbc or riccati), not wbc: pd")
    schedule = run_schedule(config, robot)
    factory = functools.partial(realtime_mpc, config.model_dump(mode="json"))
    if low_level is None:
        low_level = build_low_level(config, robot)
    # knots: the whole-body grid knots plus the splits at contact switches (a few per horizon)
    controller = RealtimeMpcController(
        robot,
        factory,
        low_level,
        config.mpc.period,
        schedule.whole_body_knots + 16,
        control_period=1.0 / config.simulation.control_rate_hz,
        scheme=config.mpc.scheme if config.planner != "template" else "one_phase",
    )
    controller.reference = build_reference(config, robot)  # for the run's report (gait stance)
    return controller


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
    try:
        estimator = StateEstimator(robot, config.kinematic_kf)
    except ValueError as error:
        raise ConfigError(f"kinematic_kf: {error}") from error
    if capacity is None:
        capacity = int(np.ceil(config.simulation.duration * config.simulation.control_rate_hz)) + 2
    return SensingController(inner, estimator, capacity=capacity, position_xy=position_xy)
