"""Seeing the plan (issue 15): the overlay drawn into a MuJoCo scene, ``cafe-mpc run --viewer`` (MuJoCo's
passive viewer; under Xvfb here) and the same overlay in ``--render`` videos.

The viewer test needs Debian's ``xvfb`` and the video test an off-screen OpenGL (``libosmesa6``); each skips
with the reason when it is missing (CI may lack them).
"""

from __future__ import annotations

import json
import os
import select
import shutil
import subprocess
import sys
import time

import mujoco
import numpy as np
import pytest

from cafe_mpc.config import load_config
from cafe_mpc.robots.plan_overlay import PlanOverlay, draw_plan
from cafe_mpc_lab.experiments.run import run

CLI = [sys.executable, "-m", "cafe_mpc_lab.cli"]


@pytest.fixture(scope="module")
def trot_plan(robot):
    """A real plan: the first (cold) solve of the trot preset, a tenth of a second into the gait."""
    from cafe_mpc.assembly import build_controller, resolve
    from cafe_mpc.core.measurement import Measurement

    controller = build_controller(
        resolve(load_config("trot", ["mpc.latency=fixed", "gait.start_stance=0"]), robot)
    )
    standing = Measurement.of_state(robot.q_standing, np.zeros(robot.nv), np.ones(4, dtype=bool))
    controller.start(0.0, standing)
    return controller.plan


def test_the_overlay_draws_base_path_footholds_swings_and_forces(robot, trot_plan):
    overlay = PlanOverlay.of_plan(robot, trot_plan)
    n = len(trot_plan.times)
    assert overlay.base.shape == (n + 1, 3) and overlay.feet.shape == (n + 1, 4, 3)
    assert np.allclose(overlay.feet[0], robot.foot_positions(trot_plan.xs[0, : robot.nq]))
    model = mujoco.MjModel.from_xml_string(robot.mjcf)
    scene = mujoco.MjvScene(model, maxgeom=500)
    added = draw_plan(scene, overlay, t=trot_plan.start_time)
    assert added == scene.ngeom > 0
    types = [scene.geoms[i].type for i in range(scene.ngeom)]
    stance_now = int(trot_plan.contacts[0].sum())
    assert types.count(mujoco.mjtGeom.mjGEOM_ARROW) == stance_now  # a GRF arrow per stance foot
    stance_runs = sum(
        int(np.sum(np.diff(np.concatenate([[0], trot_plan.contacts[:, foot].astype(int)])) == 1))
        for foot in range(4)
    )
    assert types.count(mujoco.mjtGeom.mjGEOM_CYLINDER) == stance_runs > 0  # a foothold per stance
    assert types.count(mujoco.mjtGeom.mjGEOM_CAPSULE) >= n  # base path + swing paths
    # a full scene takes what fits and stops without an error
    small = mujoco.MjvScene(model, maxgeom=5)
    assert draw_plan(small, overlay) == 5 and small.ngeom == 5


def _start_xvfb() -> tuple[subprocess.Popen, str]:
    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        pytest.skip("Xvfb is not installed (Debian: apt-get install xvfb); the viewer needs a display")
    read_end, write_end = os.pipe()
    process = subprocess.Popen(
        [xvfb, "-displayfd", str(write_end), "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
        pass_fds=(write_end,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    os.close(write_end)
    ready, _, _ = select.select([read_end], [], [], 20.0)
    number = os.read(read_end, 32).decode().strip() if ready else ""
    os.close(read_end)
    if not number:
        process.kill()
        process.wait()
        pytest.skip("Xvfb did not start")
    # The display number can come before clients are accepted (seen on a loaded VM): wait until a client
    # that initialises GLFW, as the viewer does, gets through (at most 20 s).
    probe = [sys.executable, "-c", "import glfw, sys; sys.exit(0 if glfw.init() else 1)"]
    environment = {**os.environ, "DISPLAY": f":{number}"}
    environment.pop("WAYLAND_DISPLAY", None)
    deadline = time.monotonic() + 20.0
    while subprocess.run(probe, env=environment, capture_output=True).returncode != 0:
        if time.monotonic() > deadline:
            process.kill()
            process.wait()
            # the X server's fault, not the viewer's (seen intermittently on one VM): nothing to test against
            pytest.skip(f"Xvfb display :{number} accepted no GLFW client within 20 s")
        time.sleep(0.2)
    return process, f":{number}"


@pytest.fixture(scope="module")
def xvfb_display():
    """A private X display (``Xvfb -displayfd``), stopped after the module's tests."""
    xvfb, display = _start_xvfb()
    yield display
    xvfb.terminate()
    xvfb.wait(timeout=10)


def _with_display(display: str) -> dict[str, str]:
    environment = {**os.environ, "DISPLAY": display}
    environment.pop("WAYLAND_DISPLAY", None)
    return environment


@pytest.mark.display
@pytest.mark.slow
def test_viewer_follows_a_run_under_xvfb_with_the_plan_drawn(tmp_path, xvfb_display):
    out = tmp_path / "run"
    result = subprocess.run(
        [
            *CLI,
            "run",
            "trot",
            "--viewer",
            "--duration",
            "0.6",
            "--out",
            str(out),
            "--set",
            "mpc.latency=fixed",
            "--set",
            "output.plots=false",
        ],
        env=_with_display(xvfb_display),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr  # (the process used to crash at exit: GLFW vs the window)
    viewer = json.loads((out / "metrics.json").read_text())["viewer"]
    assert viewer["frames"] >= 15  # 30 frames per simulated second
    assert viewer["overlay_geoms_max"] > 20  # the plan was drawn into the viewer's scene
    assert viewer["closed_by_user"] is False


CLOSE_WINDOW = """
import time
from cafe_mpc.robots.robot import load_robot
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant
from cafe_mpc_lab.sim.viewer import LiveViewer

robot = load_robot("mini_cheetah")
plant = MujocoPlant(robot)
plant.reset(robot.q_standing)
viewer = LiveViewer(robot, lambda: None, realtime=False)
viewer.start(plant)
assert viewer.update(0.04, plant)
viewer._handle.close()  # as when the user closes the window
time.sleep(0.5)
print(viewer.update(0.08, plant), viewer.stop_reason)
viewer.close()
"""


@pytest.mark.display
def test_closing_the_viewer_window_ends_the_run(xvfb_display):
    result = subprocess.run(
        [sys.executable, "-c", CLOSE_WINDOW],
        env=_with_display(xvfb_display),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "False the viewer window was closed"


@pytest.mark.display
@pytest.mark.slow
def test_sim_robot_shows_the_robot_on_the_wire_in_the_viewer(tmp_path, xvfb_display):
    summary_file = tmp_path / "sim.json"
    result = subprocess.run(
        [*CLI, "sim-robot", "--viewer", "--duration", "0.5", "--domain", "7", "--out", str(summary_file)],
        env=_with_display(xvfb_display),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    summary = json.loads(summary_file.read_text())
    assert summary["viewer_frames"] >= 10  # 30 frames per simulated second
    assert summary["duration"] >= 0.5


@pytest.mark.slow
def test_viewer_without_a_display_is_one_clear_line(tmp_path):
    environment = {
        key: value for key, value in os.environ.items() if key not in ("DISPLAY", "WAYLAND_DISPLAY")
    }
    result = subprocess.run(
        [*CLI, "run", "trot", "--viewer", "--duration", "0.2", "--out", str(tmp_path / "run")],
        env=environment,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("cafe-mpc: error: --viewer needs a display"), lines
    assert not (tmp_path / "run").exists()


def _offscreen_gl_or_skip() -> None:
    from cafe_mpc.robots.rendering import OffscreenRenderer

    try:
        renderer = OffscreenRenderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 16, 16)
        renderer.close()
    except Exception as error:  # GL back-ends fail with many exception types
        pytest.skip(f"no off-screen OpenGL here ({type(error).__name__}: {error}); Debian: libosmesa6")


@pytest.mark.display
@pytest.mark.slow
def test_render_draws_the_plan_into_the_video(tmp_path, robot):
    _offscreen_gl_or_skip()
    import imageio.v2 as imageio

    from cafe_mpc_lab.experiments.controllers import recorder_of
    from cafe_mpc_lab.report.video import render_run

    config = load_config(
        "trot",
        [
            "simulation.duration=0.5",
            "mpc.latency=fixed",
            "output.plots=false",
            "output.render=true",
            "scene.terrain=[{kind: steps, start: 0.3, rise: 0.02}]",
        ],
    )
    result = run(config, tmp_path / "run")
    assert "render_error" not in result.metrics
    video = next((tmp_path / "run").glob("run.*"))
    plans = recorder_of(result.controller).plans
    assert len(plans) >= 20 and plans[0].t == 0.0  # one per MPC update, each from when it was first used
    plain = render_run(robot, result.log, tmp_path / "plain.mp4", fps=10)  # no plans: no overlay
    drawn = render_run(robot, result.log, tmp_path / "drawn.mp4", fps=10, plans=plans)
    first_plain = imageio.get_reader(plain).get_data(3)
    first_drawn = imageio.get_reader(drawn).get_data(3)
    changed = np.any(first_plain != first_drawn, axis=-1).mean()
    assert changed > 0.002  # the overlay covers part of the frame
    assert video.stat().st_size > 1000
