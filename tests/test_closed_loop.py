"""Short closed loops of the full stack (issue 5): CAFE-MPC + low-level controller + MuJoCo plant.

Each run uses a preset exactly as ``cafe-mpc run`` does (config -> controller -> simulation -> metrics),
shortened to 1.5 s of simulated time, and asserts that the robot stayed up and walked forward at a speed
that is a fair share of the 0.5 m/s command. Long runs (10 s, every gait) are in BENCHMARKS.md.
"""

from __future__ import annotations

import numpy as np
import pytest

from cafe_mpc.config import load_config
from cafe_mpc.experiments.run import run_metrics, simulate_run

DURATION = 1.5


@pytest.mark.parametrize(
    ("preset", "wbc"),
    [("trot", "riccati"), ("trot", "vwbc"), ("bound", "vwbc")],
)
@pytest.mark.slow
def test_gait_stays_up_and_moves_forward(preset, wbc):
    config = load_config(
        preset,
        [f"simulation.duration={DURATION}", f"wbc={wbc}", "output.plots=false", "mpc.latency=fixed"],
    )
    robot, controller, log = simulate_run(config)
    metrics = run_metrics(config, robot, controller, log)
    assert not log.fell, log.fall_reason
    assert metrics["base_height_min"] > 0.15
    forward = log.q[-1, 0] - log.q[0, 0]
    assert forward > 0.25 * 0.5 * DURATION  # at least a quarter of the commanded distance
    assert abs(log.q[-1, 1] - log.q[0, 1]) < 0.15  # no large sideways drift
    assert metrics["vx_mean"] > 0.2
    assert metrics["mpc"]["failures"] == 0
    assert np.all(np.isfinite(log.torque_command))
    assert np.all(np.abs(log.torque_command) <= robot.torque_limits + 1e-6)
