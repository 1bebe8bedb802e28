"""The files of ``cafe-mpc optimize``: trajectory (``.npz``) and its settings (``.yaml``), plots, a video of
the trajectory (kinematic replay in the MuJoCo model of the robot) and ``summary.json``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from cafe_mpc.core.contacts import LEG_NAMES
from cafe_mpc.reference.trajectory_file import WholeBodyTrajectory, save_trajectory
from cafe_mpc.robots.rendering import RenderUnavailable, render_configurations
from cafe_mpc.robots.robot import Robot
from cafe_mpc.trajopt.multiphase import TrajOptResult
from cafe_mpc.trajopt.task import TrajOptTask

VIDEO_SLOWDOWN = 4.0
"""The video plays the trajectory this many times slower than real time."""


def file_stem(task: TrajOptTask) -> str:
    """``barrel-roll`` -> ``barrel_roll`` (the names of the trajectory and settings files)."""
    return task.name.replace("-", "_")


def settings_header(task: TrajOptTask) -> str:
    return (
        f"Settings of the '{task.name}' trajectory optimisation (cafe_mpc.trajopt.TrajOptTask).\n"
        f"Re-run with: cafe-mpc optimize <this file>  (or: cafe-mpc optimize {task.name} --set key=value)\n"
        "Sources and deviations of the preset's values: cafe_mpc/trajopt/barrel_roll.py.\n"
        "Base weights: x, y, z, yaw, pitch, roll; joint vectors: abad, hip, knee (every leg) or 12 values;\n"
        "heights are the authors' + 0.02 m (foot-sphere centre, see barrel_roll.py)."
    )


def write_outputs(
    robot: Robot, result: TrajOptResult, out_dir: Path, render: bool = True, command: str | None = None
) -> dict:
    """Write every file into ``out_dir``; return the summary (also in ``summary.json``)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    task, trajectory = result.task, result.trajectory
    stem = file_stem(task)
    save_trajectory(out_dir / f"{stem}.npz", trajectory, robot)
    (out_dir / f"{stem}.yaml").write_text(task.to_yaml(settings_header(task)))
    summary = result.summary()
    summary["files"] = {"trajectory": f"{stem}.npz", "settings": f"{stem}.yaml"}
    summary["plots"] = [path.name for path in write_plots(robot, task, trajectory, out_dir)]
    summary["video"] = None
    if command is not None:
        summary["command"] = command
    summary["wall_time_note"] = (
        "measured on the machine that ran the command, possibly with other jobs running"
    )
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")  # before the GL part
    if render:
        try:
            summary["video"] = render_trajectory(robot, trajectory, out_dir / "video.mp4").name
            summary["video_slowdown"] = VIDEO_SLOWDOWN
        except RenderUnavailable as error:
            summary["render_error"] = str(error)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


# --------------------------------------------------------------------------------------------------
# Plots
# --------------------------------------------------------------------------------------------------


def _subplots(nrows: int, figsize: tuple[float, float], sharex: bool = False):
    """A figure with its own Agg canvas (no pyplot, no global backend; as ``report.figures``)."""
    figure = Figure(figsize=figsize)
    FigureCanvasAgg(figure)
    return figure, figure.subplots(nrows, 1, sharex=sharex)


def cumulative_roll(trajectory: WholeBodyTrajectory) -> np.ndarray:
    """Roll turned about the body x axis at every knot (``sum omega_x dt``; ``N + 1`` values)."""
    nq = trajectory.xs.shape[1] - trajectory.us.shape[1] - 6
    return np.concatenate([[0.0], np.cumsum(trajectory.xs[:-1, nq + 3]) * trajectory.dt])


def _shade_phases(axis, trajectory: WholeBodyTrajectory, label: bool = False) -> None:
    colors = {"FT": "#fde2c8", "FS": "#dbe9f6"}
    for index, code in enumerate(trajectory.phase_contacts):
        start, end = trajectory.switching_times[index], trajectory.switching_times[index + 1]
        axis.axvspan(start, end, color=colors.get(code, "#e2f0d9"), alpha=0.6, lw=0)
        if label:
            axis.text(
                0.5 * (start + end),
                1.01,
                f"{trajectory.phase_names[index]}\n{code}",
                transform=axis.get_xaxis_transform(),
                ha="center",
                va="bottom",
                fontsize=7,
            )


def _keyframe_times(task: TrajOptTask) -> np.ndarray:
    return np.asarray(task.switching_times[1:])


def write_plots(
    robot: Robot, task: TrajOptTask, trajectory: WholeBodyTrajectory, out_dir: Path
) -> list[Path]:
    """``roll.png``, ``height.png``, ``lateral_position.png``, ``torques.png``, ``grfs.png``."""
    t, xs, us = trajectory.times, trajectory.xs, trajectory.us
    nq = robot.nq
    knots_t = t[:-1]
    keyframe_t = _keyframe_times(task)
    paths = []

    figure, (top, bottom) = _subplots(2, (8, 5.5), sharex=True)
    _shade_phases(top, trajectory, label=True)
    _shade_phases(bottom, trajectory)
    top.plot(t, cumulative_roll(trajectory), label="roll turned (sum of body omega_x dt)")
    top.plot(keyframe_t, [phase.keyframe.rpy[0] for phase in task.phases], "k^", label="keyframes")
    top.axhline(2 * np.pi, color="gray", ls="--", lw=0.8, label="2 pi")
    top.set_ylabel("roll (rad)")
    top.legend(fontsize=8, loc="lower right")
    bottom.plot(t, xs[:, nq + 3], label="body omega_x")
    bottom.plot(keyframe_t, [phase.keyframe.rpy_rates[0] for phase in task.phases], "k^", label="keyframes")
    bottom.set_ylabel("roll rate (rad/s)")
    bottom.set_xlabel("time (s)")
    bottom.legend(fontsize=8)
    paths.append(_save(figure, out_dir / "roll.png"))

    figure, axis = _subplots(1, (8, 3.5))
    _shade_phases(axis, trajectory, label=True)
    axis.plot(t, xs[:, 2], label="base height")
    axis.plot(keyframe_t, [phase.keyframe.position[2] for phase in task.phases], "k^", label="keyframes")
    minimum = [phase.minimum_height for phase in task.phases]
    if any(m is not None for m in minimum):
        for index, value in enumerate(minimum):
            if value is not None:
                axis.hlines(
                    value, task.switching_times[index], task.switching_times[index + 1], colors="r", lw=1
                )
        axis.plot([], [], "r-", lw=1, label="minimum height")
    axis.set_ylabel("z (m)")
    axis.set_xlabel("time (s)")
    axis.legend(fontsize=8)
    paths.append(_save(figure, out_dir / "height.png"))

    figure, axis = _subplots(1, (8, 3.5))
    _shade_phases(axis, trajectory, label=True)
    axis.plot(t, xs[:, 1], label="base y (world)")
    axis.plot(keyframe_t, [phase.keyframe.position[1] for phase in task.phases], "k^", label="keyframes")
    axis.set_ylabel("y (m)")
    axis.set_xlabel("time (s)")
    axis.legend(fontsize=8)
    paths.append(_save(figure, out_dir / "lateral_position.png"))

    limits = np.asarray(task.constraints.torque_limits(robot)).reshape(-1, 3)
    figure, axes = _subplots(4, (8, 8), sharex=True)
    for leg, axis in enumerate(axes):
        _shade_phases(axis, trajectory, label=leg == 0)
        for joint, name in enumerate(("abad", "hip", "knee")):
            axis.step(knots_t, us[:, 3 * leg + joint], where="post", label=name)
        for sign in (-1, 1):
            for joint, limit in enumerate(limits[leg]):
                axis.axhline(sign * limit, color=f"C{joint}", ls="--", lw=0.8)
        axis.set_ylabel(f"{LEG_NAMES[leg]} (Nm)")
    axes[0].legend(fontsize=8, ncol=3, loc="lower left")
    axes[-1].set_xlabel(f"time (s); dashed: each joint's limit, up to +-{limits.max():g} Nm")
    paths.append(_save(figure, out_dir / "torques.png"))

    forces = trajectory.forces
    figure, axes = _subplots(4, (8, 8), sharex=True)
    for leg, axis in enumerate(axes):
        _shade_phases(axis, trajectory, label=leg == 0)
        for component, name in enumerate(("fx", "fy", "fz")):
            axis.step(knots_t, forces[:, leg, component], where="post", label=name)
        axis.set_ylabel(f"{LEG_NAMES[leg]} (N)")
    axes[0].legend(fontsize=8, ncol=3, loc="upper left")
    axes[-1].set_xlabel("time (s); world-frame ground reaction forces of the planning model")
    paths.append(_save(figure, out_dir / "grfs.png"))
    return paths


def _save(figure, path: Path) -> Path:
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    return path


# --------------------------------------------------------------------------------------------------
# Video
# --------------------------------------------------------------------------------------------------


def render_trajectory(
    robot: Robot, trajectory: WholeBodyTrajectory, path: Path, fps: int = 30, slowdown: float = VIDEO_SLOWDOWN
) -> Path:
    """Kinematic replay (no simulation) of the trajectory in the robot's MuJoCo model, viewed from the front,
    ``slowdown`` times slower than real time. Needs off-screen OpenGL (``libosmesa6``; ``MUJOCO_GL=egl``
    selects EGL instead); raises ``RenderUnavailable`` with the reason otherwise."""
    times = trajectory.times
    frame_times = np.arange(times[0], times[-1] + 1e-9, 1.0 / (fps * slowdown))
    indices = np.searchsorted(times, frame_times).clip(0, len(times) - 1)
    indices = np.concatenate([np.zeros(fps // 2, dtype=int), indices, np.full(fps, len(times) - 1)])
    configurations = trajectory.xs[indices, : robot.nq]
    return render_configurations(
        robot, configurations, path, fps, camera=(1.5, -10.0, 180.0), look_at_height=0.25
    )
