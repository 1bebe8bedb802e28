"""The robustness envelope: one factor moved at a time, every other nominal; rates per point."""

from __future__ import annotations

import pytest

from cafe_mpc.assembly import load_run_config
from cafe_mpc.config import ConfigError
from cafe_mpc_lab.experiments.catalog import get_experiment
from cafe_mpc_lab.experiments.envelope import envelope_summary
from cafe_mpc_lab.experiments.registry import PlanContext
from cafe_mpc_lab.experiments.reliability import wilson_interval


def test_each_point_moves_its_factor_alone():
    envelope = get_experiment("envelope")
    options = envelope.options_from({"task": "trot", "factors": "friction,mass,motor", "trials": "2"})
    plan = envelope.plan(options, PlanContext())
    by_point: dict = {}
    for variant in plan.variants:
        fields = dict(variant.fields)
        by_point.setdefault((fields["factor"], fields["value"]), []).append(variant)
        config = load_run_config("trot", list(variant.overrides))
        plant = config.plant
        friction = fields["value"] if fields["factor"] == "friction" else 0.6
        assert plant.floor_friction == pytest.approx(friction)
        assert plant.mass_scale == pytest.approx(fields["value"] if fields["factor"] == "mass" else 1.0)
        motors = fields["value"] if fields["factor"] == "motor" else 1.0
        assert plant.motor_strength_scales == pytest.approx([motors] * 12)
        assert plant.body_mass_scale == 1.0 and plant.link_mass_scales == pytest.approx([1.0] * 12)
        assert plant.measurement_delay_max == 0.0 and config.pushes == []
        assert plant.sensors.imu.gyro_bias == (0.0, 0.0, 0.0)
    assert all(len(trials) == 2 for trials in by_point.values())
    assert {value for factor, value in by_point if factor == "motor"} == {0.7, 0.8, 0.85, 0.9, 1.0, 1.1}


def test_pushes_and_biases_grow_with_their_point():
    envelope = get_experiment("envelope")
    plan = envelope.plan(
        envelope.options_from({"task": "trot", "factors": "push", "values": "0,1.5", "seeds": "3"}),
        PlanContext(),
    )
    zero, big = (load_run_config("trot", list(v.overrides)) for v in plan.variants)
    assert zero.pushes == [] and len(big.pushes) == 1
    plan = envelope.plan(
        envelope.options_from({"task": "trot", "factors": "imu_bias", "values": "3", "seeds": "3"}),
        PlanContext(),
    )
    bias = load_run_config("trot", list(plan.variants[0].overrides)).plant.sensors.imu.gyro_bias
    assert max(abs(b) for b in bias) > 0.01  # up to 3 x 0.01 rad/s


def test_options_are_checked():
    envelope = get_experiment("envelope")
    with pytest.raises(ConfigError, match="unknown"):
        envelope.options_from({"task": "trot", "factors": "gravity"})
    with pytest.raises(ConfigError, match="exactly one"):
        envelope.options_from({"task": "trot", "factors": "friction,mass", "values": "0.5"})


def test_summary_per_point_with_wilson_intervals():
    rows = [
        {"status": "ok", "success": True, "factor": "friction", "value": 0.3, "seed": 0},
        {"status": "ok", "success": False, "fell": True, "factor": "friction", "value": 0.3, "seed": 1},
        {"status": "ok", "success": True, "factor": "friction", "value": 0.6, "seed": 0},
        {"status": "crashed", "factor": "friction", "value": 0.6, "seed": 1},
    ]
    summary = envelope_summary(rows)
    low, high = summary["friction"]
    assert (low["value"], low["trials"], low["successes"], low["failure_modes"]["fell"]) == (0.3, 2, 1, 1)
    assert low["wilson_95"] == pytest.approx(list(wilson_interval(1, 2)))
    assert (high["trials"], high["successes"]) == (1, 1)
