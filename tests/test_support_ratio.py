"""The support ratio estimated online (``estimation.support_ratio``, ``calibration.online``): motor strength
over mass factor from the impulse balance of the stance legs; applied by the low level as ``tau / r``."""

from __future__ import annotations

import numpy as np
import pytest

from cafe_mpc.assembly import load_run_config
from cafe_mpc.assembly.controllers import build_low_level
from cafe_mpc.assembly.resolve import resolve
from cafe_mpc.config import OnlineCalibrationConfig
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.dynamics.statics import static_stance_torques
from cafe_mpc.estimation.support_ratio import SupportRatioEstimator
from cafe_mpc.low_level.motor_strength import OnlineSupportCompensation
from cafe_mpc.low_level.pd import PDController
from cafe_mpc.robots.calibration import ModelCalibration, calibrated_robot
from cafe_mpc_lab.experiments.controllers import low_level_of
from cafe_mpc_lab.experiments.run import simulate_run

PERIOD = 0.002


def _standing_ratio(robot, torques: np.ndarray, seconds: float = 1.0) -> SupportRatioEstimator:
    """The estimator of ``robot`` fed a robot standing still on four feet, sent ``torques`` every tick."""
    settings = OnlineCalibrationConfig(enabled=True)
    estimator = SupportRatioEstimator(robot, settings, PERIOD)
    measurement = Measurement.of_state(robot.q_standing.copy(), np.zeros(robot.nv), np.ones(4, dtype=bool))
    for tick in range(round(seconds / PERIOD)):
        estimator.observe(tick * PERIOD, measurement)
        estimator.command(torques)
    return estimator


@pytest.mark.parametrize(("mass", "strength"), [(1.0, 1.0), (1.2, 1.0), (1.0, 0.85), (1.15, 0.9)])
def test_standing_still_the_ratio_is_strength_over_mass(robot, mass, strength):
    """Static stance: the commands that hold a robot ``mass`` times heavier on motors of ``strength`` (the
    torques it needs over the strength) give the model's estimator ``strength / mass`` (to rounding)."""
    heavier = calibrated_robot(robot, ModelCalibration(mass_scale=mass))
    needed = static_stance_torques(heavier, robot.q_standing)
    estimator = _standing_ratio(robot, needed / strength)
    assert estimator.windows >= 4
    assert estimator.ratio == pytest.approx(strength / mass, rel=1e-6)


def test_no_stance_no_estimate(robot):
    """In flight (no foot on the ground) nothing is estimated: the ratio stays 1."""
    settings = OnlineCalibrationConfig(enabled=True)
    estimator = SupportRatioEstimator(robot, settings, PERIOD)
    measurement = Measurement.of_state(robot.q_standing.copy(), np.zeros(robot.nv), np.zeros(4, dtype=bool))
    torques = static_stance_torques(robot, robot.q_standing)
    for tick in range(500):
        estimator.observe(tick * PERIOD, measurement)
        estimator.command(torques)
    assert estimator.windows == 0 and estimator.ratio == 1.0


def test_a_non_finite_state_leaves_the_ratio_alone(robot):
    """A diverged estimate (NaN velocities) gives no window and never a NaN ratio."""
    settings = OnlineCalibrationConfig(enabled=True)
    estimator = SupportRatioEstimator(robot, settings, PERIOD)
    velocity = np.full(robot.nv, np.nan)
    measurement = Measurement.of_state(robot.q_standing.copy(), velocity, np.ones(4, dtype=bool))
    torques = static_stance_torques(robot, robot.q_standing)
    for tick in range(500):
        estimator.observe(tick * PERIOD, measurement)
        estimator.command(torques)
    assert estimator.windows == 0 and estimator.ratio == 1.0 and estimator.rejected > 0


def test_the_ratio_is_bounded(robot):
    """A robot that seems twice as heavy as its model is corrected by at most ``lower`` (0.7)."""
    heavier = calibrated_robot(robot, ModelCalibration(mass_scale=1.5, body_mass_scale=1.4))
    estimator = _standing_ratio(robot, static_stance_torques(heavier, robot.q_standing))
    assert estimator.ratio == pytest.approx(0.7)


def test_a_take_off_is_left_out_and_a_payload_taken_in(robot):
    """Settled at the nominal ratio, two windows' time of 20 % more commanded support (feet the flags miss)
    leave the estimate about where it was; more in a row (``outlier_windows``) are a real change."""
    settings = OnlineCalibrationConfig(enabled=True)
    estimator = SupportRatioEstimator(robot, settings, PERIOD)
    measurement = Measurement.of_state(robot.q_standing.copy(), np.zeros(robot.nv), np.ones(4, dtype=bool))
    nominal = static_stance_torques(robot, robot.q_standing)
    heavier = static_stance_torques(
        calibrated_robot(robot, ModelCalibration(mass_scale=1.2)), robot.q_standing
    )
    ticks_per_window = round(settings.window / PERIOD)
    tick = 0
    for torques, windows in ((nominal, 6), (heavier, 2)):
        for _ in range(windows * ticks_per_window):
            estimator.observe(tick * PERIOD, measurement)
            estimator.command(torques)
            tick += 1
    assert estimator.ratio > 0.985  # the windows mixing both moved it a little; taken in, 0.9 or less
    assert estimator.rejected >= 1
    for _ in range(2 * ticks_per_window):
        estimator.observe(tick * PERIOD, measurement)
        estimator.command(heavier)
        tick += 1
    assert estimator.ratio < 0.97


def test_the_switch_builds_the_online_low_level(robot):
    """Off by default (the calibrated low level as before); on, the low level divides by the strength and
    the ratio, and reports the estimate in its statistics."""
    off = build_low_level(resolve(load_run_config("trot"), robot))
    assert not isinstance(off, OnlineSupportCompensation)
    on = build_low_level(resolve(load_run_config("trot", ["calibration.online.enabled=true"]), robot))
    assert isinstance(on, OnlineSupportCompensation)
    on.inner = PDController(robot)  # a low level that needs no plan, for one tick
    on.estimator.ratio = 0.8
    measurement = Measurement.of_state(robot.q_standing.copy(), np.zeros(robot.nv), np.ones(4, dtype=bool))
    commands = on.compute(0.0, measurement, None).copy()
    limits = on.command_limits
    np.testing.assert_allclose(commands, np.clip(on.inner.last_request / 0.8, -limits, limits), atol=1e-9)
    assert "support_ratio" in on.statistics()


def _trot_ratio(overrides: list[str]) -> float:
    config = load_run_config(
        "trot",
        [
            "simulation.duration=1.5",
            "output.plots=false",
            "mpc.latency=fixed",
            "mpc.fixed_latency=0.02",
            "calibration.online.enabled=true",
            *overrides,
        ],
    )
    _, controller, log = simulate_run(config)
    assert not log.fell
    return low_level_of(controller).statistics()["support_ratio"]["ratio"]


@pytest.mark.slow
def test_a_trot_finds_a_heavier_trunk_and_nothing_when_nominal(robot):
    """Closed loop, fixed 20 ms, the robot's sensors and the Kalman filter: the plant's trunk 1.2 x its model
    (the controller is not told) makes the whole robot ``k`` = 1 + 0.2 x trunk / total heavier; after a
    1.5 s trot (its 0.3 s stand and 1.2 s of trotting) the estimate is within 3 % of ``1 / k``; nominal,
    within 3 % of 1."""
    trunk = float(robot.model.inertias[1].mass)
    k = 1.0 + 0.2 * trunk / robot.mass
    heavier = _trot_ratio(["plant={body_mass_scale: 1.2}"])
    nominal = _trot_ratio([])
    assert heavier == pytest.approx(1.0 / k, rel=0.03)
    assert nominal == pytest.approx(1.0, rel=0.03)
    assert heavier < 1.0 / k + 0.5 * (1.0 - 1.0 / k)  # it moved most of the way, not noise around 1
