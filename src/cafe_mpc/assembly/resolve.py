"""A run config resolved once against its robot: ``resolve(config, robot) -> ResolvedRun``
(``planners.resolved``), before anything is built.

Every value a run derives from its config, and that more than one builder or the run's metrics read, is
computed here and nowhere else:

* the robot's scale (``run_scale``: ``scaling: robot`` reads the config's tuned values as the reference
  robot's, ``robots.scaling``; the identity with ``scaling: none``);
* the model schedule of the ``mpc`` section (Table I or an explicit split) with its horizons scaled
  (``planners.cafe.setup.scaled_schedule``);
* the controller's robot (``calibration``: the robot file's model with a known payload, link masses and
  motor strengths, ``robots.calibration``), from which every part of the controller is built, and the
  motors' strengths the low level divides its torques by;
* the torque limits the plan and the low level respect (``torque_limits_of``: the robot table's or the
  motors', times the calibrated motor strengths);
* the contact models: the friction the plan assumes (``mpc.friction``) and the VWBC's (``vwbc.friction``,
  else the plan's times ``VWBC_FRICTION_HEADROOM``), with the Baumgarte rate and the cone tolerance of the
  reference robot scaled to the run's;
* the contact detector's thresholds (``vwbc.contact_detection``): heights by the length scale, the early
  window and the on-time margin by the time scale (``scaled_contact_detection``), for the VWBC's detector
  and the reference's touchdown events;
* the ground the controller assumes (``terrain``): flat, or the plane through the feet's latest contact
  points (``ground_plane``) for the reference, the contact detector, the VWBC and the estimator;
* the gaits (``gait`` and the gait segments of ``reference``): phase durations, swing height, Raibert gain,
  foothold box, path gain and touchdown-event threshold scaled (``resolve_gait``);
* what the run commands over time (``assembly.references.reference_profile``) and the control period.

The builders then carry their own tuned values with ``run.scale``: the CAFE problem's cost weights, SRB force
weight and minimum base height (``planners.cafe.setup``), the PD and template swing gains (their
controllers), the fall height (the lab's plant).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from cafe_mpc.assembly.references import reference_profile
from cafe_mpc.config import (
    BAUMGARTE_ALPHA,
    CONE_TOLERANCE,
    VWBC_FRICTION_HEADROOM,
    CalibrationConfig,
    ConfigError,
    ContactDetectionSettings,
    GaitConfig,
    RunConfig,
    TerrainMapSettings,
)
from cafe_mpc.ocp.contact_schedule import GaitCycle, get_gait
from cafe_mpc.planners.cafe.setup import model_schedule, scaled_schedule
from cafe_mpc.planners.resolved import ContactModel, ResolvedGait, ResolvedRun
from cafe_mpc.reference.locomotion import FOOTHOLD_BOX
from cafe_mpc.robots.calibration import ModelCalibration, calibrated_robot
from cafe_mpc.robots.robot import Robot
from cafe_mpc.robots.scaling import IDENTITY, RobotScale, robot_scale


def resolve(config: RunConfig, robot: Robot) -> ResolvedRun:
    """The ``ResolvedRun`` of ``config`` driving ``robot`` (module docstring); ``ConfigError`` naming the
    section of a value that does not resolve."""
    scale = run_scale(config, robot)
    calibration = model_calibration(config.calibration)
    try:
        controller_robot = calibrated_robot(robot, calibration)
        motor_strength = calibration.per_joint("motor_strength_scales", robot.nu)
    except ValueError as error:
        raise ConfigError(f"calibration: {error}") from error
    motor_strength.setflags(write=False)
    torque_limits = torque_limits_of(config, robot) * motor_strength  # exact with the default strengths
    torque_limits.setflags(write=False)
    try:
        schedule = scaled_schedule(model_schedule(config.mpc), scale)
    except ValueError as error:
        raise ConfigError(f"mpc: {error}") from error
    segments = config.reference.segments if config.reference is not None else []
    blind = config.terrain == "blind"
    gait = _gait(config.gait, scale, "gait", blind)
    segment_gaits = tuple(
        _gait(segment.gait, scale, f"reference.segments.{index}.gait", blind)
        for index, segment in enumerate(segments)
    )
    contact = ContactModel(
        friction=config.mpc.friction,
        baumgarte_alpha=scale.rate(BAUMGARTE_ALPHA),
        cone_tolerance=scale.force(CONE_TOLERANCE),
    )
    vwbc_friction = config.vwbc.friction
    if vwbc_friction is None:
        vwbc_friction = VWBC_FRICTION_HEADROOM * config.mpc.friction
    return ResolvedRun(
        config=config,
        robot=robot,
        controller_robot=controller_robot,
        motor_strength=motor_strength,
        scale=scale,
        schedule=schedule,
        torque_limits=torque_limits,
        contact=contact,
        vwbc_contact=replace(contact, friction=vwbc_friction),
        contact_detection=scaled_contact_detection(detection_settings(config), scale),
        ground_plane=config.terrain != "flat",
        terrain_map=scaled_terrain_map(config.terrain_map, scale) if config.terrain == "height_map" else None,
        touchdown_on_reference=touchdown_on_reference(config),
        touchdown_below_floor=touchdown_below_floor(config),
        gait=gait,
        segment_gaits=segment_gaits,
        command_profile=reference_profile(config, robot),
        control_period=1.0 / config.simulation.control_rate_hz,
    )


def touchdown_on_reference(config: RunConfig) -> bool:
    """Whether the touchdown constraint (25) lands a foot at the reference's foothold height
    (``mpc.touchdown_surface``); by default with the height map: its footholds lie on the treads, and a
    plan that lands them on the floor below pulls every swing onto a step down into the riser."""
    surface = config.mpc.touchdown_surface
    if surface is None:
        return config.terrain == "height_map"
    return surface in ("reference", "lower")


def touchdown_below_floor(config: RunConfig) -> bool:
    """Whether the touchdown constraint (25) lands a foot at the lower of the floor z = 0 and the
    reference's foothold height (``mpc.touchdown_surface: lower``): a blind descent's footholds below the
    estimator's floor are reached, a climb's above it are met early as on the floor."""
    return config.mpc.touchdown_surface == "lower"


def model_calibration(section: CalibrationConfig) -> ModelCalibration:
    """The ``calibration`` section as the factors ``robots.calibration`` applies."""

    def factors(value: float | list[float]) -> float | tuple[float, ...]:
        return tuple(value) if isinstance(value, list) else value

    return ModelCalibration(
        section.mass_scale,
        section.body_mass_scale,
        factors(section.link_mass_scales),
        factors(section.motor_strength_scales),
    )


def run_scale(config: RunConfig, robot: Robot) -> RobotScale:
    """The robot's scale (the robot file's, whatever the ``calibration``), or the identity with ``scaling:
    none``."""
    return robot_scale(robot) if config.scaling == "robot" else IDENTITY


def torque_limits_of(config: RunConfig, robot: Robot) -> np.ndarray:
    """The torque limits the plan and the low-level controller respect (``config.torque_limits``; a
    read-only array)."""
    if config.torque_limits == "motor":
        limits = np.array(robot.plant.motor_torque_limits, dtype=float)
    else:
        limits = np.array(robot.torque_limits, dtype=float)
    limits.setflags(write=False)
    return limits


def detection_settings(config: RunConfig) -> ContactDetectionSettings:
    """``vwbc.contact_detection`` with its on-time margin resolved: the config's, or when it is null the flat
    ground's or, when the run has terrain, ``ON_TIME_OFF_FLAT`` (``ContactDetectionSettings.on_time_for``)."""
    settings = config.vwbc.contact_detection
    return settings.model_copy(update={"on_time": settings.on_time_for(flat=config.terrain == "flat")})


def scaled_contact_detection(
    settings: ContactDetectionSettings, scale: RobotScale
) -> ContactDetectionSettings:
    """The contact detector's thresholds carried to the robot: touchdown and release heights by the length
    scale, the early window and the on-time margin by the time scale (the momentum observer's gain by its
    inverse), the landing, late descent, late reach and stumble speeds by their ratio, the late reach's depth,
    the stumble's lift and forward step and the ground planes' least span by the length scale and the reach's
    frequency by the inverse time scale; the forces are already shares of the robot's
    weight and the ground's height is the scene's."""
    if scale.is_identity:
        return settings
    return settings.model_copy(
        update={
            "touchdown_height": scale.distance(settings.touchdown_height),
            "release_height": scale.distance(settings.release_height),
            "landing_speed": scale.speed(settings.landing_speed),
            "late_descent_speed": scale.speed(settings.late_descent_speed),
            "late_reach_speed": scale.speed(settings.late_reach_speed),
            "late_reach_depth": scale.distance(settings.late_reach_depth),
            "late_reach_frequency": scale.rate(settings.late_reach_frequency),
            "stumble_lift": scale.distance(settings.stumble_lift),
            "stumble_forward": scale.distance(settings.stumble_forward),
            "stumble_speed": scale.speed(settings.stumble_speed),
            "ground_min_span": (
                None if settings.ground_min_span is None else scale.distance(settings.ground_min_span)
            ),
            "early_hold_rise": (
                None if settings.early_hold_rise is None else scale.distance(settings.early_hold_rise)
            ),
            "momentum_gain": scale.rate(settings.momentum_gain),
            "early_window": scale.duration(settings.early_window),
            "on_time": None if settings.on_time is None else scale.duration(settings.on_time),
        }
    )


def scaled_terrain_map(settings: TerrainMapSettings, scale: RobotScale) -> TerrainMapSettings:
    """How the reference plans on the height map, its lengths carried to the robot."""
    if scale.is_identity:
        return settings
    return settings.model_copy(
        update={
            name: scale.distance(getattr(settings, name))
            for name in ("edge_margin", "flat_tolerance", "foothold_search", "swing_clearance", "base_window")
        }
    )


def resolve_gait(section: GaitConfig, scale: RobotScale, blind: bool = False) -> ResolvedGait:
    """A gait section carried to the robot: its cycle's phase durations, the reference's Raibert gain and the
    touchdown-event threshold by the time scale, the swing height and foothold box by the length scale, the
    path gain (rad/m) by its inverse. ``blind`` (``terrain: blind``): the swing at least
    ``blind_swing_height`` high and ``blind_swing_lift`` lifted first, its apex at least
    ``blind_touchdown_clearance`` above its touchdown where set."""
    events = section.touchdown_events
    swing_height, swing_lift = section.swing_height, section.swing_lift
    clearance = None
    if blind:
        swing_height = max(swing_height, section.blind_swing_height)
        swing_lift = max(swing_lift, section.blind_swing_lift)
        clearance = section.blind_touchdown_clearance
    return ResolvedGait(
        section=section,
        cycle=scaled_gait(section.name, scale),
        swing_height=scale.distance(swing_height),
        raibert_gain=scale.duration(section.raibert_gain),
        swing_lift=swing_lift,
        foothold_box=(scale.distance(FOOTHOLD_BOX[0]), scale.distance(FOOTHOLD_BOX[1])),
        path_gain=section.path_gain / scale.distance(1.0),
        touchdown_events=None if events is None else scale.duration(events),
        blind_ground_below=None
        if section.blind_ground_below is None
        else scale.distance(section.blind_ground_below),
        blind_ground_follow=None
        if section.blind_ground_follow is None
        else scale.distance(section.blind_ground_follow),
        touchdown_clearance=None if clearance is None else scale.distance(clearance),
    )


def _gait(section: GaitConfig | None, scale: RobotScale, key: str, blind: bool) -> ResolvedGait | None:
    if section is None:
        return None
    try:
        return resolve_gait(section, scale, blind)
    except ValueError as error:
        raise ConfigError(f"{key}: {error}") from error


def scaled_gait(name: str, scale: RobotScale) -> GaitCycle:
    """The library gait with every phase duration times the Froude time scale."""
    gait = get_gait(name)
    if scale.time == 1.0:
        return gait
    return GaitCycle(gait.name, tuple((flags, duration * scale.time) for flags, duration in gait.cycle))
