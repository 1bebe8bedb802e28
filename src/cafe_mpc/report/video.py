"""Off-screen rendering of a logged run to MP4 (or GIF) with MuJoCo's renderer.

Needs an off-screen OpenGL: set ``MUJOCO_GL=osmesa`` (Debian package ``libosmesa6``) or ``egl``.
When none is available, ``render_run`` raises ``RenderUnavailable`` with the reason.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from cafe_mpc.robots.robot import Robot
from cafe_mpc.sim.loop import SimulationLog


class RenderUnavailable(RuntimeError):
    """Off-screen rendering cannot run on this machine."""


def render_run(robot: Robot, log: SimulationLog, path: Path, fps: int = 30) -> Path:
    """Replay the logged base/joint states in MuJoCo and write a video; returns the file written."""
    os.environ.setdefault("MUJOCO_GL", "osmesa")
    try:
        import imageio.v2 as imageio
        import mujoco

        from cafe_mpc.sim.plant import MujocoPlant

        plant = MujocoPlant(robot)
        renderer = mujoco.Renderer(plant.model, height=368, width=640)
    except Exception as error:  # GL back-ends fail with many exception types
        raise RenderUnavailable(
            f"off-screen rendering is not available ({type(error).__name__}: {error}); "
            "install libosmesa6 and set MUJOCO_GL=osmesa"
        ) from error
    camera = mujoco.MjvCamera()
    camera.distance, camera.elevation, camera.azimuth = 1.2, -15.0, 120.0
    if log.ticks == 0:
        raise RenderUnavailable("nothing to render: the log is empty")
    frame_times = np.arange(0.0, log.time[-1] + 1e-9, 1.0 / fps)
    indices = np.searchsorted(log.time, frame_times).clip(0, log.ticks - 1)
    frames = []
    for index in indices:
        plant.reset(log.q[index], log.v[index])
        camera.lookat[:] = [log.q[index, 0], log.q[index, 1], 0.2]
        renderer.update_scene(plant.data, camera)
        frames.append(renderer.render().copy())
    renderer.close()
    path = Path(path)
    try:
        imageio.mimsave(path, frames, fps=fps)
    except Exception:  # no ffmpeg: fall back to GIF
        path = path.with_suffix(".gif")
        imageio.mimsave(path, frames, duration=1.0 / fps)
    return path
