"""The plant contract (``sim.plant.Plant``): every plant of the registry (``sim.assembly.PLANTS``), built
from a run config, checks its reset state, reads back what it was set to, advances time by whole physics
steps, saturates torques at its limits and pushes its trunk; an unknown ``plant.kind`` is one clear error."""

from __future__ import annotations

import importlib.util
import typing

import mujoco
import numpy as np
import pytest

from cafe_mpc.assembly import load_run_config, resolve
from cafe_mpc.assembly.checks import robot_of
from cafe_mpc.config import PlantConfig
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.sensors import SensorReadings
from cafe_mpc.robots.robot import load_robot
from cafe_mpc_lab.sim.assembly import PLANTS, build_plant, plant_factory
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant
from cafe_mpc_lab.sim.plant import Plant
from cafe_mpc_lab.sim.randomization import SensorModel
from cafe_mpc_lab.sim.sensors import IdealSensors, SensorSuite, StateSensors

GYM = importlib.util.find_spec("gym_quadruped") is not None


@pytest.fixture(
    scope="module",
    params=[
        "mujoco",
        pytest.param(
            "gym-quadruped",
            marks=pytest.mark.skipif(
                not GYM, reason="gym-quadruped is not installed (make test installs it)"
            ),
        ),
    ],
)
def plant(request):
    """The Mini Cheetah (the model file gym-quadruped simulates too) in the plant of each kind."""
    config = load_run_config(
        "stand",
        [f"plant.kind={request.param}", "robot=mini_cheetah_gym", "estimator=ground_truth"],
    )
    setup = build_plant(resolve(config, robot_of(config)))
    yield setup.plant
    setup.plant.close()


def _tilted_state(plant: Plant, seed: int) -> tuple[np.ndarray, np.ndarray]:
    robot = plant.robot
    rng = np.random.default_rng(seed)
    q = robot.q_standing.copy()
    q[3:7] = [0.05, -0.03, 0.2, 1.0]
    q[3:7] /= np.linalg.norm(q[3:7])
    q[7:] += rng.uniform(-0.1, 0.1, robot.nu)
    return q, rng.normal(scale=0.3, size=robot.nv)


def test_every_kind_of_the_config_has_a_plant():
    kinds = typing.get_args(PlantConfig.model_fields["kind"].annotation)
    assert set(PLANTS) == set(kinds)
    assert all(plant_factory(kind) is PLANTS[kind] for kind in kinds)


def test_an_unknown_plant_kind_is_one_clear_error():
    with pytest.raises(
        ValueError, match=r"^plant\.kind 'isaac' is not a plant; plants: mujoco, gym-quadruped$"
    ):
        plant_factory("isaac")
    config = load_run_config("stand").model_copy(update={"plant": PlantConfig.model_construct(kind="isaac")})
    with pytest.raises(ValueError, match=r"plant\.kind 'isaac'") as error:
        build_plant(resolve(config, robot_of(load_run_config("stand"))))
    assert "\n" not in str(error.value)


def test_the_plant_is_the_kind_the_config_names(plant):
    assert isinstance(plant, Plant)
    assert plant.kind in PLANTS
    assert isinstance(plant.sensors, SensorModel) and plant.sensors.is_identity  # ground truth, no noise
    assert plant.bar is None and not plant.bar_touched_by()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda q, v: (q[:-1], v), r"reset expects q \(19,\) and v \(18,\)"),
        (lambda q, v: (q, np.zeros(3)), r"reset expects q \(19,\) and v \(18,\)"),
        (lambda q, v: (np.where(np.arange(len(q)) == 8, np.nan, q), v), "NaN or inf"),
        (lambda q, v: (q, np.full_like(v, np.inf)), "NaN or inf"),
    ],
    ids=["short q", "short v", "NaN in q", "inf in v"],
)
def test_a_bad_reset_state_is_rejected(plant, change, message):
    q, v = _tilted_state(plant, 0)
    with pytest.raises(ValueError, match=message):
        plant.reset(*change(q, v))


def test_reset_and_read_state_round_trip_in_planning_coordinates(plant):
    robot = plant.robot
    q, v = _tilted_state(plant, 1)
    plant.reset(q, v)
    state = plant.read_state()
    assert isinstance(state, Measurement) and plant.time == state.time == 0.0
    assert state.q.shape == (robot.nq,) and state.v.shape == (robot.nv,)
    assert state.contacts.shape == (robot.n_feet,) and state.contacts.dtype == bool
    assert state.foot_forces.shape == (robot.n_feet, 3)
    np.testing.assert_allclose(state.q, q, atol=1e-12)
    np.testing.assert_allclose(state.v, v, atol=1e-12)
    assert not plant.trunk_touched_floor
    plant.reset(robot.q_standing)  # v None: at rest
    np.testing.assert_array_equal(plant.read_state().v, np.zeros(robot.nv))


def test_step_advances_whole_physics_steps_and_saturates_the_torques(plant):
    robot = plant.robot
    plant.reset(robot.q_standing)
    limits = plant.torque_limits
    assert limits.shape == (robot.nu,) and np.all(limits > 0) and np.all(np.isfinite(limits))
    command = np.where(np.arange(robot.nu) % 2 == 0, 3.0, -3.0) * limits
    np.testing.assert_array_equal(plant.applied(command), np.sign(command) * limits)
    small = 0.1 * command
    np.testing.assert_array_equal(plant.applied(small), small)
    plant.step(command, 3)
    assert plant.time == pytest.approx(3 * plant.timestep, abs=1e-15)
    np.testing.assert_allclose(plant.applied_torques(), np.sign(command) * limits, rtol=1e-12)
    state = plant.read_state()
    assert state.time == plant.time and np.all(np.isfinite(state.q)) and np.all(np.isfinite(state.v))
    assert not np.allclose(state.v[6:], 0.0)  # the joints moved


def test_an_external_force_pushes_the_trunk_sideways(plant):
    robot = plant.robot
    held = np.zeros(robot.nu)
    plant.reset(robot.q_standing + np.r_[0.0, 0.0, 0.5, np.zeros(robot.nq - 3)])  # in the air
    plant.set_external_force(np.array([0.0, 50.0 * robot.total_mass, 0.0]))
    plant.step(held, 20)
    pushed = plant.read_state().q[1]
    plant.set_external_force(np.zeros(3))
    plant.reset(robot.q_standing + np.r_[0.0, 0.0, 0.5, np.zeros(robot.nq - 3)])
    plant.step(held, 20)
    assert pushed - plant.read_state().q[1] > 1e-3  # 50 m/s^2 over 20 steps: a few mm sideways


def test_every_plant_carries_the_robots_sensors():
    """The default config (state estimator) builds the robot's sensors on every plant: our plant reads MuJoCo
    sensors of its model, gym-quadruped's environment the same quantities computed from its state."""
    config = load_run_config("stand", ["robot=mini_cheetah_gym"])  # the state estimator reads the sensors
    robot = robot_of(config)
    setup = build_plant(resolve(config, robot))
    assert isinstance(setup.plant, MujocoPlant) and isinstance(setup.plant.sensors, SensorSuite)
    setup.plant.reset(robot.q_standing)
    readings = setup.plant.sensors.measure(0, setup.plant, setup.plant.read_state())
    np.testing.assert_allclose(readings.joint_positions, robot.q_standing[7:], atol=1e-3)
    if GYM:
        gym_config = load_run_config("stand", ["robot=mini_cheetah_gym", "plant.kind=gym-quadruped"])
        gym_setup = build_plant(resolve(gym_config, robot))
        try:
            plant = gym_setup.plant
            assert isinstance(plant.sensors, SensorSuite)
            plant.reset(robot.q_standing)
            gym_readings = plant.sensors.measure(0, plant, plant.read_state())
            np.testing.assert_allclose(gym_readings.joint_positions, robot.q_standing[7:], atol=1e-3)
            np.testing.assert_allclose(
                gym_readings.orientation, [0.0, 0.0, 0.0, 1.0], atol=0.01
            )  # + IMU noise
        finally:
            gym_setup.plant.close()


@pytest.mark.parametrize("name", ["mini_cheetah", "pegasus"])
def test_sensors_from_the_state_equal_mujocos_sensors(name):
    """``StateSensors`` (for a plant whose model has no sensors) computes what MuJoCo's gyro, accelerometer,
    frame orientation and joint sensors of our plant report, in a moving state with torques applied, and after
    physics steps (the IMU's running sums); Pegasus's model file mounts its IMU turned 90 degrees in yaw."""
    robot = load_robot(name)
    plant = MujocoPlant(robot)
    ideal = IdealSensors(plant.model, robot.joint_names)
    from_state = StateSensors(plant.model, plant.base_body, robot.joint_names)
    rng = np.random.default_rng(3)
    q = robot.q_standing.copy()
    q[2] += 0.1
    q[3:7] = [0.1, -0.05, 0.2, 1.0] / np.linalg.norm([0.1, -0.05, 0.2, 1.0])
    plant.reset(q, rng.normal(0.0, 0.5, robot.nv))
    plant.step(rng.uniform(-5.0, 5.0, robot.nu), 3)
    mujoco.mj_forward(plant.model, plant.data)
    expected, got = SensorReadings.zeros(robot.nu), SensorReadings.zeros(robot.nu)
    ideal.read(plant.data, expected)
    from_state.read(plant.data, got)
    for name in (
        "gyro",
        "accelerometer",
        "orientation",
        "joint_positions",
        "joint_velocities",
        "joint_torques",
    ):
        np.testing.assert_allclose(getattr(got, name), getattr(expected, name), atol=1e-9, err_msg=name)
    assert np.linalg.norm(got.gyro) > 0.1 and np.linalg.norm(got.accelerometer) > 0.05  # a moving state
    sums = [np.zeros(3) for _ in range(4)]
    mujoco.mj_step(plant.model, plant.data)
    ideal.add_imu(plant.data, sums[0], sums[1])
    from_state.add_imu(plant.data, sums[2], sums[3])
    np.testing.assert_allclose(sums[2], sums[0], atol=1e-9)
    np.testing.assert_allclose(sums[3], sums[1], atol=1e-9)
