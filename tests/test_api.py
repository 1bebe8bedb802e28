"""``cafe_mpc.Controller``: the controller as a library, in a loop the user wrote (issue 15)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import mujoco
import numpy as np
import pytest

import cafe_mpc
from cafe_mpc.api import Controller
from cafe_mpc.assembly import load_run_config
from cafe_mpc.config import ConfigError

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "mujoco_loop.py"


def _mujoco_loop(controller: Controller, seconds: float, t0: float = 0.0, realtime: bool = False):
    """A hand-written MuJoCo loop around ``controller`` (clock offset ``t0``); returns (model, data)."""
    model = mujoco.MjModel.from_xml_string(controller.robot.mjcf)
    data = mujoco.MjData(model)
    data.qpos[:] = controller.standing_qpos()
    mujoco.mj_forward(model, data)
    substeps = round(controller.control_period / model.opt.timestep)
    controller.reset(controller.measurement(data.qpos, data.qvel, time=t0))
    start = time.perf_counter()
    for tick in range(round(seconds / controller.control_period)):
        if realtime:
            delay = start + tick * controller.control_period - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        t = t0 + data.time
        torques = controller.compute(t, controller.measurement(data.qpos, data.qvel, time=t))
        assert torques.shape == (controller.robot.nu,) and np.all(np.isfinite(torques))
        data.ctrl[:] = torques
        for _ in range(substeps):
            mujoco.mj_step(model, data)
    return model, data


def test_the_package_exports_the_controller():
    assert cafe_mpc.Controller is Controller
    with pytest.raises(AttributeError):
        cafe_mpc.NoSuchThing  # noqa: B018


def test_inline_controller_trots_in_a_users_loop_on_its_own_clock():
    with Controller("trot", ["mpc.latency=fixed"]) as controller:
        assert controller.mode == "inline" and controller.plan is None
        _, data = _mujoco_loop(controller, 1.0, t0=100.0)  # the user's clock starts at 100 s
        assert data.qpos[2] > 0.2 and data.qpos[0] > 0.15  # up, and moving forward
        plan = controller.plan
        assert plan is not None and 0.9 < plan.start_time < 1.1  # plans are on the controller's clock
        statistics = controller.statistics()
        assert statistics["solves"] >= 45 and statistics["failures"] == 0


def test_the_measurement_helper_converts_mujocos_free_joint_state():
    controller = Controller("trot")
    robot = controller.robot
    qpos = controller.standing_qpos()
    assert np.allclose(qpos[3:7], [1.0, 0.0, 0.0, 0.0])
    q_yawed = robot.q_standing.copy()
    q_yawed[3:7] = [0.0, 0.0, np.sin(0.5), np.cos(0.5)]  # yaw 1 rad
    qpos = np.concatenate([q_yawed[:3], [q_yawed[6], *q_yawed[3:6]], q_yawed[7:]])
    qvel = np.zeros(robot.nv)
    qvel[:3] = [np.cos(1.0), np.sin(1.0), 0.0]  # 1 m/s along the body's x axis, in the world frame
    measurement = controller.measurement(qpos, qvel, time=2.0, contacts=[True, False, True, False])
    assert np.allclose(measurement.q, q_yawed)
    assert np.allclose(measurement.v[:3], [1.0, 0.0, 0.0])  # base frame
    assert measurement.time == 2.0 and measurement.contacts.tolist() == [True, False, True, False]


def test_bad_uses_are_clear_errors():
    with pytest.raises(ConfigError, match="wbc: pd"):
        Controller("stand")
    with pytest.raises(ConfigError, match="mode must be"):
        Controller("trot", mode="thread")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="overrides apply"):
        Controller(load_run_config("trot"), ["mpc.period=0.03"])
    with pytest.raises(ConfigError, match=r"mpc\.friction"):
        Controller("trot", ["mpc.friction=0"])
    controller = Controller(load_run_config("trot"))
    measurement = controller.measurement(controller.standing_qpos(), np.zeros(controller.robot.nv))
    with pytest.raises(RuntimeError, match="reset"):
        controller.compute(0.0, measurement)
    controller.close()
    with pytest.raises(RuntimeError, match="closed"):
        controller.reset(measurement)


@pytest.mark.realtime
def test_process_mode_runs_the_mpc_in_its_own_process_and_cleans_up():
    import multiprocessing

    with Controller("trot", mode="process") as controller:
        _mujoco_loop(controller, 0.6, realtime=True)
        assert controller.failure is None
        assert controller.statistics()["plans_received"] >= 2  # plans arrived (how many depends on the load)
        process = controller._loop.process
        assert process.is_alive()
    assert not process.is_alive()
    assert not [child for child in multiprocessing.active_children() if child.name == "cafe-mpc-solver"]


@pytest.mark.realtime
def test_the_template_planner_runs_in_the_mpc_process_too():
    """The MPC process's plan channel carries any planner's plans (its ``PlanFormat``): the template's
    ``TemplatePlan`` arrive and its own low level follows them."""
    from cafe_mpc.planners.template.plan import TemplatePlan

    with Controller("trot", ["planner=template"], mode="process") as controller:
        _mujoco_loop(controller, 0.6, realtime=True)
        assert controller.failure is None
        assert isinstance(controller.plan, TemplatePlan)
        assert controller.statistics()["plans_received"] >= 2


@pytest.mark.slow
def test_the_example_runs_against_its_own_mujoco_loop():
    result = subprocess.run(
        [sys.executable, str(EXAMPLE), "--duration", "1.0", "--set", "mpc.latency=fixed"],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
    assert result.returncode == 0, result.stderr
    assert "trot (inline): 1.00 s simulated, fell: False" in result.stdout
