"""The state estimate of a run against the plant's truth: the ``estimator`` block of ``metrics.json`` and
``estimator.png``.

The log holds the truth (``q``, ``v``) and, with ``estimator: kinematic_kf``, the estimate the controller
used at every tick (``extra["estimate_q"]``, ``extra["estimate_v"]``, ``extra["estimated_contacts"]``;
``estimation.controller.SensingController.trace``). Errors are taken in the world frame: base linear
velocity ``R v`` (each with its own orientation), base height, and the angle of ``R_est' R_true``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.report.figures import save_figure, subplots
from cafe_mpc_lab.report.metrics import METRICS_WINDOW_START_S, roll_pitch_yaw
from cafe_mpc_lab.sim.loop import SimulationLog

ERROR_KEYS = (
    "velocity_rms_error_m_s",
    "velocity_error_max_m_s",
    "height_rms_error_m",
    "orientation_rms_error_rad",
)


def world_velocity(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """World-frame base linear velocity (N x 3) of planning states (base-frame ``v[:, :3]``)."""
    if len(q) == 0:
        return np.zeros((0, 3))
    return Rotation.from_quat(q[:, 3:7]).apply(v[:, :3])


def orientation_errors(q_estimate: np.ndarray, q_true: np.ndarray) -> np.ndarray:
    """Angle (rad) of the rotation between estimated and true base orientations, per row."""
    if len(q_true) == 0:
        return np.zeros(0)
    relative = Rotation.from_quat(q_estimate[:, 3:7]).inv() * Rotation.from_quat(q_true[:, 3:7])
    return np.linalg.norm(relative.as_rotvec(), axis=1)


def _errors(q_true, v_true, q_estimate, v_estimate, contacts_true, contacts_estimate) -> dict:
    velocity = world_velocity(q_estimate, v_estimate) - world_velocity(q_true, v_true)
    speed = np.linalg.norm(velocity, axis=1)
    height = q_estimate[:, 2] - q_true[:, 2]
    angle = orientation_errors(q_estimate, q_true)

    def rms(values: np.ndarray) -> float:
        return float(np.sqrt(np.mean(values**2)))

    return {
        "velocity_rms_error_m_s": rms(speed),
        "velocity_error_max_m_s": float(np.max(speed)),
        "velocity_rms_error_xyz_m_s": [rms(velocity[:, axis]) for axis in range(3)],
        "height_rms_error_m": rms(height),
        "height_error_max_m": float(np.max(np.abs(height))),
        "orientation_rms_error_rad": rms(angle),
        "orientation_error_max_rad": float(np.max(angle)),
        "position_xy_error_final_m": float(np.linalg.norm(q_estimate[-1, :2] - q_true[-1, :2])),
        "contact_agreement": float(np.mean(contacts_true == contacts_estimate)),
    }


def estimator_metrics(kind: str, log: SimulationLog) -> dict:
    """The ``estimator`` block: ``kind`` and the estimate's errors against the truth over the whole run and
    over the steady-state window (from ``METRICS_WINDOW_START_S``); errors are None for ``ground_truth``
    (the controller got the plant's state, perturbed only by ``plant.sensor_noise``)."""
    block: dict = {"kind": kind}
    q_estimate = log.extra.get("estimate_q")
    if kind == "ground_truth" or q_estimate is None or log.ticks == 0:
        block.update(dict.fromkeys(ERROR_KEYS))
        return block
    n = min(log.ticks, len(q_estimate))
    arrays = (
        log.q[:n],
        log.v[:n],
        q_estimate[:n],
        log.extra["estimate_v"][:n],
        log.contacts[:n],
        log.extra["estimated_contacts"][:n],
    )
    block.update(_errors(*arrays))
    steady = log.time[:n] >= METRICS_WINDOW_START_S
    block["steady_state"] = _errors(*(array[steady] for array in arrays)) if np.any(steady) else None
    if "sensors" in log.extra:
        block["sensors"] = log.extra["sensors"]
    return block


def plot_estimate(robot: Robot, log: SimulationLog, path: Path) -> Path:
    """Estimate (solid) vs truth (dashed): world-frame base velocity, base height and x-y position, roll,
    pitch and yaw; the estimated contacts as strips at the bottom of the height panel."""
    n = min(log.ticks, len(log.extra["estimate_q"]))
    t = log.time[:n]
    q_true, v_true = log.q[:n], log.v[:n]
    q_estimate, v_estimate = log.extra["estimate_q"][:n], log.extra["estimate_v"][:n]
    velocity_true, velocity_estimate = world_velocity(q_true, v_true), world_velocity(q_estimate, v_estimate)
    angles_true, angles_estimate = roll_pitch_yaw(q_true[:, 3:7]), roll_pitch_yaw(q_estimate[:, 3:7])
    figure, axes = subplots(3, 3, figsize=(13, 7.5), sharex=True)
    for axis_index, name in enumerate("xyz"):
        axis = axes[0, axis_index]
        axis.plot(t, velocity_estimate[:, axis_index], lw=0.8, label="estimate")
        axis.plot(t, velocity_true[:, axis_index], "k--", lw=0.8, label="truth")
        axis.set_ylabel(f"v{name} world [m/s]")
    for axis_index, name in enumerate("xyz"):
        axis = axes[1, axis_index]
        axis.plot(t, q_estimate[:, axis_index], lw=0.8, label="estimate")
        axis.plot(t, q_true[:, axis_index], "k--", lw=0.8, label="truth")
        axis.set_ylabel(f"{name} [m]")
    contacts = log.extra.get("estimated_contacts")
    if contacts is not None:
        axis = axes[1, 2]
        for leg in range(robot.n_feet):
            axis.fill_between(
                t,
                0.02 * leg,
                0.02 * leg + 0.015,
                where=contacts[:n, leg],
                transform=axis.get_xaxis_transform(),
                color=f"C{leg + 2}",
                lw=0,
                label=f"{robot.leg_names[leg]} used" if leg == 0 else None,
            )
    for axis_index, name in enumerate(("roll", "pitch", "yaw")):
        axis = axes[2, axis_index]
        axis.plot(t, angles_estimate[:, axis_index], lw=0.8, label="estimate")
        axis.plot(t, angles_true[:, axis_index], "k--", lw=0.8, label="truth")
        axis.set_ylabel(f"{name} [rad]")
        axis.set_xlabel("time [s]")
    axes[0, 0].legend(loc="best", fontsize=8)
    errors = _errors(
        q_true, v_true, q_estimate, v_estimate, log.contacts[:n], log.extra["estimated_contacts"][:n]
    )
    figure.suptitle(
        "state estimate vs truth: velocity RMS error "
        f"{errors['velocity_rms_error_m_s']:.3f} m/s, height {errors['height_rms_error_m'] * 1e3:.1f} mm, "
        f"orientation {errors['orientation_rms_error_rad']:.4f} rad",
        fontsize=10,
    )
    return save_figure(figure, path)
