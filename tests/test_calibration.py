"""The controller's calibration (``calibration`` section, ``robots.calibration``): a known payload, link
masses and motor strengths change the model every part of the controller is built from and the torques it
sends; the defaults change nothing. The lab's ``--oracle`` diagnostic copies a trial's plant into it."""

from __future__ import annotations

import numpy as np
import pytest

from cafe_mpc.assembly import load_run_config
from cafe_mpc.assembly.controllers import build_low_level
from cafe_mpc.assembly.resolve import resolve
from cafe_mpc.config import ConfigError
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.dynamics.srb import srb_parameters
from cafe_mpc.dynamics.statics import static_stance_torques
from cafe_mpc.low_level.motor_strength import MotorStrengthCompensation
from cafe_mpc.low_level.pd import PDController
from cafe_mpc.planners.cafe.setup import build_problem
from cafe_mpc.robots.calibration import ModelCalibration, calibrated_robot
from cafe_mpc_lab.experiments.reliability import check_oracle_overrides, oracle_overrides
from cafe_mpc_lab.experiments.run import simulate_run


def test_the_default_calibration_is_the_robot_file(robot):
    run = resolve(load_run_config("trot"), robot)
    assert run.controller_robot is robot
    np.testing.assert_array_equal(run.motor_strength, np.ones(robot.nu))
    np.testing.assert_array_equal(run.torque_limits, robot.torque_limits)
    assert calibrated_robot(robot, ModelCalibration()) is robot


def test_a_calibration_scales_the_model_and_leaves_the_robot_alone(robot):
    links = tuple(np.linspace(0.9, 1.1, robot.nu))
    strength = tuple(np.linspace(0.8, 1.0, robot.nu))
    calibration = ModelCalibration(1.1, 1.3, links, strength)
    trunk = robot.model.inertias[1]
    trunk_mass, trunk_inertia = float(trunk.mass), np.array(trunk.inertia)
    calibrated = calibrated_robot(robot, calibration)
    assert calibrated is not robot and calibrated.model is not robot.model
    assert calibrated.model.inertias[1].mass == pytest.approx(1.1 * 1.3 * trunk_mass)
    np.testing.assert_allclose(calibrated.model.inertias[1].inertia, 1.1 * 1.3 * trunk_inertia)
    np.testing.assert_allclose(calibrated.model.inertias[1].lever, trunk.lever)
    for index, name in enumerate(robot.joint_names):
        joint = robot.model.getJointId(name)
        assert calibrated.model.inertias[joint].mass == pytest.approx(
            1.1 * links[index] * robot.model.inertias[joint].mass
        )
    assert calibrated.rotor_mass == pytest.approx(1.1 * robot.rotor_mass)
    np.testing.assert_allclose(calibrated.torque_limits, np.array(strength) * robot.torque_limits)
    # the robot file's robot is untouched
    assert robot.model.inertias[1].mass == trunk_mass
    np.testing.assert_array_equal(robot.model.inertias[1].inertia, trunk_inertia)
    # the SRB tail lumps the calibrated model: the trunk's extra mass is in it
    extra = 1.1 * 1.3 * trunk_mass - trunk_mass
    links_extra = sum(
        (1.1 * links[i] - 1.0) * robot.model.inertias[robot.model.getJointId(n)].mass
        for i, n in enumerate(robot.joint_names)
    )
    rotors = 0.1 * robot.rotor_mass * robot.nu
    assert srb_parameters(calibrated).mass == pytest.approx(
        srb_parameters(robot).mass + extra + links_extra + rotors
    )


def test_the_controller_is_built_from_the_calibrated_model(robot):
    config = load_run_config(
        "trot", ["calibration.body_mass_scale=1.3", "calibration.motor_strength_scales=0.8"]
    )
    run = resolve(config, robot)
    assert run.robot is robot  # the plant's robot stays the robot file's
    heavier = run.controller_robot
    assert heavier.total_mass == pytest.approx(robot.total_mass + 0.3 * robot.model.inertias[1].mass)
    problem = build_problem(run)
    assert problem.robot is heavier
    np.testing.assert_allclose(run.torque_limits, 0.8 * robot.torque_limits)
    # the low level sends tau / strength: the motor (0.8 x the command) delivers what the VWBC wanted
    low_level = build_low_level(run)
    assert isinstance(low_level, MotorStrengthCompensation)
    np.testing.assert_allclose(low_level.strength, 0.8)


def test_the_low_level_commands_torque_over_strength(robot):
    strength = np.linspace(0.7, 1.2, robot.nu)
    calibrated = calibrated_robot(robot, ModelCalibration(motor_strength_scales=tuple(strength)))
    pd = PDController(calibrated)
    compensated = MotorStrengthCompensation(PDController(calibrated), strength)
    q = robot.q_standing.copy()
    q[7:] += 0.4 * np.sin(np.arange(robot.nu))  # far enough from the target to saturate some joints
    measurement = Measurement(0.0, q, np.zeros(robot.nv), np.ones(robot.n_feet, bool), np.zeros((4, 3)))
    wanted = pd.compute(0.0, measurement).copy()
    assert np.any(np.abs(wanted) >= strength * robot.torque_limits - 1e-12)  # clamped at strength x limit
    assert np.all(np.abs(wanted) <= strength * robot.torque_limits + 1e-12)
    commands = compensated.compute(0.0, measurement)
    np.testing.assert_allclose(strength * commands, wanted)
    np.testing.assert_allclose(compensated.last_request, pd.last_request)
    assert np.all(np.abs(commands) <= robot.torque_limits + 1e-9)
    # the stance's gravity feed-forward carries the payload
    heavy = calibrated_robot(robot, ModelCalibration(body_mass_scale=1.3))
    assert np.linalg.norm(static_stance_torques(heavy, robot.q_standing)) > np.linalg.norm(
        static_stance_torques(robot, robot.q_standing)
    )
    with pytest.raises(ValueError, match="positive"):
        MotorStrengthCompensation(pd, np.zeros(robot.nu))


def test_calibration_errors_name_the_key(robot):
    with pytest.raises(ConfigError, match=r"calibration\.body_mass_scale"):
        load_run_config("trot", ["calibration.body_mass_scale=2.0"])
    with pytest.raises(ConfigError, match=r"calibration\.link_mass_scales"):
        load_run_config("trot", ["calibration.link_mass_scales=[1.0, 1.1]"])
    with pytest.raises(ConfigError, match=r"calibration\.motor_strength_scales"):
        load_run_config("trot", ["calibration.motor_strength_scales=0.2"])
    with pytest.raises(ValueError, match="link_mass_scales"):
        calibrated_robot(robot, ModelCalibration(link_mass_scales=(1.0, 1.1)))


def test_the_oracle_tells_the_controller_the_plant(robot):
    base = load_run_config("running-barrel-roll")
    plant = {
        "floor_friction": 0.35,
        "body_mass_scale": 1.05,
        "mass_scale": 1.15,
        "motor_strength_scales": 0.85,
    }
    overrides = oracle_overrides(plant, base, robot.plant.floor_friction)
    config = load_run_config("running-barrel-roll", ["plant={floor_friction: 0.35}", *overrides])
    assert config.calibration.mass_scale == 1.15 and config.calibration.body_mass_scale == 1.05
    assert config.calibration.motor_strength_scales == 0.85 and config.calibration.link_mass_scales == 1.0
    assert config.mpc.friction == pytest.approx(
        0.35 * base.mpc.friction / robot.plant.floor_friction, abs=1e-6
    )
    check_oracle_overrides(["mpc.latency=fixed"])
    with pytest.raises(ConfigError, match="--oracle"):
        check_oracle_overrides(["mpc.friction=0.5"])


def _height_error(overrides: list[str]) -> float:
    """Mean |base height - standing height| over the last second of a 2 s PD stand."""
    config = load_run_config("stand", ["simulation.duration=2.0", "output.plots=false", *overrides])
    resolved, _, log = simulate_run(config)
    assert not log.fell
    last = log.time >= log.time[-1] - 1.0
    return float(np.mean(np.abs(log.q[last, 2] - resolved.robot.standing_height)))


@pytest.mark.slow
def test_a_calibrated_stand_holds_its_height_with_a_payload_and_weak_motors():
    """PD stance with its gravity feed-forward: a trunk 30 % heavier and motors at 0.8 make it sag 5 mm below
    its nominal stance; told both, it stands within a few tenths of a millimetre of the nominal stance."""
    nominal = _height_error([])
    plant = "plant={body_mass_scale: 1.3, motor_strength_scales: 0.8}"
    uncalibrated = _height_error([plant])
    calibrated = _height_error(
        [plant, "calibration.body_mass_scale=1.3", "calibration.motor_strength_scales=0.8"]
    )
    assert uncalibrated - nominal > 0.003
    assert abs(calibrated - nominal) < 0.1 * (uncalibrated - nominal)


@pytest.mark.slow
def test_a_calibrated_trot_holds_its_height_with_a_payload():
    """CAFE-MPC over the VWBC, fixed 20 ms: with a trunk 30 % heavier than its model the trot runs 17 mm
    below its reference height; told the payload (its whole-body knots, SRB tail and VWBC model), 2 mm, as
    the nominal trot does."""
    common = ["mpc.latency=fixed", "mpc.fixed_latency=0.02", "plant={body_mass_scale: 1.3}"]
    uncalibrated = _trot_height_error(common)
    calibrated = _trot_height_error([*common, "calibration.body_mass_scale=1.3"])
    assert uncalibrated > 0.01
    assert calibrated < 0.25 * uncalibrated


def _trot_height_error(overrides: list[str]) -> float:
    """Mean |base height - reference height| over the last second of a 3 s trot."""
    config = load_run_config("trot", ["simulation.duration=3.0", "output.plots=false", *overrides])
    resolved, _, log = simulate_run(config)
    assert not log.fell
    last = log.time >= log.time[-1] - 1.0
    return float(np.mean(np.abs(log.q[last, 2] - resolved.robot.standing_height)))
