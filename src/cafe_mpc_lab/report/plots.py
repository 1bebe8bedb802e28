"""Plots of a run (PNG): base height, orientation, velocities, joint torques with limits, contact forces,
and (with the commands / MPC statistics given) commanded vs actual velocities, foot heights over the
contact schedule, MPC solve times, and hip and knee torques with their limits (paper Fig. 9 style)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from cafe_mpc.config import VelocityCommand
from cafe_mpc.core.progress import stage
from cafe_mpc.reference.locomotion import CommandProfile
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.report.figures import save_figure, subplots
from cafe_mpc_lab.report.metrics import (
    METRICS_WINDOW_START_S,
    body_rates,
    commanded_at,
    foot_trajectories,
    roll_pitch_yaw,
)
from cafe_mpc_lab.sim.loop import SimulationLog

if TYPE_CHECKING:
    from cafe_mpc.planners.base import MpcStatistics

JOINT_KINDS = ("abad", "hip", "knee")


def _save(figure: Figure, path: Path) -> Path:
    return save_figure(figure, path)


def _mark_pushes(axis: Axes, log: SimulationLog) -> None:
    pushing = np.linalg.norm(log.external_force, axis=1) > 0
    if pushing.any():
        axis.fill_between(
            log.time,
            0,
            1,
            where=pushing,
            transform=axis.get_xaxis_transform(),
            color="orange",
            alpha=0.3,
            label="push",
        )


def plot_run(
    robot: Robot,
    log: SimulationLog,
    out_dir: Path,
    commands: Sequence[VelocityCommand] | CommandProfile | None = None,
    mpc_statistics: MpcStatistics | None = None,
    mpc_period: float | None = None,
) -> list[Path]:
    """Write the plots of a run into ``out_dir``; returns the files written.

    Always: ``base_height``, ``orientation``, ``velocities``, ``joint_torques``, ``contact_forces``,
    ``foot_heights`` and ``hip_knee_torques``. With ``commands``: ``velocity_tracking``. With
    ``mpc_statistics`` (a CAFE-MPC run): ``mpc_solve_times``.
    """
    stage("writing plots")
    out_dir = Path(out_dir)
    t = log.time
    written = []

    figure, axis = subplots(figsize=(8, 3))
    axis.plot(t, log.q[:, 2], label="base height")
    axis.axhline(robot.standing_height, color="k", ls="--", lw=0.8, label="standing height")
    _mark_pushes(axis, log)
    axis.set_xlabel("time [s]")
    axis.set_ylabel("height [m]")
    axis.legend(loc="best")
    written.append(_save(figure, out_dir / "base_height.png"))

    angles = roll_pitch_yaw(log.q[:, 3:7])
    figure, axis = subplots(figsize=(8, 3))
    for i, label in enumerate(("roll", "pitch", "yaw")):
        axis.plot(t, angles[:, i], label=label)
    _mark_pushes(axis, log)
    axis.set_xlabel("time [s]")
    axis.set_ylabel("angle [rad]")
    axis.legend(loc="best")
    written.append(_save(figure, out_dir / "orientation.png"))

    figure, axes = subplots(2, 1, figsize=(8, 5), sharex=True)
    for i, label in enumerate(("vx", "vy", "vz")):
        axes[0].plot(t, log.v[:, i], label=f"{label} (base frame)")
    for i, label in enumerate(("wx", "wy", "wz")):
        axes[1].plot(t, log.v[:, 3 + i], label=label)
    axes[0].set_ylabel("linear [m/s]")
    axes[1].set_ylabel("angular [rad/s]")
    axes[1].set_xlabel("time [s]")
    for axis in axes:
        _mark_pushes(axis, log)
        axis.legend(loc="best", fontsize=8)
    written.append(_save(figure, out_dir / "velocities.png"))

    n_legs, n_kinds = robot.n_feet, len(JOINT_KINDS)
    figure, axes = subplots(n_legs, n_kinds, figsize=(11, 2 * n_legs), sharex=True, squeeze=False)
    for leg_index, leg in enumerate(robot.leg_names):
        for kind_index, kind in enumerate(JOINT_KINDS):
            j = n_kinds * leg_index + kind_index
            axis = axes[leg_index, kind_index]
            axis.plot(t, log.torque_command[:, j], lw=0.8, label="commanded")
            axis.plot(t, log.torque_applied[:, j], lw=0.8, ls="--", label="applied")
            for limit, style in ((robot.torque_limits[j], "r--"), (robot.plant.motor_torque_limits[j], "k:")):
                axis.plot([t[0], t[-1]], [limit, limit], style, lw=0.8)
                axis.plot([t[0], t[-1]], [-limit, -limit], style, lw=0.8)
            axis.set_title(f"{leg} {kind}", fontsize=9)
            if kind_index == 0:
                axis.set_ylabel("torque [Nm]")
    axes[0, 0].legend(fontsize=7)
    for axis in axes[-1]:
        axis.set_xlabel("time [s]")
    figure.suptitle("joint torques (red: plan limit, black: motor limit)", fontsize=10)
    written.append(_save(figure, out_dir / "joint_torques.png"))

    figure, axes = subplots(robot.n_feet, 1, figsize=(8, 1.75 * robot.n_feet), sharex=True, squeeze=False)
    axes = axes[:, 0]
    for leg_index, leg in enumerate(robot.leg_names):
        axis = axes[leg_index]
        for i, label in enumerate(("fx", "fy", "fz")):
            axis.plot(t, log.foot_forces[:, leg_index, i], lw=0.8, label=label)
        axis.set_ylabel(f"{leg} [N]")
        axis.fill_between(
            t,
            0,
            1,
            where=log.contacts[:, leg_index],
            transform=axis.get_xaxis_transform(),
            color="grey",
            alpha=0.15,
        )
    axes[0].legend(loc="upper right", fontsize=7)
    axes[-1].set_xlabel("time [s]")
    figure.suptitle("ground reaction forces (world frame; grey: contact)", fontsize=10)
    written.append(_save(figure, out_dir / "contact_forces.png"))

    if commands is not None:
        written.append(plot_velocity_tracking(robot, log, commands, out_dir / "velocity_tracking.png"))
    written.append(plot_foot_heights(robot, log, out_dir / "foot_heights.png"))
    written.append(plot_hip_knee_torques(robot, log, out_dir / "hip_knee_torques.png"))
    if mpc_statistics is not None and mpc_statistics.solve_times:
        written.append(plot_mpc_solve_times(mpc_statistics, mpc_period, out_dir / "mpc_solve_times.png"))
    return written


def _shade(axis: Axes, t: np.ndarray, where: np.ndarray, color: str, alpha: float, label: str) -> None:
    axis.fill_between(
        t,
        0,
        1,
        where=where,
        transform=axis.get_xaxis_transform(),
        color=color,
        alpha=alpha,
        lw=0,
        label=label,
    )


def plot_velocity_tracking(
    robot: Robot, log: SimulationLog, commands: Sequence[VelocityCommand] | CommandProfile, path: Path
) -> Path:
    """Commanded (dashed) vs actual heading-frame vx, vy and yaw rate; the metrics window starts at the
    dotted line."""
    t = log.time
    heading, yaw_rate, _ = body_rates(log.q, log.v)
    commanded = commanded_at(t, commands, robot.standing_height)
    figure, axes = subplots(3, 1, figsize=(8, 6), sharex=True)
    actual = (heading[:, 0], heading[:, 1], yaw_rate)
    for axis, values, column, label in zip(
        axes, actual, range(3), ("vx [m/s]", "vy [m/s]", "yaw rate [rad/s]"), strict=True
    ):
        axis.plot(t, values, lw=0.8, label="actual")
        axis.step(t, commanded[:, column], "k--", lw=1.0, where="post", label="commanded")
        if len(t) and t[-1] > METRICS_WINDOW_START_S:
            axis.axvline(METRICS_WINDOW_START_S, color="grey", ls=":", lw=0.8, label="metrics window")
        low = min(np.min(values, initial=0.0), np.min(commanded[:, column], initial=0.0))
        high = max(np.max(values, initial=0.0), np.max(commanded[:, column], initial=0.0))
        if high - low < 0.1:  # do not magnify numerical noise about a zero command
            middle = 0.5 * (high + low)
            axis.set_ylim(middle - 0.1, middle + 0.1)
        _mark_pushes(axis, log)
        axis.set_ylabel(label)
    axes[0].legend(loc="best", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    figure.suptitle("velocity tracking (heading frame)", fontsize=10)
    return _save(figure, path)


def plot_foot_heights(robot: Robot, log: SimulationLog, path: Path) -> Path:
    """Foot heights above the floor, the gait's contact schedule shaded (grey; the plant's measured
    contact as the black strip at the bottom). Without a gait (PD) the measured contact is shaded."""
    t = log.time
    heights = foot_trajectories(robot, log.q)[:, :, 2] - robot.foot_radius
    schedule = log.extra.get("gait_stance")
    figure, axes = subplots(robot.n_feet, 1, figsize=(8, 1.75 * robot.n_feet), sharex=True, squeeze=False)
    axes = axes[:, 0]
    for leg_index, leg in enumerate(robot.leg_names):
        axis = axes[leg_index]
        axis.plot(t, heights[:, leg_index], lw=0.8, label="foot height")
        shaded = log.contacts[:, leg_index] if schedule is None else schedule[:, leg_index]
        _shade(axis, t, shaded, "grey", 0.2, "planned stance" if schedule is not None else "contact")
        if schedule is not None:
            axis.fill_between(
                t,
                0,
                0.06,
                where=log.contacts[:, leg_index],
                transform=axis.get_xaxis_transform(),
                color="k",
                lw=0,
                label="measured contact",
            )
        axis.set_ylabel(f"{leg} [m]")
    axes[0].legend(loc="upper right", fontsize=7)
    axes[-1].set_xlabel("time [s]")
    figure.suptitle("foot heights above the floor", fontsize=10)
    return _save(figure, path)


def plot_hip_knee_torques(robot: Robot, log: SimulationLog, path: Path) -> Path:
    """Hip and knee torques of the front-right and hind-right legs with their limits (paper Fig. 9).

    Solid: the command sent to the plant; faint: what the low-level controller requested before clamping
    (the Riccati controller's unclamped Eq. (33) torque), when the run recorded it.
    """
    t = log.time
    requested = log.extra.get("torque_requested")
    legs = [robot.leg_names.index(name) for name in ("FR", "HR") if name in robot.leg_names] or [1, 3]
    figure, axes = subplots(len(legs), 2, figsize=(10, 3 * len(legs)), sharex=True, squeeze=False)
    for row, leg_index in enumerate(legs):
        for column, kind_index in enumerate((1, 2)):
            j = 3 * leg_index + kind_index
            axis = axes[row, column]
            if requested is not None and np.any(np.isfinite(requested[:, j])):
                axis.plot(t, requested[:, j], color="tab:orange", lw=0.8, alpha=0.6, label="requested")
            axis.plot(t, log.torque_command[:, j], color="tab:blue", lw=0.8, label="commanded")
            for limit, style, label in (
                (robot.torque_limits[j], "r--", "plan limit"),
                (robot.plant.motor_torque_limits[j], "k:", "motor limit"),
            ):
                axis.axhline(limit, color=style[0], ls=style[1:], lw=0.8, label=label)
                axis.axhline(-limit, color=style[0], ls=style[1:], lw=0.8)
            _mark_pushes(axis, log)
            axis.set_title(f"{robot.leg_names[leg_index]} {JOINT_KINDS[kind_index]}", fontsize=9)
            axis.set_ylabel("torque [Nm]")
    axes[0, 0].legend(loc="best", fontsize=7)
    for axis in axes[-1]:
        axis.set_xlabel("time [s]")
    figure.suptitle("hip and knee torques with limits (paper Fig. 9)", fontsize=10)
    return _save(figure, path)


def plot_mpc_solve_times(statistics: MpcStatistics, period: float | None, path: Path) -> Path:
    """Wall-clock time and iterations of every MPC solve after the first, with the MPC period (the real-time
    budget). The first (cold) solve runs to convergence before the clock starts and is left out, as from
    ``metrics.json``'s medians and p99 (its time is in the title and ``mpc.first_solve_ms``)."""
    solve_ms = 1e3 * np.asarray(statistics.solve_times)
    iterations = np.asarray(statistics.iterations)
    cold = len(solve_ms) > 1
    if cold:
        solve_ms, iterations = solve_ms[1:], iterations[1:]
    index = np.arange(1, len(solve_ms) + 1) if cold else np.arange(len(solve_ms))
    figure, axes = subplots(2, 1, figsize=(8, 5), sharex=True)
    axes[0].plot(index, solve_ms, ".", ms=3, label="solve")
    axes[0].axhline(float(np.median(solve_ms)), color="k", lw=0.8, label="median")
    axes[0].axhline(float(np.percentile(solve_ms, 99)), color="k", ls="--", lw=0.8, label="p99")
    if period is not None:
        axes[0].axhline(1e3 * period, color="r", ls=":", lw=1.0, label="MPC period")
    axes[0].set_ylabel("solve time [ms]")
    axes[0].legend(loc="best", fontsize=7)
    axes[1].plot(index[: len(iterations)], iterations[: len(index)], ".", ms=3)
    axes[1].set_ylabel("iterations")
    axes[1].set_xlabel("MPC solve (successful solves, in order)")
    title = "MPC solves"
    if cold and statistics.first_solve_time is not None:
        cold_ms = 1e3 * statistics.first_solve_time
        title += f" (not shown: the first, cold solve, {cold_ms:.0f} ms, before the clock)"
    figure.suptitle(title, fontsize=10)
    return _save(figure, path)
