"""An elevation map of the ground around the robot: what a terrain-aware controller is handed.

A ``HeightMap`` is a regular grid of ground heights in the robot's heading frame at the time it was measured:
cell ``(row, column)`` has its centre at ``origin + R(yaw) @ (column, row) * resolution`` in the world's
``(x, y)`` (columns run along the heading, rows to its left), and a height (world z, m) that counts only
where ``valid`` is true (a cell the sensor did not see: out of its range, no surface below, occluded). The
lab's plant makes them (``cafe_mpc_lab.sim.height_map``: ray casts, as a depth camera's elevation map);
``height_at`` and ``normal_at`` read the surface between the cell centres by bilinear interpolation.

A map reaches the controller as a sensor on the trunk measures it: relative to the base (``relative_to``: the
base at the origin, heights from the base's height, the grid's axes in the heading frame), and the controller
places it in its own frame at its estimate of the base's pose (``placed_at``): a robot knows the map's pose
only through its state estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class HeightMap:
    """Ground heights on a grid in the heading frame (module docstring).

    ``origin``: world ``(x, y)`` of the centre of cell ``(0, 0)``; ``yaw``: rad, the grid's column axis from
    the world x axis; ``resolution``: m between cell centres; ``heights``: ``(rows, columns)`` world z, m;
    ``valid``: ``(rows, columns)`` bool, which heights were measured; ``time``: s, when.
    """

    origin: tuple[float, float]
    yaw: float
    resolution: float
    heights: np.ndarray
    valid: np.ndarray
    time: float = 0.0

    def __post_init__(self) -> None:
        heights = np.asarray(self.heights, dtype=float)
        valid = np.asarray(self.valid, dtype=bool)
        if heights.ndim != 2 or heights.shape != valid.shape or min(heights.shape) < 1:
            raise ValueError(
                f"height map: heights and valid must be the same 2-D shape, got {heights.shape} and "
                f"{valid.shape}"
            )
        if not (self.resolution > 0 and math.isfinite(self.resolution)):
            raise ValueError(f"height map resolution must be positive, got {self.resolution}")
        if not all(math.isfinite(value) for value in (*self.origin, self.yaw, self.time)):
            raise ValueError("height map origin, yaw and time must be finite")
        if not np.all(np.isfinite(heights[valid])):
            raise ValueError("height map: a valid cell has a non-finite height")
        object.__setattr__(self, "heights", heights)
        object.__setattr__(self, "valid", valid)

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, columns)``."""
        return self.heights.shape  # type: ignore[return-value]

    def relative_to(self, x: float, y: float, z: float, yaw: float) -> HeightMap:
        """This map (world frame) seen from a base at world ``(x, y, z)`` heading ``yaw``: origin and yaw in
        the base's heading frame, heights above the base's height (``placed_at`` undoes it)."""
        cos, sin = math.cos(yaw), math.sin(yaw)
        dx, dy = self.origin[0] - x, self.origin[1] - y
        origin = (cos * dx + sin * dy, -sin * dx + cos * dy)
        return HeightMap(origin, self.yaw - yaw, self.resolution, self.heights - z, self.valid, self.time)

    def placed_at(self, x: float, y: float, z: float, yaw: float) -> HeightMap:
        """A map relative to the base (``relative_to``) placed at a base at ``(x, y, z)`` heading ``yaw``."""
        cos, sin = math.cos(yaw), math.sin(yaw)
        ox, oy = self.origin
        origin = (x + cos * ox - sin * oy, y + sin * ox + cos * oy)
        return HeightMap(origin, self.yaw + yaw, self.resolution, self.heights + z, self.valid, self.time)

    def cell_centres(self) -> np.ndarray:
        """World ``(x, y)`` of every cell's centre, ``(rows, columns, 2)``."""
        rows, columns = self.shape
        along, across = np.meshgrid(
            np.arange(columns) * self.resolution, np.arange(rows) * self.resolution, indexing="xy"
        )
        cos, sin = math.cos(self.yaw), math.sin(self.yaw)
        x = self.origin[0] + cos * along - sin * across
        y = self.origin[1] + sin * along + cos * across
        return np.stack([x, y], axis=-1)

    def _cell(self, x: float, y: float) -> tuple[int, int, float, float] | None:
        """The cell whose centre is the lower-left corner of the interpolation square around world ``(x, y)``
        and the fractions across it, or None outside the grid's centres or next to an invalid cell."""
        dx, dy = x - self.origin[0], y - self.origin[1]
        cos, sin = math.cos(self.yaw), math.sin(self.yaw)
        column = (cos * dx + sin * dy) / self.resolution
        row = (-sin * dx + cos * dy) / self.resolution
        rows, columns = self.shape
        tolerance = 1e-9
        if not (
            -tolerance <= column <= columns - 1 + tolerance and -tolerance <= row <= rows - 1 + tolerance
        ):
            return None
        c0 = min(max(math.floor(column), 0), max(columns - 2, 0))
        r0 = min(max(math.floor(row), 0), max(rows - 2, 0))
        c1, r1 = min(c0 + 1, columns - 1), min(r0 + 1, rows - 1)
        if not (self.valid[r0, c0] and self.valid[r0, c1] and self.valid[r1, c0] and self.valid[r1, c1]):
            return None
        return r0, c0, min(max(row - r0, 0.0), 1.0), min(max(column - c0, 0.0), 1.0)

    def _corners(self, r0: int, c0: int) -> tuple[float, float, float, float]:
        rows, columns = self.shape
        r1, c1 = min(r0 + 1, rows - 1), min(c0 + 1, columns - 1)
        h = self.heights
        return float(h[r0, c0]), float(h[r0, c1]), float(h[r1, c0]), float(h[r1, c1])

    def height_at(self, x: float, y: float) -> float:
        """Ground height (world z, m) at world ``(x, y)``, bilinear between the four cell centres around it;
        NaN outside the grid's centres or when one of those cells is invalid."""
        cell = self._cell(x, y)
        if cell is None:
            return math.nan
        r0, c0, fr, fc = cell
        h00, h01, h10, h11 = self._corners(r0, c0)
        return (1 - fr) * ((1 - fc) * h00 + fc * h01) + fr * ((1 - fc) * h10 + fc * h11)

    def normal_at(self, x: float, y: float) -> np.ndarray:
        """Unit normal (world frame, pointing up) of the bilinear surface at world ``(x, y)``; NaN where
        ``height_at`` is NaN."""
        cell = self._cell(x, y)
        if cell is None:
            return np.full(3, math.nan)
        r0, c0, fr, fc = cell
        h00, h01, h10, h11 = self._corners(r0, c0)
        rows, columns = self.shape
        along = ((1 - fr) * (h01 - h00) + fr * (h11 - h10)) / self.resolution if columns > 1 else 0.0
        across = ((1 - fc) * (h10 - h00) + fc * (h11 - h01)) / self.resolution if rows > 1 else 0.0
        cos, sin = math.cos(self.yaw), math.sin(self.yaw)
        gradient_x, gradient_y = cos * along - sin * across, sin * along + cos * across
        normal = np.array([-gradient_x, -gradient_y, 1.0])
        return normal / np.linalg.norm(normal)
