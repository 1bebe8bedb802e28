"""Offline multi-phase whole-body trajectory optimisation with the MS-iLQR (paper Sec. VI-B and Appendix).

A ``TrajOptTask`` (contact sequence with switching times, one keyframe and one weight set per phase,
constraint settings) becomes a ``MultiPhaseProblem`` (Eq. (17)) of whole-body knots (Eqs. (18)-(23)) at
``dt``: one phase per contact phase, the impact map (22), (24) when feet touch down and the identity at
take-off, the touchdown constraint (25) at the end of every phase followed by a touchdown (augmented
Lagrangian), and per phase the relaxed-barrier inequalities (26), (27) and the minimum base height.

Costs (paper Appendix: "the running cost and terminal cost of each phase are simply to track the allocated
keyframes"). The terminal knot of phase ``i`` tracks keyframe ``i``. Its running knots track keyframe ``i``
too, except for the orientation: the base error is ``log3(R_ref' R)``, the shortest rotation, so a
keyframe roll of ``2 pi`` equals the identity and a running cost toward it would pull a body at roll
``pi / 2`` back the short way (the authors' Euler angles keep ``2 pi`` distinct). The running knots therefore
track the roll, pitch and yaw *interpolated in time* between keyframe ``i - 1`` (or the initial state) and
keyframe ``i``, with the rates of that interpolation, so that every knot's target lies on the intended
rotation and well within ``pi`` of the solution. Weights keep their world meaning while rolling
(``base_error="world"``).

Initial guess (multiple shooting accepts its defects, Eq. (4)): the authors' linear interpolation between
keyframes (positions, world velocities, joint angles and rates; orientation through the interpolated roll,
pitch and yaw), static stance torques (weight split over the stance feet, zero in flight); the first knot of
a phase entered through an impact is a roll-out knot (its state is the impact map of the previous phase's
end, paper Fig. 5), because the keyframe's joint rates are far from what the impact leaves.

Solve: with ``warm_up_barriers``, a first MS-iLQR solve with those (soft) barriers, then the final solve
with ``barriers``, warm-started from the first (states, torques and augmented-Lagrangian parameters).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pinocchio as pin

from cafe_mpc.core.contacts import ContactFlags, touchdown_flags
from cafe_mpc.core.interfaces import MultiPhaseProblem, Phase
from cafe_mpc.dynamics.multibody_state import MultibodyState
from cafe_mpc.dynamics.statics import static_stance_torques
from cafe_mpc.ocp.knots import WholeBodyModelFactory, WholeBodyReference, WholeBodySettings
from cafe_mpc.reference.trajectory_file import WholeBodyTrajectory, contact_code
from cafe_mpc.robots.robot import Robot
from cafe_mpc.solver import MSiLQRSolver, SolverResult
from cafe_mpc.trajopt.retarget import is_resolved, resolve_task
from cafe_mpc.trajopt.task import BarrierSetSpec, KeyframeSpec, TrajOptTask, joints12

ROTATION_AXES = ("roll", "pitch", "yaw")
"""Names of the body axes x, y, z as rotations."""

PLANNING_SETTINGS = WholeBodySettings()
"""Dynamics settings of the planning model (Baumgarte alpha 10, explicit Euler, exact KKT, impact on every
post-switch stance foot); ``check_trajectory`` rebuilds the same model."""


# --------------------------------------------------------------------------------------------------
# States from keyframes
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class KeyframeArrays:
    """A keyframe as arrays (joints expanded to 12) for interpolation."""

    position: np.ndarray
    rpy: np.ndarray
    linear_velocity: np.ndarray
    rpy_rates: np.ndarray
    joint_positions: np.ndarray
    joint_velocities: np.ndarray

    @classmethod
    def of(cls, keyframe: KeyframeSpec) -> KeyframeArrays:
        return cls(
            np.asarray(keyframe.position, dtype=float),
            np.asarray(keyframe.rpy, dtype=float),
            np.asarray(keyframe.linear_velocity, dtype=float),
            np.asarray(keyframe.rpy_rates, dtype=float),
            joints12(keyframe.joint_positions),
            joints12(keyframe.joint_velocities),
        )

    def lerp(self, other: KeyframeArrays, s: float) -> KeyframeArrays:
        """``(1 - s) self + s other`` for every part (roll, pitch, yaw included: cumulative angles)."""
        return KeyframeArrays(
            *((1.0 - s) * a + s * b for a, b in zip(self.parts(), other.parts(), strict=True))
        )

    def parts(self) -> tuple[np.ndarray, ...]:
        return (
            self.position,
            self.rpy,
            self.linear_velocity,
            self.rpy_rates,
            self.joint_positions,
            self.joint_velocities,
        )


def whole_body_state(robot: Robot, keyframe: KeyframeArrays) -> np.ndarray:
    """``[q, v]`` of a keyframe: quaternion of ``Rz(yaw) Ry(pitch) Rx(roll)``, base-frame linear velocity
    ``R' v_world`` and body angular velocity from the roll, pitch, yaw rates."""
    nq = robot.nq
    roll, pitch, yaw = keyframe.rpy
    rotation = pin.rpy.rpyToMatrix(roll, pitch, yaw)
    x = np.zeros(nq + robot.nv)
    x[0:3] = keyframe.position
    x[3:7] = pin.Quaternion(rotation).normalized().coeffs()
    x[7:nq] = keyframe.joint_positions
    x[nq : nq + 3] = rotation.T @ keyframe.linear_velocity
    x[nq + 3 : nq + 6] = pin.rpy.computeRpyJacobian(keyframe.rpy, pin.LOCAL) @ keyframe.rpy_rates
    x[nq + 6 :] = keyframe.joint_velocities
    return x


def kinematic_velocities(robot: Robot, xs: np.ndarray, dt: float, keep_first: bool = False) -> None:
    """Set the velocities of the states ``xs`` (in place) to ``(q[k+1] ⊖ q[k]) / dt`` (the explicit Euler step
    of the planning model: no configuration defect), the last state's to its predecessor's; ``keep_first``
    keeps the first state's (the given initial state)."""
    nq = robot.nq
    for k in range(1 if keep_first else 0, len(xs) - 1):
        xs[k, nq:] = pin.difference(robot.model, xs[k, :nq], xs[k + 1, :nq]) / dt
    if len(xs) > 1:
        xs[-1, nq:] = xs[-2, nq:]


def planning_robot(robot: Robot, task: TrajOptTask) -> Robot:
    """The robot with the task's joint speed limit (the knots take joint speed limits from the robot; a task
    without one keeps the robot's)."""
    if task.constraints.joint_speed_limit is None:
        return robot
    return replace(robot, velocity_limits=np.full(robot.nu, task.constraints.joint_speed_limit))


# --------------------------------------------------------------------------------------------------
# Problem construction
# --------------------------------------------------------------------------------------------------


@dataclass
class PhaseLayout:
    """Bookkeeping of one built phase."""

    name: str
    stance: ContactFlags
    start: float
    end: float
    knots: int
    entered_by_touchdown: bool


@dataclass
class TrajOptProblem:
    """The built problem, its initial guess and the layout of its phases."""

    task: TrajOptTask
    robot: Robot
    problem: MultiPhaseProblem
    initial_xs: list[np.ndarray]
    initial_us: list[np.ndarray]
    rollout_knots: list[list[int] | None]
    phases: list[PhaseLayout]

    @property
    def n_knots(self) -> int:
        return sum(phase.knots for phase in self.phases)


def build_problem(robot: Robot, task: TrajOptTask, barriers: BarrierSetSpec | None = None) -> TrajOptProblem:
    """The MS-iLQR problem of ``task`` with ``barriers`` (default: the task's final ``barriers``)."""
    if robot.name != task.robot:
        raise ValueError(f"task {task.name!r} is for robot {task.robot!r}, got {robot.name!r}")
    if not is_resolved(task):
        raise ValueError(f"task {task.name!r}: resolve it for its robot first (retarget.resolve_task)")
    barriers = task.constraints.barriers if barriers is None else barriers
    planning = planning_robot(robot, task)
    dt = task.dt
    x0 = whole_body_state(planning, KeyframeArrays.of(task.initial))
    previous = KeyframeArrays.of(task.initial)
    stances = [phase.stance for phase in task.phases]
    surfaces = task.phase_surface_heights()
    phases, layouts, xs_guess, us_guess, rollout = [], [], [], [], []
    for index, (spec, knots) in enumerate(zip(task.phases, task.knots_per_phase, strict=True)):
        stance = stances[index]
        start, end = task.switching_times[index], task.switching_times[index + 1]
        keyframe = KeyframeArrays.of(spec.keyframe)
        settings = replace(
            PLANNING_SETTINGS,
            dt=dt,
            running_weights=spec.running.weights(),
            terminal_weights=spec.terminal.weights(),
            constraints=task.constraints.settings(
                spec.minimum_height, barriers, planning, spec.minimum_normal_force
            ),
            base_error="world",
        )
        factory = WholeBodyModelFactory(planning, settings)
        rpy_rates = (keyframe.rpy - previous.rpy) / (end - start)
        running, states = [], []
        for k in range(knots + 1):
            s = k / knots
            guess = previous.lerp(keyframe, s)
            states.append(whole_body_state(planning, guess))
            if k < knots:
                target = replace(keyframe, rpy=guess.rpy, rpy_rates=rpy_rates)
                reference = WholeBodyReference(whole_body_state(planning, target))
                running.append(factory.running_knot(stance, reference, dt))
        terminal = factory.terminal_knot(stance, WholeBodyReference(whole_body_state(planning, keyframe)))
        last = index == len(task.phases) - 1
        reset = switching = None
        if not last:
            reset = factory.reset_map(stance, stances[index + 1])
            switching = factory.touchdown_constraint(stance, stances[index + 1], surfaces[index + 1])
        phases.append(Phase(running, terminal, reset, switching, dt=dt, name=spec.name))
        entered_by_touchdown = index > 0 and any(touchdown_flags(stances[index - 1], stance))
        layouts.append(PhaseLayout(spec.name, stance, start, end, knots, entered_by_touchdown))
        xs = np.array(states)
        if index == 0:
            xs[0] = x0
        if task.initial_guess == "kinematic":
            kinematic_velocities(planning, xs, dt, keep_first=index == 0)
        xs_guess.append(xs)
        if task.initial_controls == "static" and any(stance):
            us_guess.append(
                np.array([static_stance_torques(planning, x[: planning.nq], stance) for x in xs[:-1]])
            )
        else:
            us_guess.append(np.zeros((knots, planning.nu)))
        rollout.append([0] if entered_by_touchdown else None)
        previous = keyframe
    return TrajOptProblem(task, planning, MultiPhaseProblem(x0, phases), xs_guess, us_guess, rollout, layouts)


# --------------------------------------------------------------------------------------------------
# Solve
# --------------------------------------------------------------------------------------------------


@dataclass
class StageResult:
    """One MS-iLQR solve of the continuation."""

    barriers: str
    result: SolverResult
    build_time: float


@dataclass
class TrajOptResult:
    """The optimised trajectory, the solves that made it and its checks."""

    task: TrajOptTask
    trajectory: WholeBodyTrajectory
    stages: list[StageResult]
    check: TrajectoryCheck
    wall_time: float
    torque_limits: tuple[float, ...] = ()
    """The per-joint limits the solve used (``ConstraintSpec.torque_limits``), Nm."""

    @property
    def final(self) -> SolverResult:
        return self.stages[-1].result

    @property
    def converged(self) -> bool:
        return self.final.converged

    @property
    def iterations(self) -> int:
        return sum(stage.result.statistics.iterations for stage in self.stages)

    def _max_torque_share(self) -> float | None:
        """The largest ``|tau_j| / limit_j`` over the knots (above 1: the relaxed barrier let a torque past
        its limit), or None without limits."""
        if not self.torque_limits:
            return None
        return float(np.max(np.abs(self.trajectory.us) / np.asarray(self.torque_limits)))

    def summary(self) -> dict:
        """The numbers of ``summary.json`` (issue 11 names plus diagnostics)."""
        final, check = self.final, self.check
        return {
            "task": self.task.name,
            "converged": bool(self.converged),
            "status": final.status.value,
            "roll_at_landing_rad": check.roll_at_landing,
            "landing_time_s": check.landing_time,
            "max_defect": check.max_defect,
            "max_abs_torque": check.max_abs_torque,
            "torque_limit": self.task.constraints.torque_limit,  # null: torque_limit_source's limits
            "torque_limits_nm": list(self.torque_limits),
            "max_torque_share_of_limit": self._max_torque_share(),
            "iterations": self.iterations,
            "wall_time_s": self.wall_time,
            "solver_defect_max": final.defect_max,
            "switching_violation": final.switching_violation,
            "inequality_violation": final.inequality_violation,
            "touchdown_foot_height_max_error_m": check.max_touchdown_height_error,
            "max_joint_speed": check.max_joint_speed,
            "max_driven_joint_speed": check.max_driven_joint_speed,
            "max_post_impact_joint_speed": check.max_post_impact_joint_speed,
            "post_impact_knots": check.post_impact_knots,
            "max_driven_joint_speed_share_of_limit": check.driven_joint_speed_ratio,
            "max_post_impact_joint_speed_share_of_limit": check.post_impact_joint_speed_ratio,
            "joint_speed_limit": self.task.constraints.joint_speed_limit,
            "min_base_height_m": check.min_base_height,
            "min_leg_joint_height_m": check.min_leg_joint_height,
            "total_roll_rad": check.total_roll,
            "rotation_axis": ROTATION_AXES[check.rotation_axis],
            "rotation_at_landing_rad": (
                None
                if check.rotation_at_landing is None
                else float(check.rotation_at_landing[check.rotation_axis])
            ),
            "total_rotation_rad": check.total_rotation.tolist(),
            "cost": final.cost,
            "knots": self.trajectory.n_knots,
            "stages": [
                {
                    "barriers": stage.barriers,
                    "status": stage.result.status.value,
                    "converged": bool(stage.result.converged),
                    "iterations": stage.result.statistics.iterations,
                    "al_iterations": stage.result.statistics.al_iterations,
                    "solve_time_s": stage.result.statistics.solve_time,
                    "build_time_s": stage.build_time,
                    "cost": stage.result.cost,
                    "defect_max": stage.result.defect_max,
                }
                for stage in self.stages
            ],
        }


def solve_task(
    robot: Robot,
    task: TrajOptTask,
    verbose: bool = False,
    echo: Callable[[str], None] | None = None,
) -> TrajOptResult:
    """Build and solve ``task`` (resolved for ``robot`` first: ``trajopt.retarget.resolve_task``; barrier
    continuation, see the module docstring); check the result. The result's task is the resolved one."""
    start = time.perf_counter()
    task = resolve_task(task, robot)
    stages: list[StageResult] = []
    options = task.solver.options(verbose)
    continuation = (
        [("warm_up", task.constraints.warm_up_barriers)] if task.constraints.warm_up_barriers else []
    )
    continuation.append(("final", task.constraints.barriers))
    built = None
    previous: SolverResult | None = None
    for label, barriers in continuation:
        build_start = time.perf_counter()
        built = build_problem(robot, task, barriers)
        build_time = time.perf_counter() - build_start
        solver = MSiLQRSolver(options)
        if previous is None:
            result = solver.solve(built.problem, built.initial_xs, built.initial_us, built.rollout_knots)
        else:
            result = solver.solve(
                built.problem,
                previous.xs,
                previous.us,
                None,
                initial_multipliers=[phase.multiplier for phase in previous.phases],
                initial_penalties=[phase.penalty for phase in previous.phases],
            )
        stages.append(StageResult(label, result, build_time))
        if echo is not None:
            echo(
                f"{label} barriers: {result.status} after {result.statistics.iterations} iterations "
                f"({result.statistics.al_iterations} AL), cost {result.cost:.4g}, "
                f"max defect {result.defect_max:.2e}, touchdown {result.switching_violation:.2e}, "
                f"{result.statistics.solve_time:.2f} s"
            )
        previous = result
    assert built is not None and previous is not None
    trajectory = trajectory_from_solution(built, previous)
    check = check_trajectory(robot, trajectory, task.phase_surface_heights())
    limits = task.constraints.torque_limits(robot)
    return TrajOptResult(task, trajectory, stages, check, time.perf_counter() - start, limits)


def trajectory_from_solution(built: TrajOptProblem, result: SolverResult) -> WholeBodyTrajectory:
    """Flatten the phases onto one knot grid (the pre-impact end state of a phase is dropped: the next
    phase's first state is its impact map) and evaluate the stance forces of every knot."""
    robot, task = built.robot, built.task
    factory = WholeBodyModelFactory(robot, replace(PLANNING_SETTINGS, dt=task.dt))
    xs = [phase.xs[:-1] for phase in result.phases] + [result.phases[-1].xs[-1:]]
    us = np.concatenate([phase.us for phase in result.phases])
    contacts = np.concatenate(
        [np.tile(np.array(layout.stance, dtype=np.uint8), (layout.knots, 1)) for layout in built.phases]
    )
    states = np.concatenate(xs)
    forces = np.zeros((len(us), 4, 3))
    for k in range(len(us)):
        stance = tuple(bool(c) for c in contacts[k])
        if any(stance):
            forces[k] = _stance_forces(factory, stance, task.dt, states[k], us[k])
    n = len(us)
    return WholeBodyTrajectory(
        name=task.name,
        robot=task.robot,
        dt=task.dt,
        times=task.switching_times[0] + task.dt * np.arange(n + 1),
        xs=states,
        us=us,
        contacts=contacts,
        forces=forces,
        phase_contacts=tuple(contact_code(layout.stance) for layout in built.phases),
        switching_times=np.asarray(task.switching_times, dtype=float),
        phase_names=tuple(layout.name for layout in built.phases),
    )


def _stance_forces(
    factory: WholeBodyModelFactory, stance: ContactFlags, dt: float, x: np.ndarray, u: np.ndarray
) -> np.ndarray:
    """World GRFs (4 x 3, zero on swing feet) of the planning dynamics at ``(x, u)``."""
    dynamics = factory.dynamics(stance, dt)
    data = dynamics.create_data()
    dynamics.calc(data, x, u)
    forces = np.zeros((4, 3))
    forces[list(np.flatnonzero(stance))] = np.asarray(data.forces).reshape(-1, 3)
    return forces


# --------------------------------------------------------------------------------------------------
# Checks of a stored trajectory
# --------------------------------------------------------------------------------------------------


@dataclass
class TrajectoryCheck:
    """Dynamic feasibility of a trajectory under the planning model and the barrel-roll numbers.

    ``defects[k]``: max-norm of ``x[k+1] ⊖ f(x[k], u[k])`` (through the impact map where a foot touches
    down); ``touchdown_heights``: ``p_z - foot radius - surface`` of every foot that touches down, at each
    touchdown; ``roll_at_landing``: ``sum omega_x dt`` (body x axis) over the knots before the first
    touchdown; ``total_roll``: the same over the whole trajectory. ``min_leg_joint_height``: the lowest
    world z of any leg joint (abad, hip pitch, knee) over the knots: the planning model has no collision
    with the floor, so an optimum may fold a leg through it (a backflip pivoting on its hind hips);
    negative is not a motion the plant (or a robot) can make.

    Joint speeds: ``max_joint_speed`` over every knot; ``max_driven_joint_speed`` over the knots the motors
    drive, i.e. all but the *post-impact* knots (``post_impact_knots``: the first knot of a phase entered by a
    touchdown, the output of the rigid impact map (22), (24)), whose largest speed is
    ``max_post_impact_joint_speed``. The impact map jumps the joint velocities in zero time: the landing
    back-drives the motors (the torque opposes the motion, the motor brakes), which a motor's speed limit
    (the no-load speed at which its back-EMF leaves no voltage to drive) does not bound; on the plant the
    jump is spread over the contact's compliance. ``joint_speed_ratio``: the largest ``|qd_j| / limit_j``
    over the driven knots (above 1: over the robot's speed limit), ``post_impact_joint_speed_ratio`` the same
    over the post-impact knots (reported, not a limit).
    """

    defects: np.ndarray
    max_defect: float
    max_abs_torque: float
    max_joint_speed: float
    max_driven_joint_speed: float
    max_post_impact_joint_speed: float
    post_impact_knots: list[int]
    driven_joint_speed_ratio: float
    post_impact_joint_speed_ratio: float
    min_base_height: float
    min_leg_joint_height: float
    touchdown_heights: list[tuple[float, np.ndarray]] = field(default_factory=list)
    landing_time: float | None = None
    roll_at_landing: float | None = None
    total_roll: float = 0.0
    rotation_at_landing: np.ndarray | None = None
    total_rotation: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def rotation_axis(self) -> int:
        """The body axis (0 x roll, 1 y pitch, 2 z yaw) the trajectory turns most about."""
        return int(np.argmax(np.abs(self.total_rotation)))

    @property
    def max_touchdown_height_error(self) -> float:
        if not self.touchdown_heights:
            return 0.0
        return float(max(np.max(np.abs(heights)) for _, heights in self.touchdown_heights))


def rotation_turned(trajectory: WholeBodyTrajectory, until: float | None = None) -> np.ndarray:
    """``sum omega dt`` (body x, y, z) over the knots before ``until`` (the whole trajectory by default): the
    rotation turned about each body axis (explicit Euler: ``q+ = q ⊕ v dt``, so this is exact for a rotation
    about one axis)."""
    nq = len(trajectory.xs[0]) - len(trajectory.us[0]) - 6
    last = trajectory.n_knots if until is None else round((until - trajectory.times[0]) / trajectory.dt)
    return np.sum(trajectory.xs[:last, nq + 3 : nq + 6], axis=0) * trajectory.dt


def roll_turned(trajectory: WholeBodyTrajectory, until: float | None = None) -> float:
    """The roll turned about the body x axis before ``until`` (``rotation_turned``)."""
    return float(rotation_turned(trajectory, until)[0])


def min_leg_joint_height(robot: Robot, configurations: np.ndarray) -> float:
    """Lowest world z of any joint below the free flyer (the legs' abad, hip-pitch and knee joints) over the
    rows of ``configurations`` (Pinocchio forward kinematics of the planning model)."""
    model = robot.model
    data = model.createData()
    first_leg_joint = 2  # 0: universe, 1: the free flyer
    lowest = np.inf
    for q in configurations:
        pin.forwardKinematics(model, data, q)
        lowest = min(lowest, min(data.oMi[j].translation[2] for j in range(first_leg_joint, model.njoints)))
    return float(lowest)


def check_trajectory(
    robot: Robot, trajectory: WholeBodyTrajectory, surface_height: float | Sequence[float] = 0.0
) -> TrajectoryCheck:
    """Re-simulate every interval with the planning model (``PLANNING_SETTINGS``) and measure the defects,
    torques, joint speeds, base height, touchdown foot heights (above the surface of the phase touched down
    into: one height, or one per phase) and the rotation."""
    trajectory.validate(robot.nq, robot.nv, robot.nu)
    n_phases = len(trajectory.phase_stances)
    surfaces = np.broadcast_to(np.asarray(surface_height, dtype=float), (n_phases,))
    dt = trajectory.dt
    factory = WholeBodyModelFactory(robot, replace(PLANNING_SETTINGS, dt=dt))
    state = MultibodyState(robot.model)
    stances = trajectory.phase_stances
    knot_ranges = trajectory.phase_knots()
    defects = np.zeros(trajectory.n_knots)
    touchdowns: list[tuple[float, np.ndarray]] = []
    landing_time = None
    post_impact_knots: list[int] = []
    xs, us = trajectory.xs, trajectory.us
    for index, (stance, knots) in enumerate(zip(stances, knot_ranges, strict=True)):
        dynamics = factory.dynamics(stance, dt)
        data = dynamics.create_data()
        following = stances[index + 1] if index + 1 < len(stances) else None
        reset = factory.reset_map(stance, following) if following is not None else None
        for k in knots:
            dynamics.calc(data, xs[k], us[k])
            predicted = np.array(data.x_next, copy=True)
            if k == knots.stop - 1 and reset is not None:
                reset_data = reset.create_data()
                reset.calc(reset_data, predicted)
                predicted = np.array(reset_data.x_next, copy=True)
            defects[k] = float(np.max(np.abs(state.difference(predicted, xs[k + 1]))))
        if following is not None and any(touchdown_flags(stance, following)):
            legs = np.flatnonzero(touchdown_flags(stance, following))
            feet = robot.foot_positions(xs[knots.stop, : robot.nq])
            heights = feet[legs, 2] - robot.foot_radius - surfaces[index + 1]
            time_of_switch = float(trajectory.times[knots.stop])
            touchdowns.append((time_of_switch, heights))
            post_impact_knots.append(int(knots.stop))
            if landing_time is None:
                landing_time = time_of_switch
    nq = robot.nq
    joint_speeds = np.abs(xs[:, nq + 6 :])
    driven = np.ones(len(xs), dtype=bool)
    driven[post_impact_knots] = False
    speed_ratios = joint_speeds / robot.velocity_limits
    return TrajectoryCheck(
        defects=defects,
        max_defect=float(defects.max(initial=0.0)),
        max_abs_torque=float(np.max(np.abs(us))),
        max_joint_speed=float(np.max(joint_speeds)),
        max_driven_joint_speed=float(np.max(joint_speeds[driven])),
        max_post_impact_joint_speed=float(np.max(joint_speeds[~driven], initial=0.0)),
        post_impact_knots=post_impact_knots,
        driven_joint_speed_ratio=float(np.max(speed_ratios[driven])),
        post_impact_joint_speed_ratio=float(np.max(speed_ratios[~driven], initial=0.0)),
        min_base_height=float(np.min(xs[:, 2])),
        min_leg_joint_height=min_leg_joint_height(robot, xs[:, :nq]),
        touchdown_heights=touchdowns,
        landing_time=landing_time,
        roll_at_landing=roll_turned(trajectory, landing_time) if landing_time is not None else None,
        total_roll=roll_turned(trajectory),
        rotation_at_landing=rotation_turned(trajectory, landing_time) if landing_time is not None else None,
        total_rotation=rotation_turned(trajectory),
    )
