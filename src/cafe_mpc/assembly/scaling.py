"""A run's settings carried to its robot (``scaling: robot``; the laws: ``robots.scaling``).

The assembly's builders read the config's tuned values as the reference robot's and pass them through
``run_scale(config, robot)``: the MPC's horizons (``scaled_schedule``: Tw and Ts times the time scale, in
whole knots), gait phase durations, swing height, Raibert gain and foothold box (the reference), cost
weights (``scaled_weights``), the SRB force weight, the Baumgarte rates of the whole-body knots and the
VWBC, the minimum base height, PD and template swing gains, and the fall height.
"""

from __future__ import annotations

from cafe_mpc.config import RunConfig
from cafe_mpc.config.weights import SRBWeights, WholeBodyWeights
from cafe_mpc.ocp.contact_schedule import GaitCycle, get_gait
from cafe_mpc.planners.cafe.problem import ModelSchedule
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
