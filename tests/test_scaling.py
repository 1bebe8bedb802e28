"""Defaults that scale with the robot (``robots.scaling``, ``assembly.resolve``): the laws, and no change
for the reference robot."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cafe_mpc.assembly import build_low_level, build_planner
from cafe_mpc.assembly.resolve import resolve, run_scale, scaled_gait
from cafe_mpc.config import ON_TIME_FLAT, load_config
from cafe_mpc.config.weights import WholeBodyWeights
from cafe_mpc.ocp.contact_schedule import get_gait
from cafe_mpc.planners.cafe.problem import ModelSchedule
from cafe_mpc.planners.cafe.setup import scaled_schedule, scaled_weights
from cafe_mpc.robots.robot import load_robot
from cafe_mpc.robots.scaling import RobotScale, robot_scale


def test_reference_robot_scales_by_exactly_one(mini_cheetah):
    scale = robot_scale(mini_cheetah)
    assert scale.length == 1.0 and scale.mass == 1.0 and scale.is_identity
    weights = WholeBodyWeights.regular_running()
    assert scaled_weights(weights, scale) is weights
    assert scaled_gait("bound", scale) is get_gait("bound")
    schedule = ModelSchedule.named("S4")
    assert scaled_schedule(schedule, scale) is schedule


def test_scaling_laws():
    scale = RobotScale(length=4.0, mass=2.0)  # time scale 2, torque scale 8
    assert scale.time == 2.0 and scale.torque == 8.0
    gait = scaled_gait("trot", scale)
    assert [d for _, d in gait.cycle] == [0.5, 0.5] and gait.period == 2 * get_gait("trot").period
    assert scale.distance(0.06) == pytest.approx(0.24)
    assert scale.rate(10.0) == 5.0 and scale.stiffness(60.0) == 480.0 and scale.damping(1.5) == 24.0
    weights = scaled_weights(WholeBodyWeights.regular_running(), scale)
    # W / u^2: position 1/16, linear velocity 1/4 (u = L/T), angular velocity x4 (u = 1/T), torque 1/64
    assert weights.base_position == pytest.approx((0.0, 0.0, 10.0 / 16, 1.0, 2.0, 2.0))
    assert weights.base_velocity == pytest.approx((0.5, 0.5, 0.5, 4.0, 8.0, 8.0))
    assert weights.joint_position == 1.0 and weights.joint_velocity == pytest.approx(0.04)
    assert weights.torque == pytest.approx(0.1 / 64)
    assert weights.swing_foot_position == pytest.approx((10.0 / 16,) * 3)
    assert weights.swing_foot_velocity == pytest.approx((0.5,) * 3)
    stretched = scaled_schedule(ModelSchedule.named("S4"), scale)
    assert stretched.whole_body_horizon == pytest.approx(0.5) and stretched.srb_horizon == pytest.approx(0.8)
    assert stretched.whole_body_dt == 0.01 and stretched.srb_dt == 0.05
    with pytest.raises(ValueError, match="positive"):
        RobotScale(length=0.0)


def test_a_big_robot_gets_scaled_settings_and_none_turns_it_off():
    config = load_config("trot", ["robot=b2", "mpc.latency=fixed"])
    robot = load_robot("b2")
    run = resolve(config, robot)
    scale = run.scale
    assert scale == run_scale(config, robot)
    assert scale.length == pytest.approx(robot.leg_length / load_robot("mini_cheetah").leg_length)
    assert scale.mass == pytest.approx(robot.mass / 8.912)
    mpc = build_planner(run)
    assert mpc.reference.gait.period == pytest.approx(0.5 * math.sqrt(scale.length))
    assert mpc.reference.swing_height == pytest.approx(0.06 * scale.length)
    vwbc = build_low_level(run)
    assert vwbc.contact.baumgarte_alpha == pytest.approx(10.0 / math.sqrt(scale.length))
    assert vwbc.contact.cone_tolerance == pytest.approx(1e-3 * scale.mass)
    assert mpc.builder.whole_body.settings.baumgarte_alpha == vwbc.contact.baumgarte_alpha
    assert mpc.builder.schedule == run.schedule
    assert mpc.builder.schedule.whole_body_horizon == pytest.approx(
        round(0.25 * math.sqrt(scale.length) / 0.01) * 0.01
    )
    detection = vwbc.detector.settings  # the detector and the reference's touchdown events read one value
    assert detection is run.contact_detection
    assert detection.touchdown_height == pytest.approx(0.02 * scale.length)
    assert detection.release_height == pytest.approx(0.03 * scale.length)
    assert detection.early_window == pytest.approx(0.08 * math.sqrt(scale.length))
    assert detection.on_time == pytest.approx(0.025 * math.sqrt(scale.length))
    assert detection.touchdown_force == 0.35 and detection.ground_height == 0.0  # weight shares, the scene's
    overrides = ["robot=b2", "gait.touchdown_events=0.01", "gait.path_gain=1"]
    events = resolve(load_config("trot", overrides), robot)
    reference = build_planner(events).reference
    assert reference.path_gain == pytest.approx(1.0 / scale.length)
    assert reference.touchdown_events == (
        events.gait.touchdown_events,
        events.contact_detection.early_window,
        events.contact_detection.touchdown_height,
    )
    assert events.gait.touchdown_events == pytest.approx(0.01 * math.sqrt(scale.length))
    plain = resolve(load_config("trot", ["robot=b2", "mpc.latency=fixed", "scaling=none"]), robot)
    assert plain.scale.is_identity
    assert build_planner(plain).reference.gait.period == pytest.approx(0.5)
    assert np.isclose(build_planner(plain).reference.swing_height, 0.06)
    # unscaled: the config's thresholds, the on-time margin's null resolved to flat ground's
    assert plain.contact_detection == plain.config.vwbc.contact_detection.model_copy(
        update={"on_time": ON_TIME_FLAT}
    )
