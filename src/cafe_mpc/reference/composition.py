"""References joined in time, with x, y and yaw offsets (paper Sec. VII-C and the Appendix).

The paper composes its task references "by simply connecting the two types of references in proper order
without special care on motion transitions" (Sec. VII-C): locomotion references "are placed ahead and/or
appended to the in-place barrel roll trajectory with simple manipulations, for instance, the roll angles
of the appending trajectory are shifted by 2 pi" (Appendix); the CAFE-MPC smooths the seams online.
``ComposedReference`` does this for any ``Reference`` s:

* segment ``i`` covers ``[T_i, T_i + duration_i)`` of the composed time (``T_0 = 0``); the last one may be
  open-ended. The segment's reference sees its own time ``t - T_i``;
* each segment is placed in the world by a planar offset ``(x, y, yaw)``: positions ``R(yaw) p + (x, y)``,
  base quaternions ``q_yaw * q``, world foot positions, foot velocities and GRFs rotated; base-frame twists,
  joints and torques unchanged. ``None`` (the default) joins the segment where the previous one ends: the
  offset maps the segment's start pose (x, y, heading) onto the previous segment's end pose;
* orientation is carried on the quaternion, whose double cover distinguishes a rotation by 2 pi (``-q``)
  from none (``q``). Instead of shifting Euler angles by 2 pi, each segment's quaternions are multiplied by
  the sign that makes its first quaternion continuous with the previous segment's last one, so after a
  barrel roll (which ends on ``-q``) the appended standing reference continues on ``-q``: the roll count
  read from the quaternions (``2 atan2(q_x, q_w)`` about the roll axis) stays continuous and nothing asks
  the robot to unwind. (The MPC's orientation costs use ``log3(R_ref' R)``, which is sign-invariant, so the
  sign only matters to anything that reads the roll count off the reference.)
* ``update(t, q, v)`` goes to the active segment only, with the measured state expressed in that segment's
  frame (the offset undone), so a reference that re-anchors on the measurement (the locomotion reference)
  works unchanged inside a composition. Segments that have not started yet keep their initial anchor.
* weight sets: the union of the segments' ``weight_sets`` in order of first appearance; a segment may
  override all of its knots' weight set (``weight_set``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cafe_mpc.reference.base import STANCE_TIME_EPS, Reference, ReferenceWindow, switches_inside
from cafe_mpc.reference.kernels import place_configurations
from cafe_mpc.reference.trajectory import TrajectoryReference

Offset = tuple[float, float, float]
"""Planar placement ``(x, y, yaw)`` of a segment (m, m, rad)."""


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` of quaternions (x, y, z, w); ``b`` may be (N, 4)."""
    ax, ay, az, aw = a
    b = np.asarray(b, dtype=float)
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def yaw_quaternion(yaw: float) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation by ``yaw`` about the world z axis."""
    return np.array([0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)])


def heading(quaternion_xyzw: np.ndarray) -> float:
    """Heading of a base orientation: the angle of its x axis projected on the ground (rad). Unlike a ZYX
    yaw it does not flip by pi when the body rolls past pi/2 (the body x axis stays near the ground plane
    only if the pitch is small; a body pointing straight up has no heading and gives 0)."""
    x, y, z, w = quaternion_xyzw
    axis_x = 1.0 - 2.0 * (y * y + z * z)
    axis_y = 2.0 * (x * y + z * w)
    if math.hypot(axis_x, axis_y) < 1e-9:
        return 0.0
    return math.atan2(axis_y, axis_x)


@dataclass
class Segment:
    """One reference of a composition: its start and duration in composed time, its planar offset and the
    sign of its quaternions (``None`` offset until resolved)."""

    reference: Reference
    start: float
    duration: float
    offset: Offset | None = None
    weight_set: str | None = None
    sign: float = 1.0

    @property
    def end(self) -> float:
        return self.start + self.duration


class ComposedReference(Reference):
    """A sequence of references joined in time (see the module docstring).

    Args:
        segments: ``(reference, duration)`` pairs in time order; ``duration`` in seconds, ``None`` only for
            the last one (it then lasts forever). A ``TrajectoryReference`` segment typically lasts its
            ``end_time``.
        offsets: one ``(x, y, yaw)`` or ``None`` per segment (``None`` or omitted: join where the previous
            segment ends; the first segment's ``None`` means no offset).
        weight_sets: one weight-set name or ``None`` per segment: ``None`` keeps the segment's own.
        nq, nv, nu, n_feet: dimensions of the robot (for the segments' sampling windows).
        rejoin: re-join the segments without an explicit offset at every ``update``: each one that has not
            started yet is placed where the segment before it now ends (the active segment's end as
            predicted after its own update, e.g. a locomotion reference re-anchored on the measurement).
            Without it (default) the joins are fixed at construction, from the segments' initial anchors.
    """

    def __init__(
        self,
        segments: Sequence[tuple[Reference, float | None]],
        nq: int,
        nv: int,
        nu: int,
        n_feet: int,
        offsets: Sequence[Offset | None] | None = None,
        weight_sets: Sequence[str | None] | None = None,
        rejoin: bool = False,
    ) -> None:
        if not segments:
            raise ValueError("a composed reference needs at least one segment")
        offsets = list(offsets) if offsets is not None else [None] * len(segments)
        overrides = list(weight_sets) if weight_sets is not None else [None] * len(segments)
        if len(offsets) != len(segments) or len(overrides) != len(segments):
            raise ValueError(
                f"composed reference: {len(segments)} segments but {len(offsets)} offsets and "
                f"{len(overrides)} weight sets"
            )
        self.nq, self.nv, self.nu, self.n_feet = nq, nv, nu, n_feet
        self.rejoin = bool(rejoin)
        self.segments: list[Segment] = []
        self._auto: list[bool] = []  # segments placed by joining (no explicit offset)
        start = 0.0
        for index, ((reference, duration), offset, override) in enumerate(
            zip(segments, offsets, overrides, strict=True)
        ):
            last = index == len(segments) - 1
            if duration is None:
                if not last:
                    raise ValueError(
                        f"composed reference: segment {index} needs a duration (only the last "
                        "one may be open-ended)"
                    )
                duration = math.inf
            if not duration > 0:
                raise ValueError(f"composed reference: segment {index} duration must be > 0, got {duration}")
            if offset is not None:
                offset = tuple(float(value) for value in offset)
                if len(offset) != 3 or not all(math.isfinite(value) for value in offset):
                    raise ValueError(f"composed reference: segment {index} offset must be finite (x, y, yaw)")
            self.segments.append(Segment(reference, start, float(duration), offset, override))
            self._auto.append(offset is None)
            start += duration
        names: list[str] = []
        for segment in self.segments:
            for name in (segment.weight_set,) if segment.weight_set else segment.reference.weight_sets:
                if name not in names:
                    names.append(name)
        self.weight_sets = tuple(names)
        self._thresholds = np.array([segment.start - 1e-12 for segment in self.segments])
        """``segment_at``'s comparisons as an array: segment ``i`` is active from ``_thresholds[i]`` on."""
        self._weight_maps = [
            np.array([names.index(name) for name in segment.reference.weight_sets], dtype=np.int64)
            if segment.weight_set is None
            else None
            for segment in self.segments
        ]
        """Per segment without a weight-set override: its weight-set indices mapped to the composition's."""
        self._windows: dict[int, ReferenceWindow] = {}
        self._probe = ReferenceWindow(1, nq, nv, nu, n_feet)
        self._trajectory_poses: dict[tuple[int, float], np.ndarray] = {}
        """``_local_pose`` of the stored-trajectory segments by (reference id, local time): fixed poses."""
        self._resolve_offsets()

    # -------------------------------------------------------------------------------------- placement
    def _local_pose(self, segment: Segment, local_time: float) -> np.ndarray:
        """The segment's reference configuration at its own time ``local_time``, in its own frame (only its
        base pose matters to the joins: a reference with a closed-form ``base_state(t)``, the locomotion
        reference, is asked for that instead of a full sample with leg inverse kinematics)."""
        base_state = getattr(segment.reference, "base_state", None)
        if base_state is not None:
            return np.array(base_state(local_time)[0], dtype=float)
        fixed = isinstance(segment.reference, TrajectoryReference)
        if fixed:  # a stored trajectory: the same pose at every update (the re-joins ask at every one)
            pose = self._trajectory_poses.get((id(segment.reference), local_time))
            if pose is not None:
                return pose.copy()
        probe = self._probe
        probe.set_times(np.array([local_time]))
        segment.reference.sample(probe)
        pose = probe.state[0, : self.nq].copy()
        if fixed:
            self._trajectory_poses[(id(segment.reference), local_time)] = pose.copy()
        return pose

    def _placed(self, segment: Segment, q: np.ndarray) -> np.ndarray:
        """A copy of the configuration ``q`` placed in the world by the segment's current offset and sign."""
        q = q.copy()
        self._place_configuration(segment, q[None, :])
        return q

    def _pose_of(self, segment: Segment, local_time: float) -> np.ndarray:
        """The segment's reference configuration at its own time ``local_time``, placed in the world."""
        return self._placed(segment, self._local_pose(segment, local_time))

    def _resolve_offsets(self, first: int = 0) -> None:
        """Offsets of the joined segments (continuous join) and the quaternion signs of the segments from
        ``first + 1`` on (``first`` itself keeps its placement when ``first > 0``)."""
        previous_end: np.ndarray | None = None  # the previous segment's last configuration, placed
        for index, segment in enumerate(self.segments):
            if index < first:
                continue
            if index == first and first > 0:
                previous_end = self._pose_of(segment, segment.duration)
                continue
            segment.sign = 1.0
            local_start = self._local_pose(segment, 0.0) if previous_end is not None else None
            if self._auto[index]:
                segment.offset = (0.0, 0.0, 0.0)
                if previous_end is not None:  # map this segment's start pose onto the previous end pose
                    assert local_start is not None
                    start = self._placed(segment, local_start)
                    yaw = heading(previous_end[3:7]) - heading(start[3:7])
                    c, s = math.cos(yaw), math.sin(yaw)
                    xy = previous_end[:2] - np.array([[c, -s], [s, c]]) @ start[:2]
                    segment.offset = (float(xy[0]), float(xy[1]), float(yaw))
            if previous_end is not None:  # stay on the previous segment's side of the double cover
                assert local_start is not None
                start = self._placed(segment, local_start)
                segment.sign = -1.0 if float(np.dot(start[3:7], previous_end[3:7])) < 0.0 else 1.0
            if index < len(self.segments) - 1:
                previous_end = self._pose_of(segment, segment.duration)

    def _place_configuration(self, segment: Segment, q: np.ndarray) -> None:
        """Rows of configurations (N, nq) from the segment's frame into the world, in place (compiled:
        ``reference.kernels.place_configurations``)."""
        x, y, yaw = segment.offset or (0.0, 0.0, 0.0)
        place_configurations(q, float(x), float(y), float(yaw), float(segment.sign))

    def offset_of(self, index: int) -> Offset:
        """The resolved ``(x, y, yaw)`` offset of segment ``index``."""
        return self.segments[index].offset or (0.0, 0.0, 0.0)

    # ------------------------------------------------------------------------------------------- time
    def segment_at(self, t: float) -> int:
        """Index of the segment active at composed time ``t`` (the first before its start)."""
        for index in range(len(self.segments) - 1, -1, -1):
            if t >= self.segments[index].start - 1e-12:
                return index
        return 0

    @property
    def end_time(self) -> float:
        last = self.segments[-1]
        return min(last.end, last.start + last.reference.end_time)

    def stance_at(self, t: float) -> tuple[bool, ...]:
        segment = self.segments[self.segment_at(t)]
        return segment.reference.stance_at(t - segment.start)

    def switch_times(self, t0: float, t1: float) -> list[float]:
        """Contact switches in ``(t0, t1)``: each segment's own inside its time span, and the joins where
        the flags change."""
        times: list[float] = []
        for index, segment in enumerate(self.segments):
            start, end = segment.start, segment.end
            if end <= t0 or start >= t1:
                continue
            low, high = max(t0, start), min(t1, end)
            times += [segment.start + s for s in segment.reference.switch_times(low - start, high - start)]
            if index > 0 and t0 < start < t1:
                before = self.segments[index - 1]
                if before.reference.stance_at(start - before.start - STANCE_TIME_EPS) != (
                    segment.reference.stance_at(STANCE_TIME_EPS)
                ):
                    times.append(start)
        return switches_inside(times, t0, t1)

    def update(self, t: float, q: np.ndarray, v: np.ndarray) -> None:
        """Pass the measurement to the active segment, expressed in its frame (offset undone)."""
        index = self.segment_at(t)
        segment = self.segments[index]
        local = np.array(q, dtype=float)
        x, y, yaw = segment.offset or (0.0, 0.0, 0.0)
        if x or y or yaw:
            c, s = math.cos(yaw), math.sin(yaw)
            dx, dy = local[0] - x, local[1] - y
            local[0] = c * dx + s * dy
            local[1] = -s * dx + c * dy
            # quaternion_multiply(yaw_quaternion(-yaw), local[3:7]) on plain floats (the same operations)
            ax, ay, az, aw = 0.0, 0.0, math.sin(0.5 * -yaw), math.cos(0.5 * -yaw)
            bx, by, bz, bw = (float(value) for value in local[3:7])
            local[3] = aw * bx + ax * bw + ay * bz - az * by
            local[4] = aw * by - ax * bz + ay * bw + az * bx
            local[5] = aw * bz + ax * by - ay * bx + az * bw
            local[6] = aw * bw - ax * bx - ay * by - az * bz
        if segment.sign < 0:
            local[3:7] *= -1.0
        segment.reference.update(t - segment.start, local, v)
        if self.rejoin and index < len(self.segments) - 1:
            self._resolve_offsets(index)

    # ------------------------------------------------------------------------------------------ sample
    def _window(self, capacity: int) -> ReferenceWindow:
        window = self._windows.get(capacity)
        if window is None:
            window = ReferenceWindow(capacity, self.nq, self.nv, self.nu, self.n_feet)
            self._windows[capacity] = window
        return window

    def sample(self, window: ReferenceWindow) -> None:
        """Each segment samples its share of ``window.times`` in its own time; the results are placed in
        the world (offset, quaternion sign) and their weight-set indices mapped to the composition's."""
        times = window.times
        if window.n == 0:
            return
        local = self._window(window.capacity)
        nq = self.nq
        owner = np.searchsorted(self._thresholds, times, side="right") - 1  # segment_at of every time
        np.maximum(owner, 0, out=owner)
        if owner[0] == owner[-1] and bool(np.all(owner == owner[0])):
            groups: list[tuple[int, slice | np.ndarray]] = [(int(owner[0]), slice(0, window.n))]
        else:
            groups = []
            for index in np.unique(owner).tolist():
                rows = np.flatnonzero(owner == index)
                if rows[-1] - rows[0] + 1 == len(rows):
                    groups.append((index, slice(int(rows[0]), int(rows[-1]) + 1)))
                else:
                    groups.append((index, rows))
        for index, rows in groups:
            segment = self.segments[index]
            # the rows of a segment are in window order, so the ones that need joints come first
            if isinstance(rows, slice):
                joint_rows = min(rows.stop, window.joint_rows) - rows.start
            else:
                joint_rows = int(np.count_nonzero(rows < window.joint_rows))
            local.set_times(times[rows] - segment.start, joint_rows)
            segment.reference.sample(local)
            state = local.state
            self._place_configuration(segment, state[:, :nq])
            x, y, yaw = segment.offset or (0.0, 0.0, 0.0)
            feet, feet_velocity, forces = local.foot_positions, local.foot_velocities, local.forces
            if x or y or yaw:
                c, s = math.cos(yaw), math.sin(yaw)
                rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
                feet = feet @ rotation.T + np.array([x, y, 0.0])
                feet_velocity = feet_velocity @ rotation.T
                forces = forces @ rotation.T
            window.state[rows] = state
            window.stance[rows] = local.stance
            window.torque[rows] = local.torque
            window.forces[rows] = forces
            window.foot_positions[rows] = feet
            window.foot_velocities[rows] = feet_velocity
            if segment.weight_set is not None:
                window.weight_set[rows] = self.weight_sets.index(segment.weight_set)
            else:
                mapping = self._weight_maps[index]
                assert mapping is not None
                window.weight_set[rows] = mapping[local.weight_set]
