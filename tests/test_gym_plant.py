"""gym-quadruped's QuadrupedEnv as the plant: the state mapping (joint offsets) round-trips, the feet and
forces match the planning model, and a short closed-loop Go1 trot inside the environment stays up."""

from __future__ import annotations

import importlib.util

import numpy as np
import pinocchio as pin
import pytest

from cafe_mpc.assembly import load_run_config
from cafe_mpc.config import ConfigError
from cafe_mpc.robots.robot import load_robot
from cafe_mpc_lab.sim.gym_plant import JointOffsets

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("gym_quadruped") is None,
    reason="gym-quadruped is not installed (pip install 'cafe-mpc[gym]'; make test installs it)",
)


def test_joint_offsets_round_trip():
    offsets = JointOffsets(np.array([0.0, -np.pi / 2, 0.0] * 2 + [0.0, np.pi / 2, 0.0] * 2))
    joints = np.random.default_rng(0).uniform(-2.0, 2.0, 12)
    np.testing.assert_allclose(offsets.to_planning(offsets.to_environment(joints)), joints, atol=1e-15)
    np.testing.assert_allclose(offsets.to_environment(offsets.to_planning(joints)), joints, atol=1e-15)
    assert offsets.to_environment(np.zeros(12))[1] == pytest.approx(-np.pi / 2)


@pytest.fixture(scope="module")
def mini_cheetah_plant():
    from cafe_mpc_lab.sim.gym_plant import GymQuadrupedPlant

    robot = load_robot("mini_cheetah_gym")
    plant = GymQuadrupedPlant(robot, timestep=0.001)
    yield robot, plant
    plant.close()


def test_mini_cheetah_offsets_come_from_the_environment(mini_cheetah_plant):
    """gym-quadruped shifts the Mini Cheetah's thigh angles (qpos0 -pi/2 front, +pi/2 hind): the plant reads
    the offsets from the environment, and the state it reports is the planning model's."""
    robot, plant = mini_cheetah_plant
    np.testing.assert_allclose(plant.offsets.offsets, plant.env.robot_cfg.qpos0_js)
    assert plant.offsets.offsets[1] == pytest.approx(-np.pi / 2)
    assert plant.offsets.offsets[7] == pytest.approx(np.pi / 2)
    v = np.random.default_rng(1).normal(scale=0.3, size=robot.nv)
    plant.reset(robot.q_standing, v)
    state = plant.read_state()
    np.testing.assert_allclose(state.q, robot.q_standing, atol=1e-12)
    np.testing.assert_allclose(state.v, v, atol=1e-12)
    assert plant.time == 0.0
    # the environment's own feet are where the planning model puts them: the mapping is the kinematic one
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, robot.q_standing)
    for foot, geom in zip(robot.foot_frame_ids, robot.plant_foot_geoms, strict=True):
        np.testing.assert_allclose(
            plant.data.geom_xpos[plant.model.geom(geom).id], data.oMf[foot].translation, atol=1e-9
        )


def test_standing_contact_forces_carry_the_weight(mini_cheetah_plant):
    """Feet matched to the environment's legs; forces are the ground's push on each foot (world frame)."""
    robot, plant = mini_cheetah_plant
    q = robot.q_standing.copy()
    q[2] -= 0.002  # feet slightly in the floor: they touch at once
    plant.reset(q)
    gravity = pin.computeGeneralizedGravity(robot.model, robot.model.createData(), q)[6:]
    totals = []
    for _ in range(400):  # 0.4 s holding the pose: static torques, joint PD
        state = plant.read_state()
        totals.append(state.foot_forces.sum(axis=0).copy())
        plant.step(gravity + 40.0 * (q[7:] - state.q[7:]) - 1.0 * state.v[6:], 1)
    state = plant.read_state()
    assert state.contacts.all() and np.all(state.foot_forces[:, 2] > 0)
    mean = np.mean(totals[-200:], axis=0)  # the last 0.2 s
    assert mean[2] == pytest.approx(robot.total_mass * 9.81, rel=0.05)
    assert abs(mean[0]) < 0.05 * mean[2] and abs(mean[1]) < 0.05 * mean[2]


def test_config_rejects_what_the_environment_cannot_do():
    with pytest.raises(ConfigError, match=r"go1' has none\. Shipped: .*go1_gym"):
        load_run_config("trot", ["plant.kind=gym-quadruped", "robot=go1"])
    with pytest.raises(ConfigError, match=r"not available there: plant\.mass_scale"):
        load_run_config(
            "trot",
            ["plant.kind=gym-quadruped", "robot=go2", "plant.mass_scale=1.2", "estimator=ground_truth"],
        )
    config = load_run_config("trot", ["plant.kind=gym-quadruped", "robot=go2"])  # the defaults otherwise
    assert config.plant.kind == "gym-quadruped" and config.estimator == "kinematic_kf"


@pytest.mark.slow
def test_go1_trots_inside_gym_quadruped():
    """A short closed-loop trot of the Go1 inside QuadrupedEnv (its own model, contacts and 23.7 Nm motors),
    controlled through the robot file only: it stays up and walks forward."""
    from cafe_mpc_lab.experiments.run import run

    config = load_run_config(
        "trot",
        [
            "robot=go1_gym",
            "plant.kind=gym-quadruped",
            "estimator=ground_truth",
            "mpc.latency=fixed",
            "simulation.duration=1.6",
            "output.plots=false",
        ],
    )
    result = run(config, None)
    log = result.log
    assert not log.fell, log.fall_reason
    assert log.time[-1] == pytest.approx(1.598, abs=1e-6)
    late = log.time > 1.0
    assert np.mean(log.v[late, 0]) > 0.25  # the command ramps to 0.5 m/s by t = 0.7 s
    assert np.all(np.abs(log.q[late, 2] - result.robot.standing_height) < 0.06)
    assert log.contacts[late].any(axis=1).all() and not log.contacts[late].all(axis=1).all()  # stepping
    assert result.metrics["scaling"]["factors"]["length"] == pytest.approx(
        result.robot.leg_length / load_robot("mini_cheetah").leg_length
    )


@pytest.mark.slow
def test_robots_experiment_runs_both_plants(tmp_path):
    """``cafe-mpc experiment robots`` on one robot and gait: one run per plant, the table and counts."""
    from cafe_mpc_lab.experiments.catalog import get_experiment
    from cafe_mpc_lab.experiments.registry import PlanContext
    from cafe_mpc_lab.experiments.sweep import run_experiment

    experiment = get_experiment("robots")
    plan = experiment.plan(experiment.options_from({}), PlanContext())
    names = {variant.name for variant in plan.variants}
    assert "go1-trot-mujoco" in names and "go1-trot-gym-quadruped" not in names  # ours has no gym model
    assert {"go2-bound-mujoco", "go2-bound-gym-quadruped", "hyqreal2-trot-gym-quadruped"} <= names
    assert len(names) == 2 * (12 + 10)
    result = run_experiment(
        "robots",
        tmp_path / "robots",
        0.3,
        ["mpc.latency=fixed", "output.plots=false"],
        scheduler="synchronous",
        robots="go2",
        gaits="trot",
    )
    assert not result.errors
    rows = {row["plant"]: row for row in result.rows}
    assert set(rows) == {"mujoco", "gym-quadruped"}
    for row in rows.values():
        assert row["stayed_up"] and row["mass_kg"] == pytest.approx(15.206, abs=1e-3)
        assert row["steady_from_s"] == pytest.approx(0.15)
    table = (tmp_path / "robots" / "comparison.md").read_text()
    assert "| go2 | trot | gym-quadruped |" in table and "trot passes on" in table
    assert (tmp_path / "robots" / "comparison.png").is_file()


@pytest.mark.slow
def test_our_plant_from_the_model_file_reproduces_gym_quadruped():
    """Go2's feet have friction 0.6 and no priority, so the environment's friction overwrite changes nothing:
    the same closed loop in our plant (built from the same MJCF) and inside QuadrupedEnv gives the same
    trajectory."""
    from cafe_mpc_lab.experiments.run import simulate_config

    logs = {}
    for kind in ("mujoco", "gym-quadruped"):
        config = load_run_config(
            "trot",
            [
                "robot=go2",
                f"plant.kind={kind}",
                "estimator=ground_truth",
                "mpc.latency=fixed",
                "simulation.duration=0.6",
            ],
        )
        _, logs[kind] = simulate_config(config)
    ours, theirs = logs["mujoco"], logs["gym-quadruped"]
    assert ours.ticks == theirs.ticks == 300
    np.testing.assert_allclose(ours.q, theirs.q, atol=1e-8)
    np.testing.assert_allclose(ours.foot_forces, theirs.foot_forces, atol=1e-5)
    np.testing.assert_array_equal(ours.contacts, theirs.contacts)


@pytest.mark.slow
def test_go2_trots_inside_gym_quadruped_with_the_default_config():
    """``cafe-mpc run trot --set plant.kind=gym-quadruped --set robot=go2`` and nothing else: the state
    estimator (the default) reads the robot's sensors computed from the environment's state, and the robot
    trots forward."""
    from cafe_mpc_lab.experiments.run import run

    config = load_run_config(
        "trot",
        ["plant.kind=gym-quadruped", "robot=go2", "simulation.duration=1.6", "mpc.latency=fixed"],
    )
    assert config.estimator == "kinematic_kf"
    result = run(config, None)
    log = result.log
    assert not log.fell, log.fall_reason
    assert log.time[-1] == pytest.approx(1.598, abs=1e-6)
    assert np.mean(log.v[log.time > 1.0, 0]) > 0.25  # the command ramps to 0.5 m/s by t = 0.7 s
    error = log.extra["estimate_v"][log.time > 0.5, :3] - log.v[log.time > 0.5, :3]
    assert np.sqrt(np.mean(error**2)) < 0.05  # m/s: the estimate follows the environment's true state
