"""Keyboard teleop in ``--viewer`` (issue 22): arrow keys become checked velocity commands for the MPC; under
Xvfb, key presses through the viewer's key callback change the command the MPC follows mid-run.

The viewer test needs Debian's ``xvfb`` and skips with the reason without it."""

from __future__ import annotations

import subprocess
import sys

import pytest

from cafe_mpc.assembly import build_controller, resolve
from cafe_mpc.config import VelocityCommand, load_config
from cafe_mpc.control.commands import GAIT_NAMES, CommandChannel
from cafe_mpc.robots.robot import load_robot
from cafe_mpc_lab.sim.viewer import KEY_DOWN, KEY_END, KEY_HOME, KEY_LEFT, KEY_UP, KeyboardTeleop
from test_viewer_render import _with_display, xvfb_display  # noqa: F401  (the X display fixture)


def test_arrow_keys_become_checked_commands():
    robot = load_robot("mini_cheetah")
    channel = CommandChannel()
    teleop = KeyboardTeleop(robot, channel, VelocityCommand(vx=0.5))
    assert teleop.key(KEY_UP) and teleop.key(KEY_UP) and teleop.key(KEY_LEFT)
    values = channel.take()
    assert values is not None and values[:3].tolist() == pytest.approx([0.7, 0.0, 0.1])
    assert not teleop.key(ord("C"))  # MuJoCo's own keys are left alone
    teleop.key(KEY_HOME)
    assert channel.take()[:3].tolist() == [0.0, 0.0, 0.0]
    for _ in range(30):
        teleop.key(KEY_DOWN)
    assert teleop.command.vx == pytest.approx(-3.0) and not teleop.message.startswith("refused")
    assert teleop.key(KEY_DOWN) and teleop.message.startswith("refused: command vx = -3.1")
    assert teleop.command.vx == pytest.approx(-3.0)  # the refused command was not posted
    teleop.key(KEY_END)  # the next gait, posted with the command
    assert teleop.gait == "flying_trot" and channel.take()[4] == GAIT_NAMES.index("flying_trot")
    keys, actions = teleop.texts()
    assert "Up / Down" in keys and "End" in keys and "forward speed" in actions
    assert "flying_trot: vx -3.00 m/s" in actions


def test_teleop_finds_the_command_channel_of_a_gait_run_only():
    robot = load_robot("mini_cheetah")
    trot = build_controller(resolve(load_config("trot", ["mpc.latency=fixed"]), robot))
    teleop = KeyboardTeleop.of_controller(robot, trot)
    assert teleop is not None and teleop.channel is trot.commands and teleop.command.vx == 0.5
    roll = build_controller(resolve(load_config("barrel-roll", ["mpc.latency=fixed"]), robot))
    assert KeyboardTeleop.of_controller(robot, roll) is None  # a composed reference takes no commands


PRESS_KEYS = """
from cafe_mpc.config import load_config
from cafe_mpc_lab.experiments.run import simulate_run
from cafe_mpc_lab.sim import viewer as viewer_module

original = viewer_module.LiveViewer.update
pressed = []
def update(self, t, plant):  # press Up three times at 0.4 s, as a user would in the window
    if t >= 0.4 and not pressed:
        pressed.append(t)
        for _ in range(3):
            self.key_callback(viewer_module.KEY_UP)
    return original(self, t, plant)
viewer_module.LiveViewer.update = update

config = load_config("trot", ["mpc.latency=fixed", "simulation.duration=1.6", "output.plots=false"])
resolved, controller, log = simulate_run(config, viewer=True)
robot = resolved.robot
reference = controller.inner.reference if hasattr(controller, "inner") else controller.reference
last = reference.commands[-1]
print(log.extra["viewer"]["teleop_key_presses"], last.vx, round(last.start, 2))
"""


def test_viewer_keys_steer_the_mpc_under_xvfb(xvfb_display):  # noqa: F811
    result = subprocess.run(
        [sys.executable, "-c", PRESS_KEYS],
        env=_with_display(xvfb_display),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    presses, vx, start = result.stdout.split()
    assert int(presses) == 3
    assert float(vx) == pytest.approx(0.8)  # the preset's 0.5 m/s + 3 x 0.1, followed by the MPC
    assert 0.4 <= float(start) <= 0.5  # from its next update on
