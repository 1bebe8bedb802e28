"""Terrain in the plant's scene: slopes, steps, stairs, a rough field and gaps, static geoms of the world.

Only the MuJoCo model changes (the plant, its videos and the viewer); the controller keeps planning on flat
ground, so terrain tests how far its feedback carries it. Every piece runs along the world x axis from
``start``, across ``width`` m centred on ``center_y``:

* ``Slope``: an incline, a flat top, and (``descend``) the incline down; boxes, the inclines pitched.
* ``Steps``: ``count`` steps of ``rise`` up, each ``run`` deep, a top, and (``descend``) the same down.
* ``Stairs``: a building's staircase: ``count`` steps of ``rise`` and ``tread``, a landing of
  ``landing_length`` after every ``flight_steps`` steps (0: one flight), the top, and (``descend``) the same
  staircase down, landings mirrored.
* ``Rough``: a random field of heights in ``[0, 2 amplitude]`` (``+-amplitude`` about ``amplitude``) on a
  grid of ``cell_size``, ``length`` by ``width``, drawn from ``seed`` (the same field for the same seed), its
  border at the floor's height; a MuJoCo height field, its contacts stiffer than the floor's
  (``FIELD_SOLREF``).
* ``Gaps``: ``count`` trenches ``gap_width`` wide (along x), ``spacing`` apart, whose bottom is ``depth``
  below the floor. A plane cannot have holes: with gaps in the scene the floor plane moves down to the
  deepest bottom and boxes whose top is at 0 tile the ground around the trenches (``ground_boxes``).

Geoms are named ``terrain_<piece>_<kind>_<part>`` (``terrain_ground_<i>`` for the ground around gaps;
``sim.randomization.TERRAIN_PREFIX``): they collide like the floor (``contype``/``conaffinity`` 1, its
friction, which ``plant.floor_friction`` changes with the floor's), so feet touching them count as contacts
and a trunk touching them as a fall. ``terrain_height`` is the true surface (a trench's bottom in a gap);
``support_height`` is the surface with the gaps bridged, the ground a fall is measured from (a robot whose
base is over a trench has not fallen, one in the trench has).
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from cafe_mpc.config import SceneConfig, TerrainConfig
from cafe_mpc.config.run import TERRAIN_KEYS
from cafe_mpc_lab.sim.randomization import TERRAIN_PREFIX

_RGBA = "0.42 0.48 0.56 1"
_GROUND_RGBA = "0.5 0.55 0.6 1"
_SLOPE_THICKNESS = 0.2  # m: the incline boxes reach below the floor, so no edge sticks out
_FIELD_BASE = 0.05  # m: the height field's solid part below its lowest point
FIELD_SOLREF = (0.01, 1.0)
"""The rough field's contact ``solref`` (time constant s, damping ratio). The field's geom has
``priority="1"``, so MuJoCo takes its parameters for its contacts with the feet: this ``solref``, and its
friction and ``condim`` (the floor's, which are also the generated feet's); the floor and the other pieces
keep MuJoCo's default (0.02 s). MuJoCo collides a sphere with a height field as with one vertical prism per
triangle: a foot landing near a cell's diagonal at 0.02 s went up to its radius into the field, the walls
between the two prisms then pushed it sideways from both sides with nothing pushing it up (google-deepmind/
mujoco issue 2883), and feet were held under the surface for up to 0.47 s. At 0.01 s a landing foot stays on
the top faces; the surface is unchanged (docs/terrain-notes.md, "Feet stuck in the rough field")."""
GROUND_EXTENT = 100.0
"""m: with gaps in the scene, the ground boxes cover world x and y within this of the origin."""

Box = tuple[str, tuple[float, float, float], tuple[float, float, float], float]
"""``(part, centre, half sizes, pitch)`` of a box geom; ``pitch`` turns it about the y axis so that its top
face rises along +x by that angle (rad)."""


def _across(piece: Slope | Steps | Stairs | Rough | Gaps, y: float) -> bool:
    return abs(y - piece.center_y) <= 0.5 * piece.width


@dataclass(frozen=True)
class Slope:
    """An incline of ``angle_deg`` over ``length`` m (horizontal), a top of ``top_length`` m, then down."""

    start: float = 1.0
    angle_deg: float = 5.0
    length: float = 1.0
    top_length: float = 1.0
    width: float = 2.0
    center_y: float = 0.0
    descend: bool = True

    def __post_init__(self) -> None:
        _check_finite(self)
        if not 0.0 < self.angle_deg <= 45.0:
            raise ValueError(f"slope angle_deg must be in (0, 45], got {self.angle_deg}")
        if not (self.length > 0 and self.width > 0 and self.top_length >= 0):
            raise ValueError("slope length and width must be positive, top_length >= 0")

    @property
    def height(self) -> float:
        """Height of the top above the floor, m."""
        return self.length * math.tan(math.radians(self.angle_deg))

    @property
    def end(self) -> float:
        """World x where the piece ends."""
        return self.start + self.length + self.top_length + (self.length if self.descend else 0.0)

    def boxes(self) -> list[Box]:
        theta = math.radians(self.angle_deg)
        height, thickness = self.height, _SLOPE_THICKNESS
        half = (0.5 * self.length / math.cos(theta), 0.5 * self.width, 0.5 * thickness)
        parts: list[Box] = []
        # the top face's middle sits on the incline; the box centre lies half a thickness below it (normal)
        x_mid = self.start + 0.5 * self.length
        parts.append(
            (
                "up",
                (
                    x_mid + 0.5 * thickness * math.sin(theta),
                    self.center_y,
                    0.5 * height - 0.5 * thickness * math.cos(theta),
                ),
                half,
                theta,
            )
        )
        top_start = self.start + self.length
        if self.top_length > 0:
            parts.append(
                (
                    "top",
                    (top_start + 0.5 * self.top_length, self.center_y, 0.5 * height),
                    (0.5 * self.top_length, 0.5 * self.width, 0.5 * height),
                    0.0,
                )
            )
        if self.descend:
            x_mid = top_start + self.top_length + 0.5 * self.length
            parts.append(
                (
                    "down",
                    (
                        x_mid - 0.5 * thickness * math.sin(theta),
                        self.center_y,
                        0.5 * height - 0.5 * thickness * math.cos(theta),
                    ),
                    half,
                    -theta,
                )
            )
        return parts

    def height_at(self, x: float, y: float = 0.0) -> float | None:
        """Surface height at world ``(x, y)``; None off the piece."""
        if not _across(self, y):
            return None
        slope = math.tan(math.radians(self.angle_deg))
        top_start = self.start + self.length
        top_end = top_start + self.top_length
        if self.start <= x < top_start:
            return (x - self.start) * slope
        if top_start <= x <= top_end:
            return self.height
        if self.descend and top_end < x <= top_end + self.length:
            return (top_end + self.length - x) * slope
        return None


Tread = tuple[str, float, float, float]
"""``(part, x_begin, x_end, height)`` of one tread of a staircase."""


def _staircase(
    start: float,
    risers: Sequence[tuple[str, float, float]],
    top_length: float,
    descend: bool,
) -> list[Tread]:
    """Treads of a staircase: ``risers`` (part, depth, height) on the way up, the top at the last height, and
    (``descend``) the way up mirrored."""
    treads: list[Tread] = []
    x = start
    for part, depth, height in risers:
        treads.append((f"up{part}", x, x + depth, height))
        x += depth
    top = risers[-1][2]
    if top_length > 0:
        treads.append(("top", x, x + top_length, top))
        x += top_length
    if descend:
        for part, depth, height in reversed(risers):
            treads.append((f"down{part}", x, x + depth, height))
            x += depth
    return treads


def _tread_boxes(treads: Sequence[Tread], center_y: float, width: float) -> list[Box]:
    """Solid boxes from the floor up to each tread."""
    return [
        (
            part,
            (0.5 * (begin + end), center_y, 0.5 * height),
            (0.5 * (end - begin), 0.5 * width, 0.5 * height),
            0.0,
        )
        for part, begin, end, height in treads
    ]


def _tread_height(treads: Sequence[Tread], x: float) -> float | None:
    for _, begin, end, height in treads:
        if begin <= x < end:
            return height
    return None


class _Treads:
    """What a piece made of flat treads (``treads``: name, start, end, height) answers from them: where it
    ends, its boxes and its height under a point (``Steps``, ``Stairs``)."""

    treads: list[Tread]
    center_y: float
    width: float

    @property
    def end(self) -> float:
        return self.treads[-1][2]

    def boxes(self) -> list[Box]:
        return _tread_boxes(self.treads, self.center_y, self.width)

    def height_at(self, x: float, y: float = 0.0) -> float | None:
        return _tread_height(self.treads, x) if _across(self, y) else None


@dataclass(frozen=True)
class Steps(_Treads):
    """``count`` steps of ``rise`` m, each ``run`` m deep, a top of ``top_length`` m, then down."""

    start: float = 1.0
    count: int = 3
    rise: float = 0.03
    run: float = 0.3
    top_length: float = 1.0
    width: float = 2.0
    center_y: float = 0.0
    descend: bool = True

    def __post_init__(self) -> None:
        _check_finite(self)
        if self.count < 1 or not (self.rise > 0 and self.run > 0 and self.width > 0 and self.top_length >= 0):
            raise ValueError("steps need count >= 1, positive rise, run and width, top_length >= 0")

    @property
    def height(self) -> float:
        return self.count * self.rise

    @cached_property
    def treads(self) -> list[Tread]:
        risers = [(str(step), self.run, (step + 1) * self.rise) for step in range(self.count)]
        return _staircase(self.start, risers, self.top_length, self.descend)


@dataclass(frozen=True)
class Stairs(_Treads):
    """A staircase: ``count`` steps of ``rise`` m and ``tread`` m, a landing of ``landing_length`` m after
    every ``flight_steps`` steps (0: one flight, no landing), a top of ``top_length`` m, then (``descend``)
    the same staircase down."""

    start: float = 1.0
    count: int = 5
    rise: float = 0.1
    tread: float = 0.3
    flight_steps: int = 0
    landing_length: float = 1.0
    top_length: float = 1.0
    width: float = 2.0
    center_y: float = 0.0
    descend: bool = True

    def __post_init__(self) -> None:
        _check_finite(self)
        if self.count < 1 or self.flight_steps < 0:
            raise ValueError("stairs need count >= 1 and flight_steps >= 0")
        if not (self.rise > 0 and self.tread > 0 and self.width > 0):
            raise ValueError("stairs need a positive rise, tread and width")
        if self.top_length < 0 or self.landing_length < 0:
            raise ValueError("stairs need top_length >= 0 and landing_length >= 0")

    @property
    def height(self) -> float:
        return self.count * self.rise

    @cached_property
    def treads(self) -> list[Tread]:
        risers: list[tuple[str, float, float]] = []
        for step in range(self.count):
            risers.append((str(step), self.tread, (step + 1) * self.rise))
            last_of_flight = self.flight_steps > 0 and (step + 1) % self.flight_steps == 0
            if last_of_flight and step + 1 < self.count and self.landing_length > 0:
                risers.append((f"landing{step}", self.landing_length, (step + 1) * self.rise))
        return _staircase(self.start, risers, self.top_length, self.descend)


@dataclass(frozen=True)
class Rough:
    """A random height field ``length`` m (x, from ``start``) by ``width`` m: heights uniform in
    ``[0, 2 amplitude]`` at the vertices of a ``cell_size`` grid, drawn from ``seed``; the border vertices
    at 0 (flush with the floor). MuJoCo's height field is flat between vertices (two triangles per cell)."""

    start: float = 1.0
    length: float = 2.0
    amplitude: float = 0.02
    cell_size: float = 0.1
    seed: int = 0
    width: float = 2.0
    center_y: float = 0.0

    def __post_init__(self) -> None:
        _check_finite(self)
        if not (self.length > 0 and self.width > 0 and self.amplitude > 0 and self.cell_size > 0):
            raise ValueError("rough terrain needs a positive length, width, amplitude and cell_size")
        if min(self.length, self.width) < 2 * self.cell_size:
            raise ValueError("rough terrain: length and width must hold at least two cells")
        if self.seed < 0:
            raise ValueError(f"rough terrain seed must be >= 0, got {self.seed}")

    @property
    def end(self) -> float:
        return self.start + self.length

    @property
    def grid(self) -> tuple[int, int]:
        """``(rows, columns)`` of vertices: rows along y, columns along x."""
        return round(self.width / self.cell_size) + 1, round(self.length / self.cell_size) + 1

    @cached_property
    def heights(self) -> np.ndarray:
        """``(rows, columns)`` vertex heights, m; row 0 at the field's lowest y, column 0 at ``start``."""
        rows, columns = self.grid
        rng = np.random.default_rng(self.seed)
        heights = self.amplitude * (1.0 + rng.uniform(-1.0, 1.0, size=(rows, columns)))
        heights[[0, -1], :] = 0.0
        heights[:, [0, -1]] = 0.0
        return heights

    def vertex(self, row: int, column: int) -> tuple[float, float]:
        """World ``(x, y)`` of a vertex."""
        rows, columns = self.grid
        x = self.start + column * self.length / (columns - 1)
        y = self.center_y - 0.5 * self.width + row * self.width / (rows - 1)
        return x, y

    def boxes(self) -> list[Box]:
        return []

    def hfield_xml(self, name: str) -> tuple[str, str]:
        """The ``<hfield>`` asset and the ``<geom>`` attributes (without name and contact settings) of the
        field. MuJoCo reads ``elevation`` row by row from the highest y down and scales it by the size's
        third value."""
        rows, columns = self.grid
        top = float(np.max(self.heights))
        normalised = self.heights / top if top > 0 else self.heights
        elevation = " ".join(f"{value:.9g}" for value in normalised[::-1].ravel())
        asset = (
            f'    <hfield name="{name}" nrow="{rows}" ncol="{columns}" '
            f'size="{0.5 * self.length:.10g} {0.5 * self.width:.10g} {max(top, 1e-6):.10g} '
            f'{_FIELD_BASE:.10g}" '
            f'elevation="{elevation}"/>\n'
        )
        geom = (
            f'type="hfield" hfield="{name}" '
            f'pos="{self.start + 0.5 * self.length:.10g} {self.center_y:.10g} 0"'
        )
        return asset, geom

    def height_at(self, x: float, y: float = 0.0) -> float | None:
        """The field's surface: MuJoCo's two triangles per cell, split along the diagonal from the cell's
        lowest-x, lowest-y vertex to its highest-x, highest-y vertex."""
        if not (_across(self, y) and self.start <= x <= self.end):
            return None
        rows, columns = self.grid
        column = (x - self.start) / self.length * (columns - 1)
        row = (y - self.center_y + 0.5 * self.width) / self.width * (rows - 1)
        c0, r0 = min(int(column), columns - 2), min(int(row), rows - 2)
        fc, fr = column - c0, row - r0
        h = self.heights
        low, high = h[r0, c0], h[r0 + 1, c0 + 1]
        if fc >= fr:  # the triangle with the vertex (r0, c0 + 1)
            return float(low + fc * (h[r0, c0 + 1] - low) + fr * (high - h[r0, c0 + 1]))
        return float(low + fr * (h[r0 + 1, c0] - low) + fc * (high - h[r0 + 1, c0]))


@dataclass(frozen=True)
class Gaps:
    """``count`` trenches across the way, each ``gap_width`` m along x and ``width`` m across, ``spacing``
    m of ground between them, their bottom ``depth`` m below the floor."""

    start: float = 1.0
    count: int = 3
    gap_width: float = 0.1
    spacing: float = 0.6
    depth: float = 1.0
    width: float = 2.0
    center_y: float = 0.0

    def __post_init__(self) -> None:
        _check_finite(self)
        if self.count < 1 or not (
            self.gap_width > 0 and self.spacing > 0 and self.depth > 0 and self.width > 0
        ):
            raise ValueError("gaps need count >= 1 and a positive gap_width, spacing, depth and width")

    @property
    def trenches(self) -> list[tuple[float, float]]:
        """``(x_begin, x_end)`` of every trench."""
        pitch = self.gap_width + self.spacing
        return [(self.start + i * pitch, self.start + i * pitch + self.gap_width) for i in range(self.count)]

    @property
    def end(self) -> float:
        return self.trenches[-1][1]

    def boxes(self) -> list[Box]:
        return []  # the ground around the trenches is the scene's (ground_boxes)

    def height_at(self, x: float, y: float = 0.0) -> float | None:
        """``-depth`` inside a trench; None elsewhere (the ground there is the floor's level)."""
        if _across(self, y) and any(begin < x < end for begin, end in self.trenches):
            return -self.depth
        return None


Terrain = Slope | Steps | Stairs | Rough | Gaps


def _check_finite(piece: object) -> None:
    for name, value in vars(piece).items():
        if isinstance(value, float | int) and not isinstance(value, bool) and not math.isfinite(value):
            raise ValueError(f"terrain {name} must be finite, got {value}")


def ground_boxes(pieces: Sequence[Terrain]) -> tuple[list[Box], float]:
    """The ground around the scene's gaps and the floor plane's new height: boxes with their top at 0 that
    tile world x and y within ``GROUND_EXTENT`` except the trenches, down to the deepest trench's bottom (the
    floor plane's new height), and a bottom box in each shallower trench. No gaps: none, and 0."""
    gaps = [piece for piece in pieces if isinstance(piece, Gaps)]
    if not gaps:
        return [], 0.0
    floor = -max(piece.depth for piece in gaps)
    holes = [
        (begin, end, piece.center_y - 0.5 * piece.width, piece.center_y + 0.5 * piece.width, piece.depth)
        for piece in gaps
        for begin, end in piece.trenches
    ]
    edges = sorted({-GROUND_EXTENT, GROUND_EXTENT, *(h[0] for h in holes), *(h[1] for h in holes)})
    boxes: list[Box] = []
    for x0, x1 in itertools.pairwise(edges):
        if x1 - x0 <= 1e-9:
            continue
        inside = sorted((h[2], h[3]) for h in holes if h[0] < 0.5 * (x0 + x1) < h[1])
        y = -GROUND_EXTENT
        for y0, y1 in [*inside, (GROUND_EXTENT, GROUND_EXTENT)]:
            if y0 - y > 1e-9:
                boxes.append(
                    (
                        f"{len(boxes)}",
                        (0.5 * (x0 + x1), 0.5 * (y + y0), 0.5 * floor),
                        (0.5 * (x1 - x0), 0.5 * (y0 - y), -0.5 * floor),
                        0.0,
                    )
                )
            y = max(y, y1)
    for x0, x1, y0, y1, depth in holes:
        if depth < -floor - 1e-9:  # a trench shallower than the floor: its own bottom
            boxes.append(
                (
                    f"{len(boxes)}",
                    (0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.5 * (floor - depth)),
                    (0.5 * (x1 - x0), 0.5 * (y1 - y0), 0.5 * (-depth - floor)),
                    0.0,
                )
            )
    return boxes, floor


def _contact(friction: float) -> str:
    return f'contype="1" conaffinity="1" condim="3" friction="{friction:.10g} 0.005 0.0001"'


def _box_xml(name: str, box: Box, friction: float, rgba: str) -> str:
    _, centre, half, pitch = box
    # rotation about y by -pitch turns the x axis to (cos, 0, sin pitch): the top face rises along +x
    quat = (math.cos(-0.5 * pitch), 0.0, math.sin(-0.5 * pitch), 0.0)
    return (
        f'    <geom name="{name}" type="box" '
        f'pos="{centre[0]:.10g} {centre[1]:.10g} {centre[2]:.10g}" '
        f'size="{half[0]:.10g} {half[1]:.10g} {half[2]:.10g}" '
        f'quat="{quat[0]:.10g} {quat[1]:.10g} {quat[2]:.10g} {quat[3]:.10g}" '
        f'{_contact(friction)} rgba="{rgba}"/>\n'
    )


def terrain_xml(pieces: Sequence[Terrain], friction: float) -> tuple[str, str]:
    """MJCF of ``pieces``: the ``<asset>`` entries (height fields) and the world body's ``<geom>`` lines,
    colliding like the floor with ``friction``."""
    assets, lines = [], []
    for index, piece in enumerate(pieces):
        kind = type(piece).__name__.lower()
        for box in piece.boxes():
            lines.append(_box_xml(f"{TERRAIN_PREFIX}{index}_{kind}_{box[0]}", box, friction, _RGBA))
        if isinstance(piece, Rough):
            asset, geom = piece.hfield_xml(f"{TERRAIN_PREFIX}{index}_{kind}")
            assets.append(asset)
            lines.append(
                f'    <geom name="{TERRAIN_PREFIX}{index}_{kind}_field" {geom} {_contact(friction)} '
                f'priority="1" solref="{FIELD_SOLREF[0]:.10g} {FIELD_SOLREF[1]:.10g}" rgba="{_RGBA}"/>\n'
            )
    for box in ground_boxes(pieces)[0]:
        lines.append(_box_xml(f"{TERRAIN_PREFIX}ground_{box[0]}", box, friction, _GROUND_RGBA))
    return "".join(assets), "".join(lines)


_FLOOR = re.compile(r'<geom\b[^>]*\bname="floor"[^>]*>')


def _lowered_floor(mjcf: str, height: float) -> str:
    """``mjcf`` with its floor plane (the geom named ``floor``) at ``height``."""
    match = _FLOOR.search(mjcf)
    if match is None:
        raise ValueError("the robot's MJCF has no geom named floor to lower under the gaps")
    tag = re.sub(r'\spos="[^"]*"', "", match.group(0))
    tag = tag.replace("<geom", f'<geom pos="0 0 {height:.10g}"', 1)
    return mjcf[: match.start()] + tag + mjcf[match.end() :]


def with_terrain(mjcf: str, pieces: Sequence[Terrain], friction: float) -> str:
    """The robot's MJCF with ``pieces`` added to its world body (unchanged without pieces)."""
    if not pieces:
        return mjcf
    marker = "</worldbody>"
    index = mjcf.rfind(marker)
    if index < 0:
        raise ValueError("the robot's MJCF has no </worldbody> to add terrain to")
    assets, geoms = terrain_xml(pieces, friction)
    mjcf = mjcf[:index] + geoms + mjcf[index:]
    if assets:
        world = mjcf.find("<worldbody")
        mjcf = mjcf[:world] + "<asset>\n" + assets + "  </asset>\n  " + mjcf[world:]
    floor = ground_boxes(pieces)[1]
    return _lowered_floor(mjcf, floor) if floor < 0 else mjcf


def _heights(pieces: Sequence[Terrain], x: float, y: float) -> list[float]:
    return [h for piece in pieces if not isinstance(piece, Gaps) and (h := piece.height_at(x, y)) is not None]


def support_height(pieces: Sequence[Terrain], x: float, y: float = 0.0) -> float:
    """Highest terrain surface at world ``(x, y)`` with the gaps bridged (0: the floor's level): the ground a
    fall is measured from."""
    return max([0.0, *_heights(pieces, x, y)])


def terrain_height(pieces: Sequence[Terrain], x: float, y: float = 0.0) -> float:
    """Highest terrain surface at world ``(x, y)``: the floor's level (0), a trench's bottom inside a gap,
    or the piece on it."""
    bottoms = [h for piece in pieces if isinstance(piece, Gaps) and (h := piece.height_at(x, y)) is not None]
    return max([max(bottoms) if bottoms else 0.0, *_heights(pieces, x, y)])


def terrain_piece(item: TerrainConfig) -> Terrain:
    """The piece of one ``scene.terrain`` entry (the config fills each kind's keys)."""
    common = {"start": item.start, "width": item.width, "center_y": item.center_y}
    values = {key: getattr(item, key) for key in TERRAIN_KEYS[item.kind]}
    return TERRAIN_KINDS[item.kind](**common, **values)


TERRAIN_KINDS: dict[str, type[Terrain]] = {
    "slope": Slope,
    "steps": Steps,
    "stairs": Stairs,
    "rough": Rough,
    "gaps": Gaps,
}
"""``scene.terrain[].kind`` -> its piece."""


def terrain_pieces(scene: SceneConfig) -> list[Terrain]:
    """The pieces of a config's ``scene`` section (``scene.terrain``), in order."""
    return [terrain_piece(item) for item in scene.terrain]
