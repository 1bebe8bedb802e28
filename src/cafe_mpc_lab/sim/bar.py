"""A thin horizontal bar in the plant's scene: the 0.4 m cable of the running barrel roll (paper Fig. 14, 15).

``Bar`` is a capsule of radius ``radius`` whose axis runs at ``height`` above the floor through the world
point ``position`` (x, y), in the direction ``yaw`` (rad from the world x axis), ``length`` long. It is a
static geom of the world body named ``bar`` (config keys ``scene.bar_*``; ``scene.bar_height`` 0 or null:
no bar).

Contacts: the bar collides with every geom of the robot. The plant's trunk and feet already collide with
the floor (contype 0, conaffinity 1), and the bar's contype includes that bit. The leg capsules (abad links,
thighs, shanks) collide with nothing in the plain plant; with a bar they get the conaffinity bit
``BAR_BIT``, which only the bar's contype has, so the legs collide with the bar and still not with the
floor, the terrain or each other (``with_bar``). ``MujocoPlant`` reports any contact of a robot geom with the
bar (``bar_in_contact``); ``bar_clearance`` measures, post hoc from logged states, the smallest distance
between the bar's surface and any robot geom (negative: penetration).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

BAR_NAME = "bar"
BAR_BIT = 2
"""Collision bit the bar's contype and the leg capsules' conaffinity share (the floor uses bit 1)."""


@dataclass(frozen=True)
class Bar:
    """A horizontal capsule (see the module docstring); all lengths in m, ``yaw`` in rad."""

    height: float
    position: tuple[float, float] = (0.0, 0.0)
    yaw: float = 0.0
    length: float = 2.0
    radius: float = 0.005

    def __post_init__(self) -> None:
        values = (self.height, *self.position, self.yaw, self.length, self.radius)
        if not all(math.isfinite(value) for value in values):
            raise ValueError(f"bar: every value must be finite, got {self}")
        if not (self.height > 0.0 and self.length > 0.0 and self.radius > 0.0):
            raise ValueError(f"bar: height, length and radius must be > 0, got {self}")

    @property
    def endpoints(self) -> tuple[np.ndarray, np.ndarray]:
        """The two ends of the bar's axis (world, m)."""
        direction = np.array([math.cos(self.yaw), math.sin(self.yaw), 0.0])
        centre = np.array([self.position[0], self.position[1], self.height])
        return centre - 0.5 * self.length * direction, centre + 0.5 * self.length * direction


def bar_of(scene) -> Bar | None:
    """The ``Bar`` of a config's ``scene`` section (``None`` when ``bar_height`` is 0 or null)."""
    height = getattr(scene, "bar_height", None)
    if not height:
        return None
    return Bar(
        float(height),
        (float(scene.bar_position[0]), float(scene.bar_position[1])),
        float(scene.bar_yaw),
        float(scene.bar_length),
        float(scene.bar_radius),
    )


def with_bar(mjcf: str, bar: Bar | None) -> str:
    """The plant's MJCF with the bar in its world body (world geom ``bar``), the robot's leg capsules made to
    collide with it (conaffinity bit ``BAR_BIT``; see the module docstring). Unchanged without a bar."""
    if bar is None:
        return mjcf
    marker = "</worldbody>"
    index = mjcf.rfind(marker)
    if index < 0:
        raise ValueError("the plant's MJCF has no </worldbody> to add the bar to")
    start, end = bar.endpoints
    fromto = " ".join(f"{value:.10g}" for value in (*start, *end))
    geom = (
        f'    <geom name="{BAR_NAME}" type="capsule" size="{bar.radius:.10g}" fromto="{fromto}" '
        f'contype="{1 | BAR_BIT}" conaffinity="0" condim="3" rgba="0.9 0.75 0.1 1"/>\n'
    )
    legs = mjcf[:index].replace('contype="0" conaffinity="0"', f'contype="0" conaffinity="{BAR_BIT}"')
    return legs + geom + mjcf[index:]


def robot_geoms(model: mujoco.MjModel) -> list[int]:
    """Ids of the geoms on the robot's bodies (everything but the world body's)."""
    return [g for g in range(model.ngeom) if int(model.geom_bodyid[g]) != 0]


def geom_label(model: mujoco.MjModel, geom: int) -> str:
    """A geom's name, or ``<body>:<index>`` for the unnamed leg capsules."""
    name = model.geom(geom).name
    return name if name else f"{model.body(int(model.geom_bodyid[geom])).name}:{geom}"


def bar_clearance(mjcf: str, bar: Bar, q: np.ndarray, bound: float = 1.0) -> tuple[np.ndarray, list[str]]:
    """Smallest distance (m) between the bar's surface and any robot geom at each row of ``q`` (planning
    coordinates: base position, quaternion x, y, z, w, joints), and which geom it was. Distances beyond
    ``bound`` read as ``bound``; negative values are penetrations."""
    model = mujoco.MjModel.from_xml_string(with_bar(mjcf, bar))
    data = mujoco.MjData(model)
    bar_id = model.geom(BAR_NAME).id
    geoms = robot_geoms(model)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    distances = np.full(len(q), bound)
    closest = [""] * len(q)
    fromto = np.zeros(6)
    for row, configuration in enumerate(q):
        data.qpos[:3] = configuration[:3]
        data.qpos[3] = configuration[6]
        data.qpos[4:7] = configuration[3:6]
        data.qpos[7:] = configuration[7:]
        mujoco.mj_kinematics(model, data)
        for geom in geoms:
            distance = mujoco.mj_geomDistance(model, data, bar_id, geom, bound, fromto)
            if distance < distances[row]:
                distances[row] = distance
                closest[row] = geom_label(model, geom)
    return distances, closest
