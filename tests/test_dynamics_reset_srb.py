"""Impact map (22), (24), WB -> SRB transition (31), (32) and SRB dynamics (29), (30): what they compute.
Their Jacobians and the SRB knots' derivatives against finite differences: ``test_finite_differences.py``."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest

from cafe_mpc.core.interfaces import IdentityReset
from cafe_mpc.dynamics.impact import ImpactReset
from cafe_mpc.dynamics.multibody_state import MultibodyState
from cafe_mpc.dynamics.srb import SRBDynamics, SRBParameters, SRBState, quaternion_to_rotation, srb_parameters
from cafe_mpc.dynamics.transition import WholeBodyToSRB
from cafe_mpc.ocp.knots import SRBModelFactory, SRBSettings, WholeBodyModelFactory, weight_split_forces
from cafe_mpc.robots.robot import load_robot

EPS = 1e-6


PAPER_MINI_CHEETAH_SRB = SRBParameters(8.912, ((0.0616, 0.0, 0.0), (0.0, 0.2207, 0.0), (0.0, 0.0, 0.2726)))
"""The CAFE-MPC authors' Mini Cheetah SRB (8.912 kg with rotors, legs lumped; docs/settings.md): test data."""


def random_wb_state(robot, rng, spread=0.3, speed=1.0):
    q = pin.integrate(robot.model, robot.q_standing, spread * rng.standard_normal(robot.nv))
    return np.concatenate([q, speed * rng.standard_normal(robot.nv)])


def random_srb_state(rng):
    state = SRBState()
    x = state.integrate(state.zero(), rng.standard_normal(12))
    x[2] = 0.3
    return x


def analytic_reset_jacobian(reset, x):
    data = reset.create_data()
    reset.calc(data, x)
    reset.calc_diff(data, x)
    return data


# --------------------------------------------------------------------------------------------------
# Impact
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("feet", [(1, 0, 0, 0), (1, 0, 0, 1), (0, 1, 1, 1), (1, 1, 1, 1)])
def test_impact_stops_touching_feet(robot, feet):
    rng = np.random.default_rng(1)
    reset = ImpactReset(robot, feet)
    x = random_wb_state(robot, rng)
    data = analytic_reset_jacobian(reset, x)
    q, v_after = data.x_next[:19], data.x_next[19:]
    np.testing.assert_array_equal(q, x[:19])  # Eq. (24): configuration unchanged
    model, pd = robot.model, robot.model.createData()
    pin.forwardKinematics(model, pd, q, v_after)
    pin.computeJointJacobians(model, pd, q)
    jacobians = []
    for leg, frame_id in enumerate(robot.foot_frame_ids):
        velocity = pin.getFrameVelocity(model, pd, frame_id, pin.LOCAL_WORLD_ALIGNED).linear
        if feet[leg]:
            np.testing.assert_allclose(velocity, 0.0, atol=1e-10)
            jacobians.append(pin.getFrameJacobian(model, pd, frame_id, pin.LOCAL_WORLD_ALIGNED)[:3])
        else:
            assert np.linalg.norm(velocity) > 1e-3
    # Eq. (22): M (v+ - v-) = Jc' Lambda.
    mass_matrix = pin.crba(model, pd, q)
    np.testing.assert_allclose(
        mass_matrix @ (v_after - x[19:]), np.vstack(jacobians).T @ data.impulses, atol=1e-9
    )


def test_impact_requires_a_foot(robot):
    with pytest.raises(ValueError):
        ImpactReset(robot, (0, 0, 0, 0))
    with pytest.raises(ValueError):
        ImpactReset(robot, (1, 0, 0))


def test_factory_reset_maps(robot):
    factory = WholeBodyModelFactory(robot)
    assert isinstance(factory.reset_map((1, 1, 1, 1), (1, 0, 0, 1)), IdentityReset)  # take-off
    assert isinstance(factory.reset_map((0, 0, 0, 0), (0, 0, 0, 0)), IdentityReset)
    impact = factory.reset_map((1, 0, 0, 1), (1, 1, 1, 1))
    assert isinstance(impact, ImpactReset)
    assert impact.impact_feet == (True, True, True, True)  # persistent stance feet constrained too
    assert factory.touchdown_constraint((1, 0, 0, 1), (0, 1, 1, 0)).legs == (1, 2)
    assert factory.touchdown_constraint((1, 1, 1, 1), (1, 0, 0, 1)) is None


# --------------------------------------------------------------------------------------------------
# WB -> SRB transition
# --------------------------------------------------------------------------------------------------


def test_transition_projection(robot):
    rng = np.random.default_rng(2)
    projection = WholeBodyToSRB(MultibodyState(robot.model))
    x = random_wb_state(robot, rng, spread=1.0)
    data = analytic_reset_jacobian(projection, x)
    rotation = quaternion_to_rotation(x[3:7])
    np.testing.assert_allclose(data.x_next[:7], x[:7])
    np.testing.assert_allclose(data.x_next[7:10], rotation @ x[19:22])  # world linear velocity
    np.testing.assert_allclose(data.x_next[10:13], x[22:25])  # body angular velocity


# --------------------------------------------------------------------------------------------------
# SRB
# --------------------------------------------------------------------------------------------------


def test_srb_state_manifold():
    state = SRBState()
    rng = np.random.default_rng(4)
    x0, x1 = random_srb_state(rng), random_srb_state(rng)
    np.testing.assert_allclose(state.integrate(x0, state.difference(x0, x1)), x1, atol=1e-10)
    j0, j1 = state.jacobian_difference(x0, x1)
    dx = state.difference(x0, x1)
    ji0, ji1 = state.jacobian_integrate(x0, dx)
    base = state.integrate(x0, dx)
    for i, e in enumerate(np.eye(12) * EPS):
        d0 = state.difference(state.integrate(x0, e), x1) - state.difference(state.integrate(x0, -e), x1)
        d1 = state.difference(x0, state.integrate(x1, e)) - state.difference(x0, state.integrate(x1, -e))
        i0 = state.difference(base, state.integrate(state.integrate(x0, e), dx)) - state.difference(
            base, state.integrate(state.integrate(x0, -e), dx)
        )
        i1 = state.difference(base, state.integrate(x0, dx + e)) - state.difference(
            base, state.integrate(x0, dx - e)
        )
        np.testing.assert_allclose(j0[:, i], d0 / (2 * EPS), atol=1e-6)
        np.testing.assert_allclose(j1[:, i], d1 / (2 * EPS), atol=1e-6)
        np.testing.assert_allclose(ji0[:, i], i0 / (2 * EPS), atol=1e-6)
        np.testing.assert_allclose(ji1[:, i], i1 / (2 * EPS), atol=1e-6)
    # A full turn is representable: integrating 2*pi about x returns the same rotation.
    turned = state.integrate(x0, np.r_[0, 0, 0, 2 * np.pi, 0, 0, np.zeros(6)])
    np.testing.assert_allclose(state.difference(x0, turned), 0.0, atol=1e-9)


def test_srb_free_fall():
    """Eq. (29) with no contact: c_ddot = -g, omega_dot = -I^-1 (omega x I omega) (zero for omega = 0)."""
    dynamics = SRBDynamics(PAPER_MINI_CHEETAH_SRB, dt=0.05)
    data = dynamics.create_data()
    x = SRBState().zero()
    x[2] = 1.0
    x[7:10] = [0.5, 0.0, 1.0]
    dynamics.calc(data, x, 100.0 * np.ones(12), np.zeros((4, 3)), np.zeros(4))  # swing forces do nothing
    np.testing.assert_allclose(data.linear_acceleration, [0.0, 0.0, -9.81])
    np.testing.assert_allclose(data.angular_acceleration, 0.0)
    np.testing.assert_allclose(data.x_next[0:3], x[0:3] + 0.05 * x[7:10])
    np.testing.assert_allclose(data.x_next[7:10], x[7:10] + 0.05 * np.array([0.0, 0.0, -9.81]))


def test_srb_static_balance():
    """Weight split over four feet placed symmetrically about the COM: no acceleration at all."""
    parameters = PAPER_MINI_CHEETAH_SRB
    dynamics = SRBDynamics(parameters, dt=0.05)
    data = dynamics.create_data()
    x = SRBState().zero()
    x[0:3] = [0.1, -0.2, 0.25]
    x[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.0, 0.0, 0.7)).coeffs()
    feet = x[0:3] + np.array([[0.2, 0.1, -0.25], [0.2, -0.1, -0.25], [-0.2, 0.1, -0.25], [-0.2, -0.1, -0.25]])
    forces = weight_split_forces(np.ones(4), parameters.mass * parameters.gravity)
    dynamics.calc(data, x, forces, feet, np.ones(4))
    np.testing.assert_allclose(data.linear_acceleration, 0.0, atol=1e-12)
    np.testing.assert_allclose(data.angular_acceleration, 0.0, atol=1e-12)
    np.testing.assert_allclose(data.x_next, x, atol=1e-12)


def test_srb_parameters_validation():
    with pytest.raises(ValueError):
        replace(PAPER_MINI_CHEETAH_SRB, mass=0.0)
    with pytest.raises(ValueError):
        replace(PAPER_MINI_CHEETAH_SRB, inertia=((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0)))
    with pytest.raises(ValueError):
        SRBDynamics(PAPER_MINI_CHEETAH_SRB, dt=0.0)
    with pytest.raises(ValueError, match="needs the robot"):
        SRBModelFactory()


def test_srb_knot_force_regularisation_and_its_target():
    """Eq. (28): the GRF term is ``0.5 dt w (u - f_ref)^2`` (regular weight 0.01, dt 0.05); the target is the
    weight split over the stance feet, zero on swing feet."""
    rng = np.random.default_rng(6)
    factory = SRBModelFactory(SRBSettings(parameters=PAPER_MINI_CHEETAH_SRB))
    reference = factory.reference(random_srb_state(rng), rng.standard_normal((4, 3)), (1, 0, 0, 1))
    knot = factory.running_knot(reference)
    data = knot.create_data()
    x, u = random_srb_state(rng), 10.0 * rng.standard_normal(knot.nu)
    knot.calc(data, x, u)
    knot.calc_diff(data, x, u)
    np.testing.assert_allclose(np.diag(data.Luu), 0.05 * 0.01)
    weight = factory.settings.parameters.mass * 9.81
    np.testing.assert_allclose(reference.forces.reshape(4, 3)[:, 2], [weight / 2, 0, 0, weight / 2])


def test_srb_parameters_come_from_the_robot_model(robot):
    """Legs lumped at the standing pose, rotors added: the Mini Cheetah's 8.252 kg of links + 12 x 0.055 kg
    rotors = the authors' 8.912 kg; the inertia is the whole robot's composite inertia about its CoM."""
    parameters = srb_parameters(robot)
    assert robot.rotor_mass == pytest.approx(0.055)
    assert parameters.mass == pytest.approx(8.912, abs=1e-9)
    inertia = parameters.inertia_matrix
    np.testing.assert_allclose(inertia, inertia.T)
    assert np.all(np.linalg.eigvalsh(inertia) > 0)
    # legs add to the trunk's own inertia (body diag(0.011253, 0.036203, 0.042673)) about every axis
    assert np.all(np.diag(inertia) > [0.05, 0.2, 0.25])
    assert abs(inertia[0, 1]) < 1e-9 and abs(inertia[1, 2]) < 1e-9  # left/right mirror symmetry
    # independent check without rotors: parallel-axis sum over the bodies
    bare = replace(robot, rotor_mass=0.0)
    model, data = bare.model, bare.model.createData()
    q = bare.q_standing.copy()
    pin.forwardKinematics(model, data, q)
    com = pin.centerOfMass(model, data, q)
    expected = np.zeros((3, 3))
    for joint in range(1, model.njoints):
        body = model.inertias[joint]
        rotation = data.oMi[joint].rotation
        offset = data.oMi[joint].act(body.lever) - com
        expected += rotation @ body.inertia @ rotation.T
        expected += body.mass * (offset @ offset * np.eye(3) - np.outer(offset, offset))
    np.testing.assert_allclose(srb_parameters(bare).inertia_matrix, expected, atol=1e-12)
    assert srb_parameters(bare).mass == pytest.approx(bare.total_mass)


@pytest.mark.slow
def test_srb_parameters_of_go1_are_its_own():
    go1 = load_robot("go1")
    parameters = srb_parameters(go1)
    assert go1.rotor_mass == 0.0  # Go1's URDF has its rotors as links
    assert parameters.mass == pytest.approx(go1.total_mass)
    assert parameters.mass > 12.0 and parameters.mass != pytest.approx(PAPER_MINI_CHEETAH_SRB.mass)
    assert not np.allclose(parameters.inertia_matrix, PAPER_MINI_CHEETAH_SRB.inertia_matrix, atol=1e-2)


def test_compiled_so3_maths_matches_pinocchio():
    """The compiled SO(3) functions of the SRB kernels equal Pinocchio's, also near 0 and near pi."""
    from cafe_mpc.dynamics import srb_kernels as k

    rng = np.random.default_rng(31)
    vectors = [rng.standard_normal(3) * scale for scale in (1e-9, 1e-5, 0.3, 1.0, 2.5) for _ in range(4)]
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    vectors += [axis * (np.pi - eps) for eps in (1e-2, 1e-4, 1e-7)] + [axis * np.pi]
    out3, out33 = np.zeros(3), np.zeros((3, 3))
    for w in vectors:
        k.exp3(w, out33)
        np.testing.assert_allclose(out33, pin.exp3(w), atol=1e-12)
        rotation = pin.exp3(w)
        theta = k.log3(rotation, out3)
        np.testing.assert_allclose(pin.exp3(out3), rotation, atol=1e-9)  # the log is a log of R
        if np.linalg.norm(w) < np.pi - 1e-6:
            np.testing.assert_allclose(out3, pin.log3(rotation), atol=1e-9)
            k.jlog3(theta, out3, out33)
            np.testing.assert_allclose(out33, pin.Jlog3(rotation), atol=1e-7)
        k.jexp3(w, out33)
        np.testing.assert_allclose(out33, pin.Jexp3(w), atol=1e-10)
        quaternion = pin.Quaternion(pin.exp3(rng.standard_normal(3))).coeffs()
        k.quaternion_to_rotation(quaternion, out33)
        np.testing.assert_allclose(out33, pin.Quaternion(quaternion).toRotationMatrix(), atol=1e-14)
        stepped = np.zeros(4)
        k.quaternion_step(quaternion, w, stepped)
        expected = pin.Quaternion(quaternion).toRotationMatrix() @ pin.exp3(w)
        np.testing.assert_allclose(pin.Quaternion(stepped).toRotationMatrix(), expected, atol=1e-12)
