"""Domain randomisation: the plant and the sensors change, the controller's model never does; the
reliability experiment samples trials by seed, reports the Wilson interval and its failure modes."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest
import yaml

from cafe_mpc.assembly import load_run_config
from cafe_mpc.config import ConfigError, SensorNoise
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.dynamics.srb import srb_parameters
from cafe_mpc.robots.robot import load_robot
from cafe_mpc_lab.experiments.catalog import get_experiment
from cafe_mpc_lab.experiments.registry import PlanContext
from cafe_mpc_lab.experiments.reliability import (
    RandomizationRanges,
    reliability_summary,
    sample_trial,
    wilson_interval,
)
from cafe_mpc_lab.experiments.results_table import RESULTS_FILE, ResultsTable
from cafe_mpc_lab.experiments.run import simulate_run
from cafe_mpc_lab.experiments.sweep import run_experiment
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant
from cafe_mpc_lab.sim.randomization import PlantVariation, SensorModel


def test_wilson_interval_matches_known_values():
    # 16 of 22 (the paper's reliability test): 0.5185-0.8685 (scipy.stats.binomtest(...).proportion_ci
    # ("wilson") gives the same digits)
    assert wilson_interval(16, 22) == pytest.approx((0.5184826598759762, 0.8684923971201053), abs=1e-12)
    assert wilson_interval(7, 20) == pytest.approx((0.1811918241010821, 0.5671457233147637), abs=1e-12)
    assert wilson_interval(0, 10) == pytest.approx((0.0, 0.27753279986288926), abs=1e-12)
    assert wilson_interval(10, 10) == pytest.approx((0.7224672001371109, 1.0), abs=1e-12)
    assert wilson_interval(0, 0) == (0.0, 1.0)
    with pytest.raises(ValueError):
        wilson_interval(3, 2)


def test_a_plant_variation_changes_the_plant(robot):
    nominal = MujocoPlant(robot)
    links = tuple(np.linspace(0.9, 1.1, robot.nu))
    strength = tuple(np.linspace(1.1, 0.9, robot.nu))
    variation = PlantVariation(0.45, 1.08, links, strength)
    varied = MujocoPlant(robot, variation=variation)
    base = nominal.model.body("base").id
    assert varied.model.body_mass[base] == pytest.approx(1.08 * nominal.model.body_mass[base])
    np.testing.assert_allclose(varied.model.body_inertia[base], 1.08 * nominal.model.body_inertia[base])
    for index, name in enumerate(robot.joint_names):
        body = nominal.model.jnt_bodyid[nominal.model.joint(name).id]
        assert varied.model.body_mass[body] == pytest.approx(links[index] * nominal.model.body_mass[body])
    np.testing.assert_allclose(varied.model.actuator_gear[:, 0], strength)
    for geom in ("floor", *robot.foot_frame_names):
        assert varied.model.geom(geom).friction[0] == pytest.approx(0.45)
        assert nominal.model.geom(geom).friction[0] == pytest.approx(robot.plant.floor_friction)
    # the motors deliver strength x the saturated command
    command = np.full(robot.nu, 100.0)
    np.testing.assert_allclose(varied.applied(command), np.array(strength) * robot.plant.motor_torque_limits)
    # the applied torque really is scaled: one step from rest with the same command
    for plant in (nominal, varied):
        plant.reset(robot.q_standing)
        plant.step(np.full(robot.nu, 2.0))
        mujoco.mj_forward(plant.model, plant.data)
    np.testing.assert_allclose(varied.data.qfrc_actuator[6:], 2.0 * np.array(strength), rtol=1e-9)
    with pytest.raises(ValueError, match="link_mass_scales"):
        MujocoPlant(robot, variation=PlantVariation(link_mass_scales=(1.0, 1.0)))


def test_randomisation_never_touches_the_controllers_model(robot):
    varied = load_run_config(
        "trot",
        [
            "simulation.duration=0.1",
            "mpc.latency=fixed",
            "estimator=ground_truth",  # noise on the measured state: ground truth only
            "plant={floor_friction: 0.4, body_mass_scale: 1.1, link_mass_scales: 0.9, "
            "motor_strength_scales: 0.9, measurement_delay_max: 0.004, seed: 3, "
            "sensor_noise: {joint_velocity: 0.05, base_orientation: 0.01}}",
        ],
    )
    nominal_robot = load_robot("mini_cheetah")
    resolved, controller, log = simulate_run(varied)
    used_robot = resolved.robot
    # the controller planned with the nominal robot: same masses, inertias, SRB model, limits, MJCF
    assert controller.robot is used_robot
    assert used_robot.total_mass == pytest.approx(nominal_robot.total_mass)
    for ours, theirs in zip(used_robot.model.inertias, nominal_robot.model.inertias, strict=True):
        assert ours.mass == theirs.mass
        np.testing.assert_array_equal(ours.inertia, theirs.inertia)
    assert used_robot.mjcf == nominal_robot.mjcf
    np.testing.assert_array_equal(used_robot.torque_limits, nominal_robot.torque_limits)
    srb, expected = srb_parameters(used_robot), srb_parameters(nominal_robot)
    assert srb.mass == expected.mass
    np.testing.assert_array_equal(srb.inertia_matrix, expected.inertia_matrix)
    whole_body = controller.planner.builder.whole_body
    assert whole_body.robot is used_robot
    # ... while the plant was varied: its motors applied 0.9 x the (saturated) command
    limits = used_robot.plant.motor_torque_limits
    np.testing.assert_allclose(log.torque_applied, 0.9 * np.clip(log.torque_command, -limits, limits))
    # the sensors were late: the delay statistics are in the log
    assert log.extra["sensor"]["delay_max_ticks"] == 2 and log.extra["sensor"]["delay_ticks_max"] <= 2


def test_the_sensor_model_delays_in_order_and_adds_noise(robot):
    q, v = robot.q_standing.copy(), np.zeros(robot.nv)

    def state(tick: int) -> Measurement:
        moved = q.copy()
        moved[0] = tick  # x = tick number, to read the delay off
        return Measurement.of_state(moved, v, np.ones(4, dtype=bool), time=0.002 * tick)

    sensor = SensorModel(SensorNoise(), delay_max_ticks=3, seed=5)
    sensor.reset()
    seen = [sensor.observe(tick, state(tick)).q[0] for tick in range(200)]
    delays = np.arange(200) - np.array(seen)
    assert delays.min() == 0 and delays.max() == 3 and np.all(np.diff(seen) >= 0)  # late, never reordered
    sensor.reset()
    assert [sensor.observe(tick, state(tick)).q[0] for tick in range(200)] == seen  # a seed is a sequence
    identity = SensorModel()
    measurement = state(4)
    assert identity.observe(4, measurement) is measurement
    noisy = SensorModel(SensorNoise(joint_position=0.01, base_orientation=0.02), seed=1)
    measured = noisy.observe(0, state(0))
    assert np.linalg.norm(measured.q[3:7]) == pytest.approx(1.0)
    assert 0 < np.max(np.abs(measured.q[7:] - q[7:])) < 0.1 and measured.q[0] == 0.0
    assert not np.allclose(measured.q[3:7], q[3:7])


def test_plant_config_errors_name_the_key():
    with pytest.raises(ConfigError, match=r"plant\.link_mass_scales: one factor or 12"):
        load_run_config("trot", ["plant.link_mass_scales=[1.0, 1.0]"])
    with pytest.raises(ConfigError, match=r"plant\.floor_friction"):
        load_run_config("trot", ["plant.floor_friction=-1"])
    with pytest.raises(ConfigError, match=r"factors must be in \[0.5, 1.5\]"):
        load_run_config("trot", ["plant.motor_strength_scales=3"])


def test_reliability_trials_are_drawn_from_their_seed():
    ranges = RandomizationRanges()
    plant, push = sample_trial(ranges, 7, 12, 10.0)
    assert (plant, push) == sample_trial(ranges, 7, 12, 10.0) != sample_trial(ranges, 8, 12, 10.0)
    for seed in range(30):
        plant, push = sample_trial(ranges, seed, 12, 10.0)
        assert 0.4 <= plant["floor_friction"] <= 0.9 and 0.9 <= plant["body_mass_scale"] <= 1.1
        assert len(plant["link_mass_scales"]) == 12 and all(
            0.9 <= s <= 1.1 for s in plant["link_mass_scales"]
        )
        assert all(0.9 <= s <= 1.1 for s in plant["motor_strength_scales"]) and plant["seed"] == seed
        assert 2.5 <= push["start"] <= 7.5 and np.hypot(*push["velocity_change"][:2]) <= 0.5 + 1e-9
    experiment = get_experiment("reliability")
    plan = experiment.plan(
        experiment.options_from({"task": "bound-push", "trials": "3", "seed": "5"}), PlanContext()
    )
    assert [v.name for v in plan.variants] == ["trial-0005", "trial-0006", "trial-0007"]
    assert plan.drop_files == ("log.npz",) and plan.options == {
        "--task": "bound-push",
        "--trials": "3",
        "--seed": "5",
    }
    alone = experiment.plan(experiment.options_from({"task": "bound-push", "seeds": "7"}), PlanContext())
    assert alone.variants[0] == plan.variants[2]  # a trial re-runs alone from its seed
    config = load_run_config("bound-push", list(plan.variants[0].overrides))
    assert len(config.pushes) == 2  # the preset's push, then the random one
    assert config.plant.floor_friction == dict(plan.variants[0].fields)["floor_friction"]


def test_reliability_ranges_from_a_file(tmp_path):
    path = tmp_path / "ranges.yaml"
    path.write_text(yaml.safe_dump({"floor_friction": [0.2, 0.3], "push": {"max_velocity_change": 1.0}}))
    reliability = get_experiment("reliability")
    plan = reliability.plan(
        reliability.options_from({"task": "trot", "trials": "2", "ranges": str(path)}), PlanContext()
    )
    assert all(0.2 <= dict(v.fields)["floor_friction"] <= 0.3 for v in plan.variants)
    path.write_text(yaml.safe_dump({"floor_friction": [0.9, 0.3]}))
    with pytest.raises(ConfigError, match="floor_friction: need"):
        reliability.plan(reliability.options_from({"task": "trot", "ranges": str(path)}), PlanContext())
    path.write_text(yaml.safe_dump({"friction": [0.2, 0.3]}))
    with pytest.raises(ConfigError, match="--ranges: friction: unknown key"):
        reliability.plan(reliability.options_from({"task": "trot", "ranges": str(path)}), PlanContext())


def test_reliability_summary_counts_failure_modes():
    rows = [
        {"status": "ok", "success": True, "seed": 0, "slipped": True},
        {
            "status": "ok",
            "success": False,
            "fell": True,
            "slipped": True,
            "torque_saturated": True,
            "seed": 1,
        },
        {"status": "error", "error": "SimulationDiverged: x", "seed": 2},
        {"status": "crashed", "error": "KilledWorker", "seed": 3},
    ]
    summary = reliability_summary(rows)
    assert (summary["trials"], summary["successes"], summary["crashed"]) == (3, 1, 1)
    assert summary["success_rate"] == pytest.approx(1 / 3)
    assert summary["wilson_95"] == pytest.approx(list(wilson_interval(1, 3)))
    modes = summary["failure_modes"]
    assert modes["fell"] == {"trials": 1, "failed": 1}
    assert modes["slipped"] == {"trials": 2, "failed": 1}
    assert modes["torque_saturated"] == {"trials": 1, "failed": 1}
    assert modes["simulation_error"] == {"trials": 1, "failed": 1}
    assert modes["solver_failed"] == {"trials": 0, "failed": 0}
    assert summary["failed_seeds"] == [1, 2] and summary["paper"]["successes"] == 16


def test_reliability_experiment_writes_summary_and_trials_rerun_alone(tmp_path, capsys):
    from cafe_mpc_lab.cli import main

    out = tmp_path / "rel"
    argv = ["experiment", "reliability", "--task", "trot", "--trials", "2", "--duration", "0.2"]
    assert main([*argv, "--out", str(out), "--scheduler", "synchronous"]) == 0
    printed = capsys.readouterr().out
    assert "reliability: " in printed and "trials succeeded" in printed
    summary = json.loads((out / "summary.json").read_text())
    assert summary["trials"] == 2 and summary["successes"] == 2 and summary["success_rate"] == 1.0
    assert len(summary["wilson_95"]) == 2 and summary["wilson_95"] == pytest.approx(
        list(wilson_interval(2, 2))
    )
    assert set(summary["failure_modes"]) == {
        "fell",
        "slipped",
        "torque_saturated",
        "solver_failed",
        "simulation_error",
    }
    assert summary["seeds"] == [0, 1] and summary["ranges"]["floor_friction"] == [0.4, 0.9]
    table = (out / "comparison.md").read_text()
    assert "Success: **2 of 2**" in table and "| fell | 0 | 0 |" in table
    rows = ResultsTable.load(out / RESULTS_FILE).rows
    assert [row["seed"] for row in rows] == [0, 1] and all(row["timing_mode"] == "fixed" for row in rows)
    assert all(row["variant"] == "trot" and 0.4 <= row["floor_friction"] <= 0.9 for row in rows)
    trial = out / "trial-0001"
    assert (trial / "config.yaml").is_file() and not (trial / "log.npz").exists()
    # the trial alone, from its seed: the same plant, push and (fixed latency) the same outcome
    again = run_experiment(
        "reliability", tmp_path / "alone", 0.2, task="trot", seeds="1", scheduler="synchronous"
    )
    alone = again.rows[0]
    assert alone["config_hash"] == rows[1]["config_hash"]
    assert alone["vx_mean"] == rows[1]["vx_mean"] and alone["foot_slip_max_m"] == rows[1]["foot_slip_max_m"]
