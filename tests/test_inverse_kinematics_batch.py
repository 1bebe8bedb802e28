"""The compiled batch leg IK (``LegInverseKinematics.solve_batch``) against the Pinocchio implementation.

The batch path reimplements the leg kinematics (chains read from the Pinocchio model, forward kinematics
and Jacobians in numba), so these tests pin it to Pinocchio: same joints, rates and errors as the per-knot
Pinocchio solver (``_solve_pinocchio``) on the Mini Cheetah, on Go1 and on a synthetic quadruped with rotated
joint placements and all revolute joint kinds; Pinocchio's forward kinematics and frame Jacobians of the
solution reproduce the targets; a leg the Newton iteration leaves short of its target is repaired on the
standing knee branch (a folded swing foot is reached, an unreachable one ends at a closest point); models
that do not fit fall back to Pinocchio instead of failing.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pinocchio as pin
import pytest

from cafe_mpc.dynamics.leg_inverse_kinematics import (
    LegChainError,
    LegInverseKinematics,
    _chain_kinematics,
    extract_leg_chains,
    knee_branches,
)
from cafe_mpc.robots.robot import Robot, load_robot

KNOTS = 26
MATCH = 1e-8  # batch vs Pinocchio path (same iteration, different rounding)
FOLDED_SWING = np.array(
    [[0.154, 0.109, -0.264], [0.052, -0.127, -0.098], [-0.358, 0.009, -0.162], [-0.261, -0.057, -0.193]]
)
"""Base-frame feet of the reference's first knot in the blind flying trot on 6 cm steps from 1.0 m at fixed
2 ms, the update at 2.70 s (docs/terrain-notes.md, "the reference's leg IK at the joint limits"): FR's
swing starts folded off the riser's corner, 10 cm below and 14 cm behind its hip."""
LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


# ------------------------------------------------------------------------------------ helpers
def _random_quaternion(rng: np.random.Generator, tilt: float) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)`` of a random yaw and a roll/pitch up to ``tilt`` rad."""
    rotation = pin.rpy.rpyToMatrix(*rng.uniform(-tilt, tilt, 2), rng.uniform(-np.pi, np.pi))
    return pin.Quaternion(rotation).coeffs().copy()


def _feet_and_jacobians(robot: Robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World foot positions (4, 3) and LOCAL_WORLD_ALIGNED translational frame Jacobians (4, 3, nv)."""
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    positions = np.array([data.oMf[f].translation.copy() for f in robot.foot_frame_ids])
    pin.computeJointJacobians(robot.model, data, q)
    jacobians = np.array(
        [pin.getFrameJacobian(robot.model, data, f, LWA)[:3].copy() for f in robot.foot_frame_ids]
    )
    return positions, jacobians


def _trajectory(
    robot: Robot, rng: np.random.Generator, n: int = KNOTS, smooth: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Reachable knots: configurations (n, 19), foot targets (n, 4, 3), base velocities (n, 6), foot
    velocities (n, 4, 3) consistent with joint rates (n, 12) (targets from Pinocchio's kinematics).

    Joints stay within 0.4 rad of standing (away from the straight-knee singularity) and 0.05 rad inside the
    limits; ``smooth`` knots follow a sine per joint (as the MPC's), otherwise each knot is independent.
    """
    lower, upper = robot.position_lower + 0.05, robot.position_upper - 0.05
    times = np.linspace(0.0, 0.5, n)
    if smooth:
        amplitude, frequency, phase = (
            rng.uniform(0.1, 0.4, 12),
            rng.uniform(0.5, 2.0, 12),
            rng.uniform(0, 6, 12),
        )
        joints = robot.q_standing[7:] + amplitude * np.sin(frequency * times[:, None] + phase)
    else:
        joints = robot.q_standing[7:] + rng.uniform(-0.4, 0.4, (n, 12))
    joints = np.clip(joints, lower, upper)
    configurations = np.zeros((n, robot.nq))
    configurations[:, :3] = rng.uniform(-1.0, 1.0, 3) + rng.uniform(-0.2, 0.2, (n, 3))
    configurations[:, 3:7] = [_random_quaternion(rng, 0.4) for _ in range(n)]
    configurations[:, 7:] = joints
    base_velocities = rng.uniform(-1.0, 1.0, (n, 6))
    rates = rng.uniform(-3.0, 3.0, (n, 12))
    targets = np.zeros((n, 4, 3))
    foot_velocities = np.zeros((n, 4, 3))
    for i in range(n):
        targets[i], jacobians = _feet_and_jacobians(robot, configurations[i])
        foot_velocities[i] = jacobians @ np.concatenate([base_velocities[i], rates[i]])
    return configurations, targets, base_velocities, foot_velocities, rates


def _pinocchio_knots(
    ik: LegInverseKinematics,
    bases: np.ndarray,
    targets: np.ndarray,
    guess: np.ndarray | None,
    base_velocities: np.ndarray | None,
    foot_velocities: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The reference: Pinocchio path knot by knot, each warm-started from the previous knot."""
    n = len(bases)
    joints, rates, errors = np.zeros((n, 12)), np.zeros((n, 12)), np.zeros(n)
    for i in range(n):
        joints[i], rates[i], errors[i] = ik._solve_pinocchio(
            bases[i],
            targets[i],
            guess,
            None if base_velocities is None else base_velocities[i],
            None if foot_velocities is None else foot_velocities[i],
        )
        guess = joints[i]
    return joints, rates, errors


def _assert_matches_pinocchio(ik: LegInverseKinematics, bases, targets, guess, base_velocities, velocities):
    """Batch result equals the per-knot Pinocchio result (joints, rates, errors) to ``MATCH``."""
    joints, rates, errors = ik.solve_batch(bases, targets, guess, base_velocities, velocities)
    expected = _pinocchio_knots(ik, bases, targets, guess, base_velocities, velocities)
    np.testing.assert_allclose(joints, expected[0], rtol=0, atol=MATCH)
    np.testing.assert_allclose(rates, expected[1], rtol=0, atol=MATCH)
    np.testing.assert_allclose(errors, expected[2], rtol=0, atol=MATCH)
    return joints, rates, errors


def _synthetic_robot(base: Robot, seed: int) -> Robot:
    """A quadruped with rotated joint placements, a rotated foot frame and every revolute joint kind.

    The real robots' placements are all unrotated and use only RX/RY/unaligned-y axes, so a mistake in
    composing placement rotations, or in the RZ axis, would pass their tests; this model exercises both.
    """
    rng = np.random.default_rng(seed)
    model = pin.Model()
    root = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "root_joint")
    kinds = [pin.JointModelRX, pin.JointModelRY, pin.JointModelRZ, None]
    frame_ids = []
    for leg, name in enumerate(("FL", "FR", "HL", "HR")):
        parent = root
        hip = np.array([0.2 if leg < 2 else -0.2, 0.05 if leg % 2 == 0 else -0.05, 0.0])
        offsets = [hip, np.array([0.0, 0.06, 0.0]), np.array([0.0, 0.0, -0.21])]
        for k in range(3):
            kind = kinds[rng.integers(len(kinds))]
            if kind is None:
                axis = rng.normal(size=3)
                joint = pin.JointModelRevoluteUnaligned(axis / np.linalg.norm(axis))
            else:
                joint = kind()
            rotation = pin.rpy.rpyToMatrix(*rng.uniform(-0.6, 0.6, 3))
            parent = model.addJoint(parent, joint, pin.SE3(rotation, offsets[k]), f"{name}_{k}")
        foot = pin.SE3(pin.rpy.rpyToMatrix(*rng.uniform(-1.0, 1.0, 3)), np.array([0.01, -0.02, -0.2]))
        frame_ids.append(model.addFrame(pin.Frame(f"{name}_foot", parent, foot, pin.FrameType.OP_FRAME)))
    q_standing = pin.neutral(model)
    q_standing[2] = 0.3
    q_standing[7:] = np.tile([0.1, 0.7, -1.4], 4)
    return dataclasses.replace(
        base,
        name=f"synthetic_{seed}",
        model=model,
        foot_frame_ids=tuple(frame_ids),
        position_lower=np.full(12, -2.5),
        position_upper=np.full(12, 2.5),
        q_standing=q_standing,
    )


# ------------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module", params=["mini_cheetah", "go1"])
def robot(request) -> Robot:
    return load_robot(request.param)


@pytest.fixture(scope="module")
def ik(robot: Robot) -> LegInverseKinematics:
    return LegInverseKinematics(robot)


# ------------------------------------------------------------------------------------ tests
@pytest.mark.slow
def test_compiled_path_is_used(ik):
    """Both robots fit the compiled path (otherwise the comparisons below would compare Pinocchio with
    itself): a kinematics extraction that disagrees with Pinocchio switches it off and fails here."""
    assert ik.fast, ik.fallback_reason
    assert ik.fallback_reason is None


def test_chain_kinematics_equal_pinocchio(robot, ik):
    """Foot positions and leg Jacobians of the extracted chains equal Pinocchio's (base at the origin)."""
    rng = np.random.default_rng(1)
    positions, jacobians = np.empty((4, 3)), np.empty((4, 3, 3))
    for _ in range(20):
        q = pin.neutral(robot.model)
        q[7:] = rng.uniform(robot.position_lower, robot.position_upper)
        _chain_kinematics(ik._joints, ik._feet, np.ascontiguousarray(q[7:]), positions, jacobians)
        expected_positions, expected_jacobians = _feet_and_jacobians(robot, q)
        np.testing.assert_allclose(positions, expected_positions, rtol=0, atol=1e-12)
        for leg in range(4):
            leg_columns = expected_jacobians[leg, :, 6 + 3 * leg : 9 + 3 * leg]
            np.testing.assert_allclose(jacobians[leg], leg_columns, rtol=0, atol=1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_batch_equals_pinocchio_on_reachable_trajectories(robot, ik, seed):
    """Smooth reachable knots, warm start near the first knot: same joints, rates and errors as the
    per-knot Pinocchio solver, and Pinocchio's kinematics of the solution reproduce the targets."""
    rng = np.random.default_rng(seed)
    configurations, targets, base_velocities, velocities, _ = _trajectory(robot, rng)
    guess = configurations[0, 7:] + rng.uniform(-0.05, 0.05, 12)
    bases = configurations[:, :7]
    joints, rates, errors = _assert_matches_pinocchio(ik, bases, targets, guess, base_velocities, velocities)
    assert np.all(errors < ik.tolerance)
    for i in range(KNOTS):
        q = np.concatenate([bases[i], joints[i]])
        positions, jacobians = _feet_and_jacobians(robot, q)
        np.testing.assert_allclose(positions, targets[i], rtol=0, atol=1e-6)
        # rates: base motion plus leg Jacobian times rates gives the foot velocities (up to the damping)
        np.testing.assert_allclose(
            jacobians @ np.concatenate([base_velocities[i], rates[i]]), velocities[i], rtol=0, atol=1e-3
        )


@pytest.mark.parametrize("seed", range(4))
def test_batch_equals_pinocchio_on_independent_random_targets(robot, ik, seed):
    """Unrelated reachable targets per knot from the standing guess (Newton may take all iterations)."""
    rng = np.random.default_rng(100 + seed)
    configurations, targets, base_velocities, velocities, _ = _trajectory(robot, rng, smooth=False)
    _assert_matches_pinocchio(ik, configurations[:, :7], targets, None, base_velocities, velocities)


def test_rates_are_the_derivative_of_the_foot_motion(robot, ik):
    """Finite-difference check with Pinocchio: moving ``q`` along ``[base velocity, rates]`` moves the feet
    with the requested velocities; and the rates equal the undamped inverse up to the damping."""
    rng = np.random.default_rng(7)
    configurations, targets, base_velocities, velocities, true_rates = _trajectory(robot, rng, n=8)
    joints, rates, _ = ik.solve_batch(
        configurations[:, :7], targets, configurations[0, 7:], base_velocities, velocities
    )
    dt = 1e-7
    data = robot.model.createData()
    for i in range(len(joints)):
        q = np.concatenate([configurations[i, :7], joints[i]])
        v = np.concatenate([base_velocities[i], rates[i]])
        pin.framesForwardKinematics(robot.model, data, pin.integrate(robot.model, q, dt * v))
        moved = np.array([data.oMf[f].translation for f in robot.foot_frame_ids])
        np.testing.assert_allclose((moved - targets[i]) / dt, velocities[i], rtol=0, atol=1e-3)
    np.testing.assert_allclose(rates, true_rates, rtol=1e-3, atol=1e-3)


def test_unreachable_targets_end_closer_on_the_standing_knee_branch(robot, ik):
    """Feet 1-10 m away: finite joints and rates inside the limits, the knees on the standing side of
    straight (``ik.branch``), a large error, and each foot closer to its target than the standing foot (the
    repair's steps only ever reduce the error; it ends at a local least of the distance, not necessarily
    the global one for such targets).

    Before the repair, whole Newton steps on the nearly singular Jacobian jumped between limit corners and
    left the feet there. Not compared with the Pinocchio path: rounding differences of 1e-16 in that
    iteration can end at another corner, from which the repair may settle on another local least.
    """
    rng = np.random.default_rng(3)
    n = 12
    bases = np.tile(robot.q_standing[:7], (n, 1))
    directions = rng.normal(size=(n, 4, 3))
    distances = rng.uniform(1.0, 10.0, (n, 4, 1))
    standing_feet = robot.foot_positions(robot.q_standing)
    targets = standing_feet[None] + distances * directions / np.linalg.norm(directions, axis=2, keepdims=True)
    velocities = rng.normal(size=(n, 4, 3))
    base_velocities = rng.normal(size=(n, 6))
    joints, rates, errors = ik.solve_batch(bases, targets, None, base_velocities, velocities)
    assert np.all(np.isfinite(joints)) and np.all(np.isfinite(rates)) and np.all(np.isfinite(errors))
    assert np.all(joints >= ik.branch[0]) and np.all(joints <= ik.branch[1])
    assert np.all(errors > 0.3)
    for i in range(n):
        positions, _ = _feet_and_jacobians(robot, np.concatenate([bases[i], joints[i]]))
        reached = np.linalg.norm(positions - targets[i], axis=1)
        assert np.all(reached < distances[i, :, 0]), (i, reached, distances[i, :, 0])


def test_the_knee_branch_is_the_standing_side_of_a_straight_knee(robot, ik):
    """``knee_branches``: the Mini Cheetah's knees bend forward from straight at 0 (its branch 0 .. pi);
    Go1's knee limits lie on one side of straight already (kept). Abduction and hip keep their limits,
    and the standing joints lie in the branch."""
    branch = knee_branches(robot)
    np.testing.assert_array_equal(branch, ik.branch)
    standing = robot.q_standing[7:]
    assert np.all(branch[0] <= standing) and np.all(standing <= branch[1])
    knees = slice(2, None, 3)
    not_knees = np.ones(12, bool)
    not_knees[knees] = False
    np.testing.assert_array_equal(branch[0, not_knees], robot.position_lower[not_knees])
    np.testing.assert_array_equal(branch[1, not_knees], robot.position_upper[not_knees])
    if robot.name == "mini_cheetah":
        np.testing.assert_allclose(branch[0, knees], 0.0, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(branch[1, knees], robot.position_upper[knees])
    else:
        np.testing.assert_array_equal(branch, np.vstack([robot.position_lower, robot.position_upper]))


def test_a_folded_swing_foot_is_reached_on_the_standing_knee_branch(mini_cheetah):
    """The flying trot's folded FR swing (``FOLDED_SWING``, the base standing): whole Newton steps from the
    standing guess ended with FR's abduction at its limit and its knee reversed (1.3, -0.67, -2.26 rad),
    16 cm from the target, and the plan tracked that. The repair reaches every foot (both paths), FR with
    its knee bent the standing way, and no joint at a limit."""
    ik = LegInverseKinematics(mini_cheetah)
    base = mini_cheetah.q_standing[None, :7]
    targets = base[:, None, :3] + FOLDED_SWING[None]
    joints, _, errors = ik.solve_batch(base, targets)
    expected = ik._solve_pinocchio(base[0], targets[0])
    np.testing.assert_allclose(joints[0], expected[0], rtol=0, atol=MATCH)
    assert errors[0] < ik.tolerance and expected[2] < ik.tolerance
    assert np.all(joints[0] > ik.branch[0]) and np.all(joints[0] < ik.branch[1])
    assert joints[0, 5] > 1.0  # FR's knee, bent as standing (1.94 rad)
    positions, _ = _feet_and_jacobians(mini_cheetah, np.concatenate([base[0], joints[0]]))
    np.testing.assert_allclose(positions, targets[0], rtol=0, atol=1e-5)


def test_a_leg_converged_with_its_knee_reversed_is_kept(mini_cheetah):
    """A guess with FR's knee reversed that reaches the target: the iteration converges there and the leg
    is kept as it is (only legs left short of their targets are repaired; repairing these too lost the
    bound-steps preset's climb, see the module's docstring), equal to the Pinocchio path."""
    ik = LegInverseKinematics(mini_cheetah)
    reversed_q = mini_cheetah.q_standing.copy()
    reversed_q[7 + 3 : 7 + 6] = [0.0, 0.8, -1.6]
    base = reversed_q[None, :7]
    targets, _ = _feet_and_jacobians(mini_cheetah, reversed_q)
    joints, _, errors = ik.solve_batch(base, targets[None], reversed_q[7:])
    assert errors[0] < ik.tolerance
    np.testing.assert_allclose(joints[0], reversed_q[7:], rtol=0, atol=1e-9)  # one Newton step of rounding
    expected = ik._solve_pinocchio(base[0], targets, reversed_q[7:])
    np.testing.assert_allclose(joints[0], expected[0], rtol=0, atol=MATCH)


def test_solve_matches_pinocchio_and_batch(robot, ik):
    """``solve`` (one knot) equals the Pinocchio path, defaults included (standing guess, zero rates
    without velocities), and equals row ``i`` of the batch when chained the same way."""
    rng = np.random.default_rng(11)
    configurations, targets, base_velocities, velocities, _ = _trajectory(robot, rng, n=5)
    bases = configurations[:, :7]
    for args in (
        (bases[0], targets[0]),
        (bases[1], targets[1], configurations[1, 7:] + 0.1),
        (bases[2], targets[2], None, base_velocities[2], velocities[2]),
        (bases[3], targets[3], None, base_velocities[3], None),
    ):
        joints, rates, error = ik.solve(*args)
        expected = ik._solve_pinocchio(*args)
        np.testing.assert_allclose(joints, expected[0], rtol=0, atol=MATCH)
        np.testing.assert_allclose(rates, expected[1], rtol=0, atol=MATCH)
        assert isinstance(error, float) and error == pytest.approx(expected[2], abs=MATCH)
    assert not np.any(ik.solve(bases[3], targets[3], None, base_velocities[3], None)[1])
    batch = ik.solve_batch(bases, targets, None, base_velocities, velocities)
    guess = None
    for i in range(5):
        joints, rates, error = ik.solve(bases[i], targets[i], guess, base_velocities[i], velocities[i])
        np.testing.assert_array_equal(joints, batch[0][i])
        np.testing.assert_array_equal(rates, batch[1][i])
        assert error == batch[2][i]
        guess = joints


def test_batch_accepts_views_and_writes_into_out(ik, robot):
    """Strided views of a state array (as the reference passes) and ``out=`` arrays give the same result;
    ``out`` is filled and returned; bad shapes raise."""
    rng = np.random.default_rng(5)
    configurations, targets, base_velocities, velocities, _ = _trajectory(robot, rng, n=6)
    state = np.zeros((6, robot.nq + robot.nv))
    state[:, :7] = configurations[:, :7]
    state[:, robot.nq : robot.nq + 6] = base_velocities
    expected = ik.solve_batch(configurations[:, :7].copy(), targets, None, base_velocities, velocities)
    out = (np.full((6, 12), np.nan), np.full((6, 12), np.nan), np.full(6, np.nan))
    result = ik.solve_batch(
        state[:, :7], targets, None, state[:, robot.nq : robot.nq + 6], velocities, out=out
    )
    assert all(a is b for a, b in zip(result, out, strict=True))
    for a, b in zip(result, expected, strict=True):
        np.testing.assert_array_equal(a, b)
    no_rates = ik.solve_batch(state[:, :7], targets, None, None, velocities)
    np.testing.assert_array_equal(no_rates[0], expected[0])
    assert not np.any(no_rates[1])
    with pytest.raises(ValueError):
        ik.solve_batch(state[:, :7], targets[:5])
    with pytest.raises(ValueError):
        ik.solve_batch(state[:, :7], targets, out=(np.zeros((6, 12)), np.zeros((6, 12)), np.zeros(5)))
    empty = ik.solve_batch(np.zeros((0, 7)), np.zeros((0, 4, 3)))
    assert [a.shape for a in empty] == [(0, 12), (0, 12), (0,)]


@pytest.mark.parametrize("seed", range(3))
def test_synthetic_robot_with_rotated_placements(mini_cheetah, seed):
    """Rotated placements and RX/RY/RZ/unaligned joints: compiled kinematics and IK equal Pinocchio's."""
    robot = _synthetic_robot(mini_cheetah, seed)
    ik = LegInverseKinematics(robot)
    assert ik.fast, ik.fallback_reason
    rng = np.random.default_rng(seed)
    configurations, targets, base_velocities, velocities, _ = _trajectory(robot, rng, n=10)
    guess = configurations[0, 7:] + 0.03
    _assert_matches_pinocchio(ik, configurations[:, :7], targets, guess, base_velocities, velocities)
    _assert_matches_pinocchio(ik, configurations[:, :7], targets, None, None, None)


def test_models_that_do_not_fit_fall_back_to_pinocchio(mini_cheetah):
    """Feet out of leg order, or a prismatic joint in a leg: a warning, the Pinocchio path, no crash."""
    swapped = dataclasses.replace(mini_cheetah, foot_frame_ids=tuple(reversed(mini_cheetah.foot_frame_ids)))
    with pytest.raises(LegChainError, match="velocity index"):
        extract_leg_chains(swapped.model, swapped.foot_frame_ids)
    with pytest.warns(RuntimeWarning, match="Pinocchio path"):
        ik = LegInverseKinematics(swapped)
    assert not ik.fast and "velocity index" in ik.fallback_reason
    bases = np.tile(swapped.q_standing[:7], (3, 1))
    targets = np.tile(swapped.foot_positions(swapped.q_standing), (3, 1, 1))
    joints, rates, errors = ik.solve_batch(bases, targets, None, np.zeros((3, 6)), np.zeros((3, 4, 3)))
    expected = _pinocchio_knots(ik, bases, targets, None, np.zeros((3, 6)), np.zeros((3, 4, 3)))
    for a, b in zip((joints, rates, errors), expected, strict=True):
        np.testing.assert_array_equal(a, b)
    assert np.all(np.isfinite(joints))

    model = pin.Model(mini_cheetah.model)
    knee = model.getJointId("FL_knee")
    model.joints[knee] = pin.JointModel(pin.JointModelPZ())
    model.joints[knee].setIndexes(knee, mini_cheetah.model.idx_qs[knee], mini_cheetah.model.idx_vs[knee])
    with pytest.raises(LegChainError, match="not a 1-DoF revolute"):
        extract_leg_chains(model, mini_cheetah.foot_frame_ids)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        prismatic = LegInverseKinematics(dataclasses.replace(mini_cheetah, model=model))
    assert not prismatic.fast and caught
    joints, _, _ = prismatic.solve(mini_cheetah.q_standing[:7], targets[0])
    assert np.all(np.isfinite(joints))


def test_a_stretched_leg_short_of_its_target_inside_the_limits_is_kept(mini_cheetah):
    """A knot of the running roll's approach pace (the reliability trial in
    ``test_contact_detection.py``, trunk 9 % heavier): HR's foot 35 cm behind its hip, past its reach. From
    the previous knot's joints the iteration flips HR's knee through straight (1.17 -> -1.95 rad) and stops
    1.1 cm short, inside the joint limits. That leg is the iteration's on both paths (a repair would put it
    straight on the standing side, and that trial's pace then fell at 0.92 s): only a leg left short at a
    joint limit is repaired."""
    ik = LegInverseKinematics(mini_cheetah)
    base = np.array(
        [
            [
                0.35999978523317239,
                3.9323284425676517e-04,
                0.25,
                0.0,
                0.0,
                5.4615680959021139e-04,
                0.99999985085635856,
            ]
        ]
    )
    feet = np.array(
        [
            [
                [0.21952195875814706, 0.09989957899961013, 0.02],
                [0.5284273620144013, -0.0995637416163877, 0.07376],
                [-0.1805342720930353, 0.09946359986456571, 0.02],
                [0.12840772414539597, -0.1000010265319384, 0.07376],
            ]
        ]
    )
    guess = np.array(
        [
            -0.06724529484120086,
            -1.1772087934447568,
            0.4519487407436593,
            0.08730296578474384,
            -1.3010617067475458,
            2.2627060102640977,
            -0.06745819593515477,
            -1.5516898505077223,
            1.1693392299233776,
            0.08730061983739859,
            -1.3970792935076437,
            2.230258798070215,
        ]
    )
    joints, _, errors = ik.solve_batch(base, feet, guess)
    expected = ik._solve_pinocchio(base[0], feet[0], guess)
    np.testing.assert_allclose(errors[0], 0.0112, rtol=0, atol=5e-4)
    np.testing.assert_allclose(joints[0, 6:9], [-0.0675, -0.058, -1.947], rtol=0, atol=1e-3)
    assert np.all(joints[0] > mini_cheetah.position_lower) and np.all(joints[0] < mini_cheetah.position_upper)
    np.testing.assert_allclose(joints[0], expected[0], rtol=0, atol=MATCH)
