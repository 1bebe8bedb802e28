"""Acrobatic task runs (paper Sec. VII-C): the composed reference of a run config and its weight sets.

``task_reference(config, robot)`` turns the config's ``reference`` section into a ``ComposedReference``
(``reference.composition``): ``stand`` segments are locomotion references with the gait ``stand`` (Sec. VI-A)
and weight set ``regular``; ``trajectory`` segments are stored whole-body trajectories sampled by time
(``reference.trajectory``, Sec. VI-B) with weight set ``barrel_roll``, optionally from a later phase on;
``gait`` segments are locomotion references of a gait section (weight set ``regular``), e.g. the flying pace
before and after the running barrel roll. ``task_weight_sets`` builds that weight
set's whole-body and SRB knot factories (``CafeProblemBuilder(weights=...)``), and ``task_block`` the ``task``
block of ``metrics.json`` (``report.task_metrics``).
"""

from __future__ import annotations

import numpy as np

from cafe_mpc.config import (
    ConfigError,
    ReferenceConfig,
    RunConfig,
    load_reference_trajectory,
    velocity_command,
)
from cafe_mpc.dynamics.srb import srb_parameters
from cafe_mpc.experiments.scaling import run_scale, scaled_gait, scaled_weights, srb_force_weight
from cafe_mpc.mpc.problem import ModelSchedule
from cafe_mpc.ocp.constraints import WholeBodyConstraintSettings
from cafe_mpc.ocp.contact_schedule import get_gait
from cafe_mpc.ocp.costs import SRBWeights
from cafe_mpc.ocp.knots import SRBModelFactory, SRBSettings, WholeBodyModelFactory, WholeBodySettings
from cafe_mpc.reference.base import Reference
from cafe_mpc.reference.composition import ComposedReference
from cafe_mpc.reference.locomotion import FOOTHOLD_BOX, LocomotionReference, VelocityCommand
from cafe_mpc.reference.trajectory import TrajectoryReference
from cafe_mpc.report.task_metrics import task_from_reference, task_metrics
from cafe_mpc.robots.robot import Robot
from cafe_mpc.robots.scaling import IDENTITY, RobotScale
from cafe_mpc.sim.bar import bar_of
from cafe_mpc.sim.loop import SimulationLog

TRAJECTORY_WEIGHT_SET = "barrel_roll"
"""Weight set of the knots inside stored trajectories (``WholeBodyWeights.barrel_roll_*`` by default)."""


def minimum_base_height(scale: RobotScale) -> float | None:
    """The whole-body knots' minimum base height (``WholeBodyConstraintSettings``) scaled to the robot."""
    default = WholeBodyConstraintSettings().minimum_base_height
    return None if default is None else scale.distance(default)


def torque_limits_of(config: RunConfig, robot: Robot) -> np.ndarray:
    """The torque limits the plan and the low-level controller respect (``config.torque_limits``)."""
    if config.torque_limits == "motor":
        return np.asarray(robot.plant.motor_torque_limits, dtype=float).copy()
    return np.asarray(robot.torque_limits, dtype=float).copy()


def task_reference(section: ReferenceConfig, robot: Robot, scale: RobotScale = IDENTITY) -> ComposedReference:
    """The composed reference of a ``reference`` config section (see the module docstring); gait segments'
    timings and swing heights scaled by ``scale`` (``experiments.scaling``; stored trajectories are the
    robot's own)."""
    pieces: list[tuple[Reference, float | None]] = []
    offsets = []
    try:
        for segment in section.segments:
            if segment.kind == "trajectory":
                assert segment.trajectory is not None
                trajectory = load_reference_trajectory(robot.name, segment.trajectory)
                trajectory = trajectory.from_phase(segment.from_phase)
                reference: Reference = TrajectoryReference(
                    robot, trajectory, weight_set=TRAJECTORY_WEIGHT_SET, hold_weight_set=TRAJECTORY_WEIGHT_SET
                )
                duration = segment.duration if segment.duration is not None else reference.end_time
            elif segment.kind == "gait":
                gait = segment.gait
                assert gait is not None
                reference = LocomotionReference(
                    robot,
                    scaled_gait(gait.name, scale),
                    [velocity_command(command) for command in gait.commands],
                    swing_height=scale.distance(gait.swing_height),
                    raibert_gain=scale.duration(gait.raibert_gain),
                    foothold_box=tuple(scale.distance(v) for v in FOOTHOLD_BOX),
                    start_stance=gait.start_stance,
                    command_ramp=gait.command_ramp,
                )
                duration = segment.duration
            else:
                reference = LocomotionReference(
                    robot, get_gait("stand"), [VelocityCommand(height=segment.height)]
                )
                duration = segment.duration
            pieces.append((reference, duration))
            offsets.append(segment.offset)
        return ComposedReference(
            pieces,
            robot.nq,
            robot.nv,
            robot.nu,
            robot.n_feet,
            offsets=offsets,
            rejoin=section.join == "measured",
        )
    except ValueError as error:
        raise ConfigError(f"reference: {error}") from error


def task_weight_sets(
    config: RunConfig, robot: Robot, schedule: ModelSchedule
) -> dict[str, tuple[WholeBodyModelFactory, SRBModelFactory]]:
    """The ``barrel_roll`` weight set's knot factories: the section's weights and base error, the regular
    constraints (minimum base height 0.20 m, ...) with the run's torque limits; the SRB tail with the same
    base weights."""
    section = config.reference
    if section is None:
        return {}
    scale = run_scale(config, robot)
    try:
        running = scaled_weights(section.costs.running.to_weights(), scale)
        terminal = scaled_weights(section.costs.terminal.to_weights(), scale)
        srb_running = SRBWeights.from_whole_body(running, force=srb_force_weight(scale))
        srb_terminal = SRBWeights.from_whole_body(terminal, force=0.0)
        constraints = WholeBodyConstraintSettings(
            friction_coefficient=config.mpc.friction,
            torque_limit_values=tuple(float(limit) for limit in torque_limits_of(config, robot)),
            minimum_base_height=minimum_base_height(scale),
        )
    except ValueError as error:
        raise ConfigError(f"reference: {error}") from error
    whole_body = WholeBodyModelFactory(
        robot,
        WholeBodySettings(
            dt=schedule.whole_body_dt,
            baumgarte_alpha=scale.rate(WholeBodySettings().baumgarte_alpha),
            running_weights=running,
            terminal_weights=terminal,
            constraints=constraints,
            base_error=section.base_error,
        ),
    )
    srb = SRBModelFactory(
        SRBSettings(
            dt=schedule.srb_dt,
            parameters=srb_parameters(robot),
            running_weights=srb_running,
            terminal_weights=srb_terminal,
        )
    )
    return {TRAJECTORY_WEIGHT_SET: (whole_body, srb)}


def task_block(
    config: RunConfig, robot: Robot, log: SimulationLog, reference: Reference | None
) -> dict | None:
    """The ``task`` block of ``metrics.json`` for a run whose reference holds a stored trajectory with a
    flight phase (``report.task_metrics``); ``None`` otherwise."""
    task = task_from_reference(reference)
    if task is None:
        return None
    return task_metrics(
        robot,
        log,
        task,
        1.0 / config.simulation.control_rate_hz,
        requested=log.extra.get("torque_requested"),
        planned_stance=log.extra.get("planned_stance"),
        limits=torque_limits_of(config, robot),
        bar=bar_of(config.scene),
    )
