"""Terrain in the plant's scene: slopes and steps as static MuJoCo boxes on the floor.

Only the MuJoCo model changes (the plant, its videos and the viewer); the controller keeps planning on flat
ground, so terrain tests how far its feedback carries it. Every piece runs along the world x axis from
``start``, across ``width`` m centred on ``center_y``, and (``descend``) comes down again after its flat top.
Geoms are named ``terrain_<piece>_<part>`` (``sim.randomization.TERRAIN_PREFIX``): they collide like the
floor (``contype``/``conaffinity`` 1, its friction, which ``plant.floor_friction`` changes with the floor's),
so feet touching them count as contacts and a trunk touching them as a fall.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from cafe_mpc.config import SceneConfig
from cafe_mpc_lab.sim.randomization import TERRAIN_PREFIX

_RGBA = "0.42 0.48 0.56 1"
_SLOPE_THICKNESS = 0.2  # m: the incline boxes reach below the floor, so no edge sticks out


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

    def boxes(self) -> list[tuple[str, tuple[float, float, float], tuple[float, float, float], float]]:
        """``(part, centre, half sizes, pitch)`` of each box; ``pitch`` turns the box about the y axis so that
        its top face rises along +x by that angle (rad)."""
        theta = math.radians(self.angle_deg)
        height, thickness = self.height, _SLOPE_THICKNESS
        half = (0.5 * self.length / math.cos(theta), 0.5 * self.width, 0.5 * thickness)
        parts = []
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

    def height_at(self, x: float, y: float = 0.0) -> float:
        """Terrain height at world ``(x, y)`` (0 off the piece)."""
        if abs(y - self.center_y) > 0.5 * self.width:
            return 0.0
        slope = math.tan(math.radians(self.angle_deg))
        top_start = self.start + self.length
        top_end = top_start + self.top_length
        if self.start <= x < top_start:
            return (x - self.start) * slope
        if top_start <= x <= top_end:
            return self.height
        if self.descend and top_end < x <= top_end + self.length:
            return (top_end + self.length - x) * slope
        return 0.0


@dataclass(frozen=True)
class Steps:
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

    def _treads(self) -> list[tuple[str, float, float, float]]:
        """``(part, x_begin, x_end, height)`` of every tread."""
        treads = []
        x = self.start
        for step in range(self.count):
            treads.append((f"up{step}", x, x + self.run, (step + 1) * self.rise))
            x += self.run
        if self.top_length > 0:
            treads.append(("top", x, x + self.top_length, self.height))
            x += self.top_length
        if self.descend:
            for step in range(self.count - 1, -1, -1):
                treads.append((f"down{step}", x, x + self.run, (step + 1) * self.rise))
                x += self.run
        return treads

    def boxes(self) -> list[tuple[str, tuple[float, float, float], tuple[float, float, float], float]]:
        return [
            (
                part,
                (0.5 * (begin + end), self.center_y, 0.5 * height),
                (0.5 * (end - begin), 0.5 * self.width, 0.5 * height),
                0.0,
            )
            for part, begin, end, height in self._treads()
        ]

    def height_at(self, x: float, y: float = 0.0) -> float:
        if abs(y - self.center_y) > 0.5 * self.width:
            return 0.0
        for _, begin, end, height in self._treads():
            if begin <= x < end:
                return height
        return 0.0


Terrain = Slope | Steps


def _check_finite(piece: object) -> None:
    for name, value in vars(piece).items():
        if isinstance(value, float | int) and not isinstance(value, bool) and not math.isfinite(value):
            raise ValueError(f"terrain {name} must be finite, got {value}")


def terrain_xml(pieces: Sequence[Terrain], friction: float) -> str:
    """MJCF ``<geom>`` lines of ``pieces`` (world body), colliding like the floor with ``friction``."""
    lines = []
    for index, piece in enumerate(pieces):
        kind = type(piece).__name__.lower()
        for part, centre, half, pitch in piece.boxes():
            # rotation about y by -pitch turns the x axis to (cos, 0, sin pitch): the top face rises along +x
            quat = (math.cos(-0.5 * pitch), 0.0, math.sin(-0.5 * pitch), 0.0)
            lines.append(
                f'    <geom name="{TERRAIN_PREFIX}{index}_{kind}_{part}" type="box" '
                f'pos="{centre[0]:.10g} {centre[1]:.10g} {centre[2]:.10g}" '
                f'size="{half[0]:.10g} {half[1]:.10g} {half[2]:.10g}" '
                f'quat="{quat[0]:.10g} {quat[1]:.10g} {quat[2]:.10g} {quat[3]:.10g}" '
                f'contype="1" conaffinity="1" condim="3" friction="{friction:.10g} 0.005 0.0001" '
                f'rgba="{_RGBA}"/>\n'
            )
    return "".join(lines)


def with_terrain(mjcf: str, pieces: Sequence[Terrain], friction: float) -> str:
    """The robot's MJCF with ``pieces`` added to its world body (unchanged without pieces)."""
    if not pieces:
        return mjcf
    marker = "</worldbody>"
    index = mjcf.rfind(marker)
    if index < 0:
        raise ValueError("the robot's MJCF has no </worldbody> to add terrain to")
    return mjcf[:index] + terrain_xml(pieces, friction) + mjcf[index:]


def terrain_height(pieces: Sequence[Terrain], x: float, y: float = 0.0) -> float:
    """Highest terrain surface at world ``(x, y)`` (0: the floor)."""
    return max([0.0, *(piece.height_at(x, y) for piece in pieces)])


def terrain_pieces(scene: SceneConfig) -> list[Terrain]:
    """The pieces of a config's ``scene`` section (``scene.terrain``), in order."""
    pieces: list[Terrain] = []
    for item in scene.terrain:
        common = {
            "start": item.start,
            "width": item.width,
            "center_y": item.center_y,
            "top_length": item.top_length,
            "descend": item.descend,
        }
        if item.kind == "slope":
            assert item.angle_deg is not None and item.length is not None
            pieces.append(Slope(angle_deg=item.angle_deg, length=item.length, **common))
        else:
            assert item.count is not None and item.rise is not None and item.run is not None
            pieces.append(Steps(count=item.count, rise=item.rise, run=item.run, **common))
    return pieces
