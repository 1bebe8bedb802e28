"""Carry a trajectory-optimisation task written for one robot to another (``TrajOptTask.keyframes_robot``).

A task's keyframes are written for one robot (``keyframes_robot``; the Mini Cheetah for the presets): its
joint angles, heights, speeds and durations. Solving the same numbers on another robot fails for reasons
that have nothing to do with the optimiser: Unitree legs bend the other way (knee angles of opposite sign,
outside the joint limits), a taller robot's stance feet hang in the air or sink into the floor, and the
robot's own torque and speed limits differ. ``retarget_task`` rewrites every number for the target robot:

* **Lengths** by dimensional similarity (``robots.scaling``): with ``s_L`` the leg-length ratio and
  ``s_T = sqrt(s_L)`` (Froude), base positions (heights above the foot-sphere centre plane), minimum
  heights and the surface height scale by ``s_L``, linear velocities by ``sqrt(s_L)``, angular rates by
  ``1 / s_T``, phase durations by ``s_T`` (rounded to the knot spacing ``dt``); angles are kept.
* **Legs through the feet.** Each leg's foot position relative to the foot's place with the leg hanging
  straight (base frame) is scaled by ``s_L`` and solved back to joint angles on the target robot by inverse
  kinematics, seeded with the target's standing pose (its knee direction); joint rates through the legs'
  Jacobians (foot velocity relative to the base scaled by ``sqrt(s_L)``).
* **Stance feet on the ground** (``keyframe_feet: stance-ik``, also for a task solved on its own robot): in
  the initial state and in the keyframe of every phase, each stance foot is put by inverse kinematics at its
  foothold, the point where it stands in that phase (world ``x, y`` from the last keyframe before the phase in
  which the leg was in the air or, for legs that never left the ground, the initial state; height: the
  surface). Keyframes whose stance legs do not reach their footholds otherwise ask the optimiser for a state
  the contact constraint cannot hold, which the guess inherits as a large defect at every stance knot.
* **Weights** keep their share of the cost (``RobotScale``: position weights ``/ s_L^2``, linear velocity
  ``/ s_L``, angular rates ``x s_L``, torque ``/ (s_m s_L)^2``), barrier thresholds keep their meaning
  (friction ``x s_m``, torque ``x s_m s_L``, height ``x s_L``, joint speed ``/ s_T``).
* **Limits** are the target robot's own (``torque_limit`` and ``joint_speed_limit`` null: the robot file's
  torque limits and joint speed limits).
"""

from __future__ import annotations

import itertools

import numpy as np
import pinocchio as pin

from cafe_mpc.robots.robot import Robot, load_robot
from cafe_mpc.robots.scaling import RobotScale
from cafe_mpc.trajopt.task import (
    BarrierSetSpec,
    BarrierSpec,
    KeyframeSpec,
    TrajOptTask,
    WeightsSpec,
    joints12,
)

IK_TOLERANCE = 1e-9
"""Foot position error (m) at which the leg inverse kinematics stops."""
IK_ITERATIONS = 100


def leg_joint_indices(leg: int) -> slice:
    """Indices of a leg's three joints in the joint vector (leg order)."""
    return slice(3 * leg, 3 * leg + 3)


def base_configuration(robot: Robot, keyframe: KeyframeSpec, joints: np.ndarray) -> np.ndarray:
    """``q`` of a keyframe's base pose with ``joints``."""
    q = pin.neutral(robot.model)
    q[0:3] = keyframe.position
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(*keyframe.rpy)).normalized().coeffs()
    q[7:] = joints
    return q


def foot_positions_base(robot: Robot, joints: np.ndarray) -> np.ndarray:
    """Feet in the base frame (4 x 3) at ``joints``."""
    q = pin.neutral(robot.model)
    q[7:] = joints
    return robot.foot_positions(q)


def hanging_feet(robot: Robot) -> np.ndarray:
    """Feet in the base frame with every leg hanging straight (all joint angles zero)."""
    return foot_positions_base(robot, np.zeros(robot.nu))


def solve_leg_ik(robot: Robot, q: np.ndarray, leg: int, target: np.ndarray) -> np.ndarray:
    """Joint angles of ``leg`` that put its foot at ``target`` (world) with the rest of ``q`` fixed; Gauss-
    Newton from the leg's angles in ``q`` (their knee direction is kept). Raises ``ValueError`` when the foot
    cannot reach the target (more than 1 mm away after ``IK_ITERATIONS``)."""
    model, data = robot.model, robot.model.createData()
    frame = robot.foot_frame_ids[leg]
    columns = np.arange(6, robot.nv)[leg_joint_indices(leg)]
    q = np.array(q, dtype=float)
    indices = 7 + np.arange(robot.nu)[leg_joint_indices(leg)]
    error = np.full(3, np.inf)
    for _ in range(IK_ITERATIONS):
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        error = data.oMf[frame].translation - target
        if np.linalg.norm(error) < IK_TOLERANCE:
            break
        jacobian = pin.getFrameJacobian(model, data, frame, pin.LOCAL_WORLD_ALIGNED)[:3, columns]
        step = np.linalg.solve(jacobian.T @ jacobian + 1e-6 * np.eye(3), jacobian.T @ error)
        q[indices] -= np.clip(step, -0.3, 0.3)
    if np.linalg.norm(error) > 1e-3:
        raise ValueError(
            f"leg {robot.leg_names[leg]}: the foot cannot reach {np.round(target, 3)} "
            f"({np.linalg.norm(error):.3f} m away)"
        )
    return q[indices]


def leg_velocity_map(robot: Robot, joints: np.ndarray, leg: int) -> np.ndarray:
    """3 x 3 Jacobian of the leg's foot position in the base frame w.r.t. its joint angles."""
    model, data = robot.model, robot.model.createData()
    q = pin.neutral(model)
    q[7:] = joints
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    columns = np.arange(6, robot.nv)[leg_joint_indices(leg)]
    return pin.getFrameJacobian(model, data, robot.foot_frame_ids[leg], pin.LOCAL_WORLD_ALIGNED)[:3, columns]


class Retargeter:
    """Maps the values of a task written for ``source`` to ``target`` (see the module docstring)."""

    def __init__(self, source: Robot, target: Robot) -> None:
        self.source, self.target = source, target
        self.scale = RobotScale(target.leg_length / source.leg_length, target.mass / source.mass)
        self.source_hanging = hanging_feet(source)
        self.target_hanging = hanging_feet(target)
        self.seed = np.array(target.q_standing[7:], dtype=float)

    # scalars
    def height(self, z: float) -> float:
        """A base height above the floor (the foot-sphere centre plane scales)."""
        return round(self.target.foot_radius + self.scale.length * (z - self.source.foot_radius), 6)

    def position(self, position: tuple[float, float, float]) -> tuple[float, float, float]:
        x, y, z = position
        return (round(self.scale.distance(x), 6), round(self.scale.distance(y), 6), self.height(z))

    def velocity(self, velocity: tuple[float, float, float]) -> tuple[float, float, float]:
        factor = self.scale.length / self.scale.time
        return tuple(round(factor * v, 6) for v in velocity)

    def rates(self, rates: tuple[float, float, float]) -> tuple[float, float, float]:
        return tuple(round(self.scale.rate(r), 6) for r in rates)

    # legs
    def joints(self, joints: np.ndarray) -> np.ndarray:
        """Joint angles of the target that put every foot at the source's foot offset (from the hanging foot,
        base frame) scaled by ``s_L``."""
        feet = foot_positions_base(self.source, joints)
        targets = self.target_hanging + self.scale.length * (feet - self.source_hanging)
        q = pin.neutral(self.target.model)
        q[7:] = self.seed
        result = np.array(self.seed)
        for leg in range(4):
            result[leg_joint_indices(leg)] = solve_leg_ik(self.target, q, leg, targets[leg])
        return result

    def joint_velocities(
        self, source_joints: np.ndarray, target_joints: np.ndarray, qd: np.ndarray
    ) -> np.ndarray:
        if not np.any(qd):
            return np.zeros_like(qd)
        factor = self.scale.length / self.scale.time
        result = np.zeros_like(qd)
        for leg in range(4):
            rows = leg_joint_indices(leg)
            foot_velocity = leg_velocity_map(self.source, source_joints, leg) @ qd[rows]
            result[rows] = np.linalg.solve(
                leg_velocity_map(self.target, target_joints, leg), factor * foot_velocity
            )
        return result

    def keyframe(self, keyframe: KeyframeSpec) -> KeyframeSpec:
        source_joints = joints12(keyframe.joint_positions)
        target_joints = self.joints(source_joints)
        qd = self.joint_velocities(source_joints, target_joints, joints12(keyframe.joint_velocities))
        return KeyframeSpec(
            position=self.position(keyframe.position),
            rpy=keyframe.rpy,
            linear_velocity=self.velocity(keyframe.linear_velocity),
            rpy_rates=self.rates(keyframe.rpy_rates),
            joint_positions=_rounded(target_joints),
            joint_velocities=_rounded(qd),
        )

    def weights(self, weights: WeightsSpec) -> WeightsSpec:
        scale = self.scale
        position = [w * scale.position_weight for w in weights.base_position[:3]]
        velocity = [w * scale.linear_velocity_weight for w in weights.base_velocity[:3]]
        rates = [w * scale.angular_velocity_weight for w in weights.base_velocity[3:]]
        return weights.model_copy(
            update={
                "base_position": tuple(map(_significant, position)) + tuple(weights.base_position[3:]),
                "base_velocity": tuple(map(_significant, velocity + rates)),
                "torque": _significant(weights.torque * scale.torque_weight),
            }
        )

    def barriers(self, barriers: BarrierSetSpec | None) -> BarrierSetSpec | None:
        if barriers is None:
            return None
        scale = self.scale

        def scaled(spec: BarrierSpec, factor: float) -> BarrierSpec:
            return BarrierSpec(delta=_significant(spec.delta * factor), eps=spec.eps)

        return BarrierSetSpec(
            friction=scaled(barriers.friction, scale.mass),
            torque=scaled(barriers.torque, scale.torque),
            joint_position=barriers.joint_position,
            joint_speed=scaled(barriers.joint_speed, 1.0 / scale.time),
            height=scaled(barriers.height, scale.length),
        )

    def switching_times(self, times: list[float], dt: float) -> list[float]:
        """Phase durations scaled by ``s_T`` and rounded to ``dt`` (at least one knot each)."""
        result = [self.scale.duration(times[0])]
        for start, end in itertools.pairwise(times):
            knots = max(1, round(self.scale.duration(end - start) / dt))
            result.append(result[-1] + knots * dt)
        return [round(t, 9) for t in result]


def _rounded(values: np.ndarray) -> list[float]:
    return [round(float(v), 6) for v in values]


def _significant(value: float) -> float:
    """``value`` to 6 significant digits (readable settings files)."""
    return float(f"{value:.6g}")


def retarget_task(task: TrajOptTask, source: Robot, target: Robot) -> TrajOptTask:
    """``task`` (written for ``source``) for ``target``: see the module docstring. The result is written for
    ``target`` (``keyframes_robot`` = its name) and names the robot's own limits."""
    mapper = Retargeter(source, target)
    phases = [
        phase.model_copy(
            update={
                "keyframe": mapper.keyframe(phase.keyframe),
                "running": mapper.weights(phase.running),
                "terminal": mapper.weights(phase.terminal),
                "minimum_height": (
                    None if phase.minimum_height is None else mapper.height(phase.minimum_height)
                ),
                "surface_height": (
                    None
                    if phase.surface_height is None
                    else round(mapper.scale.distance(phase.surface_height), 6)
                ),
            }
        )
        for phase in task.phases
    ]
    constraints = task.constraints.model_copy(
        update={
            "torque_limit": None,
            "joint_speed_limit": None,
            "barriers": mapper.barriers(task.constraints.barriers),
            "warm_up_barriers": mapper.barriers(task.constraints.warm_up_barriers),
        }
    )
    return TrajOptTask(
        **{
            **task.model_dump(),
            "robot": target.name,
            "keyframes_robot": target.name,
            "surface_height": round(mapper.scale.distance(task.surface_height), 6),
            "switching_times": mapper.switching_times(task.switching_times, task.dt),
            "initial": mapper.keyframe(task.initial).model_dump(),
            "phases": [phase.model_dump() for phase in phases],
            "constraints": constraints.model_dump(),
        }
    )


# --------------------------------------------------------------------------------------------------
# Stance feet on their footholds
# --------------------------------------------------------------------------------------------------


def _keyframe_with_joints(keyframe: KeyframeSpec, joints: np.ndarray) -> KeyframeSpec:
    return keyframe.model_copy(update={"joint_positions": _rounded(joints)})


def place_stance_feet(task: TrajOptTask, robot: Robot) -> TrajOptTask:
    """``task`` with every stance foot of the initial state and of each phase's keyframe solved onto its
    foothold (module docstring, "Stance feet on the ground"); swing legs keep their angles."""
    surfaces = task.phase_surface_heights()
    initial_joints = joints12(task.initial.joint_positions)
    q0 = base_configuration(robot, task.initial, initial_joints)
    feet = robot.foot_positions(q0)
    # The initial state stands on the first phase's surface, at the feet's own x, y.
    joints = np.array(initial_joints)
    for leg in range(4):
        target = np.array([feet[leg, 0], feet[leg, 1], surfaces[0] + robot.foot_radius])
        joints[leg_joint_indices(leg)] = solve_leg_ik(robot, q0, leg, target)
    initial = _keyframe_with_joints(task.initial, joints)
    footholds = robot.foot_positions(base_configuration(robot, initial, joints))
    previous_keyframe, previous_stance = initial, (True,) * 4
    phases = []
    for phase, surface_height in zip(task.phases, surfaces, strict=True):
        stance = phase.stance
        surface = surface_height + robot.foot_radius
        previous_joints = joints12(previous_keyframe.joint_positions)
        previous_feet = robot.foot_positions(base_configuration(robot, previous_keyframe, previous_joints))
        for leg in range(4):
            if stance[leg] and not previous_stance[leg]:  # touches down: where the last keyframe put it
                footholds[leg] = (previous_feet[leg, 0], previous_feet[leg, 1], surface)
        keyframe_joints = joints12(phase.keyframe.joint_positions).copy()
        q = base_configuration(robot, phase.keyframe, keyframe_joints)
        for leg in range(4):
            if stance[leg]:
                keyframe_joints[leg_joint_indices(leg)] = solve_leg_ik(robot, q, leg, footholds[leg])
        keyframe = _keyframe_with_joints(phase.keyframe, keyframe_joints)
        phases.append(phase.model_copy(update={"keyframe": keyframe}))
        previous_keyframe, previous_stance = keyframe, stance
    return task.model_copy(update={"initial": initial, "phases": phases, "keyframe_feet": "as-given"})


def resolve_task(task: TrajOptTask, robot: Robot) -> TrajOptTask:
    """The task as solved on ``robot``: retargeted when its keyframes were written for another robot
    (``keyframes_robot``), stance feet placed (``keyframe_feet: stance-ik``)."""
    if task.keyframes_robot not in (None, robot.name):
        task = retarget_task(task, load_robot(task.keyframes_robot), robot)
    if task.keyframe_feet == "stance-ik":
        task = place_stance_feet(task, robot)
    return task


def is_resolved(task: TrajOptTask) -> bool:
    """Whether ``task`` is solved as written (no retargeting, no foot placement)."""
    return task.keyframes_robot in (None, task.robot) and task.keyframe_feet == "as-given"


__all__ = ["Retargeter", "is_resolved", "place_stance_feet", "resolve_task", "retarget_task", "solve_leg_ik"]
