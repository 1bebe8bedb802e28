"""The ground a blind robot believes it stands on: a plane through the points where its feet last stood.

A robot without a map of the terrain still knows where its feet are when they stand: the plane through
each foot's latest contact point (the sole's position, from the measured state's leg kinematics, while the
foot is in stance) is its estimate of the ground around it: its height under the base, its slope, its
normal.

``GroundPlane`` keeps one contact point per foot and fits ``z = height + slope_x (x - cx) + slope_y (y - cy)``
by least squares (``cx, cy``: the points' centroid), when the plane is next read after a point changed: a
plane observed at every control tick and read at every MPC update fits once per update. With fewer than three
points that span the plane (feet in a line), the slope stays zero and the height is the points' mean. The
slope is limited to ``max_slope`` (rise per run) so that a misplaced point cannot tip the plane over. With
``min_span`` a slope along a direction the points spread less than that along (their root-mean-square
distance from the centroid along it) is not fitted but held from the last fit that resolved it (a bound's hind
feet land 6-7 cm ahead of the front feet's last points, and a centimetre between the pairs' heights, the
soles' sinking or the estimate's drift, then tilted the plane by 0.25). The
reference (``reference.locomotion``: base height, pitch and footholds on the plane) and the contact detector
(``low_level.contact_detection``: a foot's height above the plane) each keep their own, updated from the
measurement they see.
"""

from __future__ import annotations

import math

import numpy as np

MAX_SLOPE = 0.7
"""Rise per run of the steepest plane the estimate believes (35 degrees)."""


class GroundPlane:
    """A plane through the feet's latest contact points (module docstring); starts flat at ``height``."""

    def __init__(
        self, n_feet: int, height: float = 0.0, max_slope: float = MAX_SLOPE, min_span: float = 0.0
    ) -> None:
        if n_feet < 1:
            raise ValueError(f"a ground plane needs at least one foot, got {n_feet}")
        if not (math.isfinite(height) and math.isfinite(max_slope) and max_slope >= 0.0):
            raise ValueError(
                f"ground plane: height must be finite and max_slope >= 0, got {height}, {max_slope}"
            )
        if not (math.isfinite(min_span) and min_span >= 0.0):
            raise ValueError(f"ground plane: min_span must be >= 0 m, got {min_span}")
        self.n_feet = n_feet
        self.initial_height = float(height)
        self.max_slope = float(max_slope)
        self.min_span = float(min_span)
        """m; the points' root-mean-square spread along a direction below which the slope along it is held
        (module docstring); 0: every fit's slope (the points in a line: flat)."""
        self.points = np.zeros((n_feet, 3))
        """Each foot's latest contact point (world; the sole), valid where ``known``."""
        self.known = np.zeros(n_feet, dtype=bool)
        self._standing = np.zeros(n_feet, dtype=bool)
        self._design = np.zeros((n_feet, 3))
        self._stale = False
        self.reset()

    def reset(self) -> None:
        """Forget the contact points: flat at the initial height."""
        self.known[:] = False
        self._standing[:] = False
        self.frame_shift = 0.0
        """How far the measurement's frame has moved up in all (the sum of the shifts ``observe`` saw)."""
        self._height = self.initial_height
        self._slope = np.zeros(2)
        self._centre = np.zeros(2)
        self._held_slope = np.zeros(2)
        """With ``min_span``, the slope of the last fit (what a direction the points do not resolve keeps)."""
        self._stale = False

    @property
    def height(self) -> float:
        """The plane's height (world z) at ``centre``."""
        if self._stale:
            self._fit()
        return self._height

    @property
    def slope(self) -> np.ndarray:
        """The plane's rise per run along world x and y."""
        if self._stale:
            self._fit()
        return self._slope

    @property
    def centre(self) -> np.ndarray:
        """The contact points' centroid (world x, y)."""
        if self._stale:
            self._fit()
        return self._centre

    def observe(self, soles: np.ndarray, stance: np.ndarray) -> None:
        """The soles (world, ``(n_feet, 3)``) of the feet in ``stance`` are contact points now; refit.

        A foot that stood at the last observation and still stands has not moved: if its measured height
        changed, the measurement's frame moved (an estimator that holds its stance feet at z = 0 shifts its
        heights when the feet stand on a new level). The older points of the feet that do not stand now
        move by the same mean shift, so that every point is in the frame of the newest measurement."""
        standing = np.asarray(stance, dtype=bool)
        continuing = standing & self._standing
        if continuing.any():
            shift = float(np.mean(soles[continuing, 2] - self.points[continuing, 2]))
            self.points[~standing & self.known, 2] += shift
            self.frame_shift += shift
        self._standing[:] = standing
        if standing.any():
            self.points[standing] = soles[standing]
            self.known[standing] = True
            self._stale = True

    def _fit(self) -> None:
        self._stale = False
        points = self.points[self.known]
        centre = points[:, :2].mean(axis=0)
        self._centre = centre
        self._height = float(points[:, 2].mean())
        self._slope = np.zeros(2)
        if self.min_span > 0.0:
            self._fit_spanned(points, centre)
            return
        if len(points) < 3:
            return
        design = self._design[: len(points)]
        design[:, 0] = 1.0
        design[:, 1:] = points[:, :2] - centre
        # feet (nearly) in a line leave the slope across it unknown: keep it flat
        singular = np.linalg.svd(design[:, 1:], compute_uv=False)
        if singular[-1] < 1e-3:
            return
        solution, *_ = np.linalg.lstsq(design, points[:, 2], rcond=None)
        slope = solution[1:]
        norm = float(np.hypot(slope[0], slope[1]))
        if norm > self.max_slope:
            slope = slope * (self.max_slope / norm)
        self._height = float(solution[0])
        self._slope = slope

    def _fit_spanned(self, points: np.ndarray, centre: np.ndarray) -> None:
        """``_fit`` with ``min_span``: the least-squares slope along each principal direction of the points'
        spread (``D = U S V'``, ``D`` their centred x, y) that they spread at least ``min_span`` along
        (``S_i / sqrt(n)``), the held slope's component along the others, limited to ``max_slope``; the
        height at the centroid is then the points' mean height (the centred columns sum to zero)."""
        design = self._design[: len(points), :2]
        np.subtract(points[:, :2], centre, out=design)
        _, singular, directions = np.linalg.svd(design)  # directions: 2 x 2 even for one point
        spread = np.zeros(2)
        spread[: len(singular)] = singular
        resolved = spread >= max(self.min_span * math.sqrt(len(points)), 1e-3)
        along = directions @ self._held_slope  # the held slope in the principal directions
        for i in np.flatnonzero(resolved):
            # least squares along a principal direction alone (the projections on them are uncorrelated,
            # so this is the plane's least-squares slope there): sum (d_i . p) z / sum (d_i . p)^2
            projection = design @ directions[i]
            along[i] = float(projection @ points[:, 2]) / float(projection @ projection)
        slope = directions.T @ along
        norm = float(np.hypot(slope[0], slope[1]))
        if norm > self.max_slope:
            slope = slope * (self.max_slope / norm)
        self._slope = slope
        self._held_slope = slope.copy()

    def height_at(self, x: float, y: float) -> float:
        """The plane's height (world z) at world ``(x, y)``."""
        return self.height + self.slope[0] * (x - self.centre[0]) + self.slope[1] * (y - self.centre[1])

    def normal(self) -> np.ndarray:
        """The plane's unit normal (world, pointing up)."""
        normal = np.array([-self.slope[0], -self.slope[1], 1.0])
        return normal / np.linalg.norm(normal)

    def contact_frame(self) -> np.ndarray:
        """The plane's contact frame (``contact_frame`` of its normal): the axes of the friction pyramids
        of the plan (26) and the VWBC (34f) on it."""
        return contact_frame(self.normal())

    def pitch_along(self, yaw: float) -> float:
        """Pitch (rad, about the heading frame's y axis; negative: nose up) of a body lying on the plane with
        heading ``yaw``."""
        rise = self.slope[0] * math.cos(yaw) + self.slope[1] * math.sin(yaw)
        return -math.atan(rise)


def contact_frame(normal: np.ndarray) -> np.ndarray:
    """The frame of a friction pyramid about the ground's unit ``normal`` (world, pointing up): rows ``along``
    (the ground's direction in the world x-z plane), ``across`` (``normal x along``) and ``normal``; the
    identity for ``normal = z``."""
    normal = np.asarray(normal, dtype=float)
    along = np.array([normal[2], 0.0, -normal[0]])
    along /= np.linalg.norm(along)
    return np.array([along, np.cross(normal, along), normal])
