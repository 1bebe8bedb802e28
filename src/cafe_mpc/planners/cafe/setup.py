"""The CAFE problem of a run (paper Sec. IV-D): model schedule, weights scaled to the robot, knot factories,
limits.

``build_problem(run)`` turns a resolved run (``planners.resolved.ResolvedRun``: its scaled model schedule,
torque limits and contact model) and its ``costs`` section into a ``CafeProblemBuilder``: the whole-body
knots (Eq. (18) costs at ``dt_w``, friction pyramid, torque limits and minimum base height as relaxed
barriers) over the first ``Tw`` seconds, the SRB tail (Eq. (28), the robot's own mass and inertia:
``dynamics.srb.srb_parameters``) over the next ``Ts``, every tuned value scaled to the robot
(``robots.scaling``: ``scaled_weights``, ``scaled_srb_weights``, the minimum base height). A composed
reference's stored trajectories ask for a second weight set (``task_weight_sets``: the ``reference.costs``
section, knots of ``TRAJECTORY_WEIGHT_SET``). ``model_schedule`` and ``scaled_schedule`` are what the
assembly resolves the run's schedule with.
"""

from __future__ import annotations

from cafe_mpc.config import ConfigError, MpcConfig
from cafe_mpc.config.weights import SRBWeights, WholeBodyWeights
from cafe_mpc.dynamics.srb import srb_parameters
from cafe_mpc.ocp.constraints import BarrierParameters, WholeBodyConstraintSettings
from cafe_mpc.ocp.knots import SRBModelFactory, SRBSettings, WholeBodyModelFactory, WholeBodySettings
from cafe_mpc.planners.cafe.problem import CafeProblemBuilder, ModelSchedule
from cafe_mpc.planners.resolved import ResolvedRun
from cafe_mpc.robots.scaling import RobotScale

TRAJECTORY_WEIGHT_SET = "barrel_roll"
"""Weight set of the knots inside stored trajectories (the config's ``reference.costs``)."""


def minimum_base_height(scale: RobotScale) -> float | None:
    """The whole-body knots' minimum base height (``WholeBodyConstraintSettings``) scaled to the robot."""
    default = WholeBodyConstraintSettings().minimum_base_height
    return None if default is None else scale.distance(default)


def plan_constraints(run: ResolvedRun) -> WholeBodyConstraintSettings:
    """The whole-body plan's constraints: the friction pyramid (26) at the run's friction (``mpc.friction``),
    the run's torque limits (27a) times ``mpc.plan_torque_fraction`` under a barrier of weight
    ``mpc.torque_barrier_eps``, the minimum base height scaled to the robot."""
    mpc = run.config.mpc
    return WholeBodyConstraintSettings(
        friction_coefficient=run.contact.friction,
        torque_limit_values=tuple(float(limit) for limit in run.torque_limits * mpc.plan_torque_fraction),
        torque_barrier=BarrierParameters(1.0, mpc.torque_barrier_eps),
        minimum_base_height=minimum_base_height(run.scale),
    )


def model_schedule(section: MpcConfig) -> ModelSchedule:
    """The ``ModelSchedule`` an ``mpc`` section describes: a paper schedule (Table I) or an explicit split,
    at the section's time steps (``ValueError`` if it has no whole knots)."""
    if section.schedule is not None:
        return ModelSchedule.named(section.schedule, section.whole_body_dt, section.srb_dt)
    assert section.whole_body_horizon is not None and section.srb_horizon is not None
    return ModelSchedule(
        section.whole_body_horizon, section.srb_horizon, section.whole_body_dt, section.srb_dt
    )


def build_problem(run: ResolvedRun) -> CafeProblemBuilder:
    """The CAFE problem builder of a run (see the module docstring)."""
    config, scale = run.config, run.scale
    try:
        running = scaled_weights(config.costs.running, scale)
        terminal = scaled_weights(config.costs.terminal, scale)
        srb_running = scaled_srb_weights(config.costs.srb_running, scale)
        srb_terminal = scaled_srb_weights(config.costs.srb_terminal, scale)
    except ValueError as error:
        raise ConfigError(f"costs: {error}") from error
    constraints = plan_constraints(run)
    whole_body, srb = _knot_factories(run, (running, terminal), (srb_running, srb_terminal), constraints)
    return CafeProblemBuilder(
        whole_body,
        srb,
        run.schedule,
        weights=task_weight_sets(run),
        touchdown_on_reference=run.touchdown_on_reference,
        touchdown_below_floor=run.touchdown_below_floor,
    )


def _knot_factories(
    run: ResolvedRun,
    weights: tuple[WholeBodyWeights, WholeBodyWeights],
    srb_weights: tuple[SRBWeights, SRBWeights],
    constraints: WholeBodyConstraintSettings,
    base_error: str = "tangent",
) -> tuple[WholeBodyModelFactory, SRBModelFactory]:
    """The whole-body and SRB knot factories of one weight set (running, terminal weights of each) at the
    run's time steps and contact model."""
    whole_body = WholeBodyModelFactory(
        run.controller_robot,
        WholeBodySettings(
            dt=run.schedule.whole_body_dt,
            baumgarte_alpha=run.contact.baumgarte_alpha,
            integration=run.config.mpc.integration,
            running_weights=weights[0],
            terminal_weights=weights[1],
            constraints=constraints,
            base_error=base_error,
        ),
    )
    srb = SRBModelFactory(
        SRBSettings(
            dt=run.schedule.srb_dt,
            parameters=srb_parameters(run.controller_robot),
            running_weights=srb_weights[0],
            terminal_weights=srb_weights[1],
        )
    )
    return whole_body, srb


def task_weight_sets(run: ResolvedRun) -> dict[str, tuple[WholeBodyModelFactory, SRBModelFactory]]:
    """The ``barrel_roll`` weight set's knot factories: the section's weights and base error, the regular
    constraints (minimum base height 0.20 m, ...) with the run's torque limits; the SRB tail with the same
    base weights (Eq. (28))."""
    config, scale = run.config, run.scale
    section = config.reference
    if section is None:
        return {}
    try:
        running = scaled_weights(section.costs.running, scale)
        terminal = scaled_weights(section.costs.terminal, scale)
        srb_running = SRBWeights.from_whole_body(running, force=srb_force_weight(scale))
        srb_terminal = SRBWeights.from_whole_body(terminal, force=0.0)
        constraints = plan_constraints(run)
    except ValueError as error:
        raise ConfigError(f"reference: {error}") from error
    whole_body, srb = _knot_factories(
        run, (running, terminal), (srb_running, srb_terminal), constraints, section.base_error
    )
    return {TRAJECTORY_WEIGHT_SET: (whole_body, srb)}


def scaled_schedule(schedule: ModelSchedule, scale: RobotScale) -> ModelSchedule:
    """The model schedule with both horizons times the Froude time scale, in whole knots of the unchanged time
    steps (the plan sees the same share of the gait cycle; a larger robot's update has more knots)."""
    if scale.time == 1.0:
        return schedule

    def stretched(horizon: float, dt: float) -> float:
        return round(horizon * scale.time / dt) * dt if horizon > 0 else 0.0

    return ModelSchedule(
        stretched(schedule.whole_body_horizon, schedule.whole_body_dt),
        stretched(schedule.srb_horizon, schedule.srb_dt),
        schedule.whole_body_dt,
        schedule.srb_dt,
    )


def _scaled_vector(value, factors: tuple[float, ...]):
    if isinstance(value, tuple | list):
        if len(value) == len(factors):
            return tuple(float(v) * f for v, f in zip(value, factors, strict=True))
        if len(factors) == 1:
            return tuple(float(v) * factors[0] for v in value)
        raise ValueError(f"cannot scale {value} by {factors}")
    if len(set(factors)) != 1:  # a scalar weight on terms of different units: give it per axis
        return tuple(float(value) * f for f in factors)
    return float(value) * factors[0]


def scaled_weights(weights: WholeBodyWeights, scale: RobotScale) -> WholeBodyWeights:
    """Whole-body weights in the robot's units (``robots.scaling``: ``W / u^2`` per residual)."""
    if scale.is_identity:
        return weights
    p, v, w = scale.position_weight, scale.linear_velocity_weight, scale.angular_velocity_weight
    foot_p, foot_v = scale.position_weight, scale.linear_velocity_weight
    values = {
        "base_position": _scaled_vector(weights.base_position, (p, p, p, 1.0, 1.0, 1.0)),
        "base_velocity": _scaled_vector(weights.base_velocity, (v, v, v, w, w, w)),
        "joint_position": weights.joint_position,
        "joint_velocity": _scaled_vector(weights.joint_velocity, (w,)),
        "torque": _scaled_vector(weights.torque, (scale.torque_weight,)),
        "swing_foot_position": _scaled_vector(weights.swing_foot_position, (foot_p,)),
        "swing_foot_velocity": _scaled_vector(weights.swing_foot_velocity, (foot_v,)),
    }
    assert set(values) == set(WholeBodyWeights.model_fields)
    return WholeBodyWeights(**values)


def scaled_srb_weights(weights: SRBWeights, scale: RobotScale) -> SRBWeights:
    """SRB tail weights in the robot's units (``robots.scaling``: ``W / u^2`` per residual)."""
    if scale.is_identity:
        return weights
    p, v, w = scale.position_weight, scale.linear_velocity_weight, scale.angular_velocity_weight
    return SRBWeights(
        base_position=_scaled_vector(weights.base_position, (p, p, p, 1.0, 1.0, 1.0)),
        base_velocity=_scaled_vector(weights.base_velocity, (v, v, v, w, w, w)),
        force=scaled_srb_force_weight(weights.force, scale),
    )


def scaled_srb_force_weight(force: float | tuple[float, ...], scale: RobotScale):
    """The SRB tail's ground-reaction-force weight in the robot's units."""
    return _scaled_vector(force, (scale.force_weight,))


def srb_force_weight(scale: RobotScale, terminal: bool = False):
    """The authors' SRB GRF weight (``SRBWeights``) scaled to the robot."""
    base = SRBWeights.regular_terminal() if terminal else SRBWeights.regular_running()
    return scaled_srb_force_weight(base.force, scale)
