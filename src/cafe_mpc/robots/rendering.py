"""Off-screen rendering of robot configurations with MuJoCo, to MP4 (or GIF without ffmpeg).

Used for run videos (``report/video.py``) and trajectory-optimisation videos (``trajopt/outputs.py``): both
replay a sequence of configurations (planning coordinates) kinematically in the robot's MuJoCo model.

The OpenGL context is created explicitly (OSMesa, or EGL with ``MUJOCO_GL=egl``): ``mujoco.Renderer`` picks
its back-end from ``MUJOCO_GL`` when MuJoCo is *imported*, and the command line imports MuJoCo to build its
parser, so without the variable it tried GLFW, failed without a display and then aborted the process.
Creating the context here works whatever was imported before. Needs ``libosmesa6`` (Debian) for OSMesa;
``RenderUnavailable`` says why when no back-end works.
"""

from __future__ import annotations

import ctypes.util
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cafe_mpc.core.free_joint import free_joint_qpos
from cafe_mpc.robots.robot import Robot

if TYPE_CHECKING:
    import mujoco


class RenderUnavailable(RuntimeError):
    """Off-screen rendering cannot run on this machine (or there is nothing to render)."""


class OffscreenRenderer:
    """``mujoco.Renderer``'s job with an explicitly created OSMesa/EGL context (see the module docstring)."""

    def __init__(self, model, height: int, width: int) -> None:
        import mujoco

        backend = os.environ.get("MUJOCO_GL", "osmesa").lower()
        library = "EGL" if backend == "egl" else "OSMesa"
        if ctypes.util.find_library(library) is None:
            # checked first: a GL context built without its library fails inside PyOpenGL and its __del__
            # then reports an AttributeError of its own
            raise RuntimeError(f"no lib{library} on this machine (MUJOCO_GL={backend})")
        if backend == "egl":
            from mujoco.egl import GLContext
        else:
            from mujoco.osmesa import GLContext
        self._mujoco = mujoco
        self._context = GLContext(width, height)
        self._context.make_current()
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, height)
        self._model = model
        self._render_context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._render_context)
        self._scene = mujoco.MjvScene(model, maxgeom=1000)
        self._option = mujoco.MjvOption()
        self._viewport = mujoco.MjrRect(0, 0, width, height)
        self._pixels = np.empty((height, width, 3), dtype=np.uint8)

    def update_scene(self, data, camera) -> None:
        mujoco = self._mujoco
        mujoco.mjv_updateScene(
            self._model, data, self._option, None, camera, mujoco.mjtCatBit.mjCAT_ALL, self._scene
        )

    @property
    def scene(self):
        """The ``MjvScene`` of the last ``update_scene`` (user geoms may be appended before ``render``)."""
        return self._scene

    def render(self) -> np.ndarray:
        self._mujoco.mjr_render(self._viewport, self._scene, self._render_context)
        self._mujoco.mjr_readPixels(self._pixels, None, self._viewport, self._render_context)
        return np.flipud(self._pixels).copy()

    def close(self) -> None:
        self._render_context.free()
        self._context.free()


def render_configurations(
    robot: Robot,
    configurations: np.ndarray,
    path: Path,
    fps: int = 30,
    camera: Sequence[float] = (1.2, -15.0, 120.0),
    look_at_height: float = 0.2,
    size: tuple[int, int] = (368, 640),
    mjcf: str | None = None,
    decorate: Callable[[int, mujoco.MjvScene], None] | None = None,
) -> Path:
    """Write a video of ``configurations`` (frames x nq, planning coordinates: quaternion (x, y, z, w)), one
    frame each, the camera (``distance, elevation, azimuth``) following the base. Returns the file written
    (``.gif`` instead of ``.mp4`` when ffmpeg is missing). Raises ``RenderUnavailable``.

    ``mjcf``: the scene to render (default the robot's own; e.g. the plant's with terrain). ``decorate(frame,
    scene)``: adds user geoms to each frame's scene after MuJoCo's own (the plan overlay,
    ``robots.plan_overlay.draw_plan``)."""
    configurations = np.asarray(configurations, dtype=float)
    if configurations.ndim != 2 or len(configurations) == 0:
        raise RenderUnavailable("nothing to render: no configurations")
    try:
        import imageio.v2 as imageio
        import mujoco

        model = mujoco.MjModel.from_xml_string(robot.mjcf if mjcf is None else mjcf)
        data = mujoco.MjData(model)
        renderer = OffscreenRenderer(model, height=size[0], width=size[1])
    except Exception as error:  # GL back-ends fail with many exception types
        raise RenderUnavailable(
            f"off-screen rendering is not available ({type(error).__name__}: {error}); "
            "install libosmesa6 (and set MUJOCO_GL=osmesa)"
        ) from error
    view = mujoco.MjvCamera()
    view.distance, view.elevation, view.azimuth = camera
    frames = []
    try:
        for frame, q in enumerate(configurations):
            data.qpos[:] = free_joint_qpos(q)
            mujoco.mj_forward(model, data)
            view.lookat[:] = [q[0], q[1], look_at_height]
            renderer.update_scene(data, view)
            if decorate is not None:
                decorate(frame, renderer.scene)
            frames.append(renderer.render())
    finally:
        renderer.close()
    path = Path(path)
    try:
        imageio.mimsave(path, frames, fps=fps)
    except Exception:  # no ffmpeg: fall back to GIF
        path = path.with_suffix(".gif")
        imageio.mimsave(path, frames, duration=1.0 / fps)
    return path
