"""Compiled (numba) sampling of the references.

Every MPC update samples its reference at some forty to seventy knot times. In Python, the per-time work
(the base integrated from the anchor, the contact flags, the swings with their Raibert footholds and Bezier
curves, a stored trajectory's interpolation, a composition's placement) cost more than the rest of building
the problem. Here each reference samples all its times in one or two calls:

* ``sample_base`` and ``sample_feet``: ``LocomotionReference.sample`` (base, flags, loads; swings, footholds,
  feet), the swing of one foot being ``sample_foot``;
* ``sample_trajectory``: ``TrajectoryReference.sample``;
* ``place_configurations``: a ``ComposedReference`` segment's configurations placed in the world.

Each does the arithmetic of the Python it replaces in the same order, so the samples are the same to the
last bit: where that Python multiplied through numpy (a 2 x 2 rotation ``@`` a vector, a quaternion ``dot``),
the kernels round as numpy's BLAS does, with one fused multiply-add per term (``_rotate``, ``_dot4``). The
last bit matters: the joint-rate references of a nearly straight leg amplify a foot target's last bit by up
to 1e12.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types
from numba.extending import intrinsic


@njit(cache=True, nogil=True)
def _bezier(s: float) -> tuple[float, float]:
    """Cubic Bezier with control points (0, 0, 1, 1): ``3s^2 - 2s^3`` and its derivative (``s`` clamped)."""
    s = min(max(s, 0.0), 1.0)
    return 3.0 * s * s - 2.0 * s * s * s, 6.0 * s - 6.0 * s * s


@njit(cache=True, nogil=True)
def sample_foot(
    times: np.ndarray,
    liftoffs: np.ndarray,
    touchdowns: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    stance_position: np.ndarray,
    swing_height: float,
    foot: int,
    stance: np.ndarray,
    positions: np.ndarray,
    velocities: np.ndarray,
) -> None:
    """One foot's reference at ``times`` from its swing segments ``[liftoffs[j], touchdowns[j])`` (from
    ``starts[j]`` to ``ends[j]``, ordered in time): on a segment, the Bezier swing (planar blend, apex
    ``swing_height`` above the higher end at mid-swing, zero velocity at both ends); elsewhere stance on the
    end of the last segment that touched down before ``t`` (``stance_position`` before any). Writes column
    ``foot`` of ``stance`` (n, n_feet), ``positions`` and ``velocities`` (n, n_feet, 3)."""
    floors = np.full(liftoffs.shape[0], -np.inf)
    sample_foot_floored(
        times,
        liftoffs,
        touchdowns,
        starts,
        ends,
        stance_position,
        swing_height,
        floors,
        0.0,
        swing_height,
        foot,
        stance,
        positions,
        velocities,
    )


@njit(cache=True, nogil=True)
def sample_foot_floored(
    times: np.ndarray,
    liftoffs: np.ndarray,
    touchdowns: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    stance_position: np.ndarray,
    swing_height: float,
    apex_floors: np.ndarray,
    lift: float,
    touchdown_clearance: float,
    foot: int,
    stance: np.ndarray,
    positions: np.ndarray,
    velocities: np.ndarray,
) -> None:
    """``sample_foot`` with each swing's apex at least ``apex_floors[j]`` (world z; -inf: no floor): a
    swing over terrain higher than its ends clears it. Without a floor the apex is ``swing_height`` above
    the lift-off and ``touchdown_clearance`` above the touchdown, whichever is higher (with both equal,
    ``swing_height`` above the higher end). With ``lift`` > 0 the foot's horizontal Bezier starts after that
    fraction of the swing (the foot rises off a riser it stands against before it moves toward it) and ends
    with it."""
    tolerance = 1e-9
    for i in range(times.shape[0]):
        t = times[i]
        px, py, pz = stance_position[0], stance_position[1], stance_position[2]
        in_swing = False
        for j in range(liftoffs.shape[0]):
            liftoff, touchdown = liftoffs[j], touchdowns[j]
            if liftoff - tolerance <= t < touchdown - tolerance:
                in_swing = True
                duration = touchdown - liftoff
                s = (t - liftoff) / duration
                if lift > 0.0:
                    moving = max(s - lift, 0.0) / (1.0 - lift)
                    blend, dblend = _bezier(moving)
                    dblend /= 1.0 - lift
                else:
                    blend, dblend = _bezier(s)
                for a in range(2):
                    delta = ends[j, a] - starts[j, a]
                    positions[i, foot, a] = starts[j, a] + delta * blend
                    velocities[i, foot, a] = delta * dblend / duration
                z0, z1 = starts[j, 2], ends[j, 2]
                apex = max(max(z0 + swing_height, z1 + touchdown_clearance), apex_floors[j])
                if s < 0.5:
                    blend, dblend = _bezier(2.0 * s)
                    positions[i, foot, 2] = z0 + (apex - z0) * blend
                    velocities[i, foot, 2] = (apex - z0) * dblend * 2.0 / duration
                else:
                    blend, dblend = _bezier(2.0 * s - 1.0)
                    positions[i, foot, 2] = apex + (z1 - apex) * blend
                    velocities[i, foot, 2] = (z1 - apex) * dblend * 2.0 / duration
                break
            if t >= touchdown - tolerance:
                px, py, pz = ends[j, 0], ends[j, 1], ends[j, 2]
        stance[i, foot] = not in_swing
        if not in_swing:
            positions[i, foot, 0] = px
            positions[i, foot, 1] = py
            positions[i, foot, 2] = pz
            for a in range(3):
                velocities[i, foot, a] = 0.0


# ------------------------------------------------------------------------------- commands and base pose
@njit(cache=True, nogil=True)
def _command_segment(profile_times: np.ndarray, t: float) -> int:
    """``CommandProfile._segment``: the last breakpoint at or before ``t + 1e-12`` (0 before the first)."""
    low, high = 0, profile_times.shape[0]
    key = t + 1e-12
    while low < high:  # bisect_right
        middle = (low + high) // 2
        if key < profile_times[middle]:
            high = middle
        else:
            low = middle + 1
    return max(low - 1, 0)


@njit(cache=True, nogil=True)
def command_values(
    profile_times: np.ndarray, profile_starts: np.ndarray, profile_slopes: np.ndarray, t: float, axis: int
) -> float:
    """``CommandProfile.values_at(t)[axis]`` (the same arithmetic, so the same floats)."""
    index = _command_segment(profile_times, t)
    dt = max(t - profile_times[index], 0.0)
    return profile_starts[index, axis] + profile_slopes[index, axis] * dt


@njit(cache=True, nogil=True)
def displacement(
    profile_times: np.ndarray,
    profile_starts: np.ndarray,
    profile_slopes: np.ndarray,
    gauss_nodes: np.ndarray,
    gauss_weights: np.ndarray,
    t0: float,
    t1: float,
) -> tuple[float, float, float]:
    """``CommandProfile.displacement_floats``: heading-frame ``(x, y, yaw)`` change from ``t0`` to ``t1``,
    term for term (closed form on constant commands, Gauss-Legendre on ramps)."""
    x = y = yaw = 0.0
    time = t0
    index = _command_segment(profile_times, t0)
    count = profile_times.shape[0]
    while time < t1 - 1e-15:
        following = profile_times[index + 1] if index + 1 < count else np.inf
        boundary = min(following, t1)
        dt = boundary - time
        if dt > 1e-15:
            offset = max(time - profile_times[index], 0.0)
            vx = profile_starts[index, 0] + profile_slopes[index, 0] * offset
            vy = profile_starts[index, 1] + profile_slopes[index, 1] * offset
            w = profile_starts[index, 2] + profile_slopes[index, 2] * offset
            ax, ay, aw = profile_slopes[index, 0], profile_slopes[index, 1], profile_slopes[index, 2]
            if ax == 0.0 and ay == 0.0 and aw == 0.0:
                c0, s0 = math.cos(yaw), math.sin(yaw)
                if abs(w) < 1e-9:
                    x += (c0 * vx - s0 * vy) * dt
                    y += (s0 * vx + c0 * vy) * dt
                else:
                    c1, s1 = math.cos(yaw + w * dt), math.sin(yaw + w * dt)
                    x += ((s1 - s0) * vx + (c1 - c0) * vy) / w
                    y += (-(c1 - c0) * vx + (s1 - s0) * vy) / w
                    yaw += w * dt
            else:
                for g in range(gauss_nodes.shape[0]):
                    s = 0.5 * dt * (gauss_nodes[g] + 1.0)
                    heading = yaw + w * s + 0.5 * aw * s * s
                    ux, uy = vx + ax * s, vy + ay * s
                    c, si = math.cos(heading), math.sin(heading)
                    x += 0.5 * dt * gauss_weights[g] * (c * ux - si * uy)
                    y += 0.5 * dt * gauss_weights[g] * (si * ux + c * uy)
                yaw += w * dt + 0.5 * aw * dt * dt
        time = boundary
        index += 1
    return x, y, yaw


@njit(cache=True, nogil=True)
def _gait_segment(gaits: np.ndarray, segments: int, t: float, time_tolerance: float) -> int:
    """The last gait segment (row of ``gaits``, start time in column 0) started by ``t``; 0 before any."""
    for segment in range(segments - 1, 0, -1):
        if t >= gaits[segment, 0] - time_tolerance:
            return segment
    return 0


@njit(cache=True, nogil=True)
def sample_base(
    times: np.ndarray,
    anchor: np.ndarray,
    profile_times: np.ndarray,
    profile_starts: np.ndarray,
    profile_slopes: np.ndarray,
    gauss_nodes: np.ndarray,
    gauss_weights: np.ndarray,
    gaits: np.ndarray,
    phase_ends: np.ndarray,
    phase_flags: np.ndarray,
    stand_from: float,
    stand_until: float,
    stance_eps: float,
    time_tolerance: float,
    nq: int,
    state: np.ndarray,
    stance: np.ndarray,
    factors: np.ndarray,
    keys: np.ndarray,
) -> None:
    """The locomotion reference's base, flags and load class at every time (``LocomotionReference.sample``).

    ``anchor`` = (time, x, y, yaw); all feet stand on ``[stand_from, stand_until)`` (the start stance, or a
    gait restart's stand: load class 0); ``gaits`` (segments, 5) = (start, cycle start, period, support
    factor, phases) of each gait in force (``_GaitSegment``), their cycles' phase ends and flags padded to
    ``phase_ends`` (segments, phases) and ``phase_flags`` (segments, phases, feet). Writes the base pose
    ``state[:, :7]`` and the base twist ``state[:, nq : nq + 6]``, the stance flags of the interval starting
    at each time, the support factor and ``keys``: ``load class * 2^feet + flag bits`` (load class 0: the
    stand, ``1 + s``: gait segment ``s``), the index of the knot's torque reference in the table
    the reference keeps.
    """
    anchor_time, anchor_x, anchor_y, anchor_yaw = anchor[0], anchor[1], anchor[2], anchor[3]
    cos_anchor, sin_anchor = math.cos(anchor_yaw), math.sin(anchor_yaw)
    n_feet = stance.shape[1]
    segments = gaits.shape[0]
    for i in range(times.shape[0]):
        t = times[i]
        # contact flags a hair after t (LocomotionReference.stance_at)
        flag_time = t + stance_eps
        code = 0
        if stand_from - 1e-9 <= flag_time < stand_until - 1e-9:
            for foot in range(n_feet):
                stance[i, foot] = True
                code |= 1 << foot
        else:
            segment = _gait_segment(gaits, segments, flag_time, time_tolerance)
            tau = (flag_time - gaits[segment, 1]) % gaits[segment, 2]
            phase = 0
            for p in range(int(gaits[segment, 4])):
                if tau < phase_ends[segment, p] - time_tolerance:
                    phase = p
                    break
            for foot in range(n_feet):
                flag = phase_flags[segment, phase, foot]
                stance[i, foot] = flag
                if flag:
                    code |= 1 << foot
        # support factor at t (LocomotionReference.support_factor)
        if stand_from - 1e-9 <= t < stand_until - 1e-9:
            load = 0
            factors[i] = 1.0 / n_feet
        else:
            segment = _gait_segment(gaits, segments, t, time_tolerance)
            load = 1 + segment
            factors[i] = gaits[segment, 3]
        keys[i] = (load << n_feet) + code
        # base pose from the anchor and the commands (LocomotionReference.base_state)
        x, y, turn = displacement(
            profile_times,
            profile_starts,
            profile_slopes,
            gauss_nodes,
            gauss_weights,
            anchor_time,
            max(t, anchor_time),
        )
        yaw = anchor_yaw + turn
        index = _command_segment(profile_times, t)
        dt = max(t - profile_times[index], 0.0)
        state[i, 0] = anchor_x + (cos_anchor * x - sin_anchor * y)
        state[i, 1] = anchor_y + (sin_anchor * x + cos_anchor * y)
        state[i, 2] = profile_starts[index, 3] + profile_slopes[index, 3] * dt
        state[i, 3] = 0.0
        state[i, 4] = 0.0
        state[i, 5] = math.sin(0.5 * yaw)
        state[i, 6] = math.cos(0.5 * yaw)
        for a in range(6):
            state[i, nq + a] = 0.0
        state[i, nq] = profile_starts[index, 0] + profile_slopes[index, 0] * dt
        state[i, nq + 1] = profile_starts[index, 1] + profile_slopes[index, 1] * dt
        state[i, nq + 5] = profile_starts[index, 2] + profile_slopes[index, 2] * dt


# ------------------------------------------------------------------------------------- swings and feet
@intrinsic
def _fused_multiply_add(typingctx, a, b, c):
    """``a * b + c`` rounded once (LLVM ``fma``)."""
    signature = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, sig, args):
        return builder.fma(*args)

    return signature, codegen


@njit(cache=True, nogil=True)
def _rotate(c: float, s: float, x: float, y: float) -> tuple[float, float]:
    """``[[c, -s], [s, c]] @ (x, y)`` rounded as numpy's ``@`` of a 2 x 2 and a 2-vector (OpenBLAS
    ``dgemv``: each row a product and one fused multiply-add), so that the footholds are the Python
    ``LocomotionReference.foothold``'s to the last bit: the joint-rate references of near-singular legs
    amplify a last-bit difference of a foot target by up to 1e12."""
    return _fused_multiply_add(c, x, -s * y), _fused_multiply_add(s, x, c * y)


@njit(cache=True, nogil=True)
def _base_pose(
    anchor: np.ndarray,
    profile_times: np.ndarray,
    profile_starts: np.ndarray,
    profile_slopes: np.ndarray,
    gauss_nodes: np.ndarray,
    gauss_weights: np.ndarray,
    t: float,
) -> tuple[float, float, float]:
    """``LocomotionReference.base_pose``: world (x, y, yaw) of the reference base at ``t`` (>= the anchor)."""
    anchor_time, anchor_yaw = anchor[0], anchor[3]
    t = max(t, anchor_time)
    x, y, turn = displacement(
        profile_times, profile_starts, profile_slopes, gauss_nodes, gauss_weights, anchor_time, t
    )
    dx, dy = _rotate(math.cos(anchor_yaw), math.sin(anchor_yaw), x, y)
    return anchor[1] + dx, anchor[2] + dy, anchor_yaw + turn


@njit(cache=True, nogil=True)
def _foothold(
    anchor: np.ndarray,
    profile_times: np.ndarray,
    profile_starts: np.ndarray,
    profile_slopes: np.ndarray,
    gauss_nodes: np.ndarray,
    gauss_weights: np.ndarray,
    offset: np.ndarray,
    parameters: np.ndarray,
    touchdown: float,
    stance_duration: float,
    out: np.ndarray,
) -> None:
    """``LocomotionReference.foothold``: the Raibert foothold (hip at mid-stance plus velocity feedback,
    clamped to the box about the hip at touchdown) into ``out`` (3). ``parameters`` = (Raibert gain,
    measured world vx, vy, box x, box y, foot radius, swing height, ground height, slope x, slope y, ground
    centre x, y: ``core.ground.GroundPlane``, zeros on flat ground)."""
    ox, oy = offset[0], offset[1]
    x, y, yaw = _base_pose(
        anchor, profile_times, profile_starts, profile_slopes, gauss_nodes, gauss_weights, touchdown
    )
    c, s = math.cos(yaw), math.sin(yaw)
    hip_x, hip_y = _rotate(c, s, ox, oy)
    nominal_x, nominal_y = x + hip_x, y + hip_y
    mx, my, mid_yaw = _base_pose(
        anchor,
        profile_times,
        profile_starts,
        profile_slopes,
        gauss_nodes,
        gauss_weights,
        touchdown + 0.5 * stance_duration,
    )
    hip_x, hip_y = _rotate(math.cos(mid_yaw), math.sin(mid_yaw), ox, oy)
    mid_x, mid_y = mx + hip_x, my + hip_y
    vx = command_values(profile_times, profile_starts, profile_slopes, touchdown, 0)
    vy = command_values(profile_times, profile_starts, profile_slopes, touchdown, 1)
    gain = parameters[0]
    commanded_x, commanded_y = _rotate(c, s, vx, vy)
    feedback_x = gain * (parameters[1] - commanded_x)
    feedback_y = gain * (parameters[2] - commanded_y)
    dx, dy = mid_x + feedback_x - nominal_x, mid_y + feedback_y - nominal_y
    step_x, step_y = _rotate(math.cos(-yaw), math.sin(-yaw), dx, dy)
    step_x = min(max(step_x, -parameters[3]), parameters[3])
    step_y = min(max(step_y, -parameters[4]), parameters[4])
    move_x, move_y = _rotate(c, s, step_x, step_y)
    out[0] = nominal_x + move_x
    out[1] = nominal_y + move_y
    # the ground plane under the foothold (zero on flat ground): height, slope x, y about its centre
    ground = parameters[7] + parameters[8] * (out[0] - parameters[10])
    ground += parameters[9] * (out[1] - parameters[11])
    out[2] = parameters[5] + ground


# ------------------------------------------------------------------------------------ terrain (height map)
TERRAIN_ENABLED, TERRAIN_ORIGIN_X, TERRAIN_ORIGIN_Y, TERRAIN_COS, TERRAIN_SIN = 0, 1, 2, 3, 4
TERRAIN_RESOLUTION, TERRAIN_SEARCH, TERRAIN_OFFSET, TERRAIN_CLEARANCE, TERRAIN_HOLD = 5, 6, 7, 8, 9
TERRAIN_PARAMETERS = 10
"""The ``terrain`` array of the kernels (``reference.terrain_map.TerrainMap``): a map in use (1) or none (0),
the grid's origin (world x, y of cell (0, 0)), the cosine and sine of its yaw, its resolution (m), how far a
foothold may move to a flat spot (m), a height offset added to every height read (m: how far the
estimator's frame moved since the map was placed), the clearance (m) a swing keeps above terrain that
rises above its ends' ground (a riser) and how much farther than the nearest flat spot (m) the one a swing's
foothold moved to before may be and be kept (0: the nearest at every sampling;
``terrain_map.foothold_hysteresis``)."""

HOLD_MATCH = 0.1
"""s; a held foothold (``sample_feet``'s ``held``) belongs to the swing whose touchdown is within this of the
touchdown it was chosen for: an early touchdown's phase advance moves it by less, the same foot's next swing
is a gait cycle later."""


@njit(cache=True, nogil=True)
def _map_cell(
    grid: np.ndarray, terrain: np.ndarray, x: float, y: float
) -> tuple[bool, int, int, float, float]:
    """Where world ``(x, y)`` falls on a grid placed by ``terrain``: whether inside the cell centres' span,
    the lower-left cell (row, column) of the four around it, and the fractional row and column (grid
    units from the grid's cell (0, 0))."""
    dx, dy = x - terrain[TERRAIN_ORIGIN_X], y - terrain[TERRAIN_ORIGIN_Y]
    cos, sin, resolution = terrain[TERRAIN_COS], terrain[TERRAIN_SIN], terrain[TERRAIN_RESOLUTION]
    column = (cos * dx + sin * dy) / resolution
    row = (-sin * dx + cos * dy) / resolution
    rows, columns = grid.shape
    tolerance = 1e-9
    inside = -tolerance <= column <= columns - 1 + tolerance and -tolerance <= row <= rows - 1 + tolerance
    c0 = min(max(math.floor(column), 0), max(columns - 2, 0)) if inside else 0
    r0 = min(max(math.floor(row), 0), max(rows - 2, 0)) if inside else 0
    return inside, r0, c0, row, column


@njit(cache=True, nogil=True)
def map_height(grid: np.ndarray, terrain: np.ndarray, x: float, y: float) -> float:
    """``core.height_map.HeightMap.height_at`` of a grid of heights (NaN: not seen) placed by ``terrain``:
    bilinear between the four cell centres around world ``(x, y)``, plus the offset; NaN outside the grid
    or next to a cell not seen."""
    inside, r0, c0, row, column = _map_cell(grid, terrain, x, y)
    if not inside:
        return np.nan
    rows, columns = grid.shape
    c1, r1 = min(c0 + 1, columns - 1), min(r0 + 1, rows - 1)
    fr = min(max(row - r0, 0.0), 1.0)
    fc = min(max(column - c0, 0.0), 1.0)
    low = (1.0 - fc) * grid[r0, c0] + fc * grid[r0, c1]
    high = (1.0 - fc) * grid[r1, c0] + fc * grid[r1, c1]
    return (1.0 - fr) * low + fr * high + terrain[TERRAIN_OFFSET]


@njit(cache=True, nogil=True)
def map_height_bound(grid: np.ndarray, terrain: np.ndarray, x: float, y: float) -> float:
    """The highest of the (seen) four cell centres around world ``(x, y)``, plus the offset: a bound on the
    terrain there that an edge between two cell centres cannot hide (the bilinear ``map_height`` ramps
    over it); NaN outside the grid or where none of the four was seen."""
    inside, r0, c0, _, _ = _map_cell(grid, terrain, x, y)
    if not inside:
        return np.nan
    rows, columns = grid.shape
    highest = -np.inf
    for r in range(r0, min(r0 + 1, rows - 1) + 1):
        for c in range(c0, min(c0 + 1, columns - 1) + 1):
            if math.isfinite(grid[r, c]) and grid[r, c] > highest:
                highest = grid[r, c]
    if not math.isfinite(highest):
        return np.nan
    return highest + terrain[TERRAIN_OFFSET]


@njit(cache=True, nogil=True)
def map_heights(
    grid: np.ndarray, terrain: np.ndarray, xs: np.ndarray, ys: np.ndarray, out: np.ndarray
) -> None:
    """``map_height`` at every ``(xs[i], ys[i])`` into ``out``."""
    for i in range(xs.shape[0]):
        out[i] = map_height(grid, terrain, xs[i], ys[i])


@njit(cache=True, nogil=True)
def terrain_foothold(
    heights: np.ndarray,
    footholds: np.ndarray,
    terrain: np.ndarray,
    foot_radius: float,
    out: np.ndarray,
    held_x: float = np.nan,
    held_y: float = np.nan,
) -> bool:
    """A planned foothold ``out`` (world x, y, z) onto the map: where the four cells around it are flat
    spots (``footholds``: a flat spot's height, NaN elsewhere; ``reference.terrain_map``) its height is
    theirs; else it moves to the nearest flat spot's centre within ``terrain[TERRAIN_SEARCH]`` m, or, over
    a hole (next to a cell the map did not see: a gap deeper than the sensor's range), to the cell under
    ``(held_x, held_y)`` (the spot this swing moved to at the last sampling) while that is a flat spot within
    reach and at most ``terrain[TERRAIN_HOLD]`` m farther than the nearest; with none there it stays, at the
    map's height (``heights``) if the map saw it, else at the height it had (the ground plane's). Whether it
    moved to a flat spot.

    Chosen afresh at every update, the nearest spot to a foothold over a gap flips from one side to the
    other as the Raibert foothold moves by a centimetre, and a plan that follows each update lands the foot
    between them, in the gap (the pronk's hind feet on 5 cm trenches). On a step's edge the foot lands on
    something either way, and holding the spot there cost the trot two of three starts over 10 cm steps at
    2 ms: the hold is for holes only."""
    z = map_height(footholds, terrain, out[0], out[1])
    if math.isfinite(z):
        out[2] = foot_radius + z
        return False
    cos, sin, resolution = terrain[TERRAIN_COS], terrain[TERRAIN_SIN], terrain[TERRAIN_RESOLUTION]
    dx, dy = out[0] - terrain[TERRAIN_ORIGIN_X], out[1] - terrain[TERRAIN_ORIGIN_Y]
    column = (cos * dx + sin * dy) / resolution
    row = (-sin * dx + cos * dy) / resolution
    reach = terrain[TERRAIN_SEARCH] / resolution
    rows, columns = footholds.shape
    best, best_row, best_column = reach * reach, -1, -1
    for r in range(max(math.floor(row - reach), 0), min(math.ceil(row + reach), rows - 1) + 1):
        for c in range(max(math.floor(column - reach), 0), min(math.ceil(column + reach), columns - 1) + 1):
            if not math.isfinite(footholds[r, c]):
                continue
            distance = (r - row) * (r - row) + (c - column) * (c - column)
            if distance <= best:
                best, best_row, best_column = distance, r, c
    seen = map_height(heights, terrain, out[0], out[1])  # NaN next to a hole
    hole = not math.isfinite(seen)
    if best_row >= 0 and hole and terrain[TERRAIN_HOLD] > 0.0 and math.isfinite(held_x + held_y):
        hx, hy = held_x - terrain[TERRAIN_ORIGIN_X], held_y - terrain[TERRAIN_ORIGIN_Y]
        r = round((-sin * hx + cos * hy) / resolution)
        c = round((cos * hx + sin * hy) / resolution)
        if 0 <= r < rows and 0 <= c < columns and math.isfinite(footholds[r, c]):
            distance = (r - row) * (r - row) + (c - column) * (c - column)
            if (
                distance <= reach * reach
                and math.sqrt(distance) <= math.sqrt(best) + terrain[TERRAIN_HOLD] / resolution
            ):
                best_row, best_column = r, c
    if best_row >= 0:
        along, across = best_column * resolution, best_row * resolution
        out[0] = terrain[TERRAIN_ORIGIN_X] + cos * along - sin * across
        out[1] = terrain[TERRAIN_ORIGIN_Y] + sin * along + cos * across
        out[2] = foot_radius + footholds[best_row, best_column] + terrain[TERRAIN_OFFSET]
        return True
    if not hole:
        out[2] = foot_radius + seen
    return False


MAX_SWING_LENGTH = 10.0
"""m; ``highest_between`` samples no longer segment (a bound on its work whatever the states)."""


@njit(cache=True, nogil=True)
def highest_between(heights: np.ndarray, terrain: np.ndarray, start: np.ndarray, end: np.ndarray) -> float:
    """The highest point the map saw on the segment from ``start`` to ``end`` (world x, y), sampled every
    half cell; -inf when it saw none of it (or the segment is not shorter than ``MAX_SWING_LENGTH``)."""
    dx, dy = end[0] - start[0], end[1] - start[1]
    length = math.sqrt(dx * dx + dy * dy)
    highest = -np.inf
    if not length < MAX_SWING_LENGTH:  # a step longer than any leg's (or not finite): no sampling
        return highest
    samples = math.ceil(length / (0.5 * terrain[TERRAIN_RESOLUTION])) + 1
    for i in range(samples + 1):
        s = i / samples
        z = map_height(heights, terrain, start[0] + s * dx, start[1] + s * dy)
        if math.isfinite(z) and z > highest:
            highest = z
    return highest


SWING_SAMPLES = 24
"""Times along a swing at which ``swing_apex_floor`` checks the terrain under the foot."""


@njit(cache=True, nogil=True)
def swing_apex_floor(
    heights: np.ndarray,
    terrain: np.ndarray,
    start: np.ndarray,
    end: np.ndarray,
    foot_radius: float,
    swing_height: float,
) -> float:
    """The lowest apex of a ``sample_foot`` swing from ``start`` to ``end`` (world, foot centres) over the
    map: ``swing_height`` above the highest point between its ends (``highest_between``) at mid-swing, and
    high enough that at every sampled time the foot passes ``terrain[TERRAIN_CLEARANCE]`` above terrain
    (``map_height_bound``: the highest cell around it) that rises above the ground of the swing's nearer
    end (a riser close to lift-off is met early in the rise, while the planar blend has moved little), at
    most ``swing_height`` more; -inf without a map under the swing."""
    highest = highest_between(heights, terrain, start, end)
    if not math.isfinite(highest):
        return -np.inf
    apex = foot_radius + highest + swing_height
    clearance = terrain[TERRAIN_CLEARANCE]
    floor = apex
    for k in range(1, SWING_SAMPLES):
        s = k / SWING_SAMPLES
        blend, _ = _bezier(s)
        z = map_height_bound(
            heights, terrain, start[0] + (end[0] - start[0]) * blend, start[1] + (end[1] - start[1]) * blend
        )
        if not math.isfinite(z):
            continue
        need = z + foot_radius + clearance
        if s < 0.5:
            lift, _ = _bezier(2.0 * s)
            if z > start[2] - foot_radius + 0.5 * clearance and need > start[2] and lift > 1e-9:
                floor = max(floor, start[2] + (need - start[2]) / lift)
        else:
            fall, _ = _bezier(2.0 * s - 1.0)
            if z > end[2] - foot_radius + 0.5 * clearance and need > end[2] and fall < 1.0 - 1e-9:
                floor = max(floor, (need - end[2] * fall) / (1.0 - fall))
    return min(floor, apex + swing_height)


@njit(cache=True, nogil=True)
def sample_feet(
    times: np.ndarray,
    t0: float,
    t1: float,
    phase_starts: np.ndarray,
    phase_ends: np.ndarray,
    phase_flags: np.ndarray,
    stance_positions: np.ndarray,
    liftoff_positions: np.ndarray,
    anchor: np.ndarray,
    profile_times: np.ndarray,
    profile_starts: np.ndarray,
    profile_slopes: np.ndarray,
    gauss_nodes: np.ndarray,
    gauss_weights: np.ndarray,
    offsets: np.ndarray,
    parameters: np.ndarray,
    terrain: np.ndarray,
    heights: np.ndarray,
    footholds: np.ndarray,
    held: np.ndarray,
    stance: np.ndarray,
    positions: np.ndarray,
    velocities: np.ndarray,
) -> None:
    """``LocomotionReference.sample_feet`` in one call: per foot, the swings of the schedule (phases
    ``phase_starts``, ``phase_ends``, ``phase_flags`` (phases, feet)) overlapping ``[t0, t1]``, each with
    the stance that follows it (``_swings``), their lift-off points (the measured lift-off point for a
    swing that started by the anchor, else the previous foothold) and Raibert footholds (``_foothold``),
    then the foot sampled at ``times`` (``sample_foot``). With a height map (``terrain``, ``heights``,
    ``footholds``: ``reference.terrain_map``) each foothold moves onto it (``terrain_foothold``) and each
    swing's apex clears the terrain between its ends (``swing_apex_floor``). ``held`` (feet, 3): per foot
    the touchdown time and world x, y of the flat spot its next touchdown moved to (NaN: none), written here
    and read at the next sampling when ``terrain[TERRAIN_HOLD]`` > 0 (``terrain_foothold``'s held spot)."""
    count = phase_starts.shape[0]
    liftoffs = np.empty(count)
    touchdowns = np.empty(count)
    starts = np.empty((count, 3))
    ends = np.empty((count, 3))
    floors = np.full(count, -np.inf)
    mapped = terrain[TERRAIN_ENABLED] > 0.0
    hold = mapped and terrain[TERRAIN_HOLD] > 0.0
    for foot in range(stance_positions.shape[0]):
        n_swings = 0
        next_touchdown = True
        start_position = stance_positions[foot]
        index = 0
        while index < count:
            if not phase_flags[index, foot]:
                start = phase_starts[index]
                end_index = index
                while end_index + 1 < count and not phase_flags[end_index + 1, foot]:
                    end_index += 1
                end = phase_ends[end_index]
                stance_duration = 0.0
                k = end_index + 1
                while k < count and phase_flags[k, foot]:
                    stance_duration += phase_ends[k] - phase_starts[k]
                    k += 1
                if end > t0 and start < t1:
                    j = n_swings
                    liftoffs[j], touchdowns[j] = start, end
                    source = liftoff_positions[foot] if start <= anchor[0] else start_position
                    for a in range(3):
                        starts[j, a] = source[a]
                    _foothold(
                        anchor,
                        profile_times,
                        profile_starts,
                        profile_slopes,
                        gauss_nodes,
                        gauss_weights,
                        offsets[foot],
                        parameters,
                        end,
                        max(stance_duration, 1e-3),
                        ends[j],
                    )
                    if mapped:
                        held_x = held_y = np.nan
                        keep = hold and next_touchdown and end > anchor[0]
                        if keep and abs(held[foot, 0] - end) <= HOLD_MATCH:
                            held_x, held_y = held[foot, 1], held[foot, 2]
                        moved = terrain_foothold(
                            heights, footholds, terrain, parameters[5], ends[j], held_x, held_y
                        )
                        if keep:
                            next_touchdown = False
                            if moved:
                                held[foot, 0], held[foot, 1], held[foot, 2] = end, ends[j, 0], ends[j, 1]
                        floors[j] = swing_apex_floor(
                            heights, terrain, starts[j], ends[j], parameters[5], parameters[6]
                        )
                    start_position = ends[j]
                    n_swings += 1
                index = end_index + 1
            else:
                index += 1
        sample_foot_floored(
            times,
            liftoffs[:n_swings],
            touchdowns[:n_swings],
            starts[:n_swings],
            ends[:n_swings],
            stance_positions[foot],
            parameters[6],
            floors[:n_swings],
            parameters[12],
            parameters[13],
            foot,
            stance,
            positions,
            velocities,
        )


# ------------------------------------------------------------------------------------ stored trajectory
@njit(cache=True, nogil=True)
def _dot4(a: np.ndarray, b: np.ndarray) -> float:
    """``a . b`` of 4-vectors rounded as numpy's (OpenBLAS ``ddot``: one fused multiply-add per term, in
    order)."""
    total = 0.0
    for i in range(4):
        total = _fused_multiply_add(a[i], b[i], total)
    return total


@njit(cache=True, nogil=True)
def _slerp(q0: np.ndarray, q1: np.ndarray, alpha: float, out: np.ndarray) -> None:
    """``trajectory.quaternion_slerp`` (the same operations, rounded alike) into ``out`` (4)."""
    dot = _dot4(q0, q1)
    sign = 1.0 if dot >= 0.0 else -1.0
    dot = min(abs(dot), 1.0)
    if dot > 1.0 - 1e-9:
        for i in range(4):
            out[i] = q0[i] + alpha * (sign * q1[i] - q0[i])
    else:
        angle = math.acos(dot)
        s = math.sin(angle)
        a = math.sin((1.0 - alpha) * angle) / s
        b = sign * math.sin(alpha * angle) / s
        for i in range(4):
            out[i] = a * q0[i] + b * q1[i]
    norm = math.sqrt(_dot4(out, out))
    for i in range(4):
        out[i] = out[i] / norm


@njit(cache=True, nogil=True)
def sample_trajectory(
    times: np.ndarray,
    timing: np.ndarray,
    n_intervals: int,
    configurations: np.ndarray,
    velocities: np.ndarray,
    feet: np.ndarray,
    feet_velocity: np.ndarray,
    torques: np.ndarray,
    forces: np.ndarray,
    contacts: np.ndarray,
    hold_configurations: np.ndarray,
    hold_stance: np.ndarray,
    hold_torques: np.ndarray,
    hold_forces: np.ndarray,
    hold_feet: np.ndarray,
    weight_sets: np.ndarray,
    state_out: np.ndarray,
    stance_out: np.ndarray,
    torque_out: np.ndarray,
    forces_out: np.ndarray,
    positions_out: np.ndarray,
    velocities_out: np.ndarray,
    weight_set_out: np.ndarray,
) -> None:
    """``TrajectoryReference.sample``: every field at every time, compiled.

    ``timing`` = (start, dt, index tolerance, stance time eps); ``n_intervals`` intervals. Knots
    (``configurations``, ``velocities``, ``feet``, ``feet_velocity``: one row per knot) interpolate (the
    quaternion by ``_slerp``); intervals (``torques``, ``forces``, ``contacts``) are piecewise constant;
    before the start and after the end the holds (row 0 and 1 of the ``hold_*`` arrays) apply.
    ``weight_sets`` = (inside, hold).
    """
    start, dt, tolerance, stance_eps = timing[0], timing[1], timing[2], timing[3]
    nq = configurations.shape[1]
    nv = velocities.shape[1]
    n_feet = feet.shape[1]
    for i in range(times.shape[0]):
        s = (times[i] - start) / dt
        k, alpha = 0, 0.0
        hold = -1
        if s < -tolerance:
            hold = 0
        else:
            k = math.floor(s + tolerance)
            if k >= n_intervals:
                if s <= n_intervals + tolerance:
                    k, alpha = n_intervals - 1, 1.0
                else:
                    hold = 1
            else:
                alpha = min(max(s - k, 0.0), 1.0)
        if hold >= 0:
            for a in range(nq):
                state_out[i, a] = hold_configurations[hold, a]
            for a in range(nv):
                state_out[i, nq + a] = 0.0
            for foot in range(n_feet):
                stance_out[i, foot] = hold_stance[hold, foot]
                for a in range(3):
                    forces_out[i, foot, a] = hold_forces[hold, foot, a]
                    positions_out[i, foot, a] = hold_feet[hold, foot, a]
                    velocities_out[i, foot, a] = 0.0
            for a in range(torque_out.shape[1]):
                torque_out[i, a] = hold_torques[hold, a]
            weight_set_out[i] = weight_sets[1]
            continue
        q0, q1 = configurations[k], configurations[k + 1]
        for a in range(3):
            state_out[i, a] = q0[a] + alpha * (q1[a] - q0[a])
        _slerp(q0[3:7], q1[3:7], alpha, state_out[i, 3:7])
        for a in range(7, nq):
            state_out[i, a] = q0[a] + alpha * (q1[a] - q0[a])
        for a in range(nv):
            state_out[i, nq + a] = velocities[k, a] + alpha * (velocities[k + 1, a] - velocities[k, a])
        for foot in range(n_feet):
            for a in range(3):
                positions_out[i, foot, a] = feet[k, foot, a] + alpha * (
                    feet[k + 1, foot, a] - feet[k, foot, a]
                )
                velocities_out[i, foot, a] = feet_velocity[k, foot, a] + alpha * (
                    feet_velocity[k + 1, foot, a] - feet_velocity[k, foot, a]
                )
        interval = k
        if alpha > 1.0 - stance_eps / dt:
            interval = min(k + 1, n_intervals - 1)
        for foot in range(n_feet):
            stance_out[i, foot] = contacts[interval, foot]
            for a in range(3):
                forces_out[i, foot, a] = forces[interval, foot, a]
        for a in range(torque_out.shape[1]):
            torque_out[i, a] = torques[interval, a]
        weight_set_out[i] = weight_sets[0]


# ---------------------------------------------------------------------------------------- composition
@njit(cache=True, nogil=True)
def place_configurations(q: np.ndarray, x: float, y: float, yaw: float, sign: float) -> None:
    """``ComposedReference._place_configuration``: rows of configurations (N, nq) moved by the planar offset
    ``(x, y, yaw)`` (positions rotated and shifted, quaternions pre-multiplied by the yaw's, term for term
    as ``composition.quaternion_multiply``) and their quaternions negated if ``sign < 0``, in place."""
    if x != 0.0 or y != 0.0 or yaw != 0.0:
        c, s = math.cos(yaw), math.sin(yaw)
        ax, ay, az, aw = 0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)
        for i in range(q.shape[0]):
            px, py = q[i, 0], q[i, 1]
            q[i, 0] = c * px - s * py + x
            q[i, 1] = s * px + c * py + y
            if yaw != 0.0:
                bx, by, bz, bw = q[i, 3], q[i, 4], q[i, 5], q[i, 6]
                q[i, 3] = aw * bx + ax * bw + ay * bz - az * by
                q[i, 4] = aw * by - ax * bz + ay * bw + az * bx
                q[i, 5] = aw * bz + ax * by - ay * bx + az * bw
                q[i, 6] = aw * bw - ax * bx - ay * by - az * bz
    if sign < 0:
        for i in range(q.shape[0]):
            for a in range(3, 7):
                q[i, a] *= -1.0
