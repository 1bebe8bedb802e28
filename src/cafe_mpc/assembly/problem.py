"""The CAFE problem of a run config (paper Sec. IV-D): model schedule, knot factories, weight sets, limits.

``build_problem(config, robot)`` turns the ``mpc`` and ``costs`` sections into a ``CafeProblemBuilder``: the
whole-body knots (Eq. (18) costs at ``dt_w``, friction pyramid, torque limits and minimum base height as
relaxed barriers) over the first ``Tw`` seconds, the SRB tail (Eq. (28), the robot's own mass and inertia:
``dynamics.srb.srb_parameters``) over the next ``Ts``, every tuned value scaled to the robot
(``assembly.scaling``). A composed reference's stored trajectories ask for a second weight set
(``task_weight_sets``: the ``reference.costs`` section).
"""

from __future__ import annotations

import numpy as np

from cafe_mpc.assembly.references import TRAJECTORY_WEIGHT_SET
from cafe_mpc.assembly.scaling import (
    run_scale,
    scaled_schedule,
    scaled_srb_weights,
    scaled_weights,
    srb_force_weight,
)
from cafe_mpc.config import ConfigError, MpcConfig, RunConfig
from cafe_mpc.config.weights import SRBWeights, WholeBodyWeights
from cafe_mpc.dynamics.srb import srb_parameters
from cafe_mpc.mpc.problem import CafeProblemBuilder, ModelSchedule
from cafe_mpc.ocp.constraints import BarrierParameters, WholeBodyConstraintSettings
from cafe_mpc.ocp.knots import SRBModelFactory, SRBSettings, WholeBodyModelFactory, WholeBodySettings
from cafe_mpc.robots.robot import Robot
from cafe_mpc.robots.scaling import RobotScale


def minimum_base_height(scale: RobotScale) -> float | None:
    """The whole-body knots' minimum base height (``WholeBodyConstraintSettings``) scaled to the robot."""
    default = WholeBodyConstraintSettings().minimum_base_height
    return None if default is None else scale.distance(default)


def torque_limits_of(config: RunConfig, robot: Robot) -> np.ndarray:
    """The torque limits the plan and the low-level controller respect (``config.torque_limits``)."""
    if config.torque_limits == "motor":
        return np.asarray(robot.plant.motor_torque_limits, dtype=float).copy()
    return np.asarray(robot.torque_limits, dtype=float).copy()


def model_schedule(section: MpcConfig) -> ModelSchedule:
    """The ``ModelSchedule`` an ``mpc`` section describes: a paper schedule (Table I) or an explicit split,
    at the section's time steps (``ValueError`` if it has no whole knots)."""
    if section.schedule is not None:
        return ModelSchedule.named(section.schedule, section.whole_body_dt, section.srb_dt)
    assert section.whole_body_horizon is not None and section.srb_horizon is not None
    return ModelSchedule(
        section.whole_body_horizon, section.srb_horizon, section.whole_body_dt, section.srb_dt
    )


def run_schedule(config: RunConfig, robot: Robot) -> ModelSchedule:
    """The run's model schedule (Tw, Ts, dt_w, dt_s) with its horizons scaled to the robot."""
    try:
        return scaled_schedule(model_schedule(config.mpc), run_scale(config, robot))
    except ValueError as error:
        raise ConfigError(f"mpc: {error}") from error


def plan_constraints(config: RunConfig, robot: Robot, scale: RobotScale) -> WholeBodyConstraintSettings:
    """The whole-body plan's constraints: friction, the run's torque limits times
    ``mpc.plan_torque_fraction`` under a barrier of weight ``mpc.torque_barrier_eps``, minimum height."""
    limits = torque_limits_of(config, robot) * config.mpc.plan_torque_fraction
    return WholeBodyConstraintSettings(
        friction_coefficient=config.mpc.friction,
        torque_limit_values=tuple(float(limit) for limit in limits),
        torque_barrier=BarrierParameters(1.0, config.mpc.torque_barrier_eps),
        minimum_base_height=minimum_base_height(scale),
    )


def build_problem(config: RunConfig, robot: Robot) -> CafeProblemBuilder:
    """The CAFE problem builder of a run (see the module docstring)."""
    scale = run_scale(config, robot)
    schedule = run_schedule(config, robot)
    try:
        running = scaled_weights(config.costs.running, scale)
        terminal = scaled_weights(config.costs.terminal, scale)
        srb_running = scaled_srb_weights(config.costs.srb_running, scale)
        srb_terminal = scaled_srb_weights(config.costs.srb_terminal, scale)
    except ValueError as error:
        raise ConfigError(f"costs: {error}") from error
    constraints = plan_constraints(config, robot, scale)
    whole_body, srb = _knot_factories(
        robot, scale, schedule, (running, terminal), (srb_running, srb_terminal), constraints
    )
    return CafeProblemBuilder(whole_body, srb, schedule, weights=task_weight_sets(config, robot, schedule))


def _knot_factories(
    robot: Robot,
    scale: RobotScale,
    schedule: ModelSchedule,
    weights: tuple[WholeBodyWeights, WholeBodyWeights],
    srb_weights: tuple[SRBWeights, SRBWeights],
    constraints: WholeBodyConstraintSettings,
    base_error: str = "tangent",
) -> tuple[WholeBodyModelFactory, SRBModelFactory]:
    """The whole-body and SRB knot factories of one weight set (running, terminal weights of each)."""
    whole_body = WholeBodyModelFactory(
        robot,
        WholeBodySettings(
            dt=schedule.whole_body_dt,
            baumgarte_alpha=scale.rate(WholeBodySettings().baumgarte_alpha),
            running_weights=weights[0],
            terminal_weights=weights[1],
            constraints=constraints,
            base_error=base_error,
        ),
    )
    srb = SRBModelFactory(
        SRBSettings(
            dt=schedule.srb_dt,
            parameters=srb_parameters(robot),
            running_weights=srb_weights[0],
            terminal_weights=srb_weights[1],
        )
    )
    return whole_body, srb


def task_weight_sets(
    config: RunConfig, robot: Robot, schedule: ModelSchedule
) -> dict[str, tuple[WholeBodyModelFactory, SRBModelFactory]]:
    """The ``barrel_roll`` weight set's knot factories: the section's weights and base error, the regular
    constraints (minimum base height 0.20 m, ...) with the run's torque limits; the SRB tail with the same
    base weights (Eq. (28))."""
    section = config.reference
    if section is None:
        return {}
    scale = run_scale(config, robot)
    try:
        running = scaled_weights(section.costs.running, scale)
        terminal = scaled_weights(section.costs.terminal, scale)
        srb_running = SRBWeights.from_whole_body(running, force=srb_force_weight(scale))
        srb_terminal = SRBWeights.from_whole_body(terminal, force=0.0)
        constraints = plan_constraints(config, robot, scale)
    except ValueError as error:
        raise ConfigError(f"reference: {error}") from error
    whole_body, srb = _knot_factories(
        robot,
        scale,
        schedule,
        (running, terminal),
        (srb_running, srb_terminal),
        constraints,
        section.base_error,
    )
    return {TRAJECTORY_WEIGHT_SET: (whole_body, srb)}
