"""Plots of acrobatic task runs (paper Sec. VII-C, Fig. 13 style): roll, height and lateral position of the
robot against the reference, and a strip of rendered frames.

The roll is shown two ways: the unwrapped ZYX roll angle of the base (robot and reference alike; the
reference's quaternions are sign-continuous across the roll, see ``reference.composition``) and, for the
robot, the integral of the body roll rate (``task.roll_turned_rad``). The planned flight is shaded; the
measured touchdown and landing are marked.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cafe_mpc.reference.base import Reference
from cafe_mpc.report.figures import save_figure, subplots
from cafe_mpc.report.metrics import roll_pitch_yaw
from cafe_mpc.report.task_metrics import AcrobaticTask, reference_trace
from cafe_mpc.robots.robot import Robot
from cafe_mpc.sim.loop import SimulationLog


def plot_task(
    robot: Robot,
    log: SimulationLog,
    reference: Reference,
    task: AcrobaticTask,
    path: Path,
    metrics: dict | None = None,
    control_period: float = 0.002,
) -> Path:
    """``task.png``: roll, base height and lateral position (world y) against the reference."""
    t = log.time
    planned = reference_trace(reference, t, robot.nq, robot.nv, robot.nu, robot.n_feet)
    roll = roll_pitch_yaw(log.q[:, 3:7])[:, 0]
    roll_reference = roll_pitch_yaw(planned[:, 3:7])[:, 0]
    roll_integrated = np.cumsum(log.v[:, 3]) * control_period
    figure, axes = subplots(3, 1, figsize=(8, 7.5), sharex=True)
    axes[0].plot(t, roll_reference, "k--", lw=1.0, label="reference (unwrapped roll)")
    axes[0].plot(t, roll, lw=1.2, label="robot (unwrapped roll)")
    axes[0].plot(t, roll_integrated, lw=0.8, ls=":", label="robot (integrated roll rate)")
    axes[0].axhline(task.roll_target, color="grey", lw=0.6)
    axes[0].set_ylabel("roll [rad]")
    axes[1].plot(t, planned[:, 2], "k--", lw=1.0, label="reference")
    axes[1].plot(t, log.q[:, 2], lw=1.2, label="robot")
    axes[1].set_ylabel("base height [m]")
    axes[2].plot(t, planned[:, 1], "k--", lw=1.0, label="reference")
    axes[2].plot(t, log.q[:, 1], lw=1.2, label="robot")
    axes[2].set_ylabel("lateral position y [m]")
    axes[2].set_xlabel("time [s]")
    for axis in axes:
        axis.axvspan(task.takeoff, task.touchdown, color="grey", alpha=0.15, lw=0)
        if metrics is not None and metrics.get("touchdown_s") is not None:
            axis.axvline(metrics["touchdown_s"], color="tab:red", lw=0.8, ls="--")
        axis.legend(loc="best", fontsize=7)
    title = f"{task.name}: planned flight shaded"
    if metrics is not None:
        title += (
            f"; roll turned {metrics['roll_turned_rad']:.2f} rad, success {metrics['success']}"
            " (red: measured touchdown)"
        )
    figure.suptitle(title, fontsize=10)
    return save_figure(figure, Path(path))


def render_frame_strip(
    robot: Robot,
    log: SimulationLog,
    times: Sequence[float],
    path: Path,
    camera: Sequence[float] = (1.1, -5.0, 180.0),
    size: tuple[int, int] = (240, 220),
) -> Path:
    """One PNG with the robot rendered at ``times`` side by side, seen from the front (camera ``distance,
    elevation, azimuth``; the roll is about the body x axis). Raises ``RenderUnavailable`` without an
    off-screen OpenGL."""
    from cafe_mpc.robots.rendering import OffscreenRenderer, RenderUnavailable

    os.environ.setdefault("MUJOCO_GL", "osmesa")
    try:
        import imageio.v2 as imageio
        import mujoco

        model = mujoco.MjModel.from_xml_string(robot.mjcf)
        data = mujoco.MjData(model)
        renderer = OffscreenRenderer(model, height=size[0], width=size[1])
    except Exception as error:  # GL back-ends fail with many exception types
        raise RenderUnavailable(
            f"off-screen rendering is not available ({type(error).__name__}: {error})"
        ) from error
    view = mujoco.MjvCamera()
    view.distance, view.elevation, view.azimuth = camera
    frames = []
    try:
        for time in times:
            q = log.q[int(np.clip(np.searchsorted(log.time, time), 0, log.ticks - 1))]
            data.qpos[:3] = q[:3]
            data.qpos[3:7] = [q[6], q[3], q[4], q[5]]
            data.qpos[7:] = q[7:]
            mujoco.mj_forward(model, data)
            view.lookat[:] = [q[0], q[1], 0.25]
            renderer.update_scene(data, view)
            frames.append(renderer.render())
    finally:
        renderer.close()
    path = Path(path)
    imageio.imwrite(path, np.concatenate(frames, axis=1))
    return path


def render_task_frames(robot: Robot, log: SimulationLog, task_block: dict, path: Path) -> Path:
    """``frames.png`` of a task run: the robot before the roll, at take-off, four times in the planned
    flight, at the measured touchdown, 0.25 s and 1 s after it (``render_frame_strip``)."""
    takeoff, touchdown = task_block["planned_takeoff_s"], task_block["planned_touchdown_s"]
    landed = task_block.get("touchdown_s") or touchdown
    flight = [takeoff + (touchdown - takeoff) * fraction for fraction in (0.2, 0.4, 0.6, 0.8)]
    times = [task_block["planned_start_s"], takeoff - 0.03, *flight, landed, landed + 0.25, landed + 1.0]
    return render_frame_strip(robot, log, [t for t in times if t <= log.time[-1]], path)
