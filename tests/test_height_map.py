"""The plant's height-map sensor (``sim.height_map``) against the scene's true heights, and its log."""

from __future__ import annotations

import numpy as np
import pytest

from cafe_mpc.config import SceneConfig
from cafe_mpc.config.run import HeightMapConfig
from cafe_mpc_lab.sim.height_map import maps_of
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant
from cafe_mpc_lab.sim.scene import scene_of
from cafe_mpc_lab.sim.terrain import terrain_height, terrain_pieces


@pytest.mark.parametrize(
    "piece",
    [
        {"kind": "steps", "rise": 0.04},
        {"kind": "slope", "angle_deg": 10, "length": 1.5},
        {"kind": "stairs"},
        {"kind": "rough"},
    ],
)
def test_the_height_map_measures_the_scenes_heights(robot, piece):
    """Without noise every cell sees the terrain's surface under its centre (cells on a step's edge may see
    either side: left out)."""
    scene = SceneConfig(terrain=[piece])
    settings = HeightMapConfig(enabled=True, noise=0.0, range=3.0, length=2.0, width=0.8)
    plant = MujocoPlant(robot, scene=scene_of(scene), height_map=settings)
    q = robot.q_standing.copy()
    q[0] = 1.5
    plant.reset(q, np.zeros(robot.nv))
    assert plant.height_map is not None
    measured = plant.height_map.measure(0.0, plant.read_state().q)
    pieces = terrain_pieces(scene)
    centres = measured.cell_centres()
    assert measured.valid.all()
    errors = []
    for row in range(measured.shape[0]):
        for column in range(measured.shape[1]):
            x, y = centres[row, column]
            near = [terrain_height(pieces, x + dx, y) for dx in (-1e-3, 1e-3)]
            if abs(near[0] - near[1]) > 0.005:
                continue  # on a step's edge
            errors.append(abs(measured.heights[row, column] - terrain_height(pieces, x, y)))
    assert len(errors) > 0.9 * measured.valid.size
    assert max(errors) < 1e-6
    assert np.max(measured.heights) > 0.02  # it saw the terrain, not only the floor


def test_height_maps_are_taken_at_their_rate_with_noise_and_logged(robot):
    scene = SceneConfig(terrain=[{"kind": "steps", "rise": 0.04}])
    settings = HeightMapConfig(enabled=True, rate_hz=20.0, noise=0.005)
    plant = MujocoPlant(robot, scene=scene_of(scene), height_map=settings, seed=3)
    plant.reset(robot.q_standing, np.zeros(robot.nv))
    sensor = plant.height_map
    assert sensor is not None
    taken = [sensor.observe(t, robot.q_standing) for t in np.arange(0.0, 0.2, 0.002)]
    assert sum(m is not None for m in taken) == 4  # 0, 50, 100, 150 ms
    heights = np.array([m.heights for m in sensor.maps])
    assert 0.002 < float(np.std(heights[:, :, :5] - 0.0)) < 0.01  # the floor under the base, with noise
    maps = maps_of(sensor.log_arrays())
    assert len(maps) == 4 and np.array_equal(maps[2].heights, sensor.maps[2].heights)
