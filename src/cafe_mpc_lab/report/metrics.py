"""Metrics of a run, written to ``metrics.json``: fall and timing, command tracking, the low-level
controller's torque limits, friction cone and foot slip (the MPC block comes from ``MpcStatistics``)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

from cafe_mpc.config import VelocityCommand
from cafe_mpc.planners.resolved import ContactModel
from cafe_mpc.reference.locomotion import CommandProfile
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.sim.loop import SimulationLog


def roll_pitch_yaw(quaternions_xyzw: np.ndarray) -> np.ndarray:
    """Unwrapped (roll, pitch, yaw) of base quaternions (N x 4, x y z w), for plots and metrics only."""
    if len(quaternions_xyzw) == 0:
        return np.zeros((0, 3))
    angles = Rotation.from_quat(quaternions_xyzw).as_euler("ZYX")[:, ::-1]
    return np.unwrap(angles, axis=0)


def base_metrics(robot: Robot, log: SimulationLog, control_period: float) -> dict:
    """The metrics every run reports: fall, timing, base height, torque use."""
    sim_time = float(log.ticks * control_period)
    heights = log.q[:, 2]
    angles = roll_pitch_yaw(log.q[:, 3:7])
    limits = robot.torque_limits
    over_limit = np.any(np.abs(log.torque_command) > limits + 1e-9, axis=1)
    return {
        "fell": bool(log.fell),
        "fall_time_s": log.fall_time,
        "fall_reason": log.fall_reason,
        "sim_time_s": sim_time,
        "wall_time_s": float(log.wall_time),
        "real_time_factor": float(sim_time / log.wall_time) if log.wall_time > 0 else None,
        "control_ticks": int(log.ticks),
        "base_height_mean": float(np.mean(heights)) if len(heights) else None,
        "base_height_min": float(np.min(heights)) if len(heights) else None,
        "base_height_max": float(np.max(heights)) if len(heights) else None,
        "roll_abs_max_rad": float(np.max(np.abs(angles[:, 0]))) if len(angles) else None,
        "pitch_abs_max_rad": float(np.max(np.abs(angles[:, 1]))) if len(angles) else None,
        "base_displacement_xy_m": (log.q[-1, :2] - log.q[0, :2]).tolist() if log.ticks else None,
        "torque_abs_max_nm": float(np.max(np.abs(log.torque_command))) if log.ticks else None,
        "torque_limit_ticks": int(np.sum(over_limit)),
    }


METRICS_WINDOW_START_S = 0.5
"""Start of the steady-state window (``steady_state`` block of ``metrics.json``): every run starts from rest
in the standing pose, and the first gait cycles (the robot accelerating to the command) are a transient that
the paper's steady-state tracking numbers (Fig. 6, 8) do not include. The top-level tracking metrics cover
the whole run."""


def body_rates(q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Heading-frame linear velocity (N x 2: forward, left), yaw rate and pitch rate (ZYX Euler rates).

    ``q``, ``v`` are planning coordinates (base-frame velocities). The heading frame is the world frame
    turned by the base yaw, the frame the commands are given in.
    """
    if len(q) == 0:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    rotations = Rotation.from_quat(q[:, 3:7])
    world_velocity = rotations.apply(v[:, :3])
    angles = roll_pitch_yaw(q[:, 3:7])
    roll, pitch, yaw = angles[:, 0], angles[:, 1], angles[:, 2]
    cos_yaw, sin_yaw = np.cos(yaw), np.sin(yaw)
    heading = np.stack(
        [
            cos_yaw * world_velocity[:, 0] + sin_yaw * world_velocity[:, 1],
            -sin_yaw * world_velocity[:, 0] + cos_yaw * world_velocity[:, 1],
        ],
        axis=1,
    )
    wy, wz = v[:, 4], v[:, 5]
    yaw_rate = (np.sin(roll) * wy + np.cos(roll) * wz) / np.cos(pitch)
    pitch_rate = np.cos(roll) * wy - np.sin(roll) * wz
    return heading, yaw_rate, pitch_rate


def commanded_at(
    times: np.ndarray,
    commands: Sequence[VelocityCommand] | CommandProfile,
    standing_height: float,
) -> np.ndarray:
    """Commanded ``[vx, vy, yaw_rate, height]`` at each time (N x 4): a ``CommandProfile`` (ramps included,
    as the reference follows it), or for a list of commands the latest one started by then (the first one
    before its start: steps, as ``LocomotionReference`` without a ramp)."""
    if isinstance(commands, CommandProfile):
        return commands.table(np.asarray(times))
    ordered = sorted(commands, key=lambda command: command.start) or [VelocityCommand()]
    starts = np.array([command.start for command in ordered])
    table = np.array(
        [[c.vx, c.vy, c.yaw_rate, standing_height if c.height is None else c.height] for c in ordered]
    )
    index = np.clip(np.searchsorted(starts, np.asarray(times) + 1e-12, side="right") - 1, 0, len(ordered) - 1)
    return table[index]


def _abs_max(values: np.ndarray) -> float | None:
    return float(np.max(np.abs(values))) if len(values) else None


def _rms(values: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else None


def tracking_metrics(
    robot: Robot,
    log: SimulationLog,
    reference_commands: Sequence[VelocityCommand] | CommandProfile,
    window_start: float = 0.0,
) -> dict:
    """Velocity, height and pitch tracking (the paper's Fig. 6 and Fig. 8 quantities).

    At every control tick from ``window_start`` on (0: the whole run; ``METRICS_WINDOW_START_S`` for the
    steady state; if the log ends before it, every tick counts and ``metrics_window_start_s`` is 0):

    * ``vx_mean``: mean forward speed in the heading frame;
    * ``vx_rms_error``, ``vy_rms_error``, ``yaw_rate_rms_error``: heading-frame velocities and the yaw
      rate (Euler rate) against the command at that tick (``commanded_at``: ramped with a profile);
    * ``vy_error_abs_max``, ``yaw_rate_error_abs_max``: the largest sideways speed and yaw rate off the
      command (the start-up lurch);
    * ``height_rms_error``: base height against the commanded height (standing height when unset);
    * ``pitch_rms``, ``pitch_rate_rms``: against the reference's zero pitch.

    A run that fell is measured up to the fall (the log ends there).
    """
    mask = log.time >= window_start - 1e-9
    start = window_start
    if not mask.any():
        mask = np.ones(log.ticks, dtype=bool)
        start = 0.0
    q, v, times = log.q[mask], log.v[mask], log.time[mask]
    heading, yaw_rate, pitch_rate = body_rates(q, v)
    commanded = commanded_at(times, reference_commands, robot.standing_height)
    pitch = roll_pitch_yaw(q[:, 3:7])[:, 1] if len(q) else np.zeros(0)
    return {
        "metrics_window_start_s": float(start),
        "vx_mean": float(np.mean(heading[:, 0])) if len(heading) else None,
        "vx_rms_error": _rms(heading[:, 0] - commanded[:, 0]),
        "vy_rms_error": _rms(heading[:, 1] - commanded[:, 1]),
        "yaw_rate_rms_error": _rms(yaw_rate - commanded[:, 2]),
        "vy_error_abs_max": _abs_max(heading[:, 1] - commanded[:, 1]),
        "yaw_rate_error_abs_max": _abs_max(yaw_rate - commanded[:, 2]),
        "height_rms_error": _rms(q[:, 2] - commanded[:, 3]),
        "pitch_rms": _rms(pitch),
        "pitch_rate_rms": _rms(pitch_rate),
    }


def foot_trajectories(robot: Robot, q: np.ndarray) -> np.ndarray:
    """World positions of the feet (planning foot points, i.e. sphere centres) at every row of ``q``
    (N x 4 x 3)."""
    data = robot.model.createData()
    positions = np.zeros((len(q), len(robot.foot_frame_ids), 3))
    for row, configuration in enumerate(q):
        pin.framesForwardKinematics(robot.model, data, configuration)
        for foot, frame_id in enumerate(robot.foot_frame_ids):
            positions[row, foot] = data.oMf[frame_id].translation
    return positions


def foot_slip_max(feet: np.ndarray, contacts: np.ndarray) -> float:
    """Largest horizontal distance a foot moved from where it touched down while it stayed in contact.

    ``feet``: N x 4 x 3 positions (``foot_trajectories``), ``contacts``: N x 4 plant contact flags. Each
    unbroken run of contact ticks of a foot is one stance; its slide is the largest horizontal distance
    from the foot's position at the first tick of that run. Foot points are sphere centres, so a foot
    rolling by an angle ``a`` adds ``radius * a`` (about 2 mm for 0.1 rad on the Mini Cheetah).
    """
    worst = 0.0
    contacts = np.asarray(contacts, dtype=bool)
    for foot in range(contacts.shape[1] if contacts.ndim == 2 else 0):
        flags = contacts[:, foot]
        edges = np.flatnonzero(np.diff(np.concatenate([[False], flags, [False]]).astype(int)))
        for begin, end in zip(edges[::2], edges[1::2], strict=True):
            slide = np.linalg.norm(feet[begin:end, foot, :2] - feet[begin, foot, :2], axis=1)
            worst = max(worst, float(np.max(slide)))
    return worst


def friction_cone_violations_post_hoc(
    robot: Robot, log: SimulationLog, stance: np.ndarray, contact: ContactModel | None = None
) -> int:
    """Ticks whose commanded torque implies a stance force outside the friction pyramid.

    The forces are those the contact dynamics (34b)-(34c) give for the logged torque with the feet in
    ``stance`` (N x 4) held (``FrictionConeScorer``), i.e. the VWBC's own check applied to any controller,
    with the run's contact model (``contact``: friction, Baumgarte rate, tolerance; default the reference
    robot's). Ticks without a stance foot are not scored.
    """
    from cafe_mpc.low_level.contact_dynamics import FrictionConeScorer

    contact = contact or ContactModel()
    scorer = FrictionConeScorer(robot, contact.friction, contact.baumgarte_alpha, contact.cone_tolerance)
    for tick in range(log.ticks):
        if stance[tick].any() and np.all(np.isfinite(log.torque_command[tick])):
            scorer.score(log.q[tick], log.v[tick], log.torque_command[tick], stance[tick])
    return int(scorer.violations)


def wbc_metrics(
    robot: Robot,
    log: SimulationLog,
    controller: str,
    low_level_statistics: dict | None = None,
    planned_stance: np.ndarray | None = None,
    contact: ContactModel | None = None,
    torque_limits: np.ndarray | None = None,
) -> dict:
    """The low-level controller's block of ``metrics.json``.

    ``low_level_statistics``: the low-level controller's ``statistics()`` (any ``LowLevelController``);
    ``torque_limits`` and ``contact``: what the run's controller was built with (its resolved run).

    * ``torque_limit_violations``: ticks where a commanded torque exceeds its (plan) limit: the controller's
      own count (``torque_limit_violations``, the Riccati controller's unclamped commands over the limit)
      when it keeps one; otherwise counted on the logged command (the VWBC and PD controllers respect the
      limits by construction, so this counts overshoot) against ``torque_limits`` (default: the robot
      table's plan limits; a run with ``torque_limits: motor`` has the motor limits).
    * ``friction_cone_violations``: the controller's own count (the VWBC's), else scored after the run
      (``friction_cone_violations_post_hoc``, ``contact``) with the plan's stance (``planned_stance``) or,
      without a plan (PD), the plant's measured contacts.
    * ``foot_slip_max_m``: ``foot_slip_max`` over the plant's contacts.
    * QP fields (``qp_iterations_histogram``, ``qp_solve_time_ms_median``/``_p99``, ``fallbacks``) from a
      controller that solves QPs (the VWBC); None for the others.
    * ``support_ratio``: the online estimate's record (``calibration.online``), only when it ran.
    """
    statistics = low_level_statistics or {}
    limits = robot.torque_limits if torque_limits is None else np.asarray(torque_limits, dtype=float)
    torque_limit_violations = statistics.get("torque_limit_violations")
    if torque_limit_violations is None:
        torque_limit_violations = int(np.sum(np.any(np.abs(log.torque_command) > limits + 1e-9, axis=1)))
    if "friction_cone_violations" in statistics:
        cone = int(statistics["friction_cone_violations"])
    else:
        stance = log.contacts if planned_stance is None else planned_stance
        cone = friction_cone_violations_post_hoc(robot, log, np.asarray(stance, dtype=bool), contact)
    solves_qps = "qp_iterations_histogram" in statistics
    feet = foot_trajectories(robot, log.q)

    def finite_or_none(value: float | None) -> float | None:
        return float(value) if value is not None and np.isfinite(value) else None

    return {
        "controller": controller,
        "torque_limit_violations": int(torque_limit_violations),
        "friction_cone_violations": cone,
        "foot_slip_max_m": foot_slip_max(feet, log.contacts),
        "qp_iterations_histogram": (
            {str(k): int(n) for k, n in statistics["qp_iterations_histogram"].items()} if solves_qps else None
        ),
        "qp_solve_time_ms_median": finite_or_none(statistics.get("qp_solve_time_ms_median")),
        "qp_solve_time_ms_p99": finite_or_none(statistics.get("qp_solve_time_ms_p99")),
        "fallbacks": int(statistics["fallbacks"]) if solves_qps else None,
        **({"support_ratio": statistics["support_ratio"]} if "support_ratio" in statistics else {}),
    }
