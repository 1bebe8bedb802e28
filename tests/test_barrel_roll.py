"""The barrel-roll preset (issue 11, part 3): the reference section is validated with one clear error, and a
short closed loop (fixed latency, deterministic) rolls 2 pi and lands on its feet."""

from __future__ import annotations

import math

import pytest

from cafe_mpc.assembly import load_run_config
from cafe_mpc.config import ConfigError
from cafe_mpc.planners.base import update_solve_options
from cafe_mpc_lab.experiments.run import run


def test_preset_loads_with_its_reference_section():
    config = load_run_config("barrel-roll")
    assert config.gait is None and config.wbc == "vwbc" and config.torque_limits == "motor"
    kinds = [segment.kind for segment in config.reference.segments]
    assert kinds == ["stand", "trajectory", "stand"]
    assert config.reference.costs.running.base_position == (0.0, 0.0, 15.0, 5.0, 5.0, 5.0)
    assert load_run_config("barrel-roll", ["wbc=riccati"]).wbc == "riccati"
    assert update_solve_options(config.mpc).al_max_penalty == 20.0
    assert update_solve_options(load_run_config("trot").mpc).al_max_penalty == 1e4  # the authors' default


@pytest.mark.parametrize(
    "overrides, message",
    [
        (
            ["reference.segments.1.trajectory=moonwalk"],
            "reference.segments.1: unknown trajectory 'moonwalk'",
        ),
        (["reference.segments.1.trajectory=missing.npz"], "missing.npz: does not exist"),
        (["reference.segments.1.trajectory=null"], "a trajectory segment needs 'trajectory'"),
        (
            ["reference.segments.0.duration=null"],
            "segments.0: a stand segment needs a duration unless it is the last one",
        ),
        (["reference.segments.0.height=0.9"], "reference.segments.0: command height = 0.9 m is outside"),
        (["reference.segments=[]"], "reference.segments: List should have at least 1 item"),
        (
            ["reference.segments.1.kind=flip"],
            "reference.segments.1.kind: Input should be 'stand', 'trajectory' or 'gait'",
        ),
        (["gait={name: trot}"], "give either a gait section or a reference section"),
        (["wbc=pd"], "wbc: 'pd' stands in place and cannot follow a reference"),
        (["torque_limits=max"], "torque_limits: Input should be 'plan' or 'motor'"),
        (["mpc.touchdown_max_penalty=0"], "mpc.touchdown_max_penalty: Input should be greater than 0"),
    ],
)
def test_bad_reference_section_is_one_clear_error(overrides, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(".", r"\.")) as error:
        load_run_config("barrel-roll", overrides)
    assert "\n" not in str(error.value)


@pytest.mark.slow
def test_closed_loop_barrel_roll_lands_on_its_feet():
    """Fixed latency (20 ms, deterministic), VWBC, 2.3 s: the roll and the landing (about 4 s wall time)."""
    config = load_run_config(
        "barrel-roll",
        ["mpc.latency=fixed", "simulation.duration=2.3", "output.plots=false"],
    )
    result = run(config, None)
    task = result.metrics["task"]
    assert not result.metrics["fell"]
    assert task["roll_turned_rad"] >= 2.0 * math.pi - 0.3
    assert task["landed"] and task["upright_after"]
    assert task["roll_motor_torque_limit_violations"] == 0
    # 2 s after landing are not simulated here: not judged, and said so
    assert task["stayed_up"] is None and task["success"] is None
    assert task["success_reason"].startswith("cannot judge: stayed_up: the run ended")
