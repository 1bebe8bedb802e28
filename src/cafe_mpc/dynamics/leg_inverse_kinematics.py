"""Joint references consistent with the foot references (leg inverse kinematics).

The whole-body cost (18) tracks joint angles as well as the base and the swing feet. If the joint reference
is the standing pose, the two fight: to lift a swing foot 6 cm it is cheaper to raise the whole body than to
fold the leg away from the standing angles, and a stance leg that must sweep backwards under a base moving
at 0.5 m/s is pulled forward by its joint cost. In closed loop that lifted the trotting base from 0.25 m to
0.28 m and halved the forward speed. The fix is the usual one: joint references from inverse kinematics of
the reference feet (stance feet at their footholds, swing feet on their Bezier curves) about the reference
base pose, and joint-rate references from the same Jacobians.

Each leg is a 3-joint chain, so per leg this is a 3 x 3 damped Newton iteration on the foot Jacobian (any
quadruped, no closed form per robot); warm-started from the previous knot it converges in two or three
iterations.

Whole Newton steps are not globalised, and near a folded leg (its foot a few cm from its hip, as a swing
lifting off a riser's corner starts) the hip's lever arm is short and a step overshoots by radians: from the
standing guess the iteration ended at the joint limits (abduction 1.3, hip 5, knee -pi rad; the knee
reversed), 15-25 cm from the target, and the MPC tracked those joint references (the blind flying trot on
6 cm steps rolled over so). So a leg the iteration leaves above the tolerance with a joint at a limit is
repaired: projected damped Newton steps with backtracking inside the limits with the knee kept on the side
of straight it bends to standing (``knee_branches``, from the Pinocchio model), from the previous knot's
joints and from standing, each following its foot to the target in stages, and the closest result is kept.
Every other leg is the iteration's, to the bit: one it converges on, with the knee reversed too (a
stretched hind leg at a bound's lift-off can end so: repairing those lost the ``bound-steps`` preset's
climb of 8 cm steps from 0.9 m, 3.06 s), and one left short inside the limits (a running roll's hind leg
stretched past straight; repairing those lost a reliability trial's pace on flat ground).

The MPC asks for ~26 knots per update. Done per knot through Pinocchio that costs milliseconds, nearly all
of it Python overhead, so the chains are read once from the Pinocchio model (joint placements, joint axes,
foot placement) and all knots are solved in one compiled call (``solve_batch``, numba). The iteration is the
same as the Pinocchio one (``_solve_pinocchio``, kept as the reference and as the fallback for models whose
legs are not three revolute joints on the free-flyer): same iteration count, tolerance, damping, clipping and
warm start, so the results agree to rounding.

The number of legs is the robot's (``robot.n_feet``), each of ``JOINTS_PER_LEG`` joints; the joints of leg
``i`` are the velocity indices ``6 + 3 i .. 8 + 3 i``. This sits with the kinematics (``dynamics``) because
the reference, the template MPC and the template low level all use it.
"""

from __future__ import annotations

import warnings

import numpy as np
import pinocchio as pin
from numba import njit

from cafe_mpc.dynamics.kernels import quaternion_rotation_into
from cafe_mpc.robots.robot import Robot

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED

JOINTS_PER_LEG = 3
"""Joints of each leg (abduction, hip, knee): the 3 x 3 Newton step per leg."""
# One row block per joint in ``LegChains.joints``: rows 0-2 placement rotation (in the parent joint frame),
# row 3 placement translation, row 4 the unit joint axis (in the joint frame).
_PLACEMENT_TRANSLATION = 3
_AXIS = 4
_AXIS_OF_TYPE = {
    "JointModelRX": (1.0, 0.0, 0.0),
    "JointModelRY": (0.0, 1.0, 0.0),
    "JointModelRZ": (0.0, 0.0, 1.0),
}
_BACKTRACKS = 30
"""Halvings of a repair step (``_refine_leg``) before its direction is given up."""
_STAGES = 4
"""Stages in which a repair moves the target from the start's foot to the knot's (``_repair_leg``)."""
# Tolerance of the construction-time comparison of the extracted chains with Pinocchio's kinematics.
_SELF_CHECK_TOLERANCE = 1e-9


_jit = njit(cache=True)


# ------------------------------------------------------------------------------------ compiled kernels
@_jit
def _leg_kinematics(
    joints: np.ndarray,
    foot: np.ndarray,
    angles: np.ndarray,
    first: int,
    position: np.ndarray,
    jacobian: np.ndarray,
    work: np.ndarray,
) -> None:
    """Foot position and 3 x 3 translational Jacobian of one leg, both in the base (free-flyer) frame.

    ``joints`` (3, 5, 3) is the leg's chain (see ``LegChains``), ``foot`` (3) the foot in the last joint's
    frame, ``angles[first : first + 3]`` the joint angles. Forward kinematics composes, joint by joint, the
    constant placement with the rotation about the joint axis (Rodrigues); column ``k`` of the Jacobian is
    ``axis_k x (foot - origin_k)`` with the axis and origin of joint ``k`` in the base frame.
    ``work`` (3, 3, 3) is scratch (frame, product, joint origins; preallocated by the caller, as numba
    would otherwise allocate per call); the axes are kept in ``jacobian``'s columns until the foot is known.
    """
    frame, product, origins = work[0], work[1], work[2]
    origin_x = origin_y = origin_z = 0.0
    for r in range(3):
        for c in range(3):
            frame[r, c] = 1.0 if r == c else 0.0
    for k in range(3):
        placement = joints[k]
        # origin of joint k: previous origin + previous frame @ placement translation
        tx = placement[_PLACEMENT_TRANSLATION, 0]
        ty = placement[_PLACEMENT_TRANSLATION, 1]
        tz = placement[_PLACEMENT_TRANSLATION, 2]
        origin_x, origin_y, origin_z = (
            origin_x + frame[0, 0] * tx + frame[0, 1] * ty + frame[0, 2] * tz,
            origin_y + frame[1, 0] * tx + frame[1, 1] * ty + frame[1, 2] * tz,
            origin_z + frame[2, 0] * tx + frame[2, 1] * ty + frame[2, 2] * tz,
        )
        # frame <- frame @ placement rotation
        for r in range(3):
            for c in range(3):
                product[r, c] = (
                    frame[r, 0] * placement[0, c]
                    + frame[r, 1] * placement[1, c]
                    + frame[r, 2] * placement[2, c]
                )
        ax, ay, az = placement[_AXIS, 0], placement[_AXIS, 1], placement[_AXIS, 2]
        origins[k, 0], origins[k, 1], origins[k, 2] = origin_x, origin_y, origin_z
        # joint axis in the base frame (unchanged by the joint's own rotation), parked in the Jacobian column
        for r in range(3):
            jacobian[r, k] = product[r, 0] * ax + product[r, 1] * ay + product[r, 2] * az
        # frame <- frame @ Rot(axis, angle)
        angle = angles[first + k]
        c, s = np.cos(angle), np.sin(angle)
        t = 1.0 - c
        r00, r01, r02 = t * ax * ax + c, t * ax * ay - s * az, t * ax * az + s * ay
        r10, r11, r12 = t * ax * ay + s * az, t * ay * ay + c, t * ay * az - s * ax
        r20, r21, r22 = t * ax * az - s * ay, t * ay * az + s * ax, t * az * az + c
        for r in range(3):
            p0, p1, p2 = product[r, 0], product[r, 1], product[r, 2]
            frame[r, 0] = p0 * r00 + p1 * r10 + p2 * r20
            frame[r, 1] = p0 * r01 + p1 * r11 + p2 * r21
            frame[r, 2] = p0 * r02 + p1 * r12 + p2 * r22
    for r in range(3):
        position[r] = origins[2, r] + frame[r, 0] * foot[0] + frame[r, 1] * foot[1] + frame[r, 2] * foot[2]
    for k in range(3):
        wx, wy, wz = jacobian[0, k], jacobian[1, k], jacobian[2, k]
        dx = position[0] - origins[k, 0]
        dy = position[1] - origins[k, 1]
        dz = position[2] - origins[k, 2]
        jacobian[0, k] = wy * dz - wz * dy
        jacobian[1, k] = wz * dx - wx * dz
        jacobian[2, k] = wx * dy - wy * dx


@_jit
def _damped_solve(jacobian: np.ndarray, rhs: np.ndarray, damping: float, out: np.ndarray) -> None:
    """``out = (J^T J + damping I)^-1 J^T rhs`` for a 3 x 3 ``J`` (Cholesky of the symmetric 3 x 3)."""
    a00 = a01 = a02 = a11 = a12 = a22 = 0.0
    b0 = b1 = b2 = 0.0
    for r in range(3):
        j0, j1, j2, e = jacobian[r, 0], jacobian[r, 1], jacobian[r, 2], rhs[r]
        a00 += j0 * j0
        a01 += j0 * j1
        a02 += j0 * j2
        a11 += j1 * j1
        a12 += j1 * j2
        a22 += j2 * j2
        b0 += j0 * e
        b1 += j1 * e
        b2 += j2 * e
    a00 += damping
    a11 += damping
    a22 += damping
    l00 = np.sqrt(a00)
    l10 = a01 / l00
    l20 = a02 / l00
    l11 = np.sqrt(a11 - l10 * l10)
    l21 = (a12 - l20 * l10) / l11
    l22 = np.sqrt(a22 - l20 * l20 - l21 * l21)
    y0 = b0 / l00
    y1 = (b1 - l10 * y0) / l11
    y2 = (b2 - l20 * y0 - l21 * y1) / l22
    out[2] = y2 / l22
    out[1] = (y1 - l21 * out[2]) / l11
    out[0] = (y0 - l10 * out[1] - l20 * out[2]) / l00


@_jit
def _chain_kinematics(
    joints: np.ndarray, feet: np.ndarray, angles: np.ndarray, positions: np.ndarray, jacobians: np.ndarray
) -> None:
    """Base-frame foot positions (legs, 3) and leg Jacobians (legs, 3, 3) at the joint ``angles``."""
    work = np.empty((3, 3, 3))
    for leg in range(joints.shape[0]):
        _leg_kinematics(joints[leg], feet[leg], angles, 3 * leg, positions[leg], jacobians[leg], work)


@_jit
def _leg_residual(
    joints: np.ndarray,
    foot: np.ndarray,
    angles: np.ndarray,
    target: np.ndarray,
    position: np.ndarray,
    jacobian: np.ndarray,
    work: np.ndarray,
    error: np.ndarray,
) -> float:
    """Squared foot error ``|target - foot(angles)|^2`` of one leg (base frame); leaves the foot error in
    ``error`` and the leg Jacobian at ``angles`` (3) in ``jacobian``."""
    _leg_kinematics(joints, foot, angles, 0, position, jacobian, work)
    total = 0.0
    for r in range(3):
        error[r] = target[r] - position[r]
        total += error[r] * error[r]
    return total


@_jit
def _refine_leg(
    joints: np.ndarray,
    foot: np.ndarray,
    angles: np.ndarray,
    target: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    iterations: int,
    tolerance: float,
    damping: float,
    position: np.ndarray,
    jacobian: np.ndarray,
    work: np.ndarray,
    error: np.ndarray,
    step: np.ndarray,
    trial: np.ndarray,
) -> float:
    """One leg's foot error minimised from ``angles`` (3, updated in place) inside the box ``lower`` ..
    ``upper`` (3): projected damped Newton steps with backtracking, a projected gradient step where the
    Newton direction does not reduce the error; returns the squared foot error at the result. A joint at a
    bound of the box that the error's gradient pushes further out is held (its Jacobian column zeroed for
    the step), so the other joints still take Newton steps (an active set).

    Every accepted step reduces ``|target - foot|``, so from a start on the nominal knee branch (the box) it
    ends at the target when that is reachable from it and otherwise at a closest point (a stationary point
    of the distance in the box), never jumping to the limits as whole Newton steps near a folded leg do.
    """
    for k in range(3):
        angles[k] = min(max(angles[k], lower[k]), upper[k])
    current = _leg_residual(joints, foot, angles, target, position, jacobian, work, error)
    value = current
    gradient = np.empty(3)
    for _ in range(iterations):
        if current < tolerance * tolerance:
            break
        # the gradient direction J^T e, without the joints held at their bounds (columns zeroed)
        for k in range(3):
            g = jacobian[0, k] * error[0] + jacobian[1, k] * error[1] + jacobian[2, k] * error[2]
            if (angles[k] <= lower[k] and g < 0.0) or (angles[k] >= upper[k] and g > 0.0):
                g = 0.0
                for r in range(3):
                    jacobian[r, k] = 0.0
            gradient[k] = g
        g0, g1, g2 = gradient[0], gradient[1], gradient[2]
        _damped_solve(jacobian, error, damping, step)
        jg_squared = 0.0
        for r in range(3):
            jg = jacobian[r, 0] * g0 + jacobian[r, 1] * g1 + jacobian[r, 2] * g2
            jg_squared += jg * jg
        accepted = False
        for direction in range(2):
            if direction == 0:
                scale = 1.0
            else:
                if jg_squared <= 0.0:
                    break
                # the Cauchy step (the linearised error's least along the gradient)
                scale = (g0 * g0 + g1 * g1 + g2 * g2) / jg_squared
                step[0], step[1], step[2] = g0, g1, g2
            for _ in range(_BACKTRACKS):
                for k in range(3):
                    trial[k] = min(max(angles[k] + scale * step[k], lower[k]), upper[k])
                value = _leg_residual(joints, foot, trial, target, position, jacobian, work, error)
                if value < current:
                    accepted = True
                    break
                scale *= 0.5
            if accepted:
                break
        if not accepted:  # stationary in the box: leave the Jacobian and error at ``angles``
            _leg_residual(joints, foot, angles, target, position, jacobian, work, error)
            break
        for k in range(3):
            angles[k] = trial[k]
        current = value
    return current


@_jit
def _repair_leg(
    joints: np.ndarray,
    foot: np.ndarray,
    q: np.ndarray,
    start: np.ndarray,
    standing: np.ndarray,
    first: int,
    target: np.ndarray,
    branch: np.ndarray,
    limits: np.ndarray,
    converged: bool,
    iterations: int,
    tolerance: float,
    damping: float,
    position: np.ndarray,
    jacobian: np.ndarray,
    work: np.ndarray,
    error: np.ndarray,
    step: np.ndarray,
    scratch: np.ndarray,
) -> bool:
    """Repair one leg of the plain iteration's result ``q`` (joints, in place) if it is left short of its
    target (not ``converged``) with a joint at ``limits`` (2, joints): the whole Newton steps' jump to a limit
    corner. Returns whether it was repaired. ``branch`` (2, joints): the limits with the knee on the
    standing side of straight (``knee_branches``).

    The leg is refined in the branch (``_refine_leg``) from the knot's warm start ``start`` and from the
    standing joints ``standing``, each toward targets moved from its own foot to ``target`` in ``_STAGES``
    equal stages (a continuation: the leg follows its foot along the segment instead of jumping, which
    from standing can end at a local least against the abduction limit with a folded target); the closest
    of those and the plain result (when on the branch) is kept, earlier ones on ties within ``tolerance``:
    the foot at its target whenever that is reachable along either segment, else a closest reachable point
    (a local least of the distance), with the knee bent the nominal way.

    A leg short of its target inside the limits is kept as the iteration left it: a leg stretched past
    its reach (passing straight, as a running roll's hind leg does) or a hip 2 pi off its usual angle. The
    plans were tuned with those joints; repairing them too moved falls between the terrain grid's cells
    and lost a reliability trial's pace on flat ground.
    """
    if converged:
        return False
    at_limit = False
    off_branch = False
    for k in range(3):
        if q[first + k] <= limits[0, first + k] or q[first + k] >= limits[1, first + k]:
            at_limit = True
        if q[first + k] < branch[0, first + k] or q[first + k] > branch[1, first + k]:
            off_branch = True
    if not at_limit:
        return False
    lower, upper, angles, best, trial = scratch[0], scratch[1], scratch[2], scratch[3], scratch[4]
    for k in range(3):
        lower[k] = branch[0, first + k]
        upper[k] = branch[1, first + k]
    best_value = np.inf
    if not off_branch:
        for k in range(3):
            best[k] = q[first + k]
        best_value = _leg_residual(joints, foot, best, target, position, jacobian, work, error)
    stage_target, origin_foot = scratch[5], scratch[6]
    value = np.inf
    for seed in range(2):
        origin = start if seed == 0 else standing
        for k in range(3):
            angles[k] = min(max(origin[first + k], lower[k]), upper[k])
        _leg_kinematics(joints, foot, angles, 0, position, jacobian, work)
        for r in range(3):
            origin_foot[r] = position[r]
        for stage in range(1, _STAGES + 1):
            fraction = stage / _STAGES
            for r in range(3):
                stage_target[r] = origin_foot[r] + fraction * (target[r] - origin_foot[r])
            value = _refine_leg(
                joints,
                foot,
                angles,
                stage_target if stage < _STAGES else target,
                lower,
                upper,
                iterations,
                tolerance,
                damping,
                position,
                jacobian,
                work,
                error,
                step,
                trial,
            )
        if np.sqrt(value) + tolerance < np.sqrt(best_value):
            best_value = value
            for k in range(3):
                best[k] = angles[k]
    for k in range(3):
        q[first + k] = best[k]
    return True


@_jit
def _solve_knots(
    base_configurations: np.ndarray,
    foot_positions: np.ndarray,
    base_velocities: np.ndarray,
    foot_velocities: np.ndarray,
    joint_guess: np.ndarray,
    joints: np.ndarray,
    feet: np.ndarray,
    limits: np.ndarray,
    branch: np.ndarray,
    standing: np.ndarray,
    iterations: int,
    repair_iterations: int,
    tolerance: float,
    damping: float,
    joints_out: np.ndarray,
    rates_out: np.ndarray,
    errors_out: np.ndarray,
) -> None:
    """Leg inverse kinematics of ``n`` knots, each warm-started from the previous knot's solution.

    Per knot: the foot targets are brought into the base frame once, then up to ``iterations`` damped Newton
    sweeps over the legs; each sweep measures the largest world-frame foot error of all legs, steps
    every leg, clips to ``limits`` (2, joints) and stops once that error (measured before the step) is below
    ``tolerance`` (the Pinocchio iteration exactly). A leg that this leaves above ``tolerance`` is
    repaired (``_repair_leg``) inside ``branch`` (2, joints; the limits with the knee kept on the standing
    side of straight); every other leg, and every knot on which the iteration converges, is the plain
    iteration's to the bit. Rates: ``(J^T J + damping I)^-1 J^T
    (v_foot - v_base part)`` at the solution, in the base frame (the rotation cancels in ``J^T J``); skipped
    (zero) when ``base_velocities`` has no rows.
    """
    n = base_configurations.shape[0]
    legs = joints.shape[0]
    with_rates = base_velocities.shape[0] > 0
    rotation = np.empty((3, 3))
    work = np.empty((3, 3, 3))
    targets = np.empty((legs, 3))
    position = np.empty(3)
    jacobian = np.empty((3, 3))
    error = np.empty(3)
    step = np.empty(3)
    leg_errors = np.empty(legs)
    repair_work = np.empty((7, 3))
    q = joint_guess.copy()
    start = np.empty_like(q)
    for i in range(n):
        start[:] = q
        base = base_configurations[i]
        quaternion_rotation_into(base[3:7], rotation)
        for leg in range(legs):
            dx = foot_positions[i, leg, 0] - base[0]
            dy = foot_positions[i, leg, 1] - base[1]
            dz = foot_positions[i, leg, 2] - base[2]
            for r in range(3):
                targets[leg, r] = rotation[0, r] * dx + rotation[1, r] * dy + rotation[2, r] * dz
        error_max = np.inf
        for _ in range(iterations):
            error_max = 0.0
            for leg in range(legs):
                first = 3 * leg
                _leg_kinematics(joints[leg], feet[leg], q, first, position, jacobian, work)
                for r in range(3):
                    error[r] = targets[leg, r] - position[r]
                for r in range(3):  # the tolerance is on the world-frame error, as in the Pinocchio path
                    world = rotation[r, 0] * error[0] + rotation[r, 1] * error[1] + rotation[r, 2] * error[2]
                    if abs(world) > error_max:
                        error_max = abs(world)
                    if r == 0 or abs(world) > leg_errors[leg]:
                        leg_errors[leg] = abs(world)
                _damped_solve(jacobian, error, damping, step)
                for k in range(3):
                    value = q[first + k] + step[k]
                    q[first + k] = min(max(value, limits[0, first + k]), limits[1, first + k])
            if error_max < tolerance:
                break
        repaired = False
        for leg in range(legs):
            if _repair_leg(
                joints[leg],
                feet[leg],
                q,
                start,
                standing,
                3 * leg,
                targets[leg],
                branch,
                limits,
                leg_errors[leg] < tolerance,
                repair_iterations,
                tolerance,
                damping,
                position,
                jacobian,
                work,
                error,
                step,
                repair_work,
            ):
                repaired = True
        if repaired:  # the largest world-frame foot error at the repaired joints
            error_max = 0.0
            for leg in range(legs):
                _leg_kinematics(joints[leg], feet[leg], q, 3 * leg, position, jacobian, work)
                for r in range(3):
                    error[r] = targets[leg, r] - position[r]
                for r in range(3):
                    world = rotation[r, 0] * error[0] + rotation[r, 1] * error[1] + rotation[r, 2] * error[2]
                    if abs(world) > error_max:
                        error_max = abs(world)
        joints_out[i] = q
        errors_out[i] = error_max
        if not with_rates:
            rates_out[i] = 0.0
            continue
        v = base_velocities[i]
        for leg in range(legs):
            first = 3 * leg
            _leg_kinematics(joints[leg], feet[leg], q, first, position, jacobian, work)
            wx, wy, wz = v[3], v[4], v[5]
            px, py, pz = position[0], position[1], position[2]
            base_part_x = v[0] + wy * pz - wz * py
            base_part_y = v[1] + wz * px - wx * pz
            base_part_z = v[2] + wx * py - wy * px
            fx, fy, fz = foot_velocities[i, leg, 0], foot_velocities[i, leg, 1], foot_velocities[i, leg, 2]
            error[0] = rotation[0, 0] * fx + rotation[1, 0] * fy + rotation[2, 0] * fz - base_part_x
            error[1] = rotation[0, 1] * fx + rotation[1, 1] * fy + rotation[2, 1] * fz - base_part_y
            error[2] = rotation[0, 2] * fx + rotation[1, 2] * fy + rotation[2, 2] * fz - base_part_z
            _damped_solve(jacobian, error, damping, step)
            for k in range(3):
                rates_out[i, first + k] = step[k]


# ------------------------------------------------------------------------------------ chain extraction
class LegChainError(ValueError):
    """The legs are not three revolute joints each on the free-flyer: the compiled path does not apply."""


def extract_leg_chains(model: pin.Model, foot_frame_ids: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The legs' kinematic chains from the free-flyer to the feet, for the compiled solver.

    Returns ``joints`` (legs, 3, 5, 3): per leg and joint, the placement rotation in the parent joint frame
    (rows 0-2), the placement translation (row 3) and the unit axis in the joint frame (row 4); and ``feet``
    (legs, 3): each foot frame's position in its parent (the leg's last) joint frame. Raises ``LegChainError``
    unless joint 1 is the root free-flyer at the identity and each foot's chain is exactly three one-DoF
    revolute joints whose velocity indices are ``6 + 3 leg .. 8 + 3 leg`` (configuration ``7 + 3 leg ..``),
    in leg order.
    """
    legs = len(foot_frame_ids)
    if legs < 1:
        raise LegChainError("the model has no feet")
    if model.njoints < 2 or model.joints[1].shortname() != "JointModelFreeFlyer" or model.parents[1] != 0:
        raise LegChainError("joint 1 is not a free-flyer on the universe")
    if not model.jointPlacements[1].isIdentity():
        raise LegChainError("the free-flyer's placement is not the identity")
    joints = np.zeros((legs, JOINTS_PER_LEG, 5, 3))
    feet = np.zeros((legs, 3))
    for leg, frame_id in enumerate(foot_frame_ids):
        frame = model.frames[frame_id]
        chain = []
        joint_id = frame.parentJoint
        while joint_id > 1:
            chain.append(joint_id)
            joint_id = model.parents[joint_id]
        chain.reverse()
        if joint_id != 1 or len(chain) != JOINTS_PER_LEG:
            raise LegChainError(f"foot {frame.name}: {len(chain)} joints below the free-flyer, expected 3")
        for k, joint_id in enumerate(chain):
            joint = model.joints[joint_id]
            kind = joint.shortname()
            if kind in _AXIS_OF_TYPE:
                axis = np.array(_AXIS_OF_TYPE[kind])
            elif kind == "JointModelRevoluteUnaligned":
                axis = np.array(joint.extract().axis, dtype=float)
            else:
                raise LegChainError(
                    f"joint {model.names[joint_id]}: type {kind} is not a 1-DoF revolute joint"
                )
            index = 6 + 3 * leg + k
            if model.nvs[joint_id] != 1 or model.nqs[joint_id] != 1:
                raise LegChainError(f"joint {model.names[joint_id]}: not one degree of freedom")
            if model.idx_vs[joint_id] != index or model.idx_qs[joint_id] != index + 1:
                raise LegChainError(
                    f"joint {model.names[joint_id]}: velocity index {model.idx_vs[joint_id]} "
                    f"(configuration {model.idx_qs[joint_id]}), expected {index} ({index + 1})"
                )
            norm = np.linalg.norm(axis)
            if not np.isfinite(norm) or abs(norm - 1.0) > 1e-9:
                raise LegChainError(f"joint {model.names[joint_id]}: axis {axis} is not a unit vector")
            placement = model.jointPlacements[joint_id]
            joints[leg, k, :3] = placement.rotation
            joints[leg, k, _PLACEMENT_TRANSLATION] = placement.translation
            joints[leg, k, _AXIS] = axis
        feet[leg] = frame.placement.translation
    return joints, feet


def _check_chains(robot: Robot, joints: np.ndarray, feet: np.ndarray) -> None:
    """Compare the compiled forward kinematics and Jacobians with Pinocchio's at a few configurations.

    A guard against joint semantics the extraction does not know: any mismatch raises ``LegChainError``.
    """
    model = robot.model
    data = model.createData()
    rng = np.random.default_rng(0)
    positions = np.empty((robot.n_feet, 3))
    jacobians = np.empty((robot.n_feet, 3, 3))
    span = np.minimum(robot.position_upper - robot.position_lower, 2.0 * np.pi)
    for trial in range(3):
        q = pin.neutral(model)
        q[7:] = (
            robot.q_standing[7:]
            if trial == 0
            else robot.position_lower + rng.uniform(0.1, 0.9, robot.nu) * span
        )
        q[7:] = np.clip(q[7:], robot.position_lower, robot.position_upper)
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        _chain_kinematics(joints, feet, np.ascontiguousarray(q[7:]), positions, jacobians)
        for leg, frame_id in enumerate(robot.foot_frame_ids):
            expected = pin.getFrameJacobian(model, data, frame_id, LWA)[:3, 6 + 3 * leg : 9 + 3 * leg]
            if not (
                np.allclose(
                    positions[leg], data.oMf[frame_id].translation, rtol=0, atol=_SELF_CHECK_TOLERANCE
                )
                and np.allclose(jacobians[leg], expected, rtol=0, atol=_SELF_CHECK_TOLERANCE)
            ):
                raise LegChainError(f"leg {leg}: extracted kinematics disagree with Pinocchio")


def knee_branches(robot: Robot) -> np.ndarray:
    """The joint limits (2, joints) with each leg's knee kept on the side of straight it bends to standing.

    The distance from a leg's hip joint (its second) to its foot depends on the knee angle ``t`` alone (the
    hip rotates about an axis through its own origin), as ``A + B cos t + C sin t`` in its square (a point
    turning about the knee axis): three evaluations on the Pinocchio model give the straight knee
    ``atan2(C, B)`` (the longest leg). The knee's range is cut to the half turn from straight on the
    standing knee's side (``robot.q_standing``), shifted by whole turns to contain it: the branch the
    standing pose bends on. A knee whose angle does not change the leg's reach keeps its limits.
    """
    model = robot.model
    data = model.createData()
    branch = np.vstack([robot.position_lower, robot.position_upper]).astype(np.float64)
    for leg, frame_id in enumerate(robot.foot_frame_ids):
        knee = model.frames[frame_id].parentJoint
        hip = model.parents[knee]
        index = JOINTS_PER_LEG * leg + JOINTS_PER_LEG - 1
        squared = []
        for angle in (0.0, 0.5 * np.pi, np.pi):
            q = robot.q_standing.copy()
            q[7 + index] = angle
            pin.framesForwardKinematics(model, data, q)
            offset = data.oMf[frame_id].translation - data.oMi[hip].translation
            squared.append(float(offset @ offset))
        mean = 0.5 * (squared[0] + squared[2])
        b, c = 0.5 * (squared[0] - squared[2]), squared[1] - mean
        if np.hypot(b, c) <= 1e-9 * mean:
            continue
        straight = float(np.arctan2(c, b))
        standing = float(robot.q_standing[7 + index])
        side = np.sin(standing - straight)
        if side == 0.0:
            continue
        low, high = (straight, straight + np.pi) if side > 0 else (straight - np.pi, straight)
        shift = 2.0 * np.pi * np.round((standing - 0.5 * (low + high)) / (2.0 * np.pi))
        branch[0, index] = max(branch[0, index], low + shift)
        branch[1, index] = min(branch[1, index], high + shift)
    return branch


# ------------------------------------------------------------------------------------ public solver
class LegInverseKinematics:
    """Joint angles and rates that put the feet at given world positions/velocities for a base pose.

    ``fast`` tells whether the compiled path is in use; ``fallback_reason`` says why not (then every call
    goes through Pinocchio, per knot, with the same results but ~80x slower).
    """

    def __init__(
        self,
        robot: Robot,
        iterations: int = 8,
        tolerance: float = 1e-5,
        damping: float = 1e-6,
        repair_iterations: int = 50,
    ):
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        self.frame_ids = robot.foot_frame_ids
        self.iterations = iterations
        self.tolerance = tolerance
        self.damping = damping
        self.repair_iterations = repair_iterations
        self._damping_matrix = damping * np.eye(3)
        self.lower = robot.position_lower
        self.upper = robot.position_upper
        self._q = robot.q_standing.copy()
        self._standing_joints = np.ascontiguousarray(robot.q_standing[7:], dtype=np.float64)
        self._limits = np.ascontiguousarray(np.vstack([self.lower, self.upper]), dtype=np.float64)
        self._no_base_velocity = np.zeros((0, 6))
        self.legs = robot.n_feet
        self.n_joints = robot.nu
        self._no_foot_velocity = np.zeros((0, self.legs, 3))
        self.fast = False
        self.fallback_reason: str | None = None
        self.branch = self._limits.copy()
        """Joint limits (2, joints) with the knees on their standing side (``knee_branches``; the limits
        where the compiled path does not apply): a leg the Newton iteration leaves short of its target is
        repaired inside it."""
        self._joints = np.zeros((self.legs, JOINTS_PER_LEG, 5, 3))
        self._feet = np.zeros((self.legs, 3))
        try:
            if self.n_joints != JOINTS_PER_LEG * self.legs:
                raise LegChainError(
                    f"{self.n_joints} joints on {self.legs} legs, not {JOINTS_PER_LEG} per leg"
                )
            self._joints, self._feet = extract_leg_chains(self.model, self.frame_ids)
            if self.lower.shape != (self.n_joints,) or self.upper.shape != (self.n_joints,):
                raise LegChainError(f"joint limits are not {self.n_joints} numbers")
            _check_chains(robot, self._joints, self._feet)
            self.fast = True
            self.branch = np.ascontiguousarray(knee_branches(robot))
        except LegChainError as error:
            self.fallback_reason = str(error)
        if self.fast:
            # Compile (or load from numba's cache) now, not in the first MPC update: one standing knot.
            standing = robot.q_standing[None, :7]
            self.solve_batch(
                standing,
                robot.foot_positions(robot.q_standing)[None],
                None,
                np.zeros((1, 6)),
                np.zeros((1, self.legs, 3)),
            )
        else:
            warnings.warn(
                f"leg inverse kinematics of {robot.name}: {self.fallback_reason}; "
                "using the (slow) Pinocchio path",
                RuntimeWarning,
                stacklevel=2,
            )

    def solve(
        self,
        base_configuration: np.ndarray,
        foot_positions: np.ndarray,
        joint_guess: np.ndarray | None = None,
        base_velocity: np.ndarray | None = None,
        foot_velocities: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Joint angles (joints), joint rates (joints) and the largest remaining foot-position error (m).

        ``base_configuration``: base position and quaternion (7); ``foot_positions``: world (legs, 3);
        ``base_velocity``: base-frame linear and angular velocity (6); ``foot_velocities``: world (legs, 3).
        Feet out of reach end as close as the iteration gets them, or, for a leg it leaves at a joint limit,
        at a closest point the leg reaches with its knee on the standing side (a local least of the
        distance); the error is returned, not raised.
        The rates are zero unless both velocities are given.
        """
        if not self.fast:
            return self._solve_pinocchio(
                base_configuration, foot_positions, joint_guess, base_velocity, foot_velocities
            )
        with_rates = base_velocity is not None and foot_velocities is not None
        joints, rates, errors = self.solve_batch(
            np.reshape(base_configuration, (1, 7)),
            np.reshape(foot_positions, (1, self.legs, 3)),
            joint_guess,
            np.reshape(base_velocity, (1, 6)) if with_rates else None,
            np.reshape(foot_velocities, (1, self.legs, 3)) if with_rates else None,
        )
        return joints[0], rates[0], float(errors[0])

    def solve_batch(
        self,
        base_configurations: np.ndarray,
        foot_positions: np.ndarray,
        joint_guess: np.ndarray | None = None,
        base_velocities: np.ndarray | None = None,
        foot_velocities: np.ndarray | None = None,
        out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint angles, joint rates (n, joints) and largest foot errors (n) of ``n`` knots in one call.

        ``base_configurations`` (n, 7): base positions and unit quaternions ``(x, y, z, w)``;
        ``foot_positions`` (n, legs, 3) world; ``joint_guess`` (joints) warm-starts the first knot (standing
        joints when None), every later knot starts from the previous knot's solution (as a per-knot loop
        over ``solve`` would); ``base_velocities`` (n, 6) base frame, ``foot_velocities`` (n, legs, 3)
        world (zero rates unless both are given). ``out``: C-contiguous float64 arrays (n, joints) twice, (n)
        to write into and return; fresh arrays otherwise.
        """
        base = np.ascontiguousarray(base_configurations, dtype=np.float64)
        feet = np.ascontiguousarray(foot_positions, dtype=np.float64)
        n = base.shape[0]
        legs, n_joints = self.legs, self.n_joints
        if base.shape != (n, 7) or feet.shape != (n, legs, 3):
            raise ValueError(f"expected (n, 7) and (n, {legs}, 3) arrays, got {base.shape} and {feet.shape}")
        if base_velocities is None or foot_velocities is None:
            base_velocity, foot_velocity = self._no_base_velocity, self._no_foot_velocity
        else:
            base_velocity = np.ascontiguousarray(base_velocities, dtype=np.float64)
            foot_velocity = np.ascontiguousarray(foot_velocities, dtype=np.float64)
            if base_velocity.shape != (n, 6) or foot_velocity.shape != (n, legs, 3):
                raise ValueError(
                    f"expected (n, 6) and (n, {legs}, 3) velocities, got {base_velocity.shape} and "
                    f"{foot_velocity.shape}"
                )
        if out is None:
            joints, rates, errors = np.empty((n, n_joints)), np.empty((n, n_joints)), np.empty(n)
        else:
            joints, rates, errors = out
            for array, shape in ((joints, (n, n_joints)), (rates, (n, n_joints)), (errors, (n,))):
                if array.shape != shape or array.dtype != np.float64 or not array.flags.c_contiguous:
                    raise ValueError(f"out: expected C-contiguous float64 arrays of shape {shape}")
        if not self.fast:
            self._solve_batch_pinocchio(
                base, feet, joint_guess, base_velocity, foot_velocity, joints, rates, errors
            )
            return joints, rates, errors
        guess = (
            self._standing_joints
            if joint_guess is None
            else np.ascontiguousarray(joint_guess, dtype=np.float64).reshape(n_joints)
        )
        _solve_knots(
            base,
            feet,
            base_velocity,
            foot_velocity,
            guess,
            self._joints,
            self._feet,
            self._limits,
            self.branch,
            self._standing_joints,
            self.iterations,
            self.repair_iterations,
            self.tolerance,
            self.damping,
            joints,
            rates,
            errors,
        )
        return joints, rates, errors

    def _solve_batch_pinocchio(
        self,
        base: np.ndarray,
        feet: np.ndarray,
        joint_guess: np.ndarray | None,
        base_velocity: np.ndarray,
        foot_velocity: np.ndarray,
        joints: np.ndarray,
        rates: np.ndarray,
        errors: np.ndarray,
    ) -> None:
        """``solve_batch`` through Pinocchio, knot by knot (the fallback when the compiled path is off)."""
        with_rates = base_velocity.shape[0] > 0
        guess = joint_guess
        for i in range(base.shape[0]):
            joints[i], rates[i], errors[i] = self._solve_pinocchio(
                base[i],
                feet[i],
                guess,
                base_velocity[i] if with_rates else None,
                foot_velocity[i] if with_rates else None,
            )
            guess = joints[i]

    def _solve_pinocchio(
        self,
        base_configuration: np.ndarray,
        foot_positions: np.ndarray,
        joint_guess: np.ndarray | None = None,
        base_velocity: np.ndarray | None = None,
        foot_velocities: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """``solve`` on Pinocchio's kinematics, one knot: the reference for the compiled path and its
        fallback for models it does not fit."""
        model, data, q = self.model, self.data, self._q
        q[:7] = base_configuration
        q[7:] = self.robot.q_standing[7:] if joint_guess is None else joint_guess
        start = q[7:].copy()
        leg_errors = np.zeros(self.legs)
        error_max = np.inf
        for _ in range(self.iterations):
            pin.forwardKinematics(model, data, q)
            error_max = 0.0
            pin.computeJointJacobians(model, data, q)
            for leg, frame_id in enumerate(self.frame_ids):
                position = pin.updateFramePlacement(model, data, frame_id).translation
                error = foot_positions[leg] - position
                leg_errors[leg] = float(np.max(np.abs(error)))
                error_max = max(error_max, leg_errors[leg])
                columns = slice(6 + 3 * leg, 9 + 3 * leg)
                jacobian = pin.getFrameJacobian(model, data, frame_id, LWA)[:3, columns]
                step = np.linalg.solve(jacobian.T @ jacobian + self._damping_matrix, jacobian.T @ error)
                rows, limits = slice(7 + 3 * leg, 10 + 3 * leg), slice(3 * leg, 3 * leg + 3)
                q[rows] = np.clip(q[rows] + step, self.lower[limits], self.upper[limits])
            if error_max < self.tolerance:
                break
        repaired = False
        for leg, frame_id in enumerate(self.frame_ids):
            if self._repair_leg_pinocchio(
                leg, frame_id, foot_positions[leg], start, leg_errors[leg] < self.tolerance
            ):
                repaired = True
        if repaired:
            pin.framesForwardKinematics(model, data, q)
            error_max = max(
                float(np.max(np.abs(foot_positions[leg] - data.oMf[frame_id].translation)))
                for leg, frame_id in enumerate(self.frame_ids)
            )
        joints = q[7:].copy()
        rates = np.zeros(self.robot.nu)
        if base_velocity is not None and foot_velocities is not None:
            pin.computeJointJacobians(model, data, q)
            for leg, frame_id in enumerate(self.frame_ids):
                jacobian = pin.getFrameJacobian(model, data, frame_id, LWA)[:3]
                columns = slice(6 + 3 * leg, 9 + 3 * leg)
                base_part = jacobian[:, :6] @ base_velocity
                leg_jacobian = jacobian[:, columns]
                rates[3 * leg : 3 * leg + 3] = np.linalg.solve(
                    leg_jacobian.T @ leg_jacobian + self._damping_matrix,
                    leg_jacobian.T @ (foot_velocities[leg] - base_part),
                )
        return joints, rates, error_max

    def _leg_error_pinocchio(
        self, leg: int, frame_id: int, target: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """World foot error (3) and leg Jacobian (3, 3) of leg ``leg`` at the joints in ``self._q``."""
        model, data, q = self.model, self.data, self._q
        pin.forwardKinematics(model, data, q)
        pin.computeJointJacobians(model, data, q)
        error = target - pin.updateFramePlacement(model, data, frame_id).translation
        jacobian = pin.getFrameJacobian(model, data, frame_id, LWA)[:3, 6 + 3 * leg : 9 + 3 * leg]
        return error, jacobian

    def _refine_leg_pinocchio(
        self, leg: int, frame_id: int, target: np.ndarray, lower: np.ndarray, upper: np.ndarray
    ) -> float:
        """``_refine_leg`` on Pinocchio's kinematics: leg ``leg``'s joints in ``self._q`` (in place)."""
        q, rows = self._q, slice(7 + 3 * leg, 10 + 3 * leg)
        q[rows] = np.clip(q[rows], lower, upper)
        error, jacobian = self._leg_error_pinocchio(leg, frame_id, target)
        current = float(error @ error)
        for _ in range(self.repair_iterations):
            if current < self.tolerance * self.tolerance:
                break
            gradient = jacobian.T @ error
            angles = q[rows]
            held = ((angles <= lower) & (gradient < 0.0)) | ((angles >= upper) & (gradient > 0.0))
            gradient[held] = 0.0
            jacobian = jacobian.copy()
            jacobian[:, held] = 0.0
            step = np.linalg.solve(jacobian.T @ jacobian + self._damping_matrix, jacobian.T @ error)
            jg_squared = float((jacobian @ gradient) @ (jacobian @ gradient))
            angles = q[rows].copy()
            accepted = False
            for direction in range(2):
                if direction == 0:
                    scale = 1.0
                else:
                    if jg_squared <= 0.0:
                        break
                    scale, step = float(gradient @ gradient) / jg_squared, gradient
                for _ in range(_BACKTRACKS):
                    q[rows] = np.clip(angles + scale * step, lower, upper)
                    error, jacobian = self._leg_error_pinocchio(leg, frame_id, target)
                    value = float(error @ error)
                    if value < current:
                        accepted = True
                        break
                    scale *= 0.5
                if accepted:
                    break
            if not accepted:
                q[rows] = angles
                break
            current = value
        return current

    def _repair_leg_pinocchio(
        self, leg: int, frame_id: int, target: np.ndarray, start: np.ndarray, converged: bool
    ) -> bool:
        """``_repair_leg`` on Pinocchio's kinematics: leg ``leg`` of ``self._q`` (in place); ``start`` is the
        knot's warm start (joints)."""
        q, rows, limits = self._q, slice(7 + 3 * leg, 10 + 3 * leg), slice(3 * leg, 3 * leg + 3)
        lower, upper = self.branch[0, limits], self.branch[1, limits]
        if converged or not (np.any(q[rows] <= self.lower[limits]) or np.any(q[rows] >= self.upper[limits])):
            return False
        off_branch = bool(np.any(q[rows] < lower) or np.any(q[rows] > upper))
        best, best_value = q[rows].copy(), np.inf
        if not off_branch:
            error, _ = self._leg_error_pinocchio(leg, frame_id, target)
            best_value = float(error @ error)
        for origin in (start, self.robot.q_standing[7:]):
            q[rows] = np.clip(origin[limits], lower, upper)
            origin_foot = target - self._leg_error_pinocchio(leg, frame_id, target)[0]
            for stage in range(1, _STAGES + 1):
                stage_target = (
                    origin_foot + stage / _STAGES * (target - origin_foot) if stage < _STAGES else target
                )
                value = self._refine_leg_pinocchio(leg, frame_id, stage_target, lower, upper)
            if np.sqrt(value) + self.tolerance < np.sqrt(best_value):
                best, best_value = q[rows].copy(), value
        q[rows] = best
        return True
