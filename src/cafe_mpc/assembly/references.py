"""The reference a run config asks the MPC to track (paper Sec. VI-A, VII-C).

``build_reference(run)`` is the one place that turns a resolved run's ``gait`` or ``reference`` section into
a ``Reference``:

* a ``gait`` section: the heuristic locomotion reference (``reference.locomotion``, Sec. VI-A) of the gait's
  velocity commands, with the timings, swing height, Raibert gain, foothold box, path gain and touchdown
  events the run resolved for the robot (``planners.resolved.ResolvedGait``; the touchdowns seen with the
  run's contact-detection thresholds);
* a ``reference`` section: a ``ComposedReference`` (``reference.composition``) of segments joined in time:
  ``stand`` segments are locomotion references with the gait ``stand`` (weight set ``regular``);
  ``trajectory`` segments are stored whole-body trajectories sampled by time (``reference.trajectory``,
  Sec. VI-B) with weight set ``TRAJECTORY_WEIGHT_SET``, optionally from a later phase on; ``gait`` segments
  are locomotion references of a gait section, e.g. the flying pace before and after the running barrel roll.

``reference_profile`` is what a run config commands over time (``assembly.resolve`` puts it in the resolved
run, for tracking metrics and plots; a stored run's plots make it from the stored config).
"""

from __future__ import annotations

from cafe_mpc.config import (
    ConfigError,
    ContactDetectionSettings,
    RunConfig,
    TerrainMapSettings,
    VelocityCommand,
)
from cafe_mpc.ocp.contact_schedule import get_gait
from cafe_mpc.planners.cafe.setup import TRAJECTORY_WEIGHT_SET
from cafe_mpc.planners.resolved import ResolvedGait, ResolvedRun
from cafe_mpc.reference.base import Reference
from cafe_mpc.reference.composition import ComposedReference
from cafe_mpc.reference.locomotion import CommandProfile, LocomotionReference
from cafe_mpc.reference.trajectory import TrajectoryReference
from cafe_mpc.reference.trajectory_file import (
    PACKAGED_TRAJECTORIES,
    WholeBodyTrajectory,
    load_packaged_trajectory,
    load_trajectory,
)
from cafe_mpc.robots.robot import Robot


def reference_commands(config: RunConfig) -> list[VelocityCommand]:
    """The commands the run tracks: the gait's, or standing still at the standing height (PD)."""
    if config.gait is None:
        return [VelocityCommand()]
    return list(config.gait.commands)


def reference_profile(config: RunConfig, robot: Robot) -> CommandProfile:
    """What the run commands over time (``CommandProfile``): the gait's commands, ramped from rest after the
    start stance when ``gait.command_ramp`` > 0; standing still for PD and composed references."""
    gait = config.gait
    if gait is None:
        return CommandProfile(reference_commands(config), robot.standing_height)
    return CommandProfile(
        reference_commands(config), robot.standing_height, gait.command_ramp, gait.start_stance
    )


def locomotion_reference(
    gait: ResolvedGait,
    robot: Robot,
    detection: ContactDetectionSettings | None = None,
    ground_plane: bool = False,
    terrain_map: TerrainMapSettings | None = None,
) -> LocomotionReference:
    """The heuristic locomotion reference (Sec. VI-A) of a resolved gait section (``ValueError`` if it cannot
    be built); with ``touchdown_events``, early touchdowns advance its clock, seen within ``detection``'s
    early window and touchdown height (a run's, resolved for its robot; default as written); with
    ``ground_plane`` its base and footholds follow the plane through the stance feet (``terrain: blind``),
    with ``terrain_map`` the height maps it is given (``terrain: height_map``)."""
    section = gait.section
    events = None
    if gait.touchdown_events is not None:
        detection = detection or ContactDetectionSettings()
        events = (gait.touchdown_events, detection.early_window, detection.touchdown_height)
    return LocomotionReference(
        robot,
        gait.cycle,
        list(section.commands),
        swing_height=gait.swing_height,
        raibert_gain=gait.raibert_gain,
        swing_lift=gait.swing_lift,
        touchdown_clearance=gait.touchdown_clearance,
        foothold_box=gait.foothold_box,
        start_stance=section.start_stance,
        command_ramp=section.command_ramp,
        path_gain=gait.path_gain,
        path_heading_limit=section.path_heading_limit,
        path_anchor=section.path_anchor,
        touchdown_events=events,
        ground_plane=ground_plane,
        terrain_map=terrain_map,
        ground_from_estimate=ground_plane and terrain_map is None and section.blind_ground == "estimate",
        ground_below=gait.blind_ground_below,
        ground_follow=gait.blind_ground_follow,
        ground_limits=(detection or ContactDetectionSettings()).ground_plane_limits(),
    )


def load_reference_trajectory(robot: Robot, name_or_path: str) -> WholeBodyTrajectory:
    """The ``WholeBodyTrajectory`` a trajectory segment names, for ``robot`` (the run's own, whether it was
    given by name or as a file): a packaged trajectory (by name) or a ``.npz`` file, validated against the
    robot (``ValueError`` if it cannot be used)."""
    if name_or_path in PACKAGED_TRAJECTORIES:
        return load_packaged_trajectory(name_or_path, robot)
    if not name_or_path.endswith(".npz"):
        raise ValueError(
            f"unknown trajectory {name_or_path!r}: packaged {', '.join(PACKAGED_TRAJECTORIES)} or a .npz file"
        )
    return load_trajectory(name_or_path, robot)


def task_reference(run: ResolvedRun) -> ComposedReference:
    """The composed reference of a run's ``reference`` section (see the module docstring); gait segments with
    the gaits the run resolved (stored trajectories are the robot's own)."""
    section, robot = run.config.reference, run.controller_robot
    assert section is not None
    pieces: list[tuple[Reference, float | None]] = []
    offsets = []
    try:
        for segment, gait in zip(section.segments, run.segment_gaits, strict=True):
            if segment.kind == "trajectory":
                assert segment.trajectory is not None
                trajectory = load_reference_trajectory(robot, segment.trajectory)
                trajectory = trajectory.from_phase(segment.from_phase)
                events = None
                if segment.touchdown_events is not None:
                    detection = run.contact_detection or ContactDetectionSettings()
                    events = (segment.touchdown_events, detection.early_window, detection.touchdown_height)
                reference: Reference = TrajectoryReference(
                    robot,
                    trajectory,
                    weight_set=TRAJECTORY_WEIGHT_SET,
                    hold_weight_set=TRAJECTORY_WEIGHT_SET,
                    touchdown_events=events,
                )
                duration = segment.duration if segment.duration is not None else reference.end_time
            elif segment.kind == "gait":
                assert gait is not None
                reference = locomotion_reference(gait, robot, run.contact_detection)
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


def build_reference(run: ResolvedRun) -> Reference:
    """The reference of a CAFE-MPC or template run: the gait's locomotion reference or the composed reference
    (see the module docstring). ``ConfigError`` naming the section when it cannot be built."""
    config = run.config
    if config.reference is not None:  # a composed reference (stand, stored trajectory, ...): Sec. VII-C
        return task_reference(run)
    if run.gait is None:  # RunConfig rejects this; kept for configs built with model_construct
        raise ConfigError(f"wbc: {config.wbc!r} needs a gait section")
    try:
        return locomotion_reference(
            run.gait, run.controller_robot, run.contact_detection, run.ground_plane, run.terrain_map
        )
    except ValueError as error:
        raise ConfigError(f"gait: {error}") from error
