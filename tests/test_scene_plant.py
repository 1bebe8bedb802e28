"""Plant and scene overrides from the run config (issue 15): floor friction, mass scale, terrain, and the
controller's own friction coefficient (``mpc.friction``), each validated at the boundary."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from cafe_mpc.assembly import build_controller, build_low_level, build_planner, load_run_config, resolve
from cafe_mpc.config import CONTROLLER_FRICTION, VWBC_FRICTION_HEADROOM, ConfigError
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant
from cafe_mpc_lab.sim.randomization import PlantVariation, plant_variation, terrain_geoms
from cafe_mpc_lab.sim.scene import Scene, scene_of
from cafe_mpc_lab.sim.terrain import Rough, Slope, Steps, terrain_height, terrain_pieces, with_terrain


def _ray_height(plant: MujocoPlant, x: float, y: float = 0.0) -> float:
    mujoco.mj_forward(plant.model, plant.data)
    geom = np.zeros(1, dtype=np.int32)
    distance = mujoco.mj_ray(
        plant.model, plant.data, np.array([x, y, 2.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, geom
    )
    return 2.0 - distance


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("plant.floor_friction=0", "plant.floor_friction"),
        ("plant.floor_friction=3", "plant.floor_friction"),
        ("plant.mass_scale=2", "plant.mass_scale"),
        ("plant.mass_scale=.nan", "plant.mass_scale"),
        ("mpc.friction=0", "mpc.friction"),
        ("mpc.friction=-0.5", "mpc.friction"),
        ("scene.terrain=[{kind: hill}]", "scene.terrain.0.kind"),
        ("scene.terrain=[{kind: slope, angle_deg: 45}]", "scene.terrain.0.angle_deg"),
        ("scene.terrain=[{kind: steps, rise: 0.5}]", "scene.terrain.0.rise"),
        ("scene.terrain=[{kind: slope, rise: 0.02}]", "'rise' belongs to terrain of kind steps"),
        ("scene.terrain=[{kind: steps, width: 0}]", "scene.terrain.0.width"),
        ("scene.terrain=[{kind: steps, typo: 1}]", "scene.terrain.0.typo: unknown key"),
        ("scene.terrain=[{start: 1}]", "scene.terrain.0.kind"),
    ],
)
def test_bad_plant_and_scene_values_are_rejected_naming_the_key(override, message):
    with pytest.raises(ConfigError, match="invalid config") as error:
        load_run_config("trot", [override])
    assert message in str(error.value)
    assert "\n" not in str(error.value)


def test_terrain_defaults_fill_the_kind_and_reach_the_plant(robot):
    config = load_run_config(
        "trot",
        ["scene.terrain=[{kind: slope, start: 1.0, angle_deg: 10}, {kind: steps, start: 5.0, rise: 0.05}]"],
    )
    slope, steps = config.scene.terrain
    assert (slope.length, slope.count) == (1.0, None) and (steps.count, steps.run, steps.angle_deg) == (
        3,
        0.3,
        None,
    )
    pieces = terrain_pieces(config.scene)
    assert pieces == [Slope(start=1.0, angle_deg=10.0), Steps(start=5.0, rise=0.05)]
    assert scene_of(config.scene) == Scene(tuple(pieces))  # no bar
    plant = MujocoPlant(robot, scene=Scene(tuple(pieces)))
    names = [plant.model.geom(i).name for i in terrain_geoms(plant.model)]
    assert names[:3] == ["terrain_0_slope_up", "terrain_0_slope_top", "terrain_0_slope_down"]
    # the geoms' surfaces are where the pieces say (rays from above)
    for x in (0.5, 1.01, 1.5, 1.99, 2.5, 3.5, 4.5, 5.1, 5.4, 5.7, 6.5, 7.2, 8.0):
        assert _ray_height(plant, x) == pytest.approx(terrain_height(pieces, x), abs=1e-6), x
    assert _ray_height(plant, 2.5, y=1.5) == pytest.approx(0.0, abs=1e-9)  # off the 2 m width
    assert Scene().mjcf(robot) == robot.mjcf  # no terrain: the robot's own model


def test_floor_friction_and_mass_scale_change_the_plant_only(robot):
    scene = Scene((Steps(start=0.5),))
    plant = MujocoPlant(robot, variation=PlantVariation(floor_friction=0.3, mass_scale=1.2), scene=scene)
    friction = plant.model.geom_friction[:, 0]
    floor = plant.model.geom("floor").id
    assert friction[floor] == 0.3
    assert np.all(friction[terrain_geoms(plant.model)] == 0.3)  # terrain is floor too
    assert float(np.sum(plant.model.body_mass)) == pytest.approx(1.2 * robot.total_mass)
    nominal = MujocoPlant(robot, scene=scene)
    assert float(np.sum(nominal.model.body_mass)) == pytest.approx(robot.total_mass)
    assert np.all(nominal.model.geom_friction[terrain_geoms(nominal.model), 0] == robot.plant.floor_friction)
    with pytest.raises(ValueError, match="mass_scale"):
        MujocoPlant(robot, variation=PlantVariation(mass_scale=0.0))
    config = load_run_config("trot", ["plant.mass_scale=1.2", "plant.floor_friction=0.3"])
    variation = plant_variation(config.plant)
    assert (variation.mass_scale, variation.floor_friction) == (1.2, 0.3)


def test_mpc_friction_is_the_controllers_own_and_independent_of_the_plant(robot):
    run = resolve(load_run_config("trot", ["mpc.friction=0.35", "plant.floor_friction=0.9"]), robot)
    assert run.contact.friction == 0.35
    mpc = build_planner(run)
    assert mpc.builder.whole_body.settings.constraints.friction_coefficient == 0.35
    # the VWBC's pyramid (34f) leaves headroom over the plan's relaxed one unless set apart
    assert build_low_level(run).contact.friction == pytest.approx(VWBC_FRICTION_HEADROOM * 0.35)
    apart = resolve(load_run_config("trot", ["mpc.friction=0.35", "vwbc.friction=0.5"]), robot)
    assert (apart.contact.friction, apart.vwbc_contact.friction) == (0.35, 0.5)
    assert build_low_level(apart).contact.friction == 0.5  # the VWBC's pyramid (34f) and its cone count
    assert build_planner(apart).builder.whole_body.settings.constraints.friction_coefficient == 0.35
    template = build_controller(
        resolve(load_run_config("trot", ["mpc.friction=0.35", "planner=template"]), robot)
    )
    assert template.planner.builder.friction == 0.35
    default = load_run_config("trot")
    assert default.mpc.friction == CONTROLLER_FRICTION == 0.4
    assert default.plant.floor_friction is None  # the robot table's 0.6
    assert build_low_level(resolve(default, robot)).contact.friction == pytest.approx(0.5)


@pytest.mark.slow
def test_a_trot_climbs_low_steps(tmp_path):
    """Terrain in a closed loop: 2 cm steps under a flat-ground plan; the feet stand on them, nobody falls."""
    from cafe_mpc_lab.experiments.run import simulate_run

    config = load_run_config(
        "trot",
        [
            "simulation.duration=2.5",
            "mpc.latency=fixed",
            "scene.terrain=[{kind: steps, start: 0.3, count: 2, rise: 0.02, run: 0.3, top_length: 1.0}]",
        ],
    )
    run, _, log = simulate_run(config)
    robot = run.robot
    assert not log.fell
    feet = np.array([robot.foot_positions(q) for q in log.q[::25]])
    contacts = log.contacts[::25]
    on_step = feet[..., 2][contacts] > robot.foot_radius + 0.015  # a stance foot on a 2 or 4 cm tread
    assert on_step.sum() > 10
    assert log.q[-1, 0] > 0.7  # it got onto the top (from 0.9 m on)


def test_a_loaded_foot_landing_on_the_rough_fields_cell_diagonals_stays_on_top(robot):
    """A foot sphere pushed down by 200 N (a stance leg's share and more) landing at 3 m/s on the middle of
    each inner cell's diagonal of the experiment's rough field (``rough2``) stays on the surface. MuJoCo
    collides a sphere with a height field as with one vertical prism per triangle; at MuJoCo's default
    contact time constant (0.02 s) 315 of these 324 drops took the sphere's centre below the surface and 34
    ended there, the walls between a cell's two prisms pushing it sideways from both sides (google-deepmind/
    mujoco issue 2883); with the field's stiffer contacts (``sim.terrain.FIELD_SOLREF``) none goes below."""
    piece = Rough(amplitude=0.02, start=0.0)
    radius = robot.foot_radius
    mjcf = (
        '<mujoco><option timestep="0.001" integrator="implicitfast" cone="elliptic"/><worldbody>'
        '<geom name="floor" type="plane" size="0 0 0.05"/>'
        f'<body name="foot"><freejoint/><geom type="sphere" size="{radius}" mass="1" contype="0" '
        'conaffinity="1"/></body></worldbody></mujoco>'
    )
    model = mujoco.MjModel.from_xml_string(with_terrain(mjcf, [piece], robot.plant.floor_friction))
    data = mujoco.MjData(model)
    foot = model.body("foot").id
    rows, columns = piece.grid
    depths = []
    for row in range(1, rows - 2):
        for column in range(1, columns - 2):
            low, high = piece.vertex(row, column), piece.vertex(row + 1, column + 1)
            x, y = 0.5 * (low[0] + high[0]), 0.5 * (low[1] + high[1])
            mujoco.mj_resetData(model, data)
            data.qpos[:3] = [x, y, piece.height_at(x, y) + radius + 0.001]
            data.qvel[:3] = [0.5, 0.0, -3.0]
            data.xfrc_applied[foot, 2] = -200.0
            for _ in range(200):
                mujoco.mj_step(model, data)
                surface = piece.height_at(data.qpos[0], data.qpos[1])
                depths.append((surface if surface is not None else 0.0) - data.qpos[2])
    assert len(depths) == 324 * 200
    assert max(depths) < 0.0  # every sphere centre above the surface throughout
