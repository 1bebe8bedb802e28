"""Metrics of acrobatic tasks (the in-place barrel roll of paper Sec. VII-C, Fig. 1): the ``task`` block.

A task run follows a reference that contains a stored trajectory (``reference.trajectory``), possibly
inside a composition (``reference.composition``). ``task_from_reference`` reads the planned windows off
it: when the trajectory starts, its first flight phase (take-off and touchdown) and its end. The metrics
are then judged on the logged closed loop alone:

* ``roll_turned_rad``: the body roll rate ``omega_x`` (base frame) integrated over the run (rectangle rule at
  the control period); it counts full turns, which no Euler angle or quaternion read-out does;
* ``max_base_height_m``;
* landing: the measured touchdown is the first tick, after all four feet were off the ground for at least
  ``MIN_FLIGHT_S`` inside the planned flight window, at which a foot touches the floor. ``landed``: all four
  feet are on the floor at some tick within ``LANDING_WINDOW_S`` after the touchdown, the run did not fall,
  and neither the trunk nor a knee or thigh touched the floor during the run. The plant's legs do not
  collide with the floor (only the feet and the trunk do), so body and knee contact is judged geometrically
  from the logged states (``body_floor_clearance``: the lowest point of the trunk box, of each thigh capsule
  and of each knee, i.e. the upper end of the shank capsule, must stay above ``CONTACT_TOLERANCE_M``;
  negative means it went through the floor);
* ``upright_after``: the base tilt (angle between body z and world z) stays below ``UPRIGHT_TILT_RAD`` at
  every tick of the ``UPRIGHT_WINDOW_S`` after the landing, the first tick with all four feet down (the
  first foot lands while the body still rolls; ``tilt_at_touchdown_rad`` reports that moment);
* ``stayed_up_s``: time from the touchdown to the end of the run without a fall; ``stayed_up`` needs
  ``STAY_UP_S``;
* during the roll (from the trajectory's start to its end): ticks whose commanded torque exceeds the motor
  limits (what the plant saturates at), ticks whose request before clamping exceeds the plan limits (the
  Riccati controller clamps), and friction-cone violations (the contact forces that the commanded torque
  implies with the plan's stance feet held, ``friction_cone_violations_post_hoc``);
* running tasks (a gait segment before and after the trajectory in the composition, e.g. the running barrel
  roll): ``speed_before_roll_mps``, the mean forward speed (heading frame) over the ``SPEED_WINDOW_S`` before
  the trajectory starts, and ``speed_after_roll_mps``, the mean over the last ``SPEED_WINDOW_S`` of the run;
  ``pace_resumed``: the latter is at least ``RESUME_FRACTION`` of the final gait's commanded speed (0.6 m/s
  for 0.8 m/s);
* a bar in the scene (``sim.bar``): ``bar_contact``, any robot geom touched it during the run (the plant's
  contacts; legs included), which geoms, and ``bar_clearance_min_m``, the smallest distance between the bar
  and the robot's geoms over the roll from the logged states (geometric; negative: penetration);
* ``feet_on_planned_surface``: for a trajectory that ends on a raised surface (a box top), at its end (the
  last tick before it) every foot the reference has in stance is within ``FOOT_SURFACE_TOLERANCE_M`` of its
  planned height (one ending on the floor is left to ``landed``: unjudged);
  ``foot_height_error_m`` and ``foot_position_error_m`` (horizontal, reported, not judged) give the largest
  differences from the planned footholds;
* ``success``: roll turned >= target - ``ROLL_TOLERANCE_RAD``, landed, upright after, stayed up, feet on the
  planned surface, no
  torque-limit violation at the motors during the roll, and, where they apply, no bar contact and the pace
  resumed. A criterion that the run ended too early to judge (it stopped, without a fall, before the
  touchdown, before the upright window or the stay-up time had passed, or before the last speed window after
  the roll) is ``null``, with its reason in ``unjudged``; ``success`` is then ``false`` if another criterion
  failed (``failed_criteria``), else ``null`` with ``success_reason`` saying what could not be judged.

The block states these thresholds in ``criteria`` so that a reader of ``metrics.json`` sees how success was
judged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from cafe_mpc.planners.resolved import ContactModel
from cafe_mpc.reference.base import Reference, ReferenceWindow
from cafe_mpc.reference.composition import ComposedReference
from cafe_mpc.reference.trajectory import TrajectoryReference
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.sim.bar import Bar, bar_clearance
from cafe_mpc_lab.sim.loop import SimulationLog, base_tilt

ROLL_TOLERANCE_RAD = 0.3
UPRIGHT_TILT_RAD = 0.3
UPRIGHT_WINDOW_S = 1.0
STAY_UP_S = 2.0
LANDING_WINDOW_S = 0.3
MIN_FLIGHT_S = 0.02
CONTACT_TOLERANCE_M = 0.002
FLIGHT_SEARCH_MARGIN_S = 0.1
"""The measured flight is searched in the planned flight window widened by this much on each side."""
SPEED_WINDOW_S = 1.0
RESUME_FRACTION = 0.75
FOOT_SURFACE_TOLERANCE_M = 0.02
"""m; a stance foot at the trajectory's end is on its planned surface when its height is this close to the
plan's (a 0.10 m box top and the floor differ by five times as much)."""
"""The gait after the roll has resumed when the last second's mean speed reaches this share of its command."""


@dataclass(frozen=True)
class AcrobaticTask:
    """The planned windows of a task (reference time, s) and its roll target (rad)."""

    name: str
    start: float
    takeoff: float
    touchdown: float
    end: float
    roll_target: float = 2.0 * math.pi
    approach_speed: float | None = None
    """Commanded forward speed of the gait segment before the trajectory (None: no gait before it)."""
    resume_speed: float | None = None
    """Commanded forward speed of the gait segment after the trajectory (None: no moving gait after it)."""
    rotation_axis: int = 0
    """The body axis the task turns about (0 x: roll, 1 y: pitch, 2 z: yaw); ``roll_target`` is the rotation
    to reach about it (signed: a backflip turns -2 pi about y)."""
    planned_feet: tuple[tuple[float, float, float], ...] | None = None
    """World foot positions the reference plans at the trajectory's end (its last interval)."""
    planned_stance: tuple[bool, ...] | None = None
    """Which feet the reference has in stance there (the feet ``feet_on_planned_surface`` judges)."""
    clock_advance: float = 0.0
    """Seconds early touchdowns (``touchdown_events``) had advanced the trajectory's clock when the task was
    read: its times above are the advanced ones, so the composed plan had the trajectory start this much
    later than ``start``."""


def _trajectory_segment(reference: Reference) -> tuple[TrajectoryReference, float] | None:
    """The first stored-trajectory reference inside ``reference`` and the time its segment starts."""
    if isinstance(reference, TrajectoryReference):
        return reference, 0.0
    if isinstance(reference, ComposedReference):
        for segment in reference.segments:
            found = _trajectory_segment(segment.reference)
            if found is not None:
                return found[0], segment.start + found[1]
    return None


def _gait_speeds(reference: Reference, trajectory: TrajectoryReference) -> tuple[float | None, float | None]:
    """Commanded forward speeds of the moving gait segments (locomotion references that are not a stand)
    right before and right after the trajectory in a composition (``None`` where there is none)."""
    from cafe_mpc.reference.locomotion import LocomotionReference

    if not isinstance(reference, ComposedReference):
        return None, None
    pieces = [segment.reference for segment in reference.segments]
    index = next((i for i, piece in enumerate(pieces) if piece is trajectory), None)
    if index is None:
        return None, None

    def speed(piece: Reference) -> float | None:
        if not isinstance(piece, LocomotionReference) or piece.gait.name == "stand":
            return None
        return float(piece.commands[-1].vx)

    before = speed(pieces[index - 1]) if index > 0 else None
    after = speed(pieces[index + 1]) if index + 1 < len(pieces) else None
    return before, after


ROTATION_AXES = ("roll", "pitch", "yaw")


def planned_rotation(trajectory) -> tuple[int, float]:
    """The body axis a stored trajectory turns most about and its turn there rounded to a quarter turn
    (``sum omega dt`` over its knots: 2 pi for a barrel roll, -2 pi for a backflip, pi for a half spin)."""
    nq = trajectory.xs.shape[1] - trajectory.us.shape[1] - 6
    turned = np.sum(trajectory.xs[:-1, nq + 3 : nq + 6], axis=0) * trajectory.dt
    axis = int(np.argmax(np.abs(turned)))
    quarter = 0.5 * math.pi
    return axis, round(float(turned[axis]) / quarter) * quarter


def task_from_reference(
    reference: Reference | None, roll_target: float | None = None
) -> AcrobaticTask | None:
    """The task of a reference that contains a stored trajectory with a flight phase (``None`` otherwise);
    its rotation axis and target from the trajectory (``planned_rotation``) unless ``roll_target`` is given
    (a rotation about the body x axis)."""
    found = _trajectory_segment(reference) if reference is not None else None
    if found is None:
        return None
    trajectory_reference, offset = found
    approach, resume = _gait_speeds(reference, trajectory_reference)
    trajectory = trajectory_reference.trajectory
    axis, target = planned_rotation(trajectory) if roll_target is None else (0, roll_target)
    start = offset + trajectory_reference.start
    origin = float(trajectory.times[0])
    end = start + trajectory_reference.duration
    feet, stance = _planned_feet(reference, trajectory_reference, end - 0.5 * trajectory_reference.dt)
    codes = list(trajectory.phase_contacts)
    for index, code in enumerate(codes):
        if code == "FT":
            last = index  # a flight may be several phases (a box jump's tuck, then its landing legs)
            while last + 1 < len(codes) and codes[last + 1] == "FT":
                last += 1
            takeoff = start + float(trajectory.switching_times[index]) - origin
            touchdown = start + float(trajectory.switching_times[last + 1]) - origin
            return AcrobaticTask(
                trajectory.name,
                start,
                takeoff,
                touchdown,
                start + trajectory_reference.duration,
                target,
                approach,
                resume,
                axis,
                feet,
                stance,
                trajectory_reference.advance_total,
            )
    return None


def _planned_feet(
    reference: Reference, trajectory: TrajectoryReference, time: float
) -> tuple[tuple[tuple[float, float, float], ...], tuple[bool, ...]]:
    """World foot positions and stance flags ``reference`` plans at ``time`` (the whole reference: a
    composition places its trajectory in the world)."""
    robot = trajectory.robot
    window = ReferenceWindow(1, robot.nq, robot.nv, robot.nu, robot.n_feet)
    window.set_times(np.array([time]))
    reference.sample(window)
    feet = tuple(tuple(float(x) for x in foot) for foot in window.foot_positions[0])
    return feet, tuple(bool(flag) for flag in window.stance[0])


def _feet_on_plan(
    robot: Robot, log: SimulationLog, task: AcrobaticTask, control_period: float, unjudged: dict[str, str]
) -> tuple[bool | None, float | None, float | None]:
    """(feet on the planned surface, largest height error, largest horizontal error) of the stance feet at
    the last tick before the trajectory's end; ``None`` (with the reason in ``unjudged``) when the run ended
    before it."""
    if task.planned_feet is None or task.planned_stance is None or not any(task.planned_stance):
        return None, None, None
    planned = np.asarray(task.planned_feet)
    stance = np.asarray(task.planned_stance, dtype=bool)
    if not np.any(planned[stance, 2] - robot.foot_radius > FOOT_SURFACE_TOLERANCE_M):
        # on the floor: ``landed`` judges it (a running flip's feet, a trot already under way at the
        # trajectory's end, stood 2.2 cm off their planned height); null, not a reason to withhold success
        return None, None, None
    ticks = np.flatnonzero(log.time <= task.end + 1e-9)
    if not log.ticks or float(log.time[-1]) + control_period < task.end - 1e-9 or not len(ticks):
        if not log.fell:
            unjudged["feet_on_planned_surface"] = "the run ended before the trajectory's end"
        return (False if log.fell else None), None, None
    measured = robot.foot_positions(log.q[ticks[-1]])
    height = float(np.max(np.abs(measured[stance, 2] - planned[stance, 2])))
    horizontal = float(np.max(np.linalg.norm(measured[stance, :2] - planned[stance, :2], axis=1)))
    return height <= FOOT_SURFACE_TOLERANCE_M, height, horizontal


# --------------------------------------------------------------------------------------------------
# Geometry: body and knee clearance above the floor
# --------------------------------------------------------------------------------------------------


def body_floor_clearance(robot: Robot, q: np.ndarray) -> dict[str, np.ndarray]:
    """Lowest height (m) above the floor of the trunk, the thighs and the knees at each row of ``q``
    (planning coordinates), from the plant's own geometry (``Robot.mjcf``). Keys ``trunk``, ``thigh``,
    ``knee`` (the minimum over the legs).

    A model with the generated robots' geometry (a ``trunk`` box, thigh and shank capsules on the
    ``*_hip_body`` and ``*_knee_body`` bodies) is measured on those shapes, the knee at the shank capsule's
    upper end. Any other model file (e.g. a Go2's): the trunk and the thighs are the collision geoms of the
    free joint's body and of each hip-pitch joint's body (lowest corner of each geom's bounding box), the
    knee is the knee joint's anchor; a part with no collision geom is left out."""
    model = mujoco.MjModel.from_xml_string(robot.mjcf)
    data = mujoco.MjData(model)
    leg_geoms = {"thigh": [], "knee": []}
    for index in range(model.ngeom):
        body_name = model.body(int(model.geom_bodyid[index])).name
        if model.geom_type[index] != mujoco.mjtGeom.mjGEOM_CAPSULE:
            continue
        if body_name.endswith("_hip_body"):
            leg_geoms["thigh"].append(index)
        elif body_name.endswith("_knee_body"):
            leg_geoms["knee"].append(index)
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "trunk") < 0 or not all(leg_geoms.values()):
        return _model_file_clearance(model, data, q)
    trunk = model.geom("trunk").id
    out = {name: np.full(len(q), np.inf) for name in ("trunk", "thigh", "knee")}
    half = model.geom_size[trunk]
    for row, configuration in enumerate(np.asarray(q, dtype=float)):
        _set_configuration(data, configuration)
        mujoco.mj_kinematics(model, data)
        rotation = data.geom_xmat[trunk].reshape(3, 3)
        out["trunk"][row] = data.geom_xpos[trunk][2] - float(np.abs(rotation[2]) @ half)
        for name, geoms in leg_geoms.items():
            for geom in geoms:
                radius, half_length = model.geom_size[geom][0], model.geom_size[geom][1]
                centre = data.geom_xpos[geom]
                axis_z = data.geom_xmat[geom].reshape(3, 3)[2, 2]
                ends = (centre[2] + half_length * axis_z, centre[2] - half_length * axis_z)
                # the knee is the shank capsule's upper end (the joint with the thigh)
                z = min(ends) if name == "thigh" else _shank_top(model, data, geom, half_length)
                out[name][row] = min(out[name][row], z - radius)
    return out


def _set_configuration(data: mujoco.MjData, configuration: np.ndarray) -> None:
    """Planning configuration (base quaternion x, y, z, w) into MuJoCo's ``qpos`` (w, x, y, z)."""
    data.qpos[:3] = configuration[:3]
    data.qpos[3] = configuration[6]
    data.qpos[4:7] = configuration[3:6]
    data.qpos[7:] = configuration[7:]


def _model_file_clearance(model: mujoco.MjModel, data: mujoco.MjData, q: np.ndarray) -> dict[str, np.ndarray]:
    """``body_floor_clearance`` of a model file without the generated geometry (see there). Leg joints follow
    the free joint three per leg (abad, hip pitch, knee), as in every robot of the package."""
    collides = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
    root_body = int(model.jnt_bodyid[0])
    leg_joints = np.arange(1, model.njnt)
    hip_bodies = {int(model.jnt_bodyid[joint]) for joint in leg_joints[1::3]}
    knee_joints = leg_joints[2::3]
    parts = {
        "trunk": np.flatnonzero(collides & (model.geom_bodyid == root_body)),
        "thigh": np.flatnonzero(collides & np.isin(model.geom_bodyid, list(hip_bodies))),
    }
    out = {name: np.full(len(q), np.inf) for name, geoms in parts.items() if len(geoms)}
    out["knee"] = np.full(len(q), np.inf)
    for row, configuration in enumerate(np.asarray(q, dtype=float)):
        _set_configuration(data, configuration)
        mujoco.mj_kinematics(model, data)
        for name, geoms in parts.items():
            for geom in geoms:
                rotation = data.geom_xmat[geom].reshape(3, 3)
                centre, half = model.geom_aabb[geom, :3], model.geom_aabb[geom, 3:]
                lowest = (data.geom_xpos[geom] + rotation @ centre)[2] - float(np.abs(rotation[2]) @ half)
                out[name][row] = min(out[name][row], lowest)
        out["knee"][row] = float(np.min(data.xanchor[knee_joints, 2]))
    return out


def _shank_top(model: mujoco.MjModel, data: mujoco.MjData, geom: int, half_length: float) -> float:
    """Height of the end of a shank capsule nearer to its body's origin (the knee joint)."""
    centre = data.geom_xpos[geom]
    axis = data.geom_xmat[geom].reshape(3, 3)[:, 2]
    origin = data.xpos[int(model.geom_bodyid[geom])]
    ends = (centre + half_length * axis, centre - half_length * axis)
    top = min(ends, key=lambda end: float(np.linalg.norm(end - origin)))
    return float(top[2])


# --------------------------------------------------------------------------------------------------
# The task block
# --------------------------------------------------------------------------------------------------


def measured_touchdown(log: SimulationLog, task: AcrobaticTask, control_period: float) -> float | None:
    """Time of the first foot contact after the measured flight (see the module docstring)."""
    times, contacts = log.time, log.contacts
    window = (times >= task.takeoff - FLIGHT_SEARCH_MARGIN_S) & (
        times <= task.touchdown + FLIGHT_SEARCH_MARGIN_S + LANDING_WINDOW_S
    )
    airborne = ~contacts.any(axis=1)
    needed = max(1, round(MIN_FLIGHT_S / control_period))
    run = 0
    for tick in np.flatnonzero(window):
        if airborne[tick]:
            run += 1
        elif run >= needed:
            return float(times[tick])
        else:
            run = 0
    return None


@dataclass(frozen=True)
class _Landing:
    """How the run came down after the flight (see the module docstring; ``None``: no measured touchdown)."""

    touchdown: float | None
    all_feet_time: float | None
    landed: bool
    upright: bool
    tilt_max_window: float | None
    roll_at_touchdown: float | None
    """Body rate about the task's rotation axis integrated up to the touchdown (rad)."""
    stayed_up_s: float
    stayed_up: bool


def _landing(
    log: SimulationLog,
    task: AcrobaticTask,
    control_period: float,
    tilt: np.ndarray,
    body_contact: bool,
) -> _Landing:
    """The measured touchdown, the landing on all four feet, the tilt after it and the time the robot
    stayed up."""
    times = log.time
    touchdown = measured_touchdown(log, task, control_period)
    landed, upright, all_feet_time, tilt_max_window = False, False, None, None
    roll_at_touchdown, stayed_up_s = None, 0.0
    if touchdown is not None:
        after = times >= touchdown - 1e-9
        landing = after & (times <= touchdown + LANDING_WINDOW_S)
        all_down = np.flatnonzero(landing & log.contacts.all(axis=1))
        if len(all_down):
            all_feet_time = float(times[all_down[0]])
        landed = all_feet_time is not None and not body_contact and not log.fell
        before = times < touchdown - 1e-9
        roll_at_touchdown = float(np.sum(log.v[before, 3 + task.rotation_axis]) * control_period)
        end = float(times[-1]) + control_period
        stayed_up_s = (log.fall_time if log.fell else end) - touchdown
        landing = all_feet_time if all_feet_time is not None else touchdown
        window = (times >= landing - 1e-9) & (times < landing + UPRIGHT_WINDOW_S - 1e-9)
        if window.any():
            tilt_max_window = float(np.max(tilt[window]))
        upright = (
            tilt_max_window is not None
            and tilt_max_window < UPRIGHT_TILT_RAD
            and end >= landing + UPRIGHT_WINDOW_S - 1e-9
            and not log.fell
        )
    stayed_up = touchdown is not None and stayed_up_s >= STAY_UP_S - 1e-9 and not log.fell
    return _Landing(
        touchdown,
        all_feet_time,
        landed,
        upright,
        tilt_max_window,
        roll_at_touchdown,
        stayed_up_s,
        stayed_up,
    )


def _unjudged_landing(
    log: SimulationLog, task: AcrobaticTask, landing: _Landing, end_of_run: float
) -> dict[str, str]:
    """Why the landing criteria cannot be judged when the run stopped early without a fall (empty: they
    can)."""
    unjudged: dict[str, str] = {}
    if log.fell:  # a run that stopped early (no fall) may not have reached a criterion's window
        return unjudged
    touchdown = landing.touchdown
    if touchdown is None and end_of_run < task.touchdown + FLIGHT_SEARCH_MARGIN_S:
        reason = f"the run ended at {end_of_run:.2f} s, before the planned touchdown ({task.touchdown:.2f} s)"
        unjudged.update(landed=reason, upright_after=reason, stayed_up=reason)
    elif touchdown is not None:
        landing_time = landing.all_feet_time if landing.all_feet_time is not None else touchdown
        tilt_ok_so_far = landing.tilt_max_window is None or landing.tilt_max_window < UPRIGHT_TILT_RAD
        if not landing.upright and tilt_ok_so_far and end_of_run < landing_time + UPRIGHT_WINDOW_S - 1e-9:
            unjudged["upright_after"] = (
                f"the run ended {end_of_run - landing_time:.2f} s after the landing; needs "
                f"{UPRIGHT_WINDOW_S} s"
            )
        if not landing.stayed_up:
            unjudged["stayed_up"] = (
                f"the run ended {landing.stayed_up_s:.2f} s after the touchdown; needs {STAY_UP_S} s"
            )
    return unjudged


def _roll_violations(
    robot: Robot,
    log: SimulationLog,
    roll: np.ndarray,
    requested: np.ndarray | None,
    planned_stance: np.ndarray | None,
    contact: ContactModel | None,
    limits: np.ndarray | None,
) -> tuple[int, int | None, dict | None]:
    """Over the ticks ``roll``: ticks above the motor limits, requests above the enforced limits (``None``
    without ``requested``), and the post-hoc friction-cone violations (``None`` without such ticks)."""
    from cafe_mpc_lab.report.metrics import friction_cone_violations_post_hoc

    motor_limits = robot.plant.motor_torque_limits
    motor_violations = int(np.sum(np.any(np.abs(log.torque_command[roll]) > motor_limits + 1e-9, axis=1)))
    request_violations = None
    if requested is not None:
        request = np.nan_to_num(np.asarray(requested)[roll], nan=0.0)
        enforced = robot.torque_limits if limits is None else np.asarray(limits, dtype=float)
        request_violations = int(np.sum(np.any(np.abs(request) > enforced + 1e-9, axis=1)))
    cone = None
    if log.ticks and roll.any():
        stance = log.contacts if planned_stance is None else np.asarray(planned_stance, dtype=bool)
        ticks = np.flatnonzero(roll)
        cone = friction_cone_violations_post_hoc(robot, _rows(log, ticks), stance[ticks], contact)
    return motor_violations, request_violations, cone


def _speeds_around_roll(
    log: SimulationLog, task: AcrobaticTask, unjudged: dict[str, str]
) -> tuple[float | None, float | None, bool | None]:
    """Mean forward speed before the trajectory and over the run's last ``SPEED_WINDOW_S``, and whether the
    gait after the roll resumed its pace (``None``: no moving gait after it, or not judged: then the reason
    is added to ``unjudged``)."""
    times = log.time
    speeds = forward_speed(log.q, log.v)
    end_time = float(times[-1]) if log.ticks else 0.0
    before = (times >= task.start - SPEED_WINDOW_S - 1e-9) & (times < task.start - 1e-9)
    last = times > end_time - SPEED_WINDOW_S + 1e-9
    speed_before = float(np.mean(speeds[before])) if before.any() else None
    speed_after = float(np.mean(speeds[last])) if last.any() else None
    pace_resumed = None
    if task.resume_speed is not None and not log.fell and end_time < task.end + SPEED_WINDOW_S:
        unjudged["pace_resumed"] = (
            f"the run ended {max(end_time - task.end, 0.0):.2f} s after the roll; needs {SPEED_WINDOW_S} s"
        )
    elif task.resume_speed is not None:
        pace_resumed = bool(
            speed_after is not None
            and end_time >= task.end + SPEED_WINDOW_S
            and abs(speed_after) >= RESUME_FRACTION * abs(task.resume_speed)
            and speed_after * task.resume_speed > 0
        )
    return speed_before, speed_after, pace_resumed


def _criteria(task: AcrobaticTask) -> dict[str, str]:
    """How each criterion is judged, in words with the thresholds (the block's ``criteria``)."""
    rotation = (
        f"integral of the body roll rate over the run >= {task.roll_target:.4f} - {ROLL_TOLERANCE_RAD} rad"
        if task.rotation_axis == 0 and task.roll_target >= 0
        else f"integral of the body {ROTATION_AXES[task.rotation_axis]} rate over the run, signed as the "
        f"target {task.roll_target:.4f} rad (roll_target_rad, about rotation_axis), >= |target| - "
        f"{ROLL_TOLERANCE_RAD} rad"
    )
    return {
        "roll_turned": rotation,
        "touchdown": f"first foot contact after >= {MIN_FLIGHT_S} s with all feet off the floor, within "
        f"{FLIGHT_SEARCH_MARGIN_S} s of the planned flight",
        "landed": f"all four feet on the floor within {LANDING_WINDOW_S} s of the touchdown; no fall; "
        f"trunk, thighs and knees never below {CONTACT_TOLERANCE_M} m (geometric: the plant's legs do "
        "not collide)",
        "upright_after": f"base tilt < {UPRIGHT_TILT_RAD} rad at every tick of the {UPRIGHT_WINDOW_S} s "
        "after the landing (the first tick with all four feet down; the touchdown if they never are)",
        "stayed_up": f"no fall for >= {STAY_UP_S} s after the touchdown",
        "violations": "during the roll (trajectory start to end): commanded torque above the motor "
        "limits; request before clamping above the limits the controller enforces; friction cone of "
        "the forces the commanded torque implies with the plan's stance feet held",
        "speeds": f"mean forward speed (heading frame) over the {SPEED_WINDOW_S} s before the trajectory "
        f"starts and over the last {SPEED_WINDOW_S} s of the run",
        "pace_resumed": f"a moving gait segment follows the trajectory: last {SPEED_WINDOW_S} s mean "
        f"forward speed >= {RESUME_FRACTION} x its command (null: no such segment)",
        "bar_contact": "a bar in the scene: any robot geom (trunk, legs, feet) in contact with it at any "
        "tick of the run (null: no bar); bar_clearance_min_m: smallest bar-to-robot distance over the "
        "roll (trajectory start - 0.3 s to its end), from the logged states",
        "feet_on_planned_surface": "a trajectory ending on a raised surface (a box top): every foot the "
        "reference has in stance at its end (the last tick before it) within "
        f"{FOOT_SURFACE_TOLERANCE_M} m of its planned height (null: it ends on the floor, landed judges it); "
        "foot_position_error_m: the largest horizontal distance to the planned foothold (not judged)",
        "success": "roll_turned and landed and upright_after and stayed_up and feet_on_planned_surface and "
        "no motor torque-limit "
        "violation during the roll; with a bar, no bar contact; with a gait after the roll, "
        "pace_resumed; null when a criterion could not be judged (the run ended too early: unjudged) "
        "and none failed",
    }


def task_metrics(
    robot: Robot,
    log: SimulationLog,
    task: AcrobaticTask,
    control_period: float,
    requested: np.ndarray | None = None,
    planned_stance: np.ndarray | None = None,
    contact: ContactModel | None = None,
    limits: np.ndarray | None = None,
    bar: Bar | None = None,
) -> dict:
    """The ``task`` block of ``metrics.json`` (see the module docstring). ``requested``: the low-level
    controller's torques before clamping (ticks, nu), ``planned_stance``: the plan knot's stance per tick,
    ``limits``: the torque limits the controller enforces (default: the robot table's plan limits);
    ``contact``: the contact model the controller assumed (the friction-cone score; default the reference
    robot's); ``bar``: the scene's bar (its contacts are the log's ``extra["bar_contact"]``)."""
    times = log.time
    roll_turned = float(np.sum(log.v[:, 3]) * control_period) if log.ticks else 0.0
    axis = task.rotation_axis
    turned = float(np.sum(log.v[:, 3 + axis]) * control_period) if log.ticks else 0.0
    clearance = body_floor_clearance(robot, log.q) if log.ticks else {}
    lowest = {name: float(np.min(values)) for name, values in clearance.items()}
    body_contact = any(value < CONTACT_TOLERANCE_M for value in lowest.values())
    tilt = np.array([base_tilt(q) for q in log.q])
    landing = _landing(log, task, control_period, tilt, body_contact)
    touchdown = landing.touchdown
    end_of_run = (float(times[-1]) + control_period) if log.ticks else 0.0
    unjudged = _unjudged_landing(log, task, landing, end_of_run)
    roll = (times >= task.start - 1e-9) & (times <= task.end + 1e-9)
    motor_violations, request_violations, cone = _roll_violations(
        robot, log, roll, requested, planned_stance, contact, limits
    )
    direction = 1.0 if task.roll_target >= 0 else -1.0
    roll_ok = direction * turned >= abs(task.roll_target) - ROLL_TOLERANCE_RAD
    if not roll_ok and not log.fell and end_of_run < task.end - 1e-9:
        unjudged["roll_turned"] = (
            f"the run ended at {end_of_run:.2f} s, before the roll's end ({task.end:.2f} s)"
        )
    speed_before, speed_after, pace_resumed = _speeds_around_roll(log, task, unjudged)
    bar_block = bar_metrics(robot, log, task, bar)
    feet_on_plan, foot_height_error, foot_position_error = _feet_on_plan(
        robot, log, task, control_period, unjudged
    )
    verdicts = {
        "roll_turned": roll_ok,
        "landed": landing.landed,
        "upright_after": landing.upright,
        "stayed_up": landing.stayed_up,
        "motor_torque_limits": motor_violations == 0,
        "bar_contact": bar_block.get("bar_contact") is not True,
        "pace_resumed": pace_resumed is not False,
        "feet_on_planned_surface": feet_on_plan is not False,
    }
    failed = [name for name, ok in verdicts.items() if not ok and name not in unjudged]
    success: bool | None = False if failed else (None if unjudged else True)
    reason = None
    if success is None:
        reason = "cannot judge: " + "; ".join(f"{name}: {why}" for name, why in unjudged.items())
    return {
        "name": task.name,
        "success": success,
        "success_reason": reason,
        "failed_criteria": failed,
        "unjudged": unjudged,
        "roll_turned_rad": roll_turned,
        "roll_target_rad": task.roll_target,
        "rotation_axis": ROTATION_AXES[axis],
        "rotation_turned_rad": turned,
        "roll_turned_at_touchdown_rad": landing.roll_at_touchdown,
        "max_base_height_m": float(np.max(log.q[:, 2])) if log.ticks else None,
        "landed": None if "landed" in unjudged else bool(landing.landed),
        "upright_after": None if "upright_after" in unjudged else bool(landing.upright),
        "stayed_up": None if "stayed_up" in unjudged else bool(landing.stayed_up),
        "stayed_up_s": float(landing.stayed_up_s),
        "planned_start_s": task.start,
        "clock_advance_s": task.clock_advance,
        "planned_takeoff_s": task.takeoff,
        "planned_touchdown_s": task.touchdown,
        "touchdown_s": touchdown,
        "all_feet_down_s": landing.all_feet_time,
        "tilt_max_first_second_after_landing_rad": landing.tilt_max_window,
        "tilt_at_touchdown_rad": float(tilt[times >= touchdown - 1e-9][0]) if touchdown is not None else None,
        "tilt_final_rad": float(tilt[-1]) if len(tilt) else None,
        "lowest_trunk_m": lowest.get("trunk"),
        "lowest_thigh_m": lowest.get("thigh"),
        "lowest_knee_m": lowest.get("knee"),
        "roll_motor_torque_limit_violations": motor_violations,
        "roll_requested_torque_limit_violations": request_violations,
        "roll_friction_cone_violations": cone,
        "approach_speed_command_mps": task.approach_speed,
        "resume_speed_command_mps": task.resume_speed,
        "speed_before_roll_mps": speed_before,
        "speed_after_roll_mps": speed_after,
        "pace_resumed": pace_resumed,
        "feet_on_planned_surface": feet_on_plan,
        "foot_height_error_m": foot_height_error,
        "foot_position_error_m": foot_position_error,
        **bar_block,
        "criteria": _criteria(task),
    }


def forward_speed(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Base forward speed in the heading frame (m/s) at each row: the world-frame linear velocity projected
    on the heading (``reference.composition.heading``, which a roll does not flip)."""
    from cafe_mpc.reference.composition import heading

    out = np.zeros(len(q))
    for row, (configuration, velocity) in enumerate(zip(q, v, strict=True)):
        x, y, z, w = configuration[3:7]
        rotation = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
        world = rotation @ velocity[:3]
        angle = heading(configuration[3:7])
        out[row] = math.cos(angle) * world[0] + math.sin(angle) * world[1]
    return out


BAR_WINDOW_BEFORE_S = 0.3
"""The bar clearance is measured from this long before the trajectory starts to its end."""


def bar_metrics(robot: Robot, log: SimulationLog, task: AcrobaticTask, bar: Bar | None) -> dict:
    """The bar entries of the task block (empty without a bar): contact from the plant, clearance from the
    logged states over the roll."""
    if bar is None:
        return {"bar_contact": None}
    contact = log.extra.get("bar_contact")
    touched = np.asarray(contact, dtype=bool)[: log.ticks] if contact is not None else np.zeros(0, bool)
    block: dict = {
        "bar_contact": bool(touched.any()),
        "bar_contact_ticks": int(touched.sum()),
        "bar_first_contact_s": float(log.time[np.argmax(touched)]) if touched.any() else None,
        "bar_touched_by": list(log.extra.get("bar", {}).get("touched_by", [])),
        "bar_height_m": bar.height,
        "bar_position_m": [float(bar.position[0]), float(bar.position[1])],
        "bar_yaw_rad": bar.yaw,
        "bar_radius_m": bar.radius,
    }
    window = (log.time >= task.start - BAR_WINDOW_BEFORE_S - 1e-9) & (log.time <= task.end + 1e-9)
    clearance, closest, when = None, None, None
    if window.any():
        distances, names = bar_clearance(robot.mjcf, bar, log.q[window])
        row = int(np.argmin(distances))
        clearance, closest, when = float(distances[row]), names[row], float(log.time[window][row])
    block.update(
        {"bar_clearance_min_m": clearance, "bar_clearance_geom": closest, "bar_clearance_time_s": when}
    )
    return block


def _rows(log: SimulationLog, ticks: np.ndarray) -> SimulationLog:
    """The log restricted to ``ticks`` (for the post-hoc scorers)."""
    return SimulationLog(
        log.time[ticks],
        log.q[ticks],
        log.v[ticks],
        log.torque_command[ticks],
        log.torque_applied[ticks],
        log.foot_forces[ticks],
        log.contacts[ticks],
        log.external_force[ticks],
        len(ticks),
    )


def reference_trace(
    reference: Reference, times: np.ndarray, nq: int, nv: int, nu: int, n_feet: int
) -> np.ndarray:
    """The reference configuration ``q`` (len(times), nq) at ``times`` (for plots; references that re-anchor
    on the measurement are sampled at their last anchor)."""
    out = np.zeros((len(times), nq))
    chunk = 256
    window = ReferenceWindow(chunk, nq, nv, nu, n_feet)
    for begin in range(0, len(times), chunk):
        part = times[begin : begin + chunk]
        window.set_times(part)
        reference.sample(window)
        out[begin : begin + len(part)] = window.state[:, :nq]
    return out


def task_summary(task: dict) -> str:
    """One line for the end of a run: ``task: success=True (roll 6.28 rad, apex 0.55 m, ...)``, naming the
    failed criteria, or why the run cannot be judged (``success=None``)."""
    axis = task.get("rotation_axis", "roll")
    turned = task["roll_turned_rad"] if axis == "roll" else task.get("rotation_turned_rad")
    parts = [f"{axis} {turned:.2f} rad"]
    if task.get("max_base_height_m") is not None:
        parts.append(f"apex {task['max_base_height_m']:.2f} m")
    if task.get("touchdown_s") is not None:
        parts.append(f"touchdown {task['touchdown_s']:.2f} s")
    if task.get("tilt_max_first_second_after_landing_rad") is not None:
        parts.append(f"tilt after landing {task['tilt_max_first_second_after_landing_rad']:.2f} rad")
    parts.append(f"{task.get('roll_motor_torque_limit_violations', 0)} ticks over the motor limits")
    if task.get("bar_contact") is not None:
        parts.append("bar touched" if task["bar_contact"] else "bar clear")
    if task.get("resume_speed_command_mps") is not None and task.get("speed_after_roll_mps") is not None:
        parts.append(f"speed after {task['speed_after_roll_mps']:.2f} m/s")
    line = f"task {task.get('name', '')}: success={task['success']} ({', '.join(parts)})"
    if task.get("failed_criteria"):
        line += f"; failed: {', '.join(task['failed_criteria'])}"
    if task.get("success") is None and task.get("success_reason"):
        line += f"; {task['success_reason']}"
    elif task.get("unjudged"):
        line += f"; not judged: {', '.join(task['unjudged'])}"
    return line
