"""Plots of acrobatic task runs (paper Sec. VII-C, Fig. 13 style): the rotation about the task's axis (roll,
pitch or yaw), height and lateral position of the robot against the reference, and a strip of rendered frames.

The rotation is shown two ways: the unwrapped planar angle of the base about the task's axis (robot and
reference alike, ``planar_angle``; the reference's quaternions are sign-continuous across the roll, see
``reference.composition``) and, for the robot, the integral of the body rate about that axis
(``task.rotation_turned_rad``). The planned flight is shaded; the
measured touchdown and landing are marked.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from cafe_mpc.core.free_joint import free_joint_qpos
from cafe_mpc.reference.base import Reference
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.report.figures import save_figure, subplots
from cafe_mpc_lab.report.task_metrics import ROTATION_AXES, AcrobaticTask, forward_speed, reference_trace
from cafe_mpc_lab.sim.loop import SimulationLog

PLANAR_ANGLE_ENTRIES = {0: ((2, 1), (2, 2)), 1: ((2, 0), (0, 0)), 2: ((1, 0), (0, 0))}
"""Rotation-matrix entries ``(sine, cosine)`` of the angle about each body axis: roll ``atan2(R21, R22)``,
pitch ``atan2(-R20, R00)``, yaw ``atan2(R10, R00)``."""


def planar_angle(quaternions_xyzw: np.ndarray, axis: int) -> np.ndarray:
    """Unwrapped angle of the base about body axis ``axis`` (0 x, 1 y, 2 z) for a motion mostly about that
    axis. Roll and yaw equal the ZYX angles; the pitch is ``atan2(-R20, R00)``, which, unlike the ZYX pitch
    (``asin(-R20)``, folded at +-pi/2), follows a flip through the whole turn."""
    if len(quaternions_xyzw) == 0:
        return np.zeros(0)
    matrices = Rotation.from_quat(quaternions_xyzw).as_matrix()
    (sine_row, sine_col), (cosine_row, cosine_col) = PLANAR_ANGLE_ENTRIES[axis]
    sign = -1.0 if axis == 1 else 1.0
    angle = np.arctan2(sign * matrices[:, sine_row, sine_col], matrices[:, cosine_row, cosine_col])
    return np.unwrap(angle)


def plot_task(
    robot: Robot,
    log: SimulationLog,
    reference: Reference,
    task: AcrobaticTask,
    path: Path,
    metrics: dict | None = None,
    control_period: float = 0.002,
) -> Path:
    """``task.png``: roll, base height and lateral position (world y) against the reference; for a running
    task (a gait before or after the roll) also the forward speed (paper Fig. 15), and the bar's height
    (``metrics["bar_height_m"]``) as a dashed line on the height plot."""
    t = log.time
    planned = reference_trace(reference, t, robot.nq, robot.nv, robot.nu, robot.n_feet)
    axis_index = task.rotation_axis
    name = ROTATION_AXES[axis_index]
    roll = planar_angle(log.q[:, 3:7], axis_index)
    roll_reference = planar_angle(planned[:, 3:7], axis_index)
    roll_integrated = np.cumsum(log.v[:, 3 + axis_index]) * control_period
    running = task.approach_speed is not None or task.resume_speed is not None
    rows = 4 if running else 3
    figure, axes = subplots(rows, 1, figsize=(8, 2.5 * rows), sharex=True)
    axes[0].plot(t, roll_reference, "k--", lw=1.0, label=f"reference (unwrapped {name})")
    axes[0].plot(t, roll, lw=1.2, label=f"robot (unwrapped {name})")
    axes[0].plot(t, roll_integrated, lw=0.8, ls=":", label=f"robot (integrated {name} rate)")
    axes[0].axhline(task.roll_target, color="grey", lw=0.6)
    axes[0].set_ylabel(f"{name} [rad]")
    axes[1].plot(t, planned[:, 2], "k--", lw=1.0, label="reference")
    axes[1].plot(t, log.q[:, 2], lw=1.2, label="robot")
    axes[1].set_ylabel("base height [m]")
    if metrics is not None and metrics.get("bar_height_m"):
        axes[1].axhline(metrics["bar_height_m"], color="tab:orange", lw=1.0, ls="--", label="bar")
    axes[2].plot(t, planned[:, 1], "k--", lw=1.0, label="reference")
    axes[2].plot(t, log.q[:, 1], lw=1.2, label="robot")
    axes[2].set_ylabel("lateral position y [m]")
    if running:
        axes[3].plot(t, forward_speed(log.q, log.v), lw=1.0, label="robot")
        for speed in {task.approach_speed, task.resume_speed} - {None}:
            axes[3].axhline(speed, color="k", lw=0.8, ls="--", label=f"gait command {speed:g} m/s")
        axes[3].set_ylabel("forward speed [m/s]")
    axes[-1].set_xlabel("time [s]")
    for axis in axes:
        axis.axvspan(task.takeoff, task.touchdown, color="grey", alpha=0.15, lw=0)
        if metrics is not None and metrics.get("touchdown_s") is not None:
            axis.axvline(metrics["touchdown_s"], color="tab:red", lw=0.8, ls="--")
        axis.legend(loc="best", fontsize=7)
    title = f"{task.name}: planned flight shaded"
    if metrics is not None:
        verdict = {True: "success", False: "failed", None: "not judged"}[metrics["success"]]
        if metrics.get("failed_criteria"):
            verdict += f" ({', '.join(metrics['failed_criteria'])})"
        elif metrics["success"] is None and metrics.get("unjudged"):
            verdict += f" (run too short for {', '.join(metrics['unjudged'])})"
        turned = metrics.get("rotation_turned_rad", metrics["roll_turned_rad"])
        title += f"; {name} turned {turned:.2f} rad, {verdict} (red: measured touchdown)"
    figure.suptitle(title, fontsize=10)
    return save_figure(figure, Path(path))


def plot_task_torques(
    robot: Robot,
    log: SimulationLog,
    task: AcrobaticTask,
    path: Path,
    limits: np.ndarray | None = None,
) -> Path:
    """``task_torques.png`` (paper Fig. 16): the torques the motors applied on every joint, one panel per
    joint kind (abad, hip, knee) with the four legs, the motor limits dashed (and the limits the controller
    enforces, ``limits``, dotted where they differ); the roll (trajectory start to end) shaded, its flight
    darker."""
    t = log.time
    motor = np.asarray(robot.plant.motor_torque_limits, dtype=float)
    enforced = motor if limits is None else np.asarray(limits, dtype=float)
    names = [name.split("_")[0] for name in robot.joint_names]
    figure, axes = subplots(3, 1, figsize=(9, 7.5), sharex=True)
    for kind, axis in enumerate(axes):
        for joint in range(kind, robot.nu, 3):
            axis.plot(t, log.torque_applied[:, joint], lw=0.9, label=names[joint])
        axis.axhline(motor[kind], color="k", lw=0.8, ls="--", label="motor limit")
        axis.axhline(-motor[kind], color="k", lw=0.8, ls="--")
        if abs(enforced[kind] - motor[kind]) > 1e-9:
            axis.axhline(enforced[kind], color="grey", lw=0.8, ls=":", label="controller limit")
            axis.axhline(-enforced[kind], color="grey", lw=0.8, ls=":")
        axis.axvspan(task.start, task.end, color="grey", alpha=0.10, lw=0)
        axis.axvspan(task.takeoff, task.touchdown, color="grey", alpha=0.15, lw=0)
        axis.set_ylabel(f"{('abad', 'hip', 'knee')[kind]} torque [Nm]")
        axis.legend(loc="upper right", fontsize=7, ncol=3)
    axes[-1].set_xlabel("time [s]")
    figure.suptitle(f"{task.name}: applied joint torques (roll shaded, flight darker)", fontsize=10)
    return save_figure(figure, Path(path))


def render_frame_strip(
    robot: Robot,
    log: SimulationLog,
    times: Sequence[float],
    path: Path,
    camera: Sequence[float] = (1.1, -5.0, 180.0),
    size: tuple[int, int] = (240, 220),
    mjcf: str | None = None,
) -> Path:
    """One PNG with the robot rendered at ``times`` side by side, seen from the front (camera ``distance,
    elevation, azimuth``; the roll is about the body x axis). ``mjcf``: the scene to render (default the
    robot's alone; ``sim.scene.Scene.mjcf`` adds terrain and the bar). Raises ``RenderUnavailable`` without an
    off-screen OpenGL."""
    from cafe_mpc.robots.rendering import OffscreenRenderer, RenderUnavailable

    try:
        import imageio.v2 as imageio
        import mujoco

        model = mujoco.MjModel.from_xml_string(robot.mjcf if mjcf is None else mjcf)
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
            data.qpos[:] = free_joint_qpos(q)
            mujoco.mj_forward(model, data)
            view.lookat[:] = [q[0], q[1], 0.25]
            renderer.update_scene(data, view)
            frames.append(renderer.render())
    finally:
        renderer.close()
    path = Path(path)
    imageio.imwrite(path, np.concatenate(frames, axis=1))
    return path


FRAME_CAMERAS = {"roll": (1.1, -5.0, 180.0), "pitch": (1.3, -5.0, 90.0), "yaw": (1.1, -30.0, 180.0)}
"""Camera ``distance, elevation, azimuth`` of a task's frames by its rotation axis."""


def render_task_frames(
    robot: Robot, log: SimulationLog, task_block: dict, path: Path, mjcf: str | None = None
) -> Path:
    """``frames.png`` of a task run: the robot before the roll, at take-off, four times in the planned
    flight, at the measured touchdown, 0.25 s and 1 s after it (``render_frame_strip``), seen along the axis
    the task turns about: from the front for a roll, from the side for a flip (``FRAME_CAMERAS``)."""
    takeoff, touchdown = task_block["planned_takeoff_s"], task_block["planned_touchdown_s"]
    landed = task_block.get("touchdown_s") or touchdown
    flight = [takeoff + (touchdown - takeoff) * fraction for fraction in (0.2, 0.4, 0.6, 0.8)]
    times = [task_block["planned_start_s"], takeoff - 0.03, *flight, landed, landed + 0.25, landed + 1.0]
    camera = FRAME_CAMERAS.get(task_block.get("rotation_axis", "roll"), FRAME_CAMERAS["roll"])
    return render_frame_strip(robot, log, [t for t in times if t <= log.time[-1]], path, camera, mjcf=mjcf)
