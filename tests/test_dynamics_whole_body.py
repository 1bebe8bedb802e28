"""Whole-body state manifold and KKT contact dynamics (paper Eqs. (19)-(23)) against finite differences,
Crocoddyl and the MuJoCo plant (the dynamics' Jacobians and contact-force Jacobians in every contact mode:
``tests/test_finite_differences.py``, through the whole-body knots)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from cafe_mpc.dynamics.multibody_state import MultibodyState
from cafe_mpc.dynamics.whole_body import ContactDynamicsError, WholeBodyDynamics

EPS = 1e-6


def random_state(robot, rng, spread=0.3, speed=1.0):
    q = pin.integrate(robot.model, robot.q_standing, spread * rng.standard_normal(robot.nv))
    return np.concatenate([q, speed * rng.standard_normal(robot.nv)])


# --------------------------------------------------------------------------------------------------
# State manifold
# --------------------------------------------------------------------------------------------------


def test_multibody_state_round_trip_and_jacobians(robot):
    state = MultibodyState(robot.model)
    rng = np.random.default_rng(0)
    x0, x1 = random_state(robot, rng, 1.0), random_state(robot, rng, 1.0)
    assert (state.nx, state.ndx) == (37, 36)
    np.testing.assert_allclose(state.integrate(x0, state.difference(x0, x1)), x1, atol=1e-10)
    j0, j1 = state.jacobian_difference(x0, x1)
    ji0, ji1 = state.jacobian_integrate(x0, state.difference(x0, x1))
    fd0, fd1, fdi0, fdi1 = (np.zeros((36, 36)) for _ in range(4))
    dx = state.difference(x0, x1)
    for i, e in enumerate(np.eye(36) * EPS):
        fd0[:, i] = (
            state.difference(state.integrate(x0, e), x1) - state.difference(state.integrate(x0, -e), x1)
        ) / (2 * EPS)
        fd1[:, i] = (
            state.difference(x0, state.integrate(x1, e)) - state.difference(x0, state.integrate(x1, -e))
        ) / (2 * EPS)
        base = state.integrate(x0, dx)
        fdi0[:, i] = (
            state.difference(base, state.integrate(state.integrate(x0, e), dx))
            - state.difference(base, state.integrate(state.integrate(x0, -e), dx))
        ) / (2 * EPS)
        fdi1[:, i] = (
            state.difference(base, state.integrate(x0, dx + e))
            - state.difference(base, state.integrate(x0, dx - e))
        ) / (2 * EPS)
    for analytic, numeric in ((j0, fd0), (j1, fd1), (ji0, fdi0), (ji1, fdi1)):
        np.testing.assert_allclose(analytic, numeric, atol=1e-6)


def test_full_roll_is_representable(robot):
    """A 2*pi roll is a tangent step of 2*pi about x: it integrates back to the same orientation (a
    quaternion of sign -1) and the difference between the two is zero, no Euler-angle wrap."""
    state = MultibodyState(robot.model)
    x = robot.x_standing.copy()
    step = np.zeros(36)
    step[3] = 2 * np.pi
    rolled = state.integrate(x, step)
    np.testing.assert_allclose(np.abs(rolled[3:7]), np.abs(x[3:7]), atol=1e-12)
    np.testing.assert_allclose(state.difference(x, rolled), 0.0, atol=1e-12)
    half = state.integrate(x, step / 2)
    assert np.linalg.norm(state.difference(x, half)[3:6]) == pytest.approx(np.pi, abs=1e-9)


# --------------------------------------------------------------------------------------------------
# Integration
# --------------------------------------------------------------------------------------------------


def test_explicit_and_semi_implicit_steps(robot):
    """Eq. (23): q+ = q ⊕ v dt (explicit) vs q+ = q ⊕ v+ dt (semi-implicit); v+ = v + a dt in both."""
    rng = np.random.default_rng(3)
    x, u = random_state(robot, rng), rng.standard_normal(12)
    explicit = WholeBodyDynamics(robot, (1, 0, 1, 0), 0.01)
    semi = WholeBodyDynamics(robot, (1, 0, 1, 0), 0.01, integration="semi_implicit")
    de, ds = explicit.create_data(), semi.create_data()
    explicit.calc(de, x, u)
    semi.calc(ds, x, u)
    np.testing.assert_allclose(de.acceleration, ds.acceleration)
    np.testing.assert_allclose(de.x_next[19:], x[19:] + 0.01 * de.acceleration)
    np.testing.assert_allclose(de.x_next[:19], pin.integrate(robot.model, x[:19], 0.01 * x[19:]))
    np.testing.assert_allclose(ds.x_next[:19], pin.integrate(robot.model, x[:19], 0.01 * ds.x_next[19:]))


# --------------------------------------------------------------------------------------------------
# Physics of the contact dynamics
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("stance", [(1, 0, 0, 0), (1, 0, 0, 1), (1, 1, 1, 0), (1, 1, 1, 1)])
def test_stance_feet_follow_baumgarte_and_equations_of_motion(robot, stance):
    """Eq. (20): stance-foot acceleration = -alpha * foot velocity; Eq. (19): M a + n = S' tau + Jc' F."""
    rng = np.random.default_rng(11)
    alpha = 10.0
    dynamics = WholeBodyDynamics(robot, stance, 0.01, baumgarte_alpha=alpha)
    data = dynamics.create_data()
    x, u = random_state(robot, rng), 2.0 * rng.standard_normal(12)
    dynamics.calc(data, x, u)
    model, pd = robot.model, robot.model.createData()
    q, v, a = x[:19], x[19:], data.acceleration
    pin.forwardKinematics(model, pd, q, v, a)
    pin.computeJointJacobians(model, pd, q)
    pin.updateFramePlacements(model, pd)
    contact_jacobian = []
    for leg, frame_id in enumerate(robot.foot_frame_ids):
        if not stance[leg]:
            continue
        acceleration = pin.getFrameClassicalAcceleration(model, pd, frame_id, pin.LOCAL_WORLD_ALIGNED).linear
        velocity = pin.getFrameVelocity(model, pd, frame_id, pin.LOCAL_WORLD_ALIGNED).linear
        assert np.linalg.norm(velocity) > 1e-3  # non-trivial check
        np.testing.assert_allclose(acceleration, -alpha * velocity, atol=1e-8)
        contact_jacobian.append(pin.getFrameJacobian(model, pd, frame_id, pin.LOCAL_WORLD_ALIGNED)[:3])
    tau = np.concatenate([np.zeros(6), u])
    residual = pin.rnea(model, pd, q, v, a) - tau - np.vstack(contact_jacobian).T @ data.forces
    np.testing.assert_allclose(residual, 0.0, atol=1e-8)


def test_standing_forces_carry_the_weight(robot):
    """At rest with gravity-compensating torques the four vertical forces sum to m g."""
    dynamics = WholeBodyDynamics(robot, (1, 1, 1, 1), 0.01)
    data = dynamics.create_data()
    x = robot.x_standing
    # Static torques: least-squares split of gravity over the four feet, joint torques from the statics.
    model, pd = robot.model, robot.model.createData()
    gravity = pin.computeGeneralizedGravity(model, pd, x[:19])
    pin.computeJointJacobians(model, pd, x[:19])
    jc = np.vstack(
        [pin.getFrameJacobian(model, pd, f, pin.LOCAL_WORLD_ALIGNED)[:3] for f in robot.foot_frame_ids]
    )
    forces = np.linalg.lstsq(jc[:, :6].T, gravity[:6], rcond=None)[0]
    tau = gravity[6:] - jc[:, 6:].T @ forces
    dynamics.calc(data, x, tau)
    np.testing.assert_allclose(data.acceleration, 0.0, atol=1e-8)
    assert data.forces[2::3].sum() == pytest.approx(robot.total_mass * 9.81, rel=1e-9)


def test_flight_is_free_floating(robot):
    """No stance foot: the base centre of mass falls with -g whatever the joint torques."""
    dynamics = WholeBodyDynamics(robot, (0, 0, 0, 0), 0.01)
    data = dynamics.create_data()
    rng = np.random.default_rng(5)
    x, u = random_state(robot, rng), 5.0 * rng.standard_normal(12)
    dynamics.calc(data, x, u)
    model, pd = robot.model, robot.model.createData()
    pin.centerOfMass(model, pd, x[:19], x[19:], data.acceleration)
    np.testing.assert_allclose(pd.acom[0], [0.0, 0.0, -9.81], atol=1e-9)


def test_damping_regularised_solution_matches_exact(robot):
    rng = np.random.default_rng(9)
    x, u = random_state(robot, rng), rng.standard_normal(12)
    exact = WholeBodyDynamics(robot, (1, 1, 1, 1), 0.01)
    damped = WholeBodyDynamics(robot, (1, 1, 1, 1), 0.01, damping=1e-8)
    de, dd = exact.create_data(), damped.create_data()
    exact.calc(de, x, u)
    damped.calc(dd, x, u)
    damped.calc_diff(dd, x, u)
    np.testing.assert_allclose(dd.acceleration, de.acceleration, rtol=1e-6, atol=1e-6)
    assert np.all(np.isfinite(dd.Fx))


def test_non_finite_input_raises_instead_of_nan(robot):
    dynamics = WholeBodyDynamics(robot, (1, 1, 0, 0), 0.01)
    data = dynamics.create_data()
    x = robot.x_standing.copy()
    x[20] = np.nan
    with pytest.raises(ContactDynamicsError):
        dynamics.calc(data, x, np.zeros(12))


@pytest.mark.parametrize(
    "kwargs",
    [
        {"stance": (1, 1, 1)},
        {"stance": (1, 1, 1, 1, 0)},
        {"stance": (1, 2, 1, 1)},
        {"stance": (1, 1, 1, 1), "dt": 0.0},
        {"stance": (1, 1, 1, 1), "dt": float("nan")},
        {"stance": (1, 1, 1, 1), "integration": "rk4"},
        {"stance": (1, 1, 1, 1), "damping": -1.0},
    ],
)
def test_invalid_construction_raises(robot, kwargs):
    arguments = {"dt": 0.01, **kwargs}
    with pytest.raises(ValueError):
        WholeBodyDynamics(robot, **arguments)


# --------------------------------------------------------------------------------------------------
# Cross-checks with Crocoddyl and MuJoCo
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("stance", [(0, 0, 0, 0), (1, 0, 0, 1), (1, 1, 1, 1)])
def test_semi_implicit_matches_crocoddyl(robot, stance):
    """Same problem as Crocoddyl's contact forward dynamics (ContactModel3D, LOCAL_WORLD_ALIGNED, gains
    [0, alpha]) wrapped in IntegratedActionModelEuler: identical next state and Jacobians."""
    from cafe_mpc_lab.bench.crocoddyl_peer import crocoddyl_contact_action

    integrated = crocoddyl_contact_action(robot, stance, 0.01)
    croc_data = integrated.createData()
    rng = np.random.default_rng(21)
    x, u = random_state(robot, rng), 2.0 * rng.standard_normal(12)
    integrated.calc(croc_data, x, u)
    integrated.calcDiff(croc_data, x, u)
    dynamics = WholeBodyDynamics(robot, stance, 0.01, integration="semi_implicit")
    data = dynamics.create_data()
    dynamics.calc(data, x, u)
    dynamics.calc_diff(data, x, u)
    np.testing.assert_allclose(data.x_next, croc_data.xnext, atol=1e-10)
    np.testing.assert_allclose(data.Fx, croc_data.Fx, atol=1e-8)
    np.testing.assert_allclose(data.Fu, croc_data.Fu, atol=1e-8)


def test_free_fall_matches_mujoco_plant(robot):
    """0.1 s of free flight at 1 ms (plant armature = the model's rotor inertia, no damping or friction):
    the planning model and MuJoCo agree. MuJoCo's free joint: qpos [pos, quat wxyz], qvel [world linear,
    body angular]."""
    mujoco = pytest.importorskip("mujoco")
    plant = mujoco.MjModel.from_xml_string(robot.mjcf)
    plant.dof_armature[:] = 0.0
    plant.dof_armature[6:] = robot.model.armature[6:]
    plant.dof_damping[:] = 0.0
    plant.dof_frictionloss[:] = 0.0
    plant.opt.timestep = 0.001
    plant_data = mujoco.MjData(plant)
    rng = np.random.default_rng(4)
    q0 = robot.q_standing.copy()
    q0[2] = 2.0
    q0[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.2, -0.1, 0.3)).coeffs()
    v0 = np.concatenate([[0.3, -0.2, 0.5, 1.0, -0.5, 0.8], 0.5 * rng.standard_normal(12)])
    rotation = pin.Quaternion(q0[3:7]).toRotationMatrix()
    plant_data.qpos[:] = np.concatenate([q0[:3], [q0[6]], q0[3:6], q0[7:]])
    plant_data.qvel[:] = np.concatenate([rotation @ v0[:3], v0[3:]])
    for _ in range(100):
        mujoco.mj_step(plant, plant_data)
    assert plant_data.ncon == 0
    q_plant = np.concatenate(
        [plant_data.qpos[:3], plant_data.qpos[4:7], plant_data.qpos[3:4], plant_data.qpos[7:]]
    )
    rotation_plant = pin.Quaternion(q_plant[3:7]).toRotationMatrix()
    v_plant = np.concatenate([rotation_plant.T @ plant_data.qvel[:3], plant_data.qvel[3:]])

    for integration, tolerance in (("semi_implicit", 1e-4), ("explicit", 2e-3)):
        dynamics = WholeBodyDynamics(robot, (0, 0, 0, 0), 0.001, integration=integration)
        data = dynamics.create_data()
        x = np.concatenate([q0, v0])
        for _ in range(100):
            dynamics.calc(data, x, np.zeros(12))
            x = data.x_next.copy()
        assert np.abs(pin.difference(robot.model, x[:19], q_plant)).max() < tolerance, integration
        assert np.abs(x[19:] - v_plant).max() < 5e-3, integration
        assert x[2] < q0[2] + 0.05  # it fell (upward initial speed 0.5 m/s is spent after ~0.05 s)


# --------------------------------------------------------------------------------------------------
# Foot kinematics
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("robot_name", ["mini_cheetah", "go2"])
def test_foot_kinematics_jacobians_match_pinocchio_and_finite_differences(robot_name):
    """The compiled foot Jacobians equal ``getPointVelocityDerivatives`` (LOCAL_WORLD_ALIGNED) and central
    differences of the foot positions and velocities on the state manifold."""
    from cafe_mpc.dynamics.kinematics import FootKinematics
    from cafe_mpc.robots.robot import load_robot

    robot = load_robot(robot_name)
    model, nq, nv = robot.model, robot.nq, robot.nv
    kinematics = FootKinematics(robot, position_legs=[0, 2], velocity_legs=[1, 2, 3])
    data = kinematics.create_data()
    reference = model.createData()
    rng = np.random.default_rng(3)
    state = MultibodyState(model)
    lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    for _ in range(4):
        x = random_state(robot, rng, spread=0.6, speed=2.0)
        q, v = x[:nq], x[nq:]
        kinematics.calc(data, q, v)
        kinematics.calc_diff(data, q, v)
        pin.computeForwardKinematicsDerivatives(model, reference, q, v, np.zeros(nv))
        for leg in range(4):
            frame = model.frames[robot.foot_frame_ids[leg]]
            dv_dq, dv_dv = pin.getPointVelocityDerivatives(
                model, reference, frame.parentJoint, frame.placement, lwa
            )
            np.testing.assert_allclose(data.position_jacobians[leg], dv_dv, atol=1e-12)
            if leg in (1, 2, 3):
                np.testing.assert_allclose(data.velocity_dq[leg], dv_dq, atol=1e-12)
        fd_position = np.zeros((4, 3, nv))
        fd_velocity = np.zeros((4, 3, nv))
        probe = kinematics.create_data()
        for i, e in enumerate(np.eye(nv) * EPS):
            plus, minus = (
                state.integrate(x, np.concatenate([e, 0 * e])),
                state.integrate(x, np.concatenate([-e, 0 * e])),
            )
            kinematics.calc(probe, plus[:nq], plus[nq:])
            p_plus, v_plus = probe.positions.copy(), probe.velocities.copy()
            kinematics.calc(probe, minus[:nq], minus[nq:])
            fd_position[:, :, i] = (p_plus - probe.positions) / (2 * EPS)
            fd_velocity[:, :, i] = (v_plus - probe.velocities) / (2 * EPS)
        for leg in (0, 1, 2, 3):
            np.testing.assert_allclose(data.position_jacobians[leg], fd_position[leg], atol=1e-6)
        for leg in (1, 2, 3):
            np.testing.assert_allclose(data.velocity_dq[leg], fd_velocity[leg], atol=1e-6)


# --------------------------------------------------------------------------------------------------
# Compiled free-flyer step and its Jacobians
# --------------------------------------------------------------------------------------------------


def _skew(a: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _right_jacobian_series(xi: np.ndarray, shift: int) -> np.ndarray:
    """``sum_k (-ad xi)^k / (k + shift)!`` on se(3) (linear, angular): ``Ad(exp6(xi)^-1)`` for ``shift = 0``,
    the right Jacobian ``Jexp6(xi)`` for ``shift = 1``; independent of any closed form."""
    ad = np.zeros((6, 6))
    ad[:3, :3] = ad[3:, 3:] = _skew(xi[3:])
    ad[:3, 3:] = _skew(xi[:3])
    out, term, factorial = np.zeros((6, 6)), np.eye(6), 1.0
    for k in range(60):
        factorial *= max(1, k + shift)
        out += term / factorial
        term = term @ -ad
    return out


ANGLES = [0.0, 1e-9, 1e-5, 1.3e-4, 1e-3, 9e-3, 1.1e-2, 0.1, 0.29, 0.31, 1.0, 2.0, 3.0]


def test_free_flyer_integrate_and_difference_jacobians_are_exact(robot):
    """The compiled free-flyer blocks of ``dIntegrate`` (``Ad(exp6(s)^-1)``, ``Jexp6(s)``) and of
    ``dDifference`` (``Jlog6``) equal the power series of ``ad`` at every rotation angle (Pinocchio's closed
    forms lose up to 1e-5 between 1e-4 and 1e-1 rad), and Pinocchio's where its closed forms are accurate."""
    from cafe_mpc.dynamics.kernels import free_flyer_difference_jacobian, free_flyer_integrate_jacobians

    rng = np.random.default_rng(5)
    model = robot.model
    for angle in ANGLES:
        for _ in range(3):
            step = rng.standard_normal(robot.nv)
            axis = rng.standard_normal(3)
            step[3:6] = angle * axis / np.linalg.norm(axis)
            dq_block, dstep_block = np.zeros((6, 6)), np.zeros((6, 6))
            free_flyer_integrate_jacobians(step, dq_block, dstep_block)
            np.testing.assert_allclose(dq_block, _right_jacobian_series(step[:6], 0), rtol=0, atol=1e-14)
            np.testing.assert_allclose(dstep_block, _right_jacobian_series(step[:6], 1), rtol=0, atol=1e-14)
            q0 = random_state(robot, rng, spread=1.0)[: robot.nq]
            q1 = pin.integrate(model, q0, step)
            jacobian = np.zeros((6, 6))
            free_flyer_difference_jacobian(q0, q1, jacobian)
            exact = np.linalg.inv(_right_jacobian_series(pin.difference(model, q0, q1)[:6], 1))
            np.testing.assert_allclose(jacobian, exact, rtol=0, atol=1e-11)
            if angle < 1e-4 or angle > 0.5:
                dq, dstep = pin.dIntegrate(model, q0, step)
                np.testing.assert_allclose(dq_block, dq[:6, :6], rtol=0, atol=1e-12)
                np.testing.assert_allclose(dstep_block, dstep[:6, :6], rtol=0, atol=1e-12)
                reference = pin.dDifference(model, q0, q1, pin.ArgumentPosition.ARG1)[:6, :6]
                np.testing.assert_allclose(jacobian, reference, rtol=0, atol=1e-11)


@pytest.mark.parametrize("integration", ["explicit", "semi_implicit"])
@pytest.mark.parametrize("stance", [(0, 0, 0, 0), (1, 0, 0, 1), (1, 1, 1, 1)])
def test_compiled_free_flyer_step_matches_pinocchio_integrate(robot, stance, integration):
    """The compiled step and Jacobians of a free-flyer robot equal the generic path through ``pin.integrate``
    and ``pin.dIntegrate`` (here with rotation steps where Pinocchio's ``Jexp6`` is accurate)."""
    rng = np.random.default_rng(2)
    compiled = WholeBodyDynamics(robot, stance, dt=0.05, integration=integration)
    generic = WholeBodyDynamics(robot, stance, dt=0.05, integration=integration)
    generic._free_flyer = False
    assert compiled._free_flyer
    dc, dg = compiled.create_data(), generic.create_data()
    for _ in range(3):
        x, u = random_state(robot, rng, speed=20.0), 3.0 * rng.standard_normal(12)
        for dynamics, data in ((compiled, dc), (generic, dg)):
            dynamics.calc(data, x, u)
            dynamics.calc_diff(data, x, u)
        assert np.linalg.norm(dc._step[3:6]) > 0.5
        np.testing.assert_allclose(dc.x_next, dg.x_next, rtol=0, atol=1e-13)
        np.testing.assert_array_equal(dc.acceleration, dg.acceleration)
        np.testing.assert_array_equal(dc.forces, dg.forces)
        scale = np.abs(dg.Fx).max()
        np.testing.assert_allclose(dc.Fx, dg.Fx, rtol=0, atol=1e-13 * scale)
        np.testing.assert_allclose(dc.Fu, dg.Fu, rtol=0, atol=1e-13 * np.abs(dg.Fu).max())


def test_compiled_difference_jacobian_products_match_pinocchio_and_series(robot):
    """``∂(x1 ⊖ x0)/∂x1 [left | right]`` (the solver's transport of ``[Fx | Fu]``) and ``∂(x1 ⊖ x0)/∂x1 M``
    of the free-flyer state equal Pinocchio's ``dDifference`` path at large rotations and the exact
    ``Jlog6`` (inverse of the power series of ``ad``) at small ones."""
    rng = np.random.default_rng(8)
    compiled, generic = MultibodyState(robot.model), MultibodyState(robot.model)
    generic.free_flyer_root = False
    assert compiled.free_flyer_root
    left, right = rng.standard_normal((36, 36)), rng.standard_normal((36, 12))
    for angle in (1e-3, 2e-2, 0.7, 2.0):
        x0 = random_state(robot, rng, spread=1.0)
        step = np.concatenate([rng.standard_normal(18), np.zeros(18)])
        axis = rng.standard_normal(3)
        step[3:6] = angle * axis / np.linalg.norm(axis)
        x1 = compiled.integrate(x0, step)
        out, expected = np.zeros((36, 48)), np.zeros((36, 48))
        compiled.difference_jacobian_product_stacked(x0, x1, left, right, out)
        product, expected_product = np.zeros((36, 36)), np.zeros((36, 36))
        compiled.difference_jacobian_product(x0, x1, left, product)
        if angle > 0.5:
            generic.difference_jacobian_product_stacked(x0, x1, left, right, expected)
            generic.difference_jacobian_product(x0, x1, left, expected_product)
        else:
            jacobian = np.eye(36)
            jacobian[:6, :6] = np.linalg.inv(_right_jacobian_series(compiled.difference(x0, x1)[:6], 1))
            expected = jacobian @ np.hstack([left, right])
            expected_product = jacobian @ left
        np.testing.assert_allclose(out, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
        np.testing.assert_allclose(product, expected_product, rtol=0, atol=1e-12 * np.abs(expected).max())


def _spinning_body_flight(integration: str, dt: float = 0.01, duration: float = 0.45) -> tuple:
    """A single rigid body (centre of mass at its origin) thrown at 0.2 m/s forward and 1.6 m/s up while
    pitching at 11 rad/s about a principal axis, stepped by the compiled kernels of ``integration`` with
    Pinocchio's free-fall acceleration: (final world velocity, final position)."""
    from cafe_mpc.dynamics.kernels import euler_step, world_velocity_euler_step

    model = pin.Model()
    joint = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    model.appendBodyToJoint(
        joint, pin.Inertia(3.3, np.zeros(3), np.diag([0.011, 0.036, 0.042])), pin.SE3.Identity()
    )
    data = model.createData()
    x = np.concatenate([pin.neutral(model), np.zeros(6)])
    x[7:10] = (0.2, 0.0, 1.6)  # the base frame starts aligned with the world
    x[11] = -11.0
    x_next, step, acceleration, no_forces = np.zeros(13), np.zeros(6), np.zeros(6), np.zeros(0)
    for _ in range(round(duration / dt)):
        a = pin.aba(model, data, x[:7], x[7:], np.zeros(6))
        if integration == "explicit_world":
            ok = world_velocity_euler_step(a, no_forces, x, dt, 7, acceleration, no_forces, x_next, step)
        else:
            ok = euler_step(a, no_forces, x, dt, True, 7, True, acceleration, no_forces, x_next, step)
        assert ok
        x = x_next.copy()
    rotation = pin.Quaternion(x[3:7]).toRotationMatrix()
    return rotation @ x[7:10], x[:3]


def test_world_velocity_step_keeps_a_spinning_body_momentum_in_flight():
    """A body spinning at 11 rad/s in free fall keeps its horizontal velocity with ``explicit_world`` over
    a 0.45 s flight; Eq. (23)'s body-frame step inflates it by about 0.6 m/s at dt = 0.01 s."""
    velocity, position = _spinning_body_flight("explicit_world")
    assert abs(velocity[0] - 0.2) < 1e-3 and abs(velocity[1]) < 1e-9
    assert velocity[2] == pytest.approx(1.6 - 9.81 * 0.45, abs=1e-9)
    # the position: the explicit step's usual drift under gravity, g dt T / 2 = 2.2 cm, no more
    assert position[0] == pytest.approx(0.2 * 0.45, abs=1e-3)
    assert position[2] == pytest.approx(1.6 * 0.45 - 9.81 * 0.45**2 / 2 + 9.81 * 0.01 * 0.45 / 2, abs=1e-3)
    explicit_velocity, explicit_position = _spinning_body_flight("explicit")
    assert explicit_velocity[0] - 0.2 > 0.5 and explicit_position[2] - position[2] > 0.03


def test_world_velocity_step_needs_a_free_flyer(robot, monkeypatch):
    """``explicit_world`` steps the base as a free flyer: another root is refused at construction."""
    import cafe_mpc.dynamics.whole_body as whole_body

    class GenericState(MultibodyState):
        def __init__(self, model) -> None:
            super().__init__(model)
            self.free_flyer_root = False

    assert WholeBodyDynamics(robot, (1, 0, 0, 1), 0.01, integration="explicit_world")._free_flyer
    monkeypatch.setattr(whole_body, "MultibodyState", GenericState)
    with pytest.raises(ValueError, match="free-flyer root"):
        WholeBodyDynamics(robot, (1, 0, 0, 1), 0.01, integration="explicit_world")
