"""The plant's scene: terrain on the floor (``sim.terrain``) and a bar to jump over (``sim.bar``).

The scene changes only the MuJoCo model of the plant, its videos and the viewer; the controller keeps
planning on flat ground without obstacles.
"""

from __future__ import annotations

from dataclasses import dataclass

from cafe_mpc.config import SceneConfig
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.sim.bar import Bar, bar_of, with_bar
from cafe_mpc_lab.sim.terrain import Terrain, terrain_pieces, with_terrain


@dataclass(frozen=True)
class Scene:
    """Slopes and steps on the floor, and the bar (None: no bar); the default is the flat, empty floor."""

    terrain: tuple[Terrain, ...] = ()
    bar: Bar | None = None

    def mjcf(self, robot: Robot) -> str:
        """The plant's MJCF: the robot's, with the terrain on its floor and the bar in its world."""
        return with_bar(with_terrain(robot.mjcf, self.terrain, robot.plant.floor_friction), self.bar)


def scene_of(scene: SceneConfig) -> Scene:
    """The ``Scene`` of a config's ``scene`` section."""
    return Scene(tuple(terrain_pieces(scene)), bar_of(scene))
