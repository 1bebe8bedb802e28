"""Commands at run time (issue 22): ``Controller.set_command`` in inline and process modes, the channel it
writes in place, the reference that follows it, and the example that steers from a command sequence."""

from __future__ import annotations

import math
import subprocess
import sys
import time
from pathlib import Path

import mujoco
import numpy as np
import pytest

from cafe_mpc.api import Controller
from cafe_mpc.config import ConfigError, VelocityCommand
from cafe_mpc.control.commands import CommandChannel
from cafe_mpc.ocp.contact_schedule import get_gait
from cafe_mpc.reference.locomotion import LocomotionReference
from cafe_mpc.robots.robot import load_robot

ROOT = Path(__file__).resolve().parents[1]


def _steered_loop(controller: Controller, seconds: float, change_at: float, command: dict, realtime=False):
    """Run a MuJoCo loop, call ``set_command(**command)`` at ``change_at`` (``set_gait(gait)`` if the
    command names a gait); forward speed per tick."""
    model = mujoco.MjModel.from_xml_string(controller.robot.mjcf)
    data = mujoco.MjData(model)
    data.qpos[:] = controller.standing_qpos()
    mujoco.mj_forward(model, data)
    period = controller.control_period
    substeps = round(period / model.opt.timestep)
    controller.reset(controller.measurement(data.qpos, data.qvel, time=0.0))
    speeds = []
    start = time.perf_counter()
    for tick in range(round(seconds / period)):
        if abs(data.time - change_at) < period / 2:
            if "gait" in command:
                controller.set_gait(command["gait"])
            else:
                controller.set_command(**command)
        if realtime:
            delay = start + tick * period - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        data.ctrl[:] = controller.compute(
            data.time, controller.measurement(data.qpos, data.qvel, time=data.time)
        )
        for _ in range(substeps):
            mujoco.mj_step(model, data)
        w, x, y, z = data.qpos[3:7]
        heading = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        speeds.append(math.cos(heading) * data.qvel[0] + math.sin(heading) * data.qvel[1])
    return np.array(speeds), data


def test_the_channel_hands_each_command_over_once():
    channel = CommandChannel()
    assert channel.take() is None
    channel.post(0.5, 0.1, 0.2, None)
    values = channel.take()
    assert values is not None and values[:3].tolist() == [0.5, 0.1, 0.2] and math.isnan(values[3])
    assert channel.take() is None  # once
    channel.array[0] += 1.0  # a writer in the middle of a write: nothing to take yet
    assert channel.take() is None


def test_the_reference_follows_a_command_from_its_time_on_and_keeps_the_past():
    robot = load_robot("mini_cheetah")
    commands = [VelocityCommand(vx=0.3), VelocityCommand(start=5.0, vx=1.0)]
    reference = LocomotionReference(robot, get_gait("trot"), commands, start_stance=0.2, command_ramp=0.5)
    before = [reference.profile.values_at(t) for t in (0.1, 0.5, 1.0, 1.9)]
    position_before, _ = reference.base_pose(2.0)
    reference.set_command(2.0, VelocityCommand(vx=0.6, yaw_rate=0.2))
    after = [reference.profile.values_at(t) for t in (0.1, 0.5, 1.0, 1.9)]
    assert np.allclose(after, before)  # the past is kept
    assert np.allclose(reference.base_pose(2.0)[0], position_before)
    assert reference.profile.values_at(2.25)[0] == pytest.approx(0.45)  # ramped from 0.3 over 0.5 s
    assert reference.profile.values_at(6.0)[:3] == pytest.approx((0.6, 0.0, 0.2))  # the timed 1.0 is gone
    with pytest.raises(ValueError, match="vx"):
        reference.set_command(3.0, VelocityCommand(vx=3.5))


def test_the_reference_switches_gait_at_a_cycle_boundary():
    robot = load_robot("mini_cheetah")
    reference = LocomotionReference(robot, get_gait("trot"), [VelocityCommand(vx=0.5)], start_stance=0.2)
    assert reference.set_gait(1.03, "bound") == pytest.approx(1.2)  # trot cycles: 0.2 + k 0.5 s
    assert reference.gait_at(1.1).name == "trot" and reference.gait_at(1.25).name == "bound"
    assert reference.stance_at(1.1) == (False, True, True, False)
    assert reference.stance_at(1.25) == (True, True, False, False)  # the bound's first phase
    phases = reference.schedule(0.8, 2.0).phases
    assert any(abs(phase.start - 1.2) < 1e-9 for phase in phases)  # a phase starts at the switch
    assert reference.support_factor(1.0) == pytest.approx(0.5) and reference.support_factor(1.3) == 1.0
    assert reference.set_gait(1.1, "trot") == pytest.approx(1.1)  # the pending switch is cancelled
    assert reference.gait_at(1.3).name == "trot"
    with pytest.raises(ValueError, match="unknown gait"):
        reference.set_gait(1.0, "gallop")


def test_set_command_is_checked_like_a_config_value():
    with Controller("trot", ["mpc.latency=fixed"]) as controller:
        with pytest.raises(ConfigError, match=r"invalid command: command vx = 3.5 m/s is outside"):
            controller.set_command(vx=3.5)
        with pytest.raises(ConfigError, match="invalid command: yaw_rate"):
            controller.set_command(yaw_rate=math.nan)
        with pytest.raises(ConfigError, match="height"):
            controller.set_command(height=0.05)
        with pytest.raises(TypeError):
            controller.set_command(0.5)  # type: ignore[misc]  # keywords only
        with pytest.raises(ConfigError, match="invalid gait 'gallop'; gaits: bound"):
            controller.set_gait("gallop")
        with pytest.raises(ValueError, match=r"qpos must have shape \(19,\)"):
            controller.measurement(np.zeros(18), np.zeros(18))
    with pytest.raises(ConfigError, match="list of 'key=value' strings"):
        Controller("trot", "gait.commands.0.vx=0.3")  # type: ignore[arg-type]
    with (
        Controller("barrel-roll", ["mpc.latency=fixed"]) as controller,
        pytest.raises(ConfigError, match="composed reference"),
    ):
        controller.set_command(vx=0.3)


def test_inline_the_robot_speed_follows_set_command():
    with Controller("trot", ["mpc.latency=fixed", "gait.commands.0.vx=0.2"]) as controller:
        speeds, data = _steered_loop(controller, 2.7, change_at=1.1, command={"vx": 0.6})
    assert data.qpos[2] > 0.2  # up
    period = controller.control_period
    before = speeds[round(0.6 / period) : round(1.1 / period)].mean()
    after = speeds[round(2.1 / period) :].mean()
    assert before == pytest.approx(0.2, abs=0.1)
    assert after == pytest.approx(0.6, abs=0.12)


def test_inline_set_gait_switches_the_plan_to_the_new_gait():
    with Controller("trot", ["mpc.latency=fixed"]) as controller:
        _, data = _steered_loop(controller, 2.2, change_at=0.9, command={"gait": "pace"})
        reference = controller._loop.reference
        plan = controller.plan
    assert data.qpos[2] > 0.2  # still up after the switch
    assert reference.gait_at(0.9).name == "trot" and reference.gait_at(2.0).name == "pace"
    pace = {(True, False, True, False), (False, True, False, True)}
    assert {tuple(bool(flag) for flag in row) for row in plan.contacts[:20]} <= pace | {(True,) * 4}


def test_process_mode_takes_commands_through_shared_memory():
    with Controller("trot", ["gait.commands.0.vx=0.2"], mode="process") as controller:
        speeds, data = _steered_loop(controller, 2.6, change_at=0.8, command={"vx": 0.6}, realtime=True)
        assert controller.failure is None
    period = controller.control_period
    assert data.qpos[2] > 0.2
    assert (
        speeds[round(1.9 / period) :].mean() > speeds[round(0.3 / period) : round(0.8 / period)].mean() + 0.2
    )


def test_the_steering_example_runs_a_command_sequence():
    result = subprocess.run(
        [
            sys.executable,
            str(ROOT / "examples" / "steer.py"),
            "--duration",
            "2.0",
            "--commands",
            "0:vx=0.2 1:vx=0.5",
            "--set",
            "mpc.latency=fixed",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
    assert result.returncode == 0, result.stderr
    assert "commanded vx" in result.stdout and "0.50 m/s" in result.stdout


def test_a_command_outside_the_tested_range_warns_and_still_runs(caplog):
    from cafe_mpc.reference.tested_ranges import outside_tested_range, tested_ranges

    assert set(tested_ranges()) >= {"trot", "pace", "bound", "pronk", "flying_trot"}
    assert outside_tested_range("trot", VelocityCommand(vx=1.0)) is None
    assert "outside the tested range 0 to 1.5 m/s" in outside_tested_range("trot", VelocityCommand(vx=2.5))
    assert "above the tested 1 rad/s" in outside_tested_range("bound", VelocityCommand(vx=0.5, yaw_rate=2.0))
    assert outside_tested_range("trot", VelocityCommand(vx=2.5), robot="go2") is None  # not measured
    with Controller("trot", ["mpc.latency=fixed"]) as controller, caplog.at_level("WARNING"):
        controller.set_command(vx=2.5)  # accepted (the legs allow 3 m/s), with a warning
    assert "set_command: gait trot: vx = 2.5 m/s is outside the tested range" in caplog.text
