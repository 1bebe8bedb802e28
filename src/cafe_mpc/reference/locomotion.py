"""Heuristic locomotion reference from user commands (paper Sec. VI-A).

Commands (forward/lateral speed in the heading frame, yaw rate, body height) may change over time. The
reference integrates them into a base trajectory (x, y, yaw; roll = pitch = 0), places footholds with the
Raibert heuristic clamped to a box about each hip, and interpolates swing feet with cubic Bezier curves
(zero velocity at lift-off and touchdown, apex ``swing_height`` above the lift-off height at mid-swing).
The normal ground-reaction-force reference is the weight shared by the stance feet.

The reference is re-anchored at every MPC update on the measured base position and yaw (the position
weights are zero in the paper's cost, so the robot is never pulled back to where the integration says it
should be) and on the measured stance-foot positions.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from cafe_mpc.config import TerrainMapSettings, VelocityCommand
from cafe_mpc.core.ground import GroundPlane
from cafe_mpc.core.ground import contact_frame as ground_contact_frame
from cafe_mpc.core.height_map import HeightMap
from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.dynamics.leg_inverse_kinematics import LegInverseKinematics
from cafe_mpc.dynamics.statics import static_stance_torques
from cafe_mpc.ocp.contact_schedule import GAITS, TIME_TOLERANCE, ContactPhase, ContactSchedule, GaitCycle
from cafe_mpc.reference.base import STANCE_TIME_EPS, Reference, ReferenceWindow, switches_inside
from cafe_mpc.reference.kernels import map_heights, sample_base, sample_feet, terrain_foothold
from cafe_mpc.reference.terrain_map import TerrainMap
from cafe_mpc.robots.robot import Robot

FOOTHOLD_BOX = (0.10, 0.06)
"""m; how far (x, y) a Raibert foothold may move from under the hip (the Mini Cheetah's; other robots' runs
scale it with the leg length, ``robots.scaling``)."""
GROUND_FOOT_SPEED = 0.2
"""m/s; a foot planned in stance moving faster than this has not landed: its point does not enter the ground
plane (``LocomotionReference.ground``)."""


def validate_command(command: VelocityCommand, robot: Robot) -> None:
    """Reject commands outside what the robot can do (clear message, no crash deep inside)."""
    straight_legs = np.concatenate([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], np.zeros(robot.nu)])
    leg_length = float(np.max(-robot.foot_positions(straight_legs)[:, 2]))
    if abs(command.vx) > 3.0:
        raise ValueError(f"command vx = {command.vx} m/s is outside [-3, 3] m/s for {robot.name}")
    if abs(command.vy) > 1.0:
        raise ValueError(f"command vy = {command.vy} m/s is outside [-1, 1] m/s for {robot.name}")
    if abs(command.yaw_rate) > 3.0:
        raise ValueError(f"command yaw_rate = {command.yaw_rate} rad/s is outside [-3, 3] rad/s")
    highest = 0.9 * leg_length + robot.foot_radius
    if command.height is not None and not (0.12 <= command.height <= highest):
        raise ValueError(
            f"command height = {command.height} m is outside [0.12, {highest:.3f}] m "
            f"(leg length {leg_length:.3f} m)"
        )


class CommandProfile:
    """The commanded ``[vx, vy, yaw_rate, height]`` over time, piecewise linear.

    With ``ramp`` = 0 the commands are steps (each holds from its ``start`` until the next one; the first also
    before its start). With ``ramp`` > 0 the robot is commanded to rest (standing height) until ``rest_until``
    (the gait's start, after its initial stance), and every change of command is approached linearly over
    ``ramp`` seconds from the value at the moment it starts (a change that comes before the previous ramp
    has finished starts from where that ramp had got to). ``breakpoints`` are the times where the slope
    changes; between two of them the profile is linear, after the last one constant.
    """

    def __init__(
        self,
        commands: Sequence[VelocityCommand],
        standing_height: float,
        ramp: float = 0.0,
        rest_until: float = 0.0,
    ) -> None:
        if not (math.isfinite(ramp) and ramp >= 0.0):
            raise ValueError(f"command ramp must be >= 0 s, got {ramp}")
        if not (math.isfinite(rest_until) and rest_until >= 0.0):
            raise ValueError(f"rest_until must be >= 0 s, got {rest_until}")
        ordered = sorted(commands, key=lambda command: command.start) or [VelocityCommand()]
        self.commands = list(ordered)
        self.standing_height = float(standing_height)
        self.ramp = float(ramp)
        self.rest_until = float(rest_until) if ramp > 0 else 0.0

        def target(command: VelocityCommand) -> np.ndarray:
            height = self.standing_height if command.height is None else command.height
            return np.array([command.vx, command.vy, command.yaw_rate, height], dtype=float)

        if self.ramp == 0.0:
            times = [0.0]
            values = [target(ordered[0])]
            for command in ordered[1:]:  # a step: the old value up to the start, the new one from it
                times += [command.start, command.start]
                values += [values[-1], target(command)]
        else:
            times = [0.0]
            values = [np.array([0.0, 0.0, 0.0, self.standing_height])]
            events = [(max(command.start, self.rest_until), target(command)) for command in ordered]
            for index, (start, goal) in enumerate(events):
                if start > times[-1]:
                    times.append(start)
                    values.append(values[-1].copy())
                end = start + self.ramp
                following = events[index + 1][0] if index + 1 < len(events) else math.inf
                if following < end:  # interrupted: stop where the ramp has got to
                    fraction = (following - start) / self.ramp
                    times.append(following)
                    values.append(values[-1] + fraction * (goal - values[-1]))
                else:
                    times.append(end)
                    values.append(goal)
        self._set_breakpoints(times, values)

    def _set_breakpoints(self, times: Sequence[float], values: Sequence[np.ndarray]) -> None:
        """The profile's breakpoints ``times`` and ``values`` (linear between two, a step where two times are
        equal) and what the hot paths read of them."""
        self.times = np.array(times)
        self.values = np.array(values)
        # the same as plain floats, per segment [times[i], times[i + 1]): start value and slope (the hot path,
        # a few hundred calls per MPC update, stays out of numpy)
        self._times = [float(t) for t in times]
        self._starts = [tuple(float(x) for x in value) for value in values]
        self._slopes = []
        for index in range(len(times)):
            if index + 1 < len(times) and times[index + 1] - times[index] > 1e-12:
                span = times[index + 1] - times[index]
                self._slopes.append(tuple(float(x) for x in (values[index + 1] - values[index]) / span))
            else:
                self._slopes.append((0.0, 0.0, 0.0, 0.0))
        # the same as arrays, for the compiled sampling (``reference.kernels``)
        self.time_array = np.array(self._times, dtype=float)
        self.start_array = np.array(self._starts, dtype=float).reshape(-1, 4)
        self.slope_array = np.array(self._slopes, dtype=float).reshape(-1, 4)

    @property
    def breakpoints(self) -> np.ndarray:
        return self.times

    def spliced(self, at: float, after: CommandProfile) -> CommandProfile:
        """This profile before ``at`` and ``after`` from ``at`` on (a step at ``at``): what a gait restart
        (``LocomotionReference.restart_gait``) commands."""
        times = [float(t) for t in self.times if t < at]
        values = [value for t, value in zip(self.times, self.values, strict=True) if t < at]
        times += [at, at]
        values += [self.at(at), after.at(at)]
        for t, value in zip(after.times, after.values, strict=True):
            if t > at:
                times.append(float(t))
                values.append(value)
        profile = CommandProfile.__new__(CommandProfile)
        profile.commands = list(after.commands)
        profile.standing_height = after.standing_height
        profile.ramp = after.ramp
        profile.rest_until = after.rest_until
        profile._set_breakpoints(times, values)
        return profile

    def _segment(self, t: float) -> int:
        """Index of the segment holding ``t`` (a step's new value from its start on)."""
        return max(bisect.bisect_right(self._times, t + 1e-12) - 1, 0)

    def values_at(self, t: float) -> tuple[float, float, float, float]:
        """``(vx, vy, yaw_rate, height)`` at ``t`` as plain floats."""
        index = self._segment(t)
        dt = max(t - self._times[index], 0.0)
        start, slope = self._starts[index], self._slopes[index]
        return (
            start[0] + slope[0] * dt,
            start[1] + slope[1] * dt,
            start[2] + slope[2] * dt,
            start[3] + slope[3] * dt,
        )

    def at(self, t: float) -> np.ndarray:
        """``[vx, vy, yaw_rate, height]`` at ``t`` (a step takes its new value at its start)."""
        return np.array(self.values_at(t))

    def table(self, times: Sequence[float]) -> np.ndarray:
        """``at`` for every time (N x 4)."""
        return np.array([self.values_at(float(t)) for t in times]).reshape(-1, 4)

    def command_at(self, t: float) -> VelocityCommand:
        vx, vy, yaw_rate, height = self.values_at(t)
        return VelocityCommand(
            start=float(t) if t > 0 else 0.0, vx=vx, vy=vy, yaw_rate=yaw_rate, height=height
        )

    def heading_displacement(self, t0: float, t1: float) -> tuple[np.ndarray, float]:
        """Position (x, y) and yaw change from ``t0`` to ``t1`` in the heading frame at ``t0``: the commands'
        velocities integrated (closed form where they are constant, Gauss-Legendre quadrature on ramps)."""
        x, y, yaw = self.displacement_floats(t0, t1)
        return np.array([x, y]), yaw

    def displacement_floats(self, t0: float, t1: float) -> tuple[float, float, float]:
        """``heading_displacement`` as plain floats ``(x, y, yaw)`` (the per-knot hot path)."""
        x = y = yaw = 0.0
        time = t0
        index = self._segment(t0)
        while time < t1 - 1e-15:
            following = self._times[index + 1] if index + 1 < len(self._times) else math.inf
            boundary = min(following, t1)
            dt = boundary - time
            if dt > 1e-15:
                start, slope = self._starts[index], self._slopes[index]
                offset = max(time - self._times[index], 0.0)
                vx, vy, w = (
                    start[0] + slope[0] * offset,
                    start[1] + slope[1] * offset,
                    start[2] + slope[2] * offset,
                )
                if slope[0] == 0.0 and slope[1] == 0.0 and slope[2] == 0.0:
                    c0, s0 = math.cos(yaw), math.sin(yaw)
                    if abs(w) < 1e-9:
                        x += (c0 * vx - s0 * vy) * dt
                        y += (s0 * vx + c0 * vy) * dt
                    else:  # integral of R(yaw + w s) ds, applied to the heading-frame velocity
                        c1, s1 = math.cos(yaw + w * dt), math.sin(yaw + w * dt)
                        x += ((s1 - s0) * vx + (c1 - c0) * vy) / w
                        y += (-(c1 - c0) * vx + (s1 - s0) * vy) / w
                        yaw += w * dt
                else:  # linear velocities and yaw rate: yaw is quadratic in time
                    for node, weight in zip(_GAUSS_NODES, _GAUSS_WEIGHTS, strict=True):
                        s = 0.5 * dt * (node + 1.0)
                        heading = yaw + w * s + 0.5 * slope[2] * s * s
                        ux, uy = vx + slope[0] * s, vy + slope[1] * s
                        c, si = math.cos(heading), math.sin(heading)
                        x += 0.5 * dt * weight * (c * ux - si * uy)
                        y += 0.5 * dt * weight * (si * ux + c * uy)
                    yaw += w * dt + 0.5 * slope[2] * dt * dt
            time = boundary
            index += 1
        return x, y, yaw


_GAUSS_NODES, _GAUSS_WEIGHTS = (values.tolist() for values in np.polynomial.legendre.leggauss(8))
_GAUSS_NODE_ARRAY, _GAUSS_WEIGHT_ARRAY = np.array(_GAUSS_NODES), np.array(_GAUSS_WEIGHTS)


def _yaw_rotation(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s], [s, c]])


def quaternion_from_yaw(yaw: float) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a pure yaw rotation."""
    return np.array([0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)])


def yaw_from_quaternion(quaternion_xyzw: np.ndarray) -> float:
    x, y, z, w = quaternion_xyzw
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def cubic_bezier_blend(s: float) -> tuple[float, float]:
    """Cubic Bezier with control points (0, 0, 1, 1): value ``3s^2 - 2s^3`` and its derivative in ``s``."""
    s = min(max(s, 0.0), 1.0)
    return 3.0 * s * s - 2.0 * s * s * s, 6.0 * s - 6.0 * s * s


@dataclass(frozen=True)
class _GaitSegment:
    """A gait in force from ``start`` on (``LocomotionReference.set_gait``), its cycles starting at
    ``cycle_start``, with the cycle's sums made once (the per-knot hot path)."""

    start: float
    gait: GaitCycle
    cycle_start: float
    period: float
    phase_ends: tuple[float, ...]
    phase_flags: tuple[tuple[bool, ...], ...]
    support_factor: float

    @classmethod
    def of(cls, start: float, gait: GaitCycle, cycle_start: float) -> _GaitSegment:
        ends = tuple(float(end) for end in np.cumsum([duration for _, duration in gait.cycle]))
        flags = tuple(flags for flags, _ in gait.cycle)
        return cls(start, gait, cycle_start, gait.period, ends, flags, gait.support_factor)


class LocomotionReference(Reference):
    """Base, feet and force references for a periodic gait driven by timed ``VelocityCommand`` s.

    ``sample`` gives the whole-body state reference with joint angles and rates from leg inverse kinematics
    of the reference feet (``LegInverseKinematics``: a joint reference that fought the swing-foot targets
    lifted the body instead of folding the legs), and the torque reference: the static torques that carry
    the gait's average stance load at the standing pose (``support_factor``; regularising toward zero torque
    biased plans toward straight legs and lifted the trotting base from 0.25 m to 0.32 m).
    """

    def __init__(
        self,
        robot: Robot,
        gait: GaitCycle,
        commands: Sequence[VelocityCommand],
        swing_height: float = 0.06,
        raibert_gain: float = 0.03,
        foothold_box: tuple[float, float] = FOOTHOLD_BOX,
        cycle_start: float = 0.0,
        start_stance: float = 0.0,
        command_ramp: float = 0.0,
        path_gain: float = 0.0,
        path_heading_limit: float = 0.2,
        path_anchor: float = 0.0,
        touchdown_events: tuple[float, float, float] | None = None,
        ground_plane: bool = False,
        terrain_map: TerrainMapSettings | None = None,
        swing_lift: float = 0.0,
        ground_from_estimate: bool = False,
        ground_below: float | None = None,
        ground_limits: dict[str, float] | None = None,
        ground_follow: float | None = None,
        touchdown_clearance: float | None = None,
    ) -> None:
        if not commands:
            commands = [VelocityCommand()]
        commands = sorted(commands, key=lambda c: c.start)
        for command in commands:
            validate_command(command, robot)
        if not 0.0 <= swing_height <= 0.2:
            raise ValueError(f"swing_height must be in [0, 0.2] m, got {swing_height}")
        self.robot = robot
        self.gait = gait
        self.commands = list(commands)
        self.swing_height = swing_height
        if not 0.0 <= swing_lift < 1.0:
            raise ValueError(f"swing_lift must be in [0, 1), got {swing_lift}")
        self.swing_lift = float(swing_lift)
        """Fraction of each swing the foot rises before it moves horizontally (``kernels.sample_foot``)."""
        if touchdown_clearance is not None and not 0.0 <= touchdown_clearance <= 0.2:
            raise ValueError(f"touchdown_clearance must be in [0, 0.2] m, got {touchdown_clearance}")
        self.touchdown_clearance = None if touchdown_clearance is None else float(touchdown_clearance)
        """A swing's least apex above its touchdown (``kernels.sample_foot_floored``); None: ``swing_height``
        (the apex that high above the higher end)."""
        self.raibert_gain = raibert_gain
        self.foothold_box = np.array(foothold_box, dtype=float)
        if not (math.isfinite(start_stance) and start_stance >= 0.0):
            raise ValueError(f"start_stance must be >= 0 s, got {start_stance}")
        self.start_stance = float(start_stance)
        """All four feet stand on ``[0, start_stance)``; the gait's first cycle starts at ``start_stance``
        (``cycle_start`` is then ignored). Dynamic gaits such as bounding cannot start from rest in their
        first phase: a short stand lets the first plans load the legs and lean into the gait."""
        self.cycle_start = self.start_stance if self.start_stance > 0 else cycle_start
        self.command_ramp = float(command_ramp)
        self._stand = (-math.inf, self.start_stance)
        self._rest = (math.inf, math.inf)
        """The commands rest on ``[start, end)`` while the gait goes on (``rest_commands``)."""
        """``(from, until)``: all feet stand on this interval and the commands rest (with a ramp): the start
        stance, or the stand of the latest ``restart_gait`` (``until`` inf: until the next one)."""
        self.restarts: list[tuple[float, float]] = []
        """Each ``restart_gait``: ``(t, stand)``."""
        self.profile = self._command_profile()
        """The commanded velocities and height over time: steps, or (``command_ramp`` > 0) rest until the
        gait starts, then linear ramps to each command."""
        self.offsets = robot.foothold_offsets.copy()
        self.mass = robot.total_mass
        self.nominal_joints = robot.q_standing[7:].copy()
        if not (math.isfinite(path_gain) and path_gain >= 0.0):
            raise ValueError(f"path_gain must be >= 0 rad/m, got {path_gain}")
        if not 0.0 <= path_heading_limit <= 1.0:
            raise ValueError(f"path_heading_limit must be in [0, 1] rad, got {path_heading_limit}")
        self.path_gain = float(path_gain)
        """rad of heading per m of cross-track error (0: no path, the commands are dead-reckoned from the
        measurement at every update)."""
        self.path_heading_limit = float(path_heading_limit)
        if not 0.0 <= path_anchor <= 1.0:
            raise ValueError(f"path_anchor must be in [0, 1], got {path_anchor}")
        if path_anchor > 0.0 and self.path_gain == 0.0:
            raise ValueError("path_anchor needs a path: give path_gain > 0")
        self.path_anchor = float(path_anchor)
        """Fraction of the cross-track error taken out of the anchor at each update: the base reference and
        the footholds under its hips start that much closer to the path than the measurement (0: at the
        measurement)."""
        self.path_origin: tuple[float, np.ndarray, float] | None = None
        self._path_offset = np.zeros(2)
        """World (x, y) of the last update's cross-track error (``_path_heading``)."""
        self.touchdown_events = touchdown_events
        """``(on_time, window, height)``: a swing foot found within ``height`` m of the ground with its
        planned touchdown between ``on_time`` and ``window`` s ahead has landed early; the gait's clock is
        advanced to it (``advance_phase``). None: the schedule runs on its clock whatever the feet do."""
        self.phase_advances = 0
        self.phase_advance_total = 0.0
        self.ground = GroundPlane(robot.n_feet, **(ground_limits or {})) if ground_plane else None
        """The plane through the stance feet's latest contact points (``core.ground``) that the base height,
        its pitch and the footholds follow; None: flat ground at z = 0 (the paper's). ``ground_limits``: its
        keyword arguments (``max_slope``: ``vwbc.contact_detection.ground_max_slope``, the detector's plane's
        limit too; ``min_span``: ``ground_min_span``, likewise)."""
        self.ground_from_estimate = bool(ground_from_estimate) and self.ground is not None
        """The plane's points from each control tick's state estimate (``observe_estimate``) instead of
        ``update``'s states (``gait.blind_ground: estimate``): with the real-time iteration those are the
        plan's predictions, in which a landing foot stands where the plan put it and then rises to where it
        is over the next updates, a change the plane's frame-shift rule takes for the estimator's frame
        moving. Until the first estimate arrives (the MPC in its own process gets none) ``update``'s."""
        if ground_below is not None and not (math.isfinite(ground_below) and ground_below >= 0.0):
            raise ValueError(f"ground_below must be >= 0 m or None, got {ground_below}")
        self.ground_below = ground_below
        """With ``ground_from_estimate``: a foot planned in stance that still moves is a point of the plane
        once its sole is this far below the plane (``gait.blind_ground_below``); None: only still feet."""
        if ground_follow is not None and not (math.isfinite(ground_follow) and ground_follow >= 0.0):
            raise ValueError(f"ground_follow must be >= 0 m or None, got {ground_follow}")
        self.ground_follow = ground_follow
        """With ``ground_from_estimate``: a foot that became a point in its planned stance stays one, however
        it moves up or down, while it stays within this horizontal distance (m) of where it became one, to
        the stance's end (``gait.blind_ground_follow``; ``_observe_ground_estimate``); None: off."""
        self._following = np.zeros(robot.n_feet, dtype=bool)
        self._follow_origins = np.zeros((robot.n_feet, 2))
        self._estimated_ground = False
        """Whether ``observe_estimate`` has fed the plane (``ground_from_estimate``)."""
        self._estimate_data = robot.model.createData()
        self._estimate_positions = np.zeros((robot.n_feet, 3))
        self._estimate_soles = np.zeros((robot.n_feet, 3))
        self._estimate_still = np.zeros(robot.n_feet, dtype=bool)
        if terrain_map is not None and self.ground is None:
            raise ValueError(
                "a reference on a height map (terrain_map) needs the ground plane (ground_plane)"
            )
        self.terrain = TerrainMap(terrain_map) if terrain_map is not None else None
        """The newest height map (``reference.terrain_map``, ``terrain: height_map``): the footholds on its
        flat spots, the swings above it, the base's height and pitch from it; where it has not seen, and
        before the first map, the ground plane. None: the ground plane alone (``terrain: blind``)."""
        hips = self.offsets[:, 0]
        self._front_feet = hips > 0.0
        self._hip_span = float(np.mean(hips[hips > 0.0]) - np.mean(hips[hips <= 0.0]))
        self._soles = np.zeros((robot.n_feet, 3))
        self._still = np.zeros(robot.n_feet, dtype=bool)
        self._terrain_normal: np.ndarray | None = None
        """(time, x y, yaw) the commanded path starts from: the first measured pose after a reset."""
        # anchor (re-set at every update)
        self.anchor_time = 0.0
        self.anchor_xy = np.zeros(2)
        self.anchor_yaw = 0.0
        self.measured_velocity_xy = np.zeros(2)
        self.stance_positions = robot.foot_positions(robot.q_standing)
        self.liftoff_positions = self.stance_positions.copy()
        self._held_footholds = np.full((robot.n_feet, 3), np.nan)
        """Per foot, the touchdown time and world x, y of the flat spot of the map its next touchdown moved
        to (``kernels.sample_feet``'s ``held``; ``terrain_map.foothold_hysteresis``)."""
        self._schedule: ContactSchedule | None = None
        self._schedule_window = (math.inf, -math.inf)
        self.inverse_kinematics = LegInverseKinematics(robot)
        self._stance_torques: dict[tuple[tuple[bool, ...], float], np.ndarray] = {}
        self._feet_stance = np.zeros((0, robot.n_feet), dtype=bool)
        self._segments = [_GaitSegment.of(-math.inf, gait, self.cycle_start)]
        """The gait in force over time: the config's, then each ``set_gait`` from its cycle boundary on."""
        library = GAITS.get(gait.name)
        self.time_scale = gait.period / library.period if library is not None else 1.0
        """Phase durations of this reference's gaits relative to the library's (the robot's Froude scaling:
        ``assembly.resolve.scaled_gait``), applied to gaits switched to by name."""
        # what the compiled sampling (``reference.kernels``) reads, kept between updates: the gaits in force
        # as arrays and the torque references of their stances (remade when ``_segments`` changes), the
        # schedule's phases as arrays (remade with the schedule), and per-update scratch
        self._tables_of: tuple[_GaitSegment, ...] = ()
        self._gaits = np.zeros((0, 5))
        self._gait_phase_ends = np.zeros((0, 0))
        self._gait_phase_flags = np.zeros((0, 0, robot.n_feet), dtype=bool)
        self._torque_table = np.zeros((0, robot.nu))
        self._torque_filled = np.zeros(0, dtype=bool)
        self._phases_of: ContactSchedule | None = None
        self._switches_of: ContactSchedule | None = None
        self._sorted_switches: list[float] = []
        """``switch_times`` of the cached schedule ``_switches_of``, sorted (remade with the schedule)."""
        self._phase_starts = np.zeros(0)
        self._phase_ends = np.zeros(0)
        self._phase_flags = np.zeros((0, robot.n_feet), dtype=bool)
        self._anchor = np.zeros(4)
        self._feet_parameters = np.zeros(14)
        self._factors = np.zeros(0)
        self._keys = np.zeros(0, dtype=np.int64)
        self._data = robot.model.createData()
        self._ik_joints = np.zeros((0, robot.nu))
        self._ik_rates = np.zeros((0, robot.nu))
        self._ik_errors = np.zeros(0)
        self._warm_up()

    def rest_commands(self, t: float, rest: bool) -> None:
        """The commands rest from ``t`` on while the gait goes on (``rest``: the MPC brings the robot to rest
        on its steps, the safe ladder's stop; docs/faults.md), or (not ``rest``) come back from ``t``, ramped
        in from rest over ``command_ramp`` as at the start. A gait restart ends a rest (its own commands
        follow)."""
        t = float(t)
        self._rest = (t, math.inf) if rest else (self._rest[0], t)
        self.profile = self._command_profile()

    def _command_profile(self) -> CommandProfile:
        """The commands over time (``_gait_profile``), resting on ``_rest`` and ramped back in after it."""
        gait = self._gait_profile()
        rest_from, rest_until = self._rest
        if math.isinf(rest_from):
            return gait
        rest = CommandProfile([VelocityCommand()], self.robot.standing_height)
        profile = gait.spliced(rest_from, rest)
        if math.isinf(rest_until):
            return profile
        if self.restarts and self.restarts[-1][0] == rest_until:  # a gait restart ended the rest
            return profile.spliced(rest_until, gait)
        back = CommandProfile(self.commands, self.robot.standing_height, self.command_ramp, rest_until)
        return profile.spliced(rest_until, back)

    def _gait_profile(self) -> CommandProfile:
        """The commands over time: ramped from rest after the start stance (``command_ramp`` > 0), and after a
        gait restart at rest from its start, ramped again from rest after its stand (a stand until further
        notice rests until then, also with steps)."""
        profile = CommandProfile(
            self.commands, self.robot.standing_height, self.command_ramp, self.start_stance
        )
        if not self.restarts:
            return profile
        stand_from, stand_until = self._stand
        if math.isinf(stand_until):
            rest = CommandProfile([VelocityCommand()], self.robot.standing_height)
            return profile.spliced(stand_from, rest)
        if self.command_ramp == 0.0:
            return profile
        ramped = CommandProfile(self.commands, self.robot.standing_height, self.command_ramp, stand_until)
        return profile.spliced(stand_from, ramped)

    def restart_gait(self, t: float, stand: float) -> None:
        """Restart the gait from the stance the robot stands in (after the safe ladder held it;
        docs/faults.md): from ``t`` all feet stand for ``stand`` s (``math.inf``: until the next restart)
        and the commands rest, then the gait in force (``target_gait``) starts its first cycle, from its
        first phase, the commands ramped in from rest as at the start (``command_ramp``). Switches and phase
        advances after ``t`` are dropped; the commanded path (``path_gain``) starts again from the next
        measured pose."""
        if not (math.isfinite(t) and stand >= 0.0):
            raise ValueError(
                f"a gait restart needs a finite time and a stand >= 0 s, got t = {t}, stand = {stand}"
            )
        t, until = float(t), float(t) + float(stand)
        target = self.target_gait
        segments = [segment for segment in self._segments if segment.start <= t + TIME_TOLERANCE]
        start = until if math.isfinite(until) else t  # a stand until further notice: taken up by the next
        segments.append(_GaitSegment.of(start, target, start))
        self._segments = segments
        self._stand = (t, until)
        if math.isinf(self._rest[1]):
            self._rest = (self._rest[0], t)  # a rest ends here: the restart's commands follow
        else:
            self._rest = (math.inf, math.inf)  # an ended rest is past (the reference anchors at the updates)
        self.restarts.append((t, float(stand)))
        self.path_origin = None
        self.profile = self._command_profile()
        self._schedule_window = (math.inf, -math.inf)

    def _standing(self, t: float) -> bool:
        """Whether all feet stand at ``t`` for the start stance or a restart's stand (``_stand``)."""
        stand_from, stand_until = self._stand
        return stand_from - 1e-9 <= t < stand_until - 1e-9

    def _warm_up(self) -> None:
        """Sample two knots once, so that the compiled kernels are compiled (or loaded from numba's cache)
        now and not in the first MPC update; the cached schedule is put back as it was, so the samples of
        later updates do not depend on this one."""
        schedule, schedule_window = self._schedule, self._schedule_window
        window = ReferenceWindow(2, self.robot.nq, self.robot.nv, self.robot.nu, self.robot.n_feet)
        window.set_times(np.array([0.0, 0.01]))
        self.sample(window)
        self._schedule, self._schedule_window = schedule, schedule_window

    def _segment_at(self, t: float) -> _GaitSegment:
        segments = self._segments
        if len(segments) == 1:
            return segments[0]
        for segment in reversed(segments):
            if t >= segment.start - TIME_TOLERANCE:
                return segment
        return segments[0]

    @property
    def target_gait(self) -> GaitCycle:
        """The gait last switched to (in force, or from a coming cycle boundary)."""
        return self._segments[-1].gait

    def gait_at(self, t: float) -> GaitCycle:
        """The gait in force at ``t`` (the config's, or one ``set_gait`` switched to)."""
        return self._segment_at(t).gait

    def _flags_at(self, t: float) -> tuple[bool, ...]:
        """``gait.flags_at(t, cycle_start)`` of the gait in force, with the cycle's sums made once."""
        segment = self._segment_at(t)
        tau = (t - segment.cycle_start) % segment.period
        for flags, end in zip(segment.phase_flags, segment.phase_ends, strict=True):
            if tau < end - TIME_TOLERANCE:
                return flags
        return segment.phase_flags[0]

    def set_gait(self, t: float, name: str) -> float:
        """Switch to the library gait ``name`` (``ocp.contact_schedule.GAITS``, timed like this reference's:
        ``time_scale``) at the first cycle boundary of the gait in force at or after ``t`` (at the end of the
        initial stand if ``t`` is before it), so that no phase is cut short; a switch requested before an
        earlier one took effect replaces it. Returns the time of the switch. ``ValueError`` for an unknown
        gait."""
        key = name.replace("-", "_").lower()
        if key not in GAITS:
            raise ValueError(f"unknown gait {name!r}; known gaits: {', '.join(sorted(GAITS))}")
        library = GAITS[key]
        gait = GaitCycle(key, tuple((flags, duration * self.time_scale) for flags, duration in library.cycle))
        if self._segments[-1].gait.cycle == gait.cycle:  # in force, or already switched to
            return max(self._segments[-1].start, t)
        self._segments = [segment for segment in self._segments if segment.start <= t + TIME_TOLERANCE]
        current = self._segments[-1]
        if current.gait.cycle == gait.cycle:  # a pending switch away from it is cancelled
            self._schedule_window = (math.inf, -math.inf)
            return t
        stand_until = self._stand[1]
        if t < stand_until - TIME_TOLERANCE:  # the gait starts (again) after the stand: so does this one
            switch = stand_until if math.isfinite(stand_until) else t
        else:
            cycles = math.ceil((t - current.cycle_start) / current.period - TIME_TOLERANCE)
            switch = current.cycle_start + cycles * current.period
        self._segments.append(_GaitSegment.of(switch, gait, switch))
        self._schedule_window = (math.inf, -math.inf)  # rebuild the cached schedule
        return switch

    # ----------------------------------------------------------------------------------------- commands
    def command_at(self, t: float) -> VelocityCommand:
        """The command in effect at ``t`` (ramped: ``profile``); its ``height`` is never None."""
        return self.profile.command_at(t)

    def height_at(self, t: float) -> float:
        return self.profile.values_at(t)[3]

    def set_command(self, t: float, command: VelocityCommand) -> None:
        """Follow ``command`` from ``t`` on (a runtime command: ``control.commands``): it replaces the timed
        commands that start at or after ``t`` and is approached like one of them (a step, or a ramp over
        ``command_ramp`` from the value at ``t``; before the gait starts, the robot stays at rest). Times
        before ``t`` keep their values, so the base reference integrated from an earlier anchor is unchanged.
        Raises ``ValueError`` for a command the robot cannot follow (``validate_command``)."""
        validate_command(command, self.robot)
        t = max(float(t), 0.0)
        kept = [earlier for earlier in self.commands if earlier.start < t - 1e-12]
        if not kept and t > 0.0:  # the first command (held before its own start) holds until t
            kept = [self.commands[0].model_copy(update={"start": 0.0})]
        self.commands = [*kept, command.model_copy(update={"start": t if kept else 0.0})]
        self.profile = self._command_profile()

    # --------------------------------------------------------------------------------------- schedule
    def schedule(self, t0: float, t1: float) -> ContactSchedule:
        """The gait's contact schedule covering ``[t0, t1]`` (cached; widened as needed)."""
        if not (self._schedule_window[0] <= t0 and t1 <= self._schedule_window[1]):
            longest = max(segment.period for segment in self._segments)
            start = max(0.0, t0 - 2.0 * longest)
            end = t1 + 4.0 * longest
            if start < self.start_stance - 1e-6 and not self.restarts:
                stand = ContactPhase((True, True, True, True), start, self.start_stance)
                gait = self.gait.schedule(self.start_stance, max(end, self.start_stance + self.gait.period))
                phases = list(gait.phases)
                if phases[0].stance == stand.stance:
                    phases[0] = ContactPhase(stand.stance, stand.start, phases[0].end)
                else:
                    phases.insert(0, stand)
                self._schedule = ContactSchedule(phases)
            else:
                self._schedule = self.gait.schedule(start, end, cycle_start=self.cycle_start)
            if len(self._segments) > 1:
                self._schedule = self._switched(self._schedule, start, end)
            if self.restarts:
                self._schedule = self._stood(self._schedule, *self._stand)
            self._schedule_window = (start, end)
        assert self._schedule is not None
        return self._schedule

    def _stood(self, base: ContactSchedule, stand_from: float, stand_until: float) -> ContactSchedule:
        """``base`` with all feet standing on ``[stand_from, stand_until)`` (a gait restart's stand), adjacent
        equal phases merged."""
        pieces: list[ContactPhase] = []
        phases = base.phases
        for phase in phases:
            _add_phase(pieces, phase.stance, phase.start, min(phase.end, stand_from))
        standing = (True,) * self.robot.n_feet
        _add_phase(pieces, standing, max(stand_from, phases[0].start), min(stand_until, phases[-1].end))
        for phase in phases:
            _add_phase(pieces, phase.stance, max(phase.start, stand_until), phase.end)
        return ContactSchedule(pieces)

    def _switched(self, base: ContactSchedule, start: float, end: float) -> ContactSchedule:
        """``base`` (the config's gait over ``[start, end]``) with the ``set_gait`` switches applied: each
        later gait's own schedule from its switch on, adjacent equal phases merged."""
        pieces: list[ContactPhase] = []

        def add(stance: tuple[bool, ...], a: float, b: float) -> None:
            _add_phase(pieces, stance, a, b)

        bounds = [segment.start for segment in self._segments[1:]] + [math.inf]
        first_switch = bounds[0]
        for phase in base.phases:
            add(phase.stance, phase.start, min(phase.end, first_switch))
        for segment, following in zip(self._segments[1:], bounds[1:], strict=True):
            a, b = max(segment.start, start), min(following, end)
            if b - a <= TIME_TOLERANCE:
                continue
            for phase in segment.gait.schedule(a, b, cycle_start=segment.cycle_start).phases:
                add(phase.stance, phase.start, phase.end)
        return ContactSchedule(pieces)

    def switch_times(self, t0: float, t1: float) -> list[float]:
        """Contact switches in ``(t0, t1)``: the gait schedule's (the start stance's end included)."""
        schedule = self.schedule(max(t0, 0.0), max(t1, t0 + 1e-6))
        if schedule is not self._switches_of:
            self._sorted_switches = sorted(float(t) for t in schedule.switch_times())
            self._switches_of = schedule
        times = self._sorted_switches
        # only the times strictly between t0 and t1 can be inside: the same result as from all of them
        return switches_inside(times[bisect.bisect_right(times, t0) : bisect.bisect_left(times, t1)], t0, t1)

    def stance_at(self, t: float) -> tuple[bool, bool, bool, bool]:
        if self._standing(t):
            return (True, True, True, True)
        return self._flags_at(t)

    # ---------------------------------------------------------------------------------- compiled tables
    def _gait_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The gaits in force as arrays for ``kernels.sample_base``: (start, cycle start, period, support
        factor, phases) per segment, the phases' ends and flags padded; made again when ``set_gait`` has
        changed the segments (the torque table with them: its load classes are the segments)."""
        segments = self._segments
        cached = self._tables_of
        if len(cached) != len(segments) or any(a is not b for a, b in zip(cached, segments, strict=False)):
            phases = max(len(segment.phase_ends) for segment in segments)
            n_feet = self.robot.n_feet
            self._gaits = np.array(
                [(s.start, s.cycle_start, s.period, s.support_factor, len(s.phase_ends)) for s in segments],
                dtype=float,
            )
            self._gait_phase_ends = np.full((len(segments), phases), np.inf)
            self._gait_phase_flags = np.zeros((len(segments), phases, n_feet), dtype=bool)
            for index, segment in enumerate(segments):
                self._gait_phase_ends[index, : len(segment.phase_ends)] = segment.phase_ends
                self._gait_phase_flags[index, : len(segment.phase_flags)] = segment.phase_flags
            rows = (len(segments) + 1) << n_feet
            self._torque_table = np.zeros((rows, self.robot.nu))
            self._torque_filled = np.zeros(rows, dtype=bool)
            self._tables_of = tuple(segments)
        return self._gaits, self._gait_phase_ends, self._gait_phase_flags

    def _torques_into(self, keys: np.ndarray, out: np.ndarray) -> None:
        """The torque reference of each knot (``stance_torque`` of its flags and support factor) from the
        table of ``_gait_tables``, indexed by the keys of ``kernels.sample_base``; missing rows are made on
        first use."""
        table, filled = self._torque_table, self._torque_filled
        if not filled[keys].all():
            n_feet = self.robot.n_feet
            for key in np.unique(keys[~filled[keys]]).tolist():
                load, code = key >> n_feet, key & ((1 << n_feet) - 1)
                factor = 1.0 / n_feet if load == 0 else self._segments[load - 1].support_factor
                flags = tuple(bool(code >> foot & 1) for foot in range(n_feet))
                table[key] = self.stance_torque(flags, factor)
                filled[key] = True
        np.take(table, keys, axis=0, out=out)

    def _phase_arrays(self, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Starts, ends and stance flags (phases, feet) of the phases of ``schedule(t0, t1)`` (remade with
        the schedule)."""
        schedule = self.schedule(t0, t1)
        if schedule is not self._phases_of:
            phases = schedule.phases
            self._phase_starts = np.array([phase.start for phase in phases], dtype=float)
            self._phase_ends = np.array([phase.end for phase in phases], dtype=float)
            self._phase_flags = np.array([phase.stance for phase in phases], dtype=bool).reshape(
                len(phases), self.robot.n_feet
            )
            self._phases_of = schedule
        return self._phase_starts, self._phase_ends, self._phase_flags

    # ------------------------------------------------------------------------------------------ update
    def update(self, t: float, q: np.ndarray, v: np.ndarray) -> None:
        """Re-anchor on the measured state: base x, y, yaw and velocity; stance feet positions."""
        self.anchor_time = t
        self.anchor_xy = q[:2].copy()
        self.anchor_yaw = yaw_from_quaternion(q[3:7])
        if self.path_gain > 0.0:
            self.anchor_yaw = self._path_heading(t, self.anchor_xy, self.anchor_yaw)
            if self.path_anchor > 0.0:
                self.anchor_xy = self.anchor_xy - self.path_anchor * self._path_offset
        rotation = _quaternion_matrix(q[3:7])
        self.measured_velocity_xy = (rotation @ v[:3])[:2]
        robot, data = self.robot, self._data
        pin.framesForwardKinematics(robot.model, data, q)
        if self.touchdown_events is not None:
            self._landed_early(t)
        stance = self.stance_at(t)
        for foot, frame_id in enumerate(robot.foot_frame_ids):
            if stance[foot]:
                position = data.oMf[frame_id].translation
                self.stance_positions[foot] = position
                if self.ground is None:
                    self.stance_positions[foot, 2] = robot.foot_radius
                self.liftoff_positions[foot] = position
        if self.ground is not None:
            if not self._estimated_ground:
                self._observe_ground(q, v, stance)
            if self.terrain is not None and self.terrain.settings.registration == "feet":
                # (registration "motion": observe_estimate)
                self.terrain.follow_frame(self.ground.frame_shift)
                self.terrain.register(self._soles, self._still)
            if self.terrain is not None and self.terrain.settings.cone == "map":
                self._follow_terrain_normal(self.terrain.normal_under(self._soles))

    def _observe_ground(self, q: np.ndarray, v: np.ndarray, stance: Sequence[bool]) -> None:
        """The ground plane through the feet planned in stance that stand still (a foot planned in stance
        that is still moving has not landed: a late touchdown, its leg hanging from a body that may be
        rising; taking its point would lift the plane, the base with it and the foot again)."""
        assert self.ground is not None
        robot, data = self.robot, self._data
        pin.forwardKinematics(robot.model, data, q, v)
        still = self._still
        for foot, frame_id in enumerate(robot.foot_frame_ids):
            velocity = pin.getFrameVelocity(robot.model, data, frame_id, pin.LOCAL_WORLD_ALIGNED).linear
            still[foot] = stance[foot] and float(np.linalg.norm(velocity)) < GROUND_FOOT_SPEED
        np.copyto(self._soles, self.stance_positions)
        self._soles[:, 2] -= robot.foot_radius
        self.ground.observe(self._soles, still)

    def _observe_ground_estimate(self, t: float, q: np.ndarray, v: np.ndarray) -> None:
        """The ground plane through the feet planned in stance at ``t`` that stand still in the state
        estimate ``q, v`` of that control tick (``_observe_ground``'s rule on the estimate; each foot's
        latest point while it stands); with ``ground_below`` also those that move with the sole that far
        below the plane: a foot below the ground believed is on lower ground (sliding down a slope, or
        landing on it), where a late foot hanging from the body stays above it. With ``ground_follow`` a foot
        that became a point in its planned stance stays one, however fast it moves up or down, while it
        stays within ``ground_follow`` (horizontally) of where it became one: the estimator's frame moves its
        stance feet to z = 0 over some 25 ms after they land on a new tread, and that change of height is
        what ``GroundPlane.observe`` moves the other points by; a foot sliding along the ground is no
        point."""
        assert self.ground is not None
        robot, data = self.robot, self._estimate_data
        pin.forwardKinematics(robot.model, data, q, v)
        pin.updateFramePlacements(robot.model, data)
        stance = self.stance_at(t)
        still = self._estimate_still
        following = self._following
        for foot, frame_id in enumerate(robot.foot_frame_ids):
            still[foot] = False
            if stance[foot]:
                self._estimate_positions[foot] = data.oMf[frame_id].translation
                velocity = pin.getFrameVelocity(robot.model, data, frame_id, pin.LOCAL_WORLD_ALIGNED).linear
                still[foot] = float(np.linalg.norm(velocity)) < GROUND_FOOT_SPEED
                if not still[foot] and self.ground_below is not None:
                    sole = self._estimate_positions[foot]
                    plane = self.ground.height_at(float(sole[0]), float(sole[1]))
                    still[foot] = sole[2] - robot.foot_radius < plane - self.ground_below
                if self.ground_follow is not None:
                    position = self._estimate_positions[foot]
                    origin = self._follow_origins[foot]
                    if following[foot]:
                        # the frame moves a standing foot up or down only; a foot sliding on is no point
                        moved = math.hypot(position[0] - origin[0], position[1] - origin[1])
                        following[foot] = moved <= self.ground_follow
                        still[foot] = still[foot] or bool(following[foot])
                    if still[foot] and not following[foot]:
                        following[foot] = True
                        origin[:] = position[:2]
            else:
                following[foot] = False
        np.copyto(self._estimate_soles, self._estimate_positions)
        self._estimate_soles[:, 2] -= robot.foot_radius
        self.ground.observe(self._estimate_soles, still)
        self._estimated_ground = True

    def _landed_early(self, t: float) -> None:
        """Advance the gait's clock when a swing foot is on the ground before its planned touchdown (the
        placements of the measured configuration in ``self._data``): the plans then give it, and the feet
        planned to land with it, their stance from now (event-based timing, as Bledt et al.'s contact fusion
        does for the Cheetah 3), instead of a flight the robot is no longer in."""
        assert self.touchdown_events is not None
        on_time, window, height = self.touchdown_events
        if t < self._stand[1] or self._segments[-1].start > t + TIME_TOLERANCE:
            return  # standing still, or a gait switch pending: the schedule decides
        stance = self.stance_at(t)
        phases = self.schedule(t, t + window).phases
        lead = None
        for foot, frame_id in enumerate(self.robot.foot_frame_ids):
            if stance[foot]:
                continue
            position = self._data.oMf[frame_id].translation
            sole = position[2] - self.robot.foot_radius - self.ground_height_at(position[0], position[1])
            if sole > height:
                continue
            touchdown = next(
                (p.start for p in phases if p.start > t and p.stance[foot] and p.start - t <= window), None
            )
            if touchdown is not None and touchdown - t > on_time:
                lead = touchdown - t if lead is None else min(lead, touchdown - t)
        if lead is not None:
            self.advance_phase(t, lead)

    def advance_phase(self, t: float, lead: float) -> None:
        """From ``t`` on, the gait in force runs ``lead`` seconds ahead (its cycle starts that much earlier):
        what was planned for ``t + lead`` happens at ``t``."""
        current = self._segments[-1]
        self._segments.append(_GaitSegment.of(t, current.gait, current.cycle_start - lead))
        self._schedule_window = (math.inf, -math.inf)
        self.phase_advances += 1
        self.phase_advance_total += lead

    def _path_heading(self, t: float, xy: np.ndarray, yaw: float) -> float:
        """The heading the reference takes from the measured pose at ``t`` when it holds the commanded path:
        the path's heading at ``t`` (the commands integrated from ``path_origin``), turned toward the path
        by ``path_gain`` per metre of cross-track error, at most ``path_heading_limit`` (a pure-pursuit
        lane keeper: dead-reckoning the commands from each measurement lets sensor bias and slip move
        the robot off its line, which a task fixed in the world, a bar to roll over, cannot afford)."""
        if self.path_origin is None:
            self.path_origin = (t, xy.copy(), yaw)
            self._path_offset = np.zeros(2)
            return yaw
        start, origin, origin_yaw = self.path_origin
        displacement, turn = self.profile.heading_displacement(start, t)
        path_xy = origin + _yaw_rotation(origin_yaw) @ displacement
        path_yaw = origin_yaw + turn
        cross = float((_yaw_rotation(path_yaw).T @ (xy - path_xy))[1])
        self._path_offset = cross * _yaw_rotation(path_yaw)[:, 1]
        correction = max(-self.path_heading_limit, min(self.path_heading_limit, self.path_gain * cross))
        return path_yaw - correction

    # ------------------------------------------------------------------------------------------- ground
    def ground_height_at(self, x: float, y: float) -> float:
        """The ground's height under world ``(x, y)`` as the reference believes it (0: flat ground; the
        height map's where it saw, else the ground plane's)."""
        if self.terrain is not None and self.terrain.available:
            height = np.zeros(1)
            map_heights(self.terrain.heights, self.terrain.parameters, np.array([x]), np.array([y]), height)
            if math.isfinite(height[0]):
                return float(height[0])
        return 0.0 if self.ground is None else self.ground.height_at(x, y)

    def contact_frame(self) -> np.ndarray | None:
        """The ground plane's contact frame (``GroundPlane.contact_frame``): the plan's pyramid about the
        normal of the ground the stance feet stand on; with ``terrain_map.cone: map`` about the map's normal
        under them (``terrain_normal``); None on flat ground (world z)."""
        normal = self.terrain_normal()
        if normal is not None:
            return ground_contact_frame(normal)
        return None if self.ground is None else self.ground.contact_frame()

    def _follow_terrain_normal(self, normal: np.ndarray | None) -> None:
        """Take the map's ``normal`` under the feet (``TerrainMap.normal_under``) for the pyramids when it
        turned more than ``NORMAL_STEP`` from the one in use, world z when within ``NORMAL_STEP`` of it;
        else keep the one in use (and with None: no foot stands on a flat spot). The map's noise tilts each
        estimate by about half a degree, in a new direction at every update; followed, it re-oriented the
        VWBC's pyramid at every update and the bound fell on 8 cm steps from 6 of 7 starts it crossed with
        the pyramid held level."""
        if normal is None:
            return
        if normal[2] >= math.cos(NORMAL_STEP):
            normal = _WORLD_Z
        current = self._terrain_normal
        if current is None or float(normal @ current) < math.cos(NORMAL_STEP):
            self._terrain_normal = normal

    def terrain_normal(self) -> np.ndarray | None:
        """With ``terrain_map.cone: map``, the height map's unit normal under the flat spots the feet stood
        on at the last update (``TerrainMap.normal_under``; what the plan's and the VWBC's pyramids are
        taken about), the last one while no foot stands on a flat spot; None otherwise, or before a foot
        stood on one."""
        if self.terrain is None or self.terrain.settings.cone != "map" or not self.terrain.available:
            return None
        return self._terrain_normal

    def observe_height_map(self, height_map: HeightMap, q: np.ndarray, v: np.ndarray | None = None) -> None:
        """A height map relative to the base (``HeightMap.relative_to``), placed at the measured base pose
        ``q`` (the estimate of the tick it was taken at; ``v``, its velocity, base frame, for
        ``terrain_map.registration: motion``): the newest terrain the reference plans on. Ignored without
        ``terrain_map`` (``terrain: flat | blind``)."""
        if self.terrain is None:
            return
        assert self.ground is not None
        vertical_velocity = 0.0
        if self.terrain.settings.registration == "motion":
            if v is None:
                raise ValueError("terrain_map.registration: motion needs each map's estimated velocity")
            vertical_velocity = float(_quaternion_matrix(q[3:7])[2] @ v[:3])
        yaw = yaw_from_quaternion(q[3:7])
        placed = height_map.placed_at(float(q[0]), float(q[1]), float(q[2]), yaw)
        self.terrain.place(placed, self.ground.frame_shift, float(q[2]), vertical_velocity)

    def observe_estimate(self, t: float, q: np.ndarray, v: np.ndarray) -> None:
        """The state estimate of the control tick at ``t`` (``v`` in the base frame): with
        ``terrain_map.registration: motion`` the map's offset follows the estimator frame's move since the
        map was placed (``TerrainMap.follow_motion``). Not from ``update``, whose states are, with the
        real-time iteration, the plan's own predictions: taken from them the offset moved the plan, which
        moved the offset (the heights ran away within 60 ms). With ``ground_from_estimate`` the ground
        plane's points come from here (``_observe_ground_estimate``)."""
        if self.ground_from_estimate:
            self._observe_ground_estimate(t, q, v)
        terrain = self.terrain
        if terrain is None or terrain.settings.registration != "motion" or not terrain.available:
            return
        vertical_velocity = float(_quaternion_matrix(q[3:7])[2] @ v[:3])
        terrain.follow_motion(t, float(q[2]), vertical_velocity)

    def _follow_ground(self, state: np.ndarray) -> None:
        """Base rows ``state[:, :7]`` (yaw-only attitude, height above z = 0) onto the ground plane: the
        height above the plane under the base, pitched along the plane's slope in the heading."""
        ground = self.ground
        if ground is None:
            return
        if self.terrain is not None and self.terrain.available:
            self._follow_terrain(state)
            return
        state[:, 2] += ground.height + ground.slope[0] * (state[:, 0] - ground.centre[0])
        state[:, 2] += ground.slope[1] * (state[:, 1] - ground.centre[1])
        if not np.any(ground.slope):
            return
        half_yaw = np.arctan2(state[:, 5], state[:, 6])  # qz, qw of a yaw-only quaternion
        rise = ground.slope[0] * np.cos(2.0 * half_yaw) + ground.slope[1] * np.sin(2.0 * half_yaw)
        half_pitch = -0.5 * np.arctan(rise)
        cy, sy, cp, sp = np.cos(half_yaw), np.sin(half_yaw), np.cos(half_pitch), np.sin(half_pitch)
        state[:, 3], state[:, 4], state[:, 5], state[:, 6] = -sy * sp, cy * sp, sy * cp, cy * cp

    def _follow_terrain(self, state: np.ndarray) -> None:
        """Base rows ``state[:, :7]`` onto the height map: the commanded height above the mean of the
        terrain under the four hips (``TerrainMap.smooth``; the ground plane where the map has not seen),
        pitched by the rise from the hind hips' terrain to the front hips'."""
        assert self.terrain is not None and self.ground is not None
        n = state.shape[0]
        half_yaw = np.arctan2(state[:, 5], state[:, 6])
        cos, sin = np.cos(2.0 * half_yaw), np.sin(2.0 * half_yaw)
        terrain = np.zeros((n, len(self.offsets)))
        column = np.zeros(n)
        ground = self.ground
        for foot, (ox, oy) in enumerate(self.offsets):
            xs = state[:, 0] + cos * ox - sin * oy
            ys = state[:, 1] + sin * ox + cos * oy
            map_heights(self.terrain.smooth, self.terrain.parameters, xs, ys, column)
            plane = ground.height + ground.slope[0] * (xs - ground.centre[0])
            plane += ground.slope[1] * (ys - ground.centre[1])
            terrain[:, foot] = np.where(np.isfinite(column), column, plane)
        front = terrain[:, self._front_feet].mean(axis=1)
        hind = terrain[:, ~self._front_feet].mean(axis=1)
        state[:, 2] += terrain.mean(axis=1)
        half_pitch = -0.5 * np.arctan((front - hind) / self._hip_span)
        cy, sy, cp, sp = np.cos(half_yaw), np.sin(half_yaw), np.cos(half_pitch), np.sin(half_pitch)
        state[:, 3], state[:, 4], state[:, 5], state[:, 6] = -sy * sp, cy * sp, sy * cp, cy * cp

    # ------------------------------------------------------------------------------------------- base
    def base_pose(self, t: float) -> tuple[np.ndarray, float]:
        """Reference base (x, y) and yaw at ``t >= anchor_time``, integrating the commands from the anchor
        (``CommandProfile.heading_displacement``: closed form on constant commands)."""
        t = max(t, self.anchor_time)
        displacement, turn = self.profile.heading_displacement(self.anchor_time, t)
        return self.anchor_xy + _yaw_rotation(self.anchor_yaw) @ displacement, self.anchor_yaw + turn

    def base_state(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Reference configuration ``q`` (19) and velocity ``v`` (18, base frame) at ``t``."""
        xy, yaw = self.base_pose(t)
        vx, vy, yaw_rate, height = self.profile.values_at(t)
        q = np.concatenate([[xy[0], xy[1], height], quaternion_from_yaw(yaw), self.nominal_joints])
        self._follow_ground(q[None, :7])
        v = np.zeros(self.robot.nv)
        v[0], v[1], v[5] = vx, vy, yaw_rate
        return q, v

    # ------------------------------------------------------------------------------------------- feet
    def hip_xy(self, t: float, foot: int) -> np.ndarray:
        """World (x, y) of a foot's nominal foothold under its hip at the reference base pose at ``t``."""
        xy, yaw = self.base_pose(t)
        return xy + _yaw_rotation(yaw) @ self.offsets[foot]

    def foothold(self, foot: int, touchdown_time: float, stance_duration: float) -> np.ndarray:
        """Raibert foothold (Sec. VI-A): the hip at mid-stance plus velocity feedback, clamped to a box; on
        the ground the reference believes in (``ground_height_at``), on a height map moved to a flat spot."""
        nominal = self.hip_xy(touchdown_time, foot)
        mid_stance = self.hip_xy(touchdown_time + 0.5 * stance_duration, foot)
        vx, vy, _, _ = self.profile.values_at(touchdown_time)
        _, yaw = self.base_pose(touchdown_time)
        commanded_world = _yaw_rotation(yaw) @ np.array([vx, vy])
        feedback = self.raibert_gain * (self.measured_velocity_xy - commanded_world)
        target = mid_stance + feedback
        step = _yaw_rotation(-yaw) @ (target - nominal)
        step = np.clip(step, -self.foothold_box, self.foothold_box)
        xy = nominal + _yaw_rotation(yaw) @ step
        foothold = np.array([xy[0], xy[1], self.robot.foot_radius + self.ground_height_at(xy[0], xy[1])])
        terrain = self.terrain
        if (
            terrain is not None and terrain.available
        ):  # onto a flat spot of the map (kernels.terrain_foothold)
            terrain_foothold(
                terrain.heights, terrain.footholds, terrain.parameters, self.robot.foot_radius, foothold
            )
        return foothold

    def _swings(self, foot: int, t0: float, t1: float) -> list[tuple[float, float, float]]:
        """Swing intervals ``(liftoff, touchdown, next stance duration)`` of ``foot`` overlapping [t0, t1]."""
        schedule = self.schedule(t0, t1)
        phases = schedule.phases
        swings = []
        index = 0
        while index < len(phases):
            if not phases[index].stance[foot]:
                start = phases[index].start
                end_index = index
                while end_index + 1 < len(phases) and not phases[end_index + 1].stance[foot]:
                    end_index += 1
                end = phases[end_index].end
                stance_duration = 0.0
                k = end_index + 1
                while k < len(phases) and phases[k].stance[foot]:
                    stance_duration += phases[k].duration
                    k += 1
                if end > t0 and start < t1:
                    swings.append((start, end, max(stance_duration, 1e-3)))
                index = end_index + 1
            else:
                index += 1
        return swings

    def feet(self, times: Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Stance flags (n, n_feet), positions and velocities (n, n_feet, 3) of the feet at ``times``."""
        times = np.asarray(times, dtype=float)
        n = len(times)
        n_feet = self.robot.n_feet
        stance = np.zeros((n, n_feet), dtype=bool)
        positions = np.zeros((n, n_feet, 3))
        velocities = np.zeros((n, n_feet, 3))
        if n == 0:
            return stance, positions, velocities
        # Swings between the anchor (the last measurement) and ``times[0]`` matter too: a foot that touches
        # down in between stands on that swing's foothold, not where it stood at the anchor (missing this put
        # the SRB tail's stance feet up to 0.4 m from where the whole-body plan had placed them).
        t0, t1 = min(float(times[0]), self.anchor_time), float(max(times[-1], times[0]))
        self.sample_feet(times, t0, t1, stance, positions, velocities)
        return stance, positions, velocities

    def sample_feet(
        self,
        times: np.ndarray,
        t0: float,
        t1: float,
        stance: np.ndarray,
        positions: np.ndarray,
        velocities: np.ndarray,
    ) -> None:
        """``feet`` into given arrays: the swings overlapping ``[t0, t1]`` (``_swings``) with their Raibert
        footholds (``foothold``) and Bezier curves, all feet in one compiled call
        (``reference.kernels.sample_feet``)."""
        phase_starts, phase_ends, phase_flags = self._phase_arrays(t0, t1)
        self._set_anchor()
        parameters = self._feet_parameters
        parameters[0] = self.raibert_gain
        parameters[1:3] = self.measured_velocity_xy
        parameters[3:5] = self.foothold_box
        parameters[5] = self.robot.foot_radius
        parameters[6] = self.swing_height
        parameters[12] = self.swing_lift
        clearance = self.touchdown_clearance
        parameters[13] = self.swing_height if clearance is None else clearance
        if self.ground is not None:
            parameters[7] = self.ground.height
            parameters[8:10] = self.ground.slope
            parameters[10:12] = self.ground.centre
        profile = self.profile
        terrain = self.terrain if self.terrain is not None else _NO_TERRAIN
        sample_feet(
            np.ascontiguousarray(times, dtype=float),
            t0,
            t1,
            phase_starts,
            phase_ends,
            phase_flags,
            self.stance_positions,
            self.liftoff_positions,
            self._anchor,
            profile.time_array,
            profile.start_array,
            profile.slope_array,
            _GAUSS_NODE_ARRAY,
            _GAUSS_WEIGHT_ARRAY,
            np.ascontiguousarray(self.offsets, dtype=float),
            parameters,
            terrain.parameters,
            terrain.heights,
            terrain.footholds,
            self._held_footholds,
            stance,
            positions,
            velocities,
        )

    def _set_anchor(self) -> None:
        """``(anchor_time, x, y, yaw)`` into the array the kernels read."""
        anchor = self._anchor
        anchor[0] = self.anchor_time
        anchor[1] = self.anchor_xy[0]
        anchor[2] = self.anchor_xy[1]
        anchor[3] = self.anchor_yaw

    def stance_torque(self, stance: Sequence[bool], support_factor: float) -> np.ndarray:
        """Torques holding the standing pose with ``support_factor * m g`` on each stance foot (zero in
        flight); cached per stance and factor."""
        key = (tuple(stance), round(float(support_factor), 6))
        torque = self._stance_torques.get(key)
        if torque is None:
            key = (tuple(bool(s) for s in stance), key[1])
            if any(key[0]):
                force = key[1] * self.mass * GRAVITY
                torque = static_stance_torques(self.robot, self.robot.q_standing, np.array(key[0]), force)
            else:
                torque = np.zeros(self.robot.nu)
            torque.setflags(write=False)
            self._stance_torques[key] = torque
        return torque

    def sample(self, window: ReferenceWindow) -> None:
        """Fill ``window`` (see ``Reference.sample``): stance, feet, base from the commands, joints from leg
        inverse kinematics (on ``window.joint_rows``), torque and GRF references from the gait's average
        stance load. All times at once in compiled kernels (``reference.kernels``): the values of
        ``stance_at``, ``support_factor``, ``stance_torque`` and ``foothold``, and the base of ``base_state``
        (rotated with plain products, where ``base_state`` uses numpy's, so equal up to the last bit)."""
        times = window.times
        nq = self.robot.nq
        positions, velocities = window.foot_positions, window.foot_velocities
        n = len(times)
        if n:
            if self._feet_stance.shape[0] < n:
                self._feet_stance = np.zeros((window.capacity, self.robot.n_feet), dtype=bool)
            t0 = min(float(times[0]), self.anchor_time)
            t1 = float(max(times[-1], times[0]))
            self.sample_feet(times, t0, t1, self._feet_stance, positions, velocities)
        state = window.state
        if n:
            # base_state, stance_at, support_factor and stance_torque of every time, compiled
            if self._keys.shape[0] < n:
                self._factors = np.zeros(window.capacity)
                self._keys = np.zeros(window.capacity, dtype=np.int64)
            factors, keys = self._factors[:n], self._keys[:n]
            gaits, phase_ends, phase_flags = self._gait_tables()
            self._set_anchor()
            profile = self.profile
            state[:, nq + 6 :] = 0.0
            sample_base(
                times,
                self._anchor,
                profile.time_array,
                profile.start_array,
                profile.slope_array,
                _GAUSS_NODE_ARRAY,
                _GAUSS_WEIGHT_ARRAY,
                gaits,
                phase_ends,
                phase_flags,
                self._stand[0],
                self._stand[1],
                STANCE_TIME_EPS,
                TIME_TOLERANCE,
                nq,
                state,
                window.stance,
                factors,
                keys,
            )
            state[:, 7:nq] = self.nominal_joints
            self._follow_ground(state[:n])
            self._torques_into(keys, window.torque)
            window.forces[:, :, :2] = 0.0
            window.forces[:, :, 2] = window.stance * (factors * self.mass * GRAVITY)[:, None]
        # joint references by leg inverse kinematics where they are used (``ReferenceWindow.joint_rows``;
        # the other rows keep the nominal joints and zero rates written above)
        m = window.joint_rows
        if self._ik_errors.shape[0] < m:
            self._ik_joints = np.zeros((window.capacity, self.robot.nu))
            self._ik_rates = np.zeros((window.capacity, self.robot.nu))
            self._ik_errors = np.zeros(window.capacity)
        out = (self._ik_joints[:m], self._ik_rates[:m], self._ik_errors[:m])
        joints, rates, _ = self.inverse_kinematics.solve_batch(
            state[:m, :7], positions[:m], None, state[:m, nq : nq + 6], velocities[:m], out=out
        )
        state[:m, 7:nq] = joints
        state[:m, nq + 6 :] = rates
        window.weight_set[:] = 0

    def support_factor(self, t: float) -> float:
        """Vertical force of a stance foot at ``t`` in units of the weight, averaged over the gait cycle
        (``GaitCycle.support_factor``: 1/2 trotting, 1 bounding); 1/4 during the initial stand."""
        if self._standing(t):
            return 1.0 / self.robot.n_feet
        return self._segment_at(t).support_factor

    def normal_forces(self, stance: np.ndarray, times: Sequence[float] | None = None) -> np.ndarray:
        """GRF reference (n, n_feet, 3): vertical, ``support_factor * m g`` on each stance foot (the weight
        shared by the stance feet when the gait has no flight), zero on swing feet.

        Without ``times`` the weight is split over the stance feet of each row (static balance).
        """
        stance = np.atleast_2d(stance)
        forces = np.zeros((*stance.shape, 3))
        if times is None:
            count = stance.sum(axis=1, keepdims=True)
            share = np.where(count > 0, self.mass * GRAVITY / np.maximum(count, 1), 0.0)
        else:
            share = np.array([[self.support_factor(float(t)) * self.mass * GRAVITY] for t in times])
        forces[..., 2] = np.where(stance, share, 0.0)
        return forces


NORMAL_STEP = math.radians(2.0)
"""rad; how far the height map's normal under the feet turns before the pyramids follow it (and within it of
world z they are level): above the half degree the map's 5 mm noise tilts it by."""

_WORLD_Z = np.array([0.0, 0.0, 1.0])

_NO_TERRAIN = TerrainMap(TerrainMapSettings())
"""No map: what the compiled sampling reads on flat ground and blind (``TerrainMap`` before ``place``)."""


def _add_phase(pieces: list[ContactPhase], stance: tuple[bool, ...], a: float, b: float) -> None:
    """Append the phase ``stance`` on ``[a, b)`` to ``pieces`` (nothing if shorter than ``TIME_TOLERANCE``),
    merged into the last one when that has the same flags and ends at ``a``."""
    if b - a <= TIME_TOLERANCE:
        return
    if pieces and pieces[-1].stance == stance and abs(pieces[-1].end - a) <= TIME_TOLERANCE:
        pieces[-1] = ContactPhase(stance, pieces[-1].start, b)
    else:
        pieces.append(ContactPhase(stance, a, b))


def _quaternion_matrix(quaternion_xyzw: np.ndarray) -> np.ndarray:
    x, y, z, w = quaternion_xyzw / np.linalg.norm(quaternion_xyzw)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
