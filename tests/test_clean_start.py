"""A clean start (issue 15): the gait presets stand first and ramp their commands in, so a run starts without
the sideways lurch; metrics cover the whole run, the steady-state window is a second, named set; no
progress-bar warning at the end of a run."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from cafe_mpc.config import VelocityCommand, load_config
from cafe_mpc.reference.locomotion import CommandProfile, LocomotionReference
from cafe_mpc_lab.experiments.run import run, run_metrics, simulate_run
from cafe_mpc_lab.report.metrics import body_rates, commanded_at

COMMANDS = [
    VelocityCommand(start=0.0, vx=0.5, vy=0.1, yaw_rate=0.3),
    VelocityCommand(start=1.0, vx=0.8, vy=0.0, yaw_rate=-0.2),
    VelocityCommand(start=1.2, vx=0.0, vy=0.3, yaw_rate=0.5, height=0.3),
]


def _integrated(profile: CommandProfile, t0: float, t1: float, steps: int = 48000):
    """Heading-frame displacement by the midpoint rule (the check for the closed form / quadrature)."""
    dt = (t1 - t0) / steps
    values = np.array([profile.at(t0 + (k + 0.5) * dt) for k in range(steps)])
    yaw = np.cumsum(values[:, 2] * dt) - 0.5 * values[:, 2] * dt
    x = np.sum((np.cos(yaw) * values[:, 0] - np.sin(yaw) * values[:, 1]) * dt)
    y = np.sum((np.sin(yaw) * values[:, 0] + np.cos(yaw) * values[:, 1]) * dt)
    return np.array([x, y]), float(np.sum(values[:, 2] * dt))


def test_a_step_profile_is_the_commands_as_before():
    profile = CommandProfile(COMMANDS, standing_height=0.25)
    assert profile.at(0.5).tolist() == [0.5, 0.1, 0.3, 0.25]
    assert profile.at(1.0).tolist() == [0.8, 0.0, -0.2, 0.25]  # a step takes its value at its start
    assert profile.at(0.999).tolist() == [0.5, 0.1, 0.3, 0.25]
    assert profile.at(5.0).tolist() == [0.0, 0.3, 0.5, 0.3]
    table = commanded_at(np.array([0.5, 1.1, 2.0]), COMMANDS, 0.25)  # the list form: the same steps
    assert np.allclose(table, profile.table([0.5, 1.1, 2.0]))


def test_a_ramped_profile_rests_until_the_gait_starts_then_ramps_linearly():
    profile = CommandProfile(COMMANDS, standing_height=0.25, ramp=0.5, rest_until=0.2)
    assert profile.at(0.1).tolist() == [0.0, 0.0, 0.0, 0.25]  # at rest during the start stance
    assert np.allclose(profile.at(0.45), [0.25, 0.05, 0.15, 0.25])  # half way up the first ramp
    assert np.allclose(profile.at(0.7), [0.5, 0.1, 0.3, 0.25])
    # the second command's ramp is cut short by the third at 1.2 s (40 % of the way), which ramps from there
    assert np.allclose(profile.at(1.2), [0.62, 0.06, 0.1, 0.25])
    assert np.allclose(profile.at(1.7), [0.0, 0.3, 0.5, 0.3])
    with pytest.raises(ValueError, match="ramp"):
        CommandProfile(COMMANDS, 0.25, ramp=-1.0)


@pytest.mark.parametrize(
    ("ramp", "t0", "t1"), [(0.0, 0.1, 2.5), (0.5, 0.0, 2.5), (0.5, 0.95, 1.33), (0.5, 0.3, 0.4)]
)
def test_the_reference_integrates_ramped_commands_exactly(ramp, t0, t1):
    profile = CommandProfile(COMMANDS, standing_height=0.25, ramp=ramp, rest_until=0.2)
    xy, yaw = profile.heading_displacement(t0, t1)
    expected_xy, expected_yaw = _integrated(profile, t0, t1)
    assert np.allclose(xy, expected_xy, atol=2e-6)
    assert yaw == pytest.approx(expected_yaw, abs=2e-6)


def test_the_locomotion_reference_follows_the_ramp(robot):
    from cafe_mpc.ocp.contact_schedule import get_gait

    reference = LocomotionReference(
        robot, get_gait("trot"), [VelocityCommand(start=0.0, vx=0.5)], start_stance=0.2, command_ramp=0.5
    )
    q, v = reference.base_state(0.1)
    assert v[0] == 0.0 and q[0] == pytest.approx(0.0)  # standing still during the start stance
    assert reference.stance_at(0.1) == (True, True, True, True)
    _, v = reference.base_state(0.45)
    assert v[0] == pytest.approx(0.25)
    q, v = reference.base_state(1.0)
    assert v[0] == pytest.approx(0.5)
    assert q[0] == pytest.approx(0.5 * 0.5 * 0.5 + 0.5 * 0.3)  # ramp (triangle) + 0.3 s at 0.5 m/s
    assert reference.command_at(0.45).vx == pytest.approx(0.25)


def test_a_preset_trot_starts_without_the_lurch_and_reports_both_windows():
    """Fixed latency (deterministic). Before: |vy| 0.23 m/s and |yaw rate| 0.26-0.32 rad/s within 0.5 s."""
    config = load_config("trot", ["simulation.duration=0.8", "mpc.latency=fixed"])
    resolved, controller, log = simulate_run(config)
    heading, yaw_rate, _ = body_rates(log.q, log.v)
    first = log.time < 0.5
    assert np.max(np.abs(heading[first, 1])) < 0.08
    assert np.max(np.abs(yaw_rate[first])) < 0.08
    assert np.max(np.abs(log.v[first, 3])) < 0.5  # roll rate (was 1.46 rad/s)
    metrics = run_metrics(resolved, controller, log)
    assert metrics["metrics_window_start_s"] == 0.0  # the whole run
    steady = metrics["steady_state"]
    assert steady["metrics_window_start_s"] == 0.5
    for key in ("vx_mean", "vx_rms_error", "vy_rms_error", "vy_error_abs_max", "yaw_rate_error_abs_max"):
        assert key in metrics and key in steady
    assert metrics["vy_error_abs_max"] < 0.08 and metrics["yaw_rate_error_abs_max"] < 0.08
    # the whole-run error is measured against the ramped command, which the reference follows
    assert metrics["vx_rms_error"] < 0.1
    assert not math.isnan(steady["pitch_rms"])


@pytest.mark.slow
def test_a_run_ends_without_a_progress_bar_warning(tmp_path, capsys):
    """tqdm warned "clamping frac to range [0, 1]" at the end of every run with a progress bar."""
    config = load_config("stand", ["simulation.duration=10.0", "output.plots=false"])  # 10 s warned, 3 s not
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run(config, tmp_path / "run", show_progress=True)
    assert "clamping frac" not in capsys.readouterr().err
