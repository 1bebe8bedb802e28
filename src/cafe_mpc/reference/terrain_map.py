"""The terrain a locomotion reference plans on from a height map (``terrain: height_map``).

The robot's height-map sensor gives a ``core.height_map.HeightMap`` relative to its base; the controller
places it at its estimate of the base's pose (``HeightMap.placed_at``) and hands it to the reference
(``LocomotionReference.observe_height_map``), which keeps the newest in a ``TerrainMap``. From each map it
makes, once, what the compiled sampling (``reference.kernels``) reads:

* ``heights``: the map's heights, NaN where it saw nothing;
* ``footholds``: the height of each *flat spot*, NaN elsewhere: a cell whose neighbours within
  ``edge_margin`` (at least one cell each way; beyond the grid's border, the border's) were all seen and
  spread by at most ``flat_tolerance``; a
  foothold lands on one (``kernels.terrain_foothold``: where it is, or the nearest within
  ``foothold_search``), so that a foot is not planned on an edge;
* ``smooth``: the heights averaged over a square of ``base_window`` around each cell (NaN where none was
  seen), the terrain under the hips that the base's height and pitch follow.

Heights are in the frame of the estimate the map was placed with. A state estimator that measures its
stance feet at z = 0 moves that frame when the feet reach a new level, and the map's ``offset`` follows the
move until the next map (a map is used for up to a sensor period after it was taken), by
``TerrainMapSettings.registration``:

* ``feet``: the lowest standing foot on a flat spot is on the terrain (``register``); where none stands on
  one, the ground plane's accumulated frame shifts (``core.ground.GroundPlane.frame_shift``,
  ``follow_frame``);
* ``motion``: the estimated base height's change since the map was placed minus the estimated vertical
  velocity integrated over the same time (``follow_motion``): what the height moved that the body did not.
  It needs no foot on the ground (a bound is in flight or on two feet most of its cycle, and a foot landing
  hard, or one the filter has not yet pulled to z = 0, read up to 10 cm off on 8 cm steps), and over a
  sensor period the integrated velocity is within 2 cm of the true rise (the bound over 8 cm steps: 90 % of
  70 ms windows within 1.4 cm, against 4.8 cm for the estimated height's change).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from cafe_mpc.config import TerrainMapSettings
from cafe_mpc.core.height_map import HeightMap
from cafe_mpc.reference.kernels import (
    TERRAIN_CLEARANCE,
    TERRAIN_COS,
    TERRAIN_ENABLED,
    TERRAIN_HOLD,
    TERRAIN_OFFSET,
    TERRAIN_ORIGIN_X,
    TERRAIN_ORIGIN_Y,
    TERRAIN_PARAMETERS,
    TERRAIN_RESOLUTION,
    TERRAIN_SEARCH,
    TERRAIN_SIN,
    map_height,
)


def _windows(grid: np.ndarray, half: int, beyond: str) -> np.ndarray:
    """Every cell's ``(2 half + 1)^2`` neighbourhood, ``(rows, columns, side, side)``; beyond the grid NaN
    (``beyond`` "unseen") or the border's cells repeated ("edge")."""
    if beyond == "edge":
        padded = np.pad(grid, half, mode="edge")
    else:
        padded = np.pad(grid, half, constant_values=np.nan)
    return sliding_window_view(padded, (2 * half + 1, 2 * half + 1))


def flat_spots(heights: np.ndarray, resolution: float, settings: TerrainMapSettings) -> np.ndarray:
    """The height of each flat spot of ``heights`` (NaN: not seen), NaN elsewhere (module docstring): the
    mean of its neighbourhood within ``edge_margin``, all seen, spread at most ``flat_tolerance``."""
    half = max(1, round(settings.edge_margin / resolution))
    windows = _windows(heights, half, "edge")  # the grid's border is not an edge of the terrain
    seen = np.all(np.isfinite(windows), axis=(2, 3))
    spots = np.full(heights.shape, np.nan)
    if not seen.any():
        return spots
    inside = windows[seen]
    spread = inside.max(axis=(1, 2)) - inside.min(axis=(1, 2))
    flat = spread <= settings.flat_tolerance
    values = np.full(len(inside), np.nan)
    values[flat] = inside[flat].mean(axis=(1, 2))
    spots[seen] = values
    return spots


def smoothed(heights: np.ndarray, resolution: float, window: float) -> np.ndarray:
    """The mean of the seen heights in a square of side ``window`` around each cell (NaN where none)."""
    half = max(0, round(0.5 * window / resolution))
    windows = _windows(heights, half, "unseen")
    seen = np.isfinite(windows)
    counts = seen.sum(axis=(2, 3))
    sums = np.where(seen, windows, 0.0).sum(axis=(2, 3))
    return np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)


class TerrainMap:
    """The newest height map as the reference reads it (module docstring); none until ``place``."""

    def __init__(self, settings: TerrainMapSettings) -> None:
        self.settings = settings
        self.parameters = np.zeros(TERRAIN_PARAMETERS)
        """The kernels' ``terrain`` array (``kernels.TERRAIN_PARAMETERS``); ``TERRAIN_ENABLED`` 0: no map."""
        self.reset()

    def reset(self) -> None:
        """No map."""
        self.parameters[:] = 0.0
        self.parameters[TERRAIN_COS] = 1.0
        self.parameters[TERRAIN_RESOLUTION] = 1.0
        self.heights = np.full((1, 1), np.nan)
        self.footholds = np.full((1, 1), np.nan)
        self.smooth = np.full((1, 1), np.nan)
        self.time = -math.inf
        self._shift_at_place = 0.0
        self._placed_height = math.nan
        """The estimated base height the newest map was placed at (``follow_motion``)."""
        self._motion_time = -math.inf
        self._motion_velocity = 0.0
        self._climb = 0.0
        """The estimated vertical velocity integrated since the map was placed (trapezoid), m."""

    @property
    def available(self) -> bool:
        """Whether a map has been placed."""
        return bool(self.parameters[TERRAIN_ENABLED] > 0.0)

    def place(
        self,
        height_map: HeightMap,
        frame_shift: float = 0.0,
        base_height: float = math.nan,
        vertical_velocity: float = 0.0,
    ) -> None:
        """Take ``height_map`` (placed in the controller's frame) as the newest; ``frame_shift``: the
        estimator frame's accumulated move now (``GroundPlane.frame_shift``); ``base_height`` and
        ``vertical_velocity`` (world z): the estimate it was placed with (``follow_motion``)."""
        heights = np.where(height_map.valid, height_map.heights, np.nan)
        resolution = height_map.resolution
        self.heights = np.ascontiguousarray(heights)
        self.footholds = np.ascontiguousarray(flat_spots(heights, resolution, self.settings))
        self.smooth = np.ascontiguousarray(smoothed(heights, resolution, self.settings.base_window))
        p = self.parameters
        p[TERRAIN_ENABLED] = 1.0
        p[TERRAIN_ORIGIN_X], p[TERRAIN_ORIGIN_Y] = height_map.origin
        p[TERRAIN_COS], p[TERRAIN_SIN] = math.cos(height_map.yaw), math.sin(height_map.yaw)
        p[TERRAIN_RESOLUTION] = resolution
        p[TERRAIN_SEARCH] = self.settings.foothold_search
        p[TERRAIN_OFFSET] = 0.0
        p[TERRAIN_CLEARANCE] = self.settings.swing_clearance
        p[TERRAIN_HOLD] = self.settings.foothold_hysteresis
        self.time = height_map.time
        self._shift_at_place = frame_shift
        self._placed_height = base_height
        self._motion_time = height_map.time
        self._motion_velocity = vertical_velocity
        self._climb = 0.0

    def follow_frame(self, frame_shift: float) -> None:
        """The estimator's frame has moved by ``frame_shift`` in all (``GroundPlane.frame_shift``): the
        map's heights move with it."""
        self.parameters[TERRAIN_OFFSET] = frame_shift - self._shift_at_place

    def follow_motion(self, t: float, base_height: float, vertical_velocity: float) -> None:
        """The estimate at ``t`` (base height, world vertical velocity): the map's offset is how far the
        estimator's frame moved since the map was placed, the estimated height's change minus the
        integrated estimated vertical velocity (module docstring; trapezoid over the estimates seen, one
        per control tick)."""
        if not self.available or not math.isfinite(self._placed_height):
            return
        step = t - self._motion_time
        if step > 0.0:
            self._climb += 0.5 * (self._motion_velocity + vertical_velocity) * step
            self._motion_time, self._motion_velocity = t, vertical_velocity
        self.parameters[TERRAIN_OFFSET] = base_height - self._placed_height - self._climb

    def normal_under(self, soles: np.ndarray) -> np.ndarray | None:
        """The terrain's unit normal (world, up) under the feet ``soles`` (``(n_feet, 3)``, world): the
        mean of the map's normals at the flat spots they stand on (a least-squares plane through the seen
        cells within ``edge_margin``, at least one cell, of each; the map's noise tilts it by about half a
        degree), None where none stands on one. Flat treads give world z however the feet are spread over
        them, where a plane through the feet tilts with the steps between them."""
        if not self.available:
            return None
        p, grid = self.parameters, self.heights
        resolution, cos, sin = p[TERRAIN_RESOLUTION], p[TERRAIN_COS], p[TERRAIN_SIN]
        half = max(1, round(self.settings.edge_margin / resolution))
        rows, columns = grid.shape
        total = np.zeros(3)
        for sole in soles:
            x, y = float(sole[0]), float(sole[1])
            if not math.isfinite(map_height(self.footholds, p, x, y)):
                continue
            dx, dy = x - p[TERRAIN_ORIGIN_X], y - p[TERRAIN_ORIGIN_Y]
            column = round((cos * dx + sin * dy) / resolution)
            row = round((-sin * dx + cos * dy) / resolution)
            r0, r1 = max(row - half, 0), min(row + half, rows - 1)
            c0, c1 = max(column - half, 0), min(column + half, columns - 1)
            block = grid[r0 : r1 + 1, c0 : c1 + 1]
            seen = np.isfinite(block)
            if seen.sum() < 4:
                continue
            along, across = np.meshgrid(np.arange(c0, c1 + 1), np.arange(r0, r1 + 1), indexing="xy")
            design = np.column_stack(
                [along[seen] * resolution, across[seen] * resolution, np.ones(int(seen.sum()))]
            )
            (rise_along, rise_across, _), *_ = np.linalg.lstsq(design, block[seen], rcond=None)
            slope_x = cos * rise_along - sin * rise_across  # the grid's axes turned to the world's
            slope_y = sin * rise_along + cos * rise_across
            normal = np.array([-slope_x, -slope_y, 1.0])
            total += normal / np.linalg.norm(normal)
        norm = float(np.linalg.norm(total))
        return total / norm if norm > 0.0 else None

    def register(self, soles: np.ndarray, standing: np.ndarray) -> bool:
        """Hold the map to the feet that stand on it: a standing foot's sole (``soles``, ``(n_feet, 3)``
        in the estimator's frame, where ``standing``) on a flat spot of the map is on the terrain there,
        so the map's offset is the sole's height above the spot's. The lowest of these over the standing
        feet is taken (a foot believed standing that still hangs above the ground reads higher, one on the
        ground cannot read lower). Whether a standing foot was on a flat spot (else the offset stays the
        frame's, ``follow_frame``).

        Measured directly, the offset does not accumulate the errors of ``GroundPlane.frame_shift``,
        whose increments come from every foot believed still (a foot sliding or not yet down moves it)."""
        if not self.available:
            return False
        parameters = self.parameters
        offset = parameters[TERRAIN_OFFSET]
        parameters[TERRAIN_OFFSET] = 0.0
        lowest = math.inf
        for sole, stands in zip(soles, standing, strict=True):
            if not stands:
                continue
            spot = map_height(self.footholds, parameters, float(sole[0]), float(sole[1]))
            if math.isfinite(spot):
                lowest = min(lowest, float(sole[2]) - spot)
        parameters[TERRAIN_OFFSET] = lowest if math.isfinite(lowest) else offset
        return math.isfinite(lowest)
