"""The plant's height-map sensor: the ground around the robot, as a depth camera's elevation map gives it.

``HeightMapSensor`` casts one vertical ray per cell of a grid centred ``forward_offset`` ahead of the base in
its heading frame (``length`` along the heading, ``width`` across, ``resolution`` apart: the run config's
``plant.height_map``), at ``rate_hz``, and returns a ``cafe_mpc.core.height_map.HeightMap``: each cell's
ground height with Gaussian ``noise``, and whether it was seen. A cell is invalid when its ray finds no
ground, or finds it farther than ``range`` from the base (a trench's far bottom, a cliff's foot): what a
camera on the trunk would not see.

The rays see the ground only: the floor and the terrain (``sim.terrain``), never the robot. The sensor puts
the ground's geoms into a geom group that no robot geom uses (``ground_group``) and casts with MuJoCo's
group filter on that group, excluding the trunk's body as well; the bar (``sim.bar``) is not ground.

The closed loop (``sim.loop.simulate``) asks the plant's sensor (``Plant.height_map``) at every control tick
and it measures when a map is due; a new map goes to the controller with that tick's readings
(``Measurement.height_map`` / ``SensorReadings.height_map``), relative to the base (``relative``: the
controller places it at its own estimate of the base's pose); the maps it took go into the run's log at
their rate (``SimulationLog.sampled``: ``height_map_time``, ``height_map_origin``, ``height_map_yaw``,
``height_map_heights``, ``height_map_valid``, ``height_map_resolution``; ``log.npz``: ``sampled_<name>``),
and ``maps_of`` turns them back into ``HeightMap``. The live viewer draws the newest one
(``draw_height_map``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import mujoco
import numpy as np

from cafe_mpc.config.run import HeightMapConfig
from cafe_mpc.core.height_map import HeightMap
from cafe_mpc_lab.sim.bar import BAR_NAME

GEOM_GROUPS = 6
"""MuJoCo's geom groups (``mjNGROUP``)."""
_DOWN = np.array([0.0, 0.0, -1.0])
NOISE_STREAM = 0x6D6170
"""Second word of the noise's seed: the plant's ``seed`` gives the sensor a stream of its own."""


def ground_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Ids of the ground's geoms: the world body's (floor, terrain), the bar excepted."""
    bar = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, BAR_NAME)
    return np.array([g for g in range(model.ngeom) if model.geom_bodyid[g] == 0 and g != bar], dtype=int)


def ground_group(model: mujoco.MjModel) -> int:
    """Give the ground's geoms a geom group of their own and return it.

    The ground keeps its group when no robot geom shares it; else it moves to the first group no robot geom
    uses, a group the viewer shows by default (0-2) first. Only the group changes: not the physics, and
    not the videos (they load the scene again)."""
    ground = ground_geoms(model)
    robot_groups = {int(group) for group in model.geom_group[model.geom_bodyid != 0]}
    own = {int(group) for group in model.geom_group[ground]}
    if len(own) == 1 and not own & robot_groups:
        return own.pop()
    free = [group for group in range(GEOM_GROUPS) if group not in robot_groups]
    if not free:
        raise ValueError("the height-map sensor needs a geom group no robot geom uses; every group is used")
    model.geom_group[ground] = free[0]
    return free[0]


class HeightMapSensor:
    """Vertical ray casts on a grid around the base (module docstring).

    ``model``, ``data``: the plant's (the ground's geoms get their own group: ``ground_group``);
    ``settings``: the config's ``plant.height_map``; ``base_body``: the trunk's body id; ``seed``: the noise's
    random stream (the plant's ``seed``). ``observe(t, q)`` at every control tick measures when a map is due
    (the first at the first tick) and returns it (None otherwise); ``latest`` is the newest map.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        settings: HeightMapConfig,
        base_body: int,
        seed: int = 0,
    ) -> None:
        self.model = model
        self.data = data
        self.settings = settings
        self.base_body = base_body
        self.seed = seed
        self.group = ground_group(model)
        self._groups = np.zeros(GEOM_GROUPS, dtype=np.uint8)
        self._groups[self.group] = 1
        self.resolution = settings.resolution
        self.columns = round(settings.length / settings.resolution)
        self.rows = round(settings.width / settings.resolution)
        # cell centres in the heading frame, relative to the grid's centre
        along = (np.arange(self.columns) - 0.5 * (self.columns - 1)) * self.resolution
        across = (np.arange(self.rows) - 0.5 * (self.rows - 1)) * self.resolution
        self._along, self._across = np.meshgrid(along + settings.forward_offset, across, indexing="xy")
        self._origin_offset = (along[0] + settings.forward_offset, across[0])
        self._point = np.zeros(3)
        self._geom = np.zeros(1, dtype=np.int32)
        self.reset()

    @property
    def period(self) -> float:
        return 1.0 / self.settings.rate_hz

    def reset(self) -> None:
        """Start a run: no maps, the first due at once, the noise's stream restarted."""
        self.maps: list[HeightMap] = []
        self.latest: HeightMap | None = None
        self._next = 0.0
        self._rng = np.random.default_rng((self.seed, NOISE_STREAM))

    def observe(self, t: float, q: np.ndarray) -> HeightMap | None:
        """At control tick time ``t`` with the base at ``q`` (planning coordinates): the map measured now
        when one is due (kept in ``maps``), else None."""
        if t < self._next - 1e-9:
            return None
        self._next += self.period * max(1, math.floor((t - self._next) / self.period + 1e-9) + 1)
        height_map = self.measure(t, q)
        self.maps.append(height_map)
        self.latest = height_map
        return height_map

    def measure(self, t: float, q: np.ndarray) -> HeightMap:
        """A map now: the rays cast down from ``range`` above the base through every cell's centre."""
        settings = self.settings
        x, y, z = float(q[0]), float(q[1]), float(q[2])
        qx, qy, qz, qw = (float(value) for value in q[3:7])
        yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        cos, sin = math.cos(yaw), math.sin(yaw)
        cells_x = x + cos * self._along - sin * self._across
        cells_y = y + sin * self._along + cos * self._across
        top = z + settings.range
        heights = np.zeros((self.rows, self.columns))
        valid = np.zeros((self.rows, self.columns), dtype=bool)
        model, data, point, geom, groups = self.model, self.data, self._point, self._geom, self._groups
        point[2] = top
        for row in range(self.rows):
            for column in range(self.columns):
                point[0], point[1] = cells_x[row, column], cells_y[row, column]
                distance = mujoco.mj_ray(model, data, point, _DOWN, groups, 1, self.base_body, geom)
                if distance < 0:
                    continue
                height = top - distance
                reach = math.sqrt((point[0] - x) ** 2 + (point[1] - y) ** 2 + (height - z) ** 2)
                if reach <= settings.range:
                    heights[row, column], valid[row, column] = height, True
        if settings.noise > 0:
            heights[valid] += self._rng.normal(0.0, settings.noise, size=int(valid.sum()))
        origin = (
            x + cos * self._origin_offset[0] - sin * self._origin_offset[1],
            y + sin * self._origin_offset[0] + cos * self._origin_offset[1],
        )
        return HeightMap(origin, yaw, self.resolution, heights, valid, float(t))

    @staticmethod
    def relative(height_map: HeightMap, q: np.ndarray) -> HeightMap:
        """``height_map`` as the trunk's sensor gives it to the controller: relative to the base at ``q``
        (its position and heading; ``HeightMap.relative_to``), its noise kept."""
        x, y, z = float(q[0]), float(q[1]), float(q[2])
        qx, qy, qz, qw = (float(value) for value in q[3:7])
        yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        return height_map.relative_to(x, y, z, yaw)

    def log_arrays(self) -> dict[str, np.ndarray]:
        """The maps taken since ``reset``, stacked for the run's log (module docstring)."""
        maps = self.maps
        shape = (len(maps), self.rows, self.columns)
        return {
            "height_map_time": np.array([m.time for m in maps], dtype=float),
            "height_map_origin": np.array([m.origin for m in maps], dtype=float).reshape(len(maps), 2),
            "height_map_yaw": np.array([m.yaw for m in maps], dtype=float),
            "height_map_heights": np.array([m.heights for m in maps], dtype=float).reshape(shape),
            "height_map_valid": np.array([m.valid for m in maps], dtype=bool).reshape(shape),
            "height_map_resolution": np.array([self.resolution]),
        }


def maps_of(arrays: Mapping[str, np.ndarray]) -> list[HeightMap]:
    """The ``HeightMap`` of each row of a log's height-map arrays (``HeightMapSensor.log_arrays``, or
    ``log.npz``'s with their ``sampled_`` prefix); none when the run had no sensor."""

    def get(name: str) -> np.ndarray | None:
        return arrays.get(f"height_map_{name}", arrays.get(f"sampled_height_map_{name}"))

    times = get("time")
    if times is None:
        return []
    origin, yaw, heights, valid = get("origin"), get("yaw"), get("heights"), get("valid")
    resolution = float(np.asarray(get("resolution")).ravel()[0])
    return [
        HeightMap(
            (float(origin[i, 0]), float(origin[i, 1])),
            float(yaw[i]),
            resolution,
            heights[i],
            valid[i],
            float(t),
        )
        for i, t in enumerate(times)
    ]


HEIGHT_MAP_RGBA = np.array([0.1, 0.85, 0.3, 0.9], dtype=np.float32)
"""Colour of the height map's points in the viewer."""
_IDENTITY = np.eye(3).flatten()


def draw_height_map(scene: mujoco.MjvScene, height_map: HeightMap, max_points: int = 600) -> int:
    """Append the map's valid cells to ``scene`` as small spheres at their measured heights (every cell, or
    every n-th row and column so that at most ``max_points`` are drawn). Returns the geoms added (fewer when
    the scene is full)."""
    rows, columns = height_map.shape
    stride = max(1, math.ceil(math.sqrt(rows * columns / max_points)))
    centres = height_map.cell_centres()
    size = np.array([0.006, 0.0, 0.0])
    added = 0
    for row in range(0, rows, stride):
        for column in range(0, columns, stride):
            if not height_map.valid[row, column]:
                continue
            if scene.ngeom >= scene.maxgeom:
                return added
            position = np.array([*centres[row, column], height_map.heights[row, column]])
            mujoco.mjv_initGeom(
                scene.geoms[scene.ngeom],
                mujoco.mjtGeom.mjGEOM_SPHERE,
                size,
                position,
                _IDENTITY,
                HEIGHT_MAP_RGBA,
            )
            scene.ngeom += 1
            added += 1
    return added
