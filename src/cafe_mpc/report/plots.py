"""Plots of a run (PNG): base height, orientation, velocities, joint torques with limits, contact forces."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from cafe_mpc.report.metrics import roll_pitch_yaw
from cafe_mpc.robots.robot import Robot
from cafe_mpc.sim.loop import SimulationLog

JOINT_KINDS = ("abad", "hip", "knee")


def _save(figure: plt.Figure, path: Path) -> Path:
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def _mark_pushes(axis: plt.Axes, log: SimulationLog) -> None:
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


def plot_run(robot: Robot, log: SimulationLog, out_dir: Path) -> list[Path]:
    """Write the standard plots of a run into ``out_dir``; returns the files written."""
    out_dir = Path(out_dir)
    t = log.time
    written = []

    figure, axis = plt.subplots(figsize=(8, 3))
    axis.plot(t, log.q[:, 2], label="base height")
    axis.axhline(robot.standing_height, color="k", ls="--", lw=0.8, label="standing height")
    _mark_pushes(axis, log)
    axis.set_xlabel("time [s]")
    axis.set_ylabel("height [m]")
    axis.legend(loc="best")
    written.append(_save(figure, out_dir / "base_height.png"))

    angles = roll_pitch_yaw(log.q[:, 3:7])
    figure, axis = plt.subplots(figsize=(8, 3))
    for i, label in enumerate(("roll", "pitch", "yaw")):
        axis.plot(t, angles[:, i], label=label)
    _mark_pushes(axis, log)
    axis.set_xlabel("time [s]")
    axis.set_ylabel("angle [rad]")
    axis.legend(loc="best")
    written.append(_save(figure, out_dir / "orientation.png"))

    figure, axes = plt.subplots(2, 1, figsize=(8, 5), sharex=True)
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

    figure, axes = plt.subplots(4, 3, figsize=(11, 8), sharex=True)
    for leg_index, leg in enumerate(robot.leg_names):
        for kind_index, kind in enumerate(JOINT_KINDS):
            j = 3 * leg_index + kind_index
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

    figure, axes = plt.subplots(4, 1, figsize=(8, 7), sharex=True)
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
    return written
