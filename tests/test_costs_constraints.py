"""Cost terms (18) and constraints (25)-(27) of the term-by-term reference knot against finite differences,
the relaxed barrier, the touchdown constraint's values, and the fused whole-body knot against the
term-by-term evaluation it replaced (the fused knots' derivatives: ``test_finite_differences.py``)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from cafe_mpc.config.weights import SRBWeights, WholeBodyWeights, base_weights_to_tangent
from cafe_mpc.ocp.barrier import RelaxedBarrier
from cafe_mpc.ocp.constraints import TouchdownFootHeight, WholeBodyConstraintSettings, friction_pyramid_matrix
from cafe_mpc.ocp.kernels import relaxed_barrier
from cafe_mpc.ocp.knots import WholeBodyKnot, WholeBodyModelFactory, WholeBodyReference, WholeBodySettings
from term_reference import (
    StateTrackingCost,
    SwingFootPositionCost,
    SwingFootVelocityCost,
    TermKnot,
    TorqueRegularisationCost,
    term_knot,
)

EPS = 1e-6


@pytest.fixture(scope="module")
def factory(robot):
    return WholeBodyModelFactory(robot)


def random_state(robot, rng, spread=0.3, speed=1.0):
    q = pin.integrate(robot.model, robot.q_standing, spread * rng.standard_normal(robot.nv))
    return np.concatenate([q, speed * rng.standard_normal(robot.nv)])


def random_reference(robot, rng):
    return WholeBodyReference(
        random_state(robot, rng, spread=1.0),
        foot_positions=rng.standard_normal((4, 3)),
        foot_velocities=rng.standard_normal((4, 3)),
        torque=rng.standard_normal(12),
    )


def knot_with_terms(robot, stance, costs=(), constraints=(), reference=None, running=True, factory=None):
    """A term-by-term reference knot (``tests/term_reference.py``) with exactly these terms."""
    factory = factory or WholeBodyModelFactory(robot)
    dynamics = factory.dynamics(stance) if running else None
    reference = reference or factory.default_reference()
    return TermKnot(robot, dynamics, costs, constraints, reference, stance=stance)


def reference_knot(robot, stance, running=True, settings=None, reference=None):
    """The term-by-term knot with the same content as a default factory's fused knot."""
    settings = settings or WholeBodySettings()
    reference = reference or WholeBodyModelFactory(robot).default_reference()
    weights = settings.running_weights if running else settings.terminal_weights
    return term_knot(
        robot, stance, weights, settings.constraints, reference, settings.dt, settings.base_error, running
    )


def fd_of(function, x, u, state, nu):
    """Central differences of a vector function of (x, u) w.r.t. the tangent of x and u."""
    base = np.atleast_1d(function(x, u))
    jx = np.zeros((base.size, state.ndx))
    ju = np.zeros((base.size, nu))
    for i, e in enumerate(np.eye(state.ndx) * EPS):
        jx[:, i] = (
            np.atleast_1d(function(state.integrate(x, e), u))
            - np.atleast_1d(function(state.integrate(x, -e), u))
        ) / (2 * EPS)
    for i, e in enumerate(np.eye(nu) * EPS):
        ju[:, i] = (np.atleast_1d(function(x, u + e)) - np.atleast_1d(function(x, u - e))) / (2 * EPS)
    return jx, ju


# --------------------------------------------------------------------------------------------------
# Weights
# --------------------------------------------------------------------------------------------------


def test_base_weight_mapping_to_tangent_order():
    # authors' order [x, y, z, yaw, pitch, roll] -> tangent [x, y, z, roll (about x), pitch (y), yaw (z)]
    np.testing.assert_array_equal(base_weights_to_tangent([1, 2, 3, 4, 5, 6]), [1, 2, 3, 6, 5, 4])
    weights = WholeBodyWeights.regular_running().state_weights(12)
    np.testing.assert_array_equal(weights[:6], [0, 0, 10, 2, 2, 1])
    np.testing.assert_array_equal(weights[6:18], 1.0)
    np.testing.assert_array_equal(weights[18:24], [2, 2, 2, 2, 2, 1])
    np.testing.assert_array_equal(weights[24:], 0.01)
    np.testing.assert_array_equal(
        SRBWeights().state_weights(), np.r_[[0, 0, 10, 2, 2, 1], [2, 2, 2, 2, 2, 1]]
    )
    with pytest.raises(ValueError):
        WholeBodyWeights(base_position=(1, 2, 3))
    with pytest.raises(ValueError):
        WholeBodyWeights(torque=-1.0)


# --------------------------------------------------------------------------------------------------
# Cost-term residual Jacobians
# --------------------------------------------------------------------------------------------------


def term_residual_check(robot, knot, term_index, x, u):
    term = knot.costs[term_index]
    data = knot.create_data()

    def residual(x_, u_):
        knot.calc(data, x_, u_)
        return data.cost_datas[term_index].r.copy()

    jx, ju = fd_of(residual, x, u, knot.state, knot.nu)
    knot.calc(data, x, u)
    knot.calc_diff(data, x, u)
    rx, ru = term.residual_jacobians(data.cost_datas[term_index])
    np.testing.assert_allclose(rx, jx, atol=1e-6 * max(1.0, np.abs(jx).max()))
    if knot.nu:
        np.testing.assert_allclose(ru, ju, atol=1e-6)
    # Gauss-Newton pieces of this term alone: Lx = Rx' W r dt, Lxx = Rx' W Rx dt.
    scale = knot.cost_scale
    r = data.cost_datas[term_index].r
    np.testing.assert_allclose(data.Lx, scale * rx.T @ (term.weights * r), atol=1e-9)
    np.testing.assert_allclose(data.Lxx, scale * rx.T @ (term.weights[:, None] * rx), atol=1e-9)
    if knot.nu:
        np.testing.assert_allclose(data.Lu, scale * ru.T @ (term.weights * r), atol=1e-9)
        np.testing.assert_allclose(data.Luu, scale * ru.T @ (term.weights[:, None] * ru), atol=1e-9)
        np.testing.assert_allclose(data.Lux, scale * ru.T @ (term.weights[:, None] * rx), atol=1e-9)


@pytest.mark.parametrize("base_error", ["tangent", "world"])
def test_state_tracking_residual(robot, base_error):
    rng = np.random.default_rng(1)
    weights = rng.uniform(0.5, 2.0, 36)
    term = StateTrackingCost(robot.model, weights, base_error)
    knot = knot_with_terms(robot, (1, 0, 0, 1), costs=[term], reference=random_reference(robot, rng))
    term_residual_check(robot, knot, 0, random_state(robot, rng, 1.0), rng.standard_normal(12))


def test_state_tracking_world_residual_meaning(robot):
    """'world': position and linear-velocity errors are world-frame, whatever the orientations."""
    rng = np.random.default_rng(2)
    term = StateTrackingCost(robot.model, np.ones(36), "world")
    reference = random_reference(robot, rng)
    knot = knot_with_terms(robot, (1, 1, 1, 1), costs=[term], reference=reference, running=False)
    data = knot.create_data()
    x = random_state(robot, rng, 1.0)
    knot.calc(data, x, np.zeros(0))
    r = data.cost_datas[0].r
    rotation = pin.Quaternion(x[3:7]).toRotationMatrix()
    rotation_ref = pin.Quaternion(reference.state[3:7]).toRotationMatrix()
    np.testing.assert_allclose(r[0:3], x[0:3] - reference.state[0:3])
    np.testing.assert_allclose(r[18:21], rotation @ x[19:22] - rotation_ref @ reference.state[19:22])
    np.testing.assert_allclose(pin.exp3(r[3:6]), rotation_ref.T @ rotation, atol=1e-12)


def test_swing_foot_residuals(robot):
    rng = np.random.default_rng(3)
    legs = (1, 2)
    reference = random_reference(robot, rng)
    x, u = random_state(robot, rng, 1.0), rng.standard_normal(12)
    position = SwingFootPositionCost(legs, rng.uniform(1, 3, 3), robot.nv)
    velocity = SwingFootVelocityCost(legs, rng.uniform(1, 3, 12), robot.nv)
    term_residual_check(
        robot, knot_with_terms(robot, (1, 0, 0, 1), costs=[velocity], reference=reference), 0, x, u
    )
    knot = knot_with_terms(robot, (1, 0, 0, 1), costs=[position], reference=reference)
    term_residual_check(robot, knot, 0, x, u)
    # The residual is the world-frame foot position error.
    data = knot.create_data()
    knot.calc(data, x, u)
    feet = robot.foot_positions(x[:19])
    np.testing.assert_allclose(
        data.cost_datas[0].r, (feet - knot.reference.foot_positions)[list(legs)].ravel()
    )


def test_torque_residual(robot):
    rng = np.random.default_rng(4)
    knot = knot_with_terms(
        robot,
        (1, 1, 1, 1),
        costs=[TorqueRegularisationCost(rng.uniform(0.1, 1, 12))],
        reference=random_reference(robot, rng),
    )
    term_residual_check(robot, knot, 0, random_state(robot, rng), rng.standard_normal(12))


# --------------------------------------------------------------------------------------------------
# Constraints
# --------------------------------------------------------------------------------------------------


def constraint_check(robot, knot, x, u):
    data = knot.create_data()
    for index, constraint in enumerate(knot.constraints):

        def values(x_, u_, index=index):
            knot.calc(data, x_, u_)
            return data.constraint_datas[index].g.copy()

        jx, ju = fd_of(values, x, u, knot.state, knot.nu)
        knot.calc(data, x, u)
        knot.calc_diff(data, x, u)
        cd = data.constraint_datas[index]
        np.testing.assert_allclose(cd.Gx, jx, atol=1e-6 * max(1.0, np.abs(jx).max()), err_msg=constraint.name)
        if knot.nu:
            np.testing.assert_allclose(
                cd.Gu, ju, atol=1e-6 * max(1.0, np.abs(ju).max()), err_msg=constraint.name
            )


@pytest.mark.parametrize("stance", [(1, 1, 1, 1), (0, 1, 1, 0), (0, 0, 0, 0)])
def test_inequality_jacobians(robot, factory, stance):
    rng = np.random.default_rng(5)
    knot = reference_knot(robot, stance)
    names = [c.name for c in knot.constraints]
    assert ("friction" in names) == any(stance)
    assert {"torque_limits", "joint_position_limits", "joint_velocity_limits", "base_height"} <= set(names)
    constraint_check(robot, knot, random_state(robot, rng), 5.0 * rng.standard_normal(12))
    terminal = reference_knot(robot, stance, running=False)
    assert {c.name for c in terminal.constraints} == {
        "joint_position_limits",
        "joint_velocity_limits",
        "base_height",
    }
    constraint_check(robot, terminal, random_state(robot, rng), np.zeros(0))


def test_friction_pyramid_values(robot, factory):
    """Eq. (26) rows per stance foot: [fz, mu fz - fx, mu fz + fx, mu fz - fy, mu fz + fy] (fused knot: the
    first rows of its stacked constraint values); the knot reports every foot's GRF (zero in swing)."""
    knot = factory.running_knot((1, 0, 0, 1))
    data = knot.create_data()
    rng = np.random.default_rng(6)
    x, u = random_state(robot, rng), rng.standard_normal(12)
    knot.calc(data, x, u)
    forces = data.forces[[0, 3]]
    np.testing.assert_array_equal(data.forces[[1, 2]], 0.0)
    np.testing.assert_allclose(forces.ravel(), data.dynamics.forces)
    expected = np.concatenate([friction_pyramid_matrix(0.6) @ f for f in forces])
    np.testing.assert_allclose(data.g[:10], expected)
    fx, fy, fz = forces[0]
    np.testing.assert_allclose(data.g[:5], [fz, 0.6 * fz - fx, 0.6 * fz + fx, 0.6 * fz - fy, 0.6 * fz + fy])


def test_friction_pyramid_in_a_tilted_contact_frame(robot, factory):
    """With the reference's ``contact_frame`` a 15 degree slope's (``core.ground.contact_frame``) the rows
    of (26) price the force's components along the slope's tangents and normal, the knot still reports
    world-frame forces, and the gradient over ``[x | u]`` matches central differences of the cost (the
    friction rows' derivatives go through the frame too)."""
    from cafe_mpc.core.ground import contact_frame

    slope = np.tan(np.radians(15.0))
    frame = contact_frame(np.array([-slope, 0.0, 1.0]) / np.hypot(slope, 1.0))
    knot = factory.running_knot((1, 1, 1, 1))
    flat_data, data = knot.create_data(), knot.create_data()
    knot.reference.contact_frame[:] = frame
    rng = np.random.default_rng(7)
    x, u = random_state(robot, rng, spread=0.05, speed=0.1), 2.0 * rng.standard_normal(12)
    knot.calc(data, x, u)
    np.testing.assert_allclose(data.forces.ravel(), data.dynamics.forces)
    expected = np.concatenate([friction_pyramid_matrix(0.6) @ (frame @ f) for f in data.forces])
    np.testing.assert_allclose(data.g[:20], expected, rtol=1e-12, atol=1e-9)
    knot.calc_diff(data, x, u)
    gradient = data.gradient.copy()
    ndx = knot.state.ndx
    numeric = np.zeros_like(gradient)
    for i in range(ndx + 12):
        step = np.zeros(ndx + 12)
        step[i] = EPS
        costs = []
        for sign in (1.0, -1.0):
            xs = knot.state.integrate(x, sign * step[:ndx])
            knot.calc(data, xs, u + sign * step[ndx:])
            costs.append(data.cost)
        numeric[i] = (costs[0] - costs[1]) / (2 * EPS)
    np.testing.assert_allclose(gradient, numeric, rtol=1e-4, atol=1e-5 * np.max(np.abs(numeric)))
    flat = knot.with_reference(knot.reference.copy())
    flat.reference.contact_frame[:] = np.eye(3)
    flat.calc(flat_data, x, u)
    flat.calc_diff(flat_data, x, u)
    assert not np.allclose(flat_data.g[:20], data.g[:20])
    assert not np.allclose(flat_data.gradient, gradient)


def test_minimum_normal_force_raises_the_unilateral_row(robot):
    """With ``minimum_normal_force`` the unilateral row of (26) is ``fz - fz_min`` and the face rows stay;
    the fused knot equals the term-by-term one (cost, gradient, Hessian) with it."""
    rng = np.random.default_rng(7)
    x, u = random_state(robot, rng, 0.1, 0.5), 5.0 * rng.standard_normal(12)
    stance = (1, 0, 1, 1)
    plain = WholeBodyModelFactory(robot).running_knot(stance)
    settings = WholeBodySettings(constraints=WholeBodyConstraintSettings(minimum_normal_force=12.0))
    raised = WholeBodyModelFactory(robot, settings).running_knot(stance)
    data, raised_data = plain.create_data(), raised.create_data()
    plain.calc(data, x, u)
    raised.calc(raised_data, x, u)
    shift = np.zeros(15)
    shift[::5] = 12.0
    np.testing.assert_allclose(raised_data.g[:15], data.g[:15] - shift)
    assert raised_data.cost != pytest.approx(data.cost)
    terms = reference_knot(robot, stance, True, settings)
    term_data = terms.create_data()
    raised.calc_diff(raised_data, x, u)
    terms.calc(term_data, x, u)
    terms.calc_diff(term_data, x, u)
    assert raised_data.cost == pytest.approx(term_data.cost, rel=1e-12)
    for name in ("Lx", "Lu", "Luu"):
        expected = getattr(term_data, name)
        np.testing.assert_allclose(getattr(raised_data, name), expected, atol=1e-12 * np.abs(expected).max())
    with pytest.raises(ValueError, match="minimum normal force"):
        WholeBodyConstraintSettings(minimum_normal_force=-1.0)


def test_constraint_violation_is_reported(robot, factory):
    knot = factory.running_knot((1, 1, 1, 1))
    data = knot.create_data()
    x = robot.x_standing.copy()
    u = np.zeros(12)
    u[4] = 17.0 + 3.0  # 3 Nm beyond the hip torque limit
    knot.calc(data, x, u)
    friction = data.g[:20]
    assert data.constraint_violation == pytest.approx(max(3.0, -friction.min()))
    x[2] = 0.15  # 5 cm below the minimum base height; zero torque to isolate it
    knot.calc(data, x, np.zeros(12))
    friction = data.g[:20]
    assert data.constraint_violation == pytest.approx(max(0.05, -friction.min()))
    assert np.isfinite(data.cost)


def test_compiled_barrier_matches_relaxed_barrier():
    rng = np.random.default_rng(7)
    deltas, eps = rng.uniform(0.05, 1.0, 40), rng.uniform(0.01, 0.2, 40)
    g = rng.uniform(-2.0, 3.0, 40)
    g[:5] = deltas[:5]  # on the switch point
    d1, d2 = np.zeros(40), np.zeros(40)
    value = relaxed_barrier(g, deltas, eps, d1, d2)
    reference_value, reference_d1, reference_d2 = RelaxedBarrier(deltas, eps).derivatives(g)
    assert value == pytest.approx(reference_value, rel=1e-12)
    np.testing.assert_allclose(d1, reference_d1, rtol=1e-12)
    np.testing.assert_allclose(d2, reference_d2, rtol=1e-12)
    # First derivative vs finite differences of the value.
    scratch = np.zeros(40)
    for i in range(40):
        step = np.zeros(40)
        step[i] = EPS
        plus = relaxed_barrier(g + step, deltas, eps, scratch, scratch.copy())
        minus = relaxed_barrier(g - step, deltas, eps, scratch, scratch.copy())
        assert (plus - minus) / (2 * EPS) == pytest.approx(reference_d1[i], abs=1e-6)
    assert relaxed_barrier(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0)) == 0.0


def test_touchdown_constraint(robot):
    rng = np.random.default_rng(8)
    constraint = TouchdownFootHeight(robot, (0, 1, 1, 0), surface_height=0.01)
    data = constraint.create_data()
    x = random_state(robot, rng)
    constraint.calc(data, x)
    feet = robot.foot_positions(x[:19])
    np.testing.assert_allclose(data.value, feet[[1, 2], 2] - robot.foot_radius - 0.01)
    # Standing feet touch the floor: zero residual at the standing pose on a flat floor.
    flat = TouchdownFootHeight(robot, (1, 1, 1, 1))
    flat_data = flat.create_data()
    flat.calc(flat_data, robot.x_standing)
    np.testing.assert_allclose(flat_data.value, 0.0, atol=1e-9)
    with pytest.raises(ValueError):
        TouchdownFootHeight(robot, (0, 0, 0, 0))


# --------------------------------------------------------------------------------------------------
# Whole knots
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("base_error", ["tangent", "world"])
@pytest.mark.parametrize("stance", [(1, 1, 1, 1), (1, 0, 0, 1), (0, 0, 1, 0), (0, 0, 0, 0)])
@pytest.mark.parametrize("terminal", [False, True])
def test_fused_knot_equals_term_by_term(robot, base_error, stance, terminal):
    """The fused knot (one stacked residual and constraint vector, compiled Gauss-Newton) gives the same cost,
    violation, gradient and Hessian as the term-by-term evaluation it replaced, and the same dynamics."""
    rng = np.random.default_rng(12)
    settings = WholeBodySettings(base_error=base_error)
    factory = WholeBodyModelFactory(robot, settings)
    reference = random_reference(robot, rng)
    knot = factory.terminal_knot(stance, reference) if terminal else factory.running_knot(stance, reference)
    terms = reference_knot(robot, stance, not terminal, settings, reference)
    data, term_data = knot.create_data(), terms.create_data()
    x = random_state(robot, rng, 0.1, 0.5)
    u = 5.0 * rng.standard_normal(knot.nu)  # large enough to activate torque and friction barriers
    for model, model_data in ((knot, data), (terms, term_data)):
        model.calc(model_data, x, u)
        model.calc_diff(model_data, x, u)
    assert data.cost == pytest.approx(term_data.cost, rel=1e-12, abs=1e-12)
    assert data.constraint_violation == pytest.approx(term_data.constraint_violation, abs=1e-12)
    for name in ("Lx", "Lu", "Lxx", "Luu", "Lux"):
        expected = getattr(term_data, name)
        scale = max(1.0, float(np.abs(expected).max())) if expected.size else 1.0
        np.testing.assert_allclose(getattr(data, name), expected, atol=1e-12 * scale, err_msg=name)
    if not terminal:
        np.testing.assert_allclose(data.x_next, term_data.x_next, atol=1e-14)
        np.testing.assert_allclose(data.Fx, term_data.Fx, atol=1e-12)


@pytest.mark.parametrize("base_error", ["tangent", "world"])
@pytest.mark.parametrize("integration", ["explicit", "semi_implicit"])
@pytest.mark.parametrize("stance", [(1, 0, 0, 1), (0, 0, 0, 0)])
def test_knot_of_a_robot_without_compiled_free_flyer_equals_the_compiled_one(
    robot, base_error, integration, stance
):
    """A knot whose state is not treated as a free-flyer root (other robots: ``pin.difference``,
    ``pin.dDifference``, ``pin.integrate``, ``pin.dIntegrate``) gives the same results as the compiled
    free-flyer path (at rotations where Pinocchio's closed forms are accurate)."""
    from cafe_mpc.dynamics.whole_body import WholeBodyDynamics

    rng = np.random.default_rng(4)
    settings = WholeBodySettings(base_error=base_error, integration=integration)
    factory = WholeBodyModelFactory(robot, settings)
    reference = random_reference(robot, rng)
    compiled = factory.running_knot(stance, reference)
    dynamics = WholeBodyDynamics(robot, stance, settings.dt, integration=integration)
    dynamics.state.free_flyer_root = False
    dynamics._free_flyer = False
    generic = WholeBodyKnot(
        robot, dynamics, settings.running_weights, settings.constraints, reference, base_error=base_error
    )
    assert compiled.dynamics._free_flyer
    data, generic_data = compiled.create_data(), generic.create_data()
    for _ in range(3):
        x = random_state(robot, rng, 0.5, 30.0)  # base rotation steps of some 0.3 rad
        u = 5.0 * rng.standard_normal(12)
        for model, model_data in ((compiled, data), (generic, generic_data)):
            model.calc(model_data, x, u)
            model.calc_diff(model_data, x, u)
        assert data.cost == pytest.approx(generic_data.cost, rel=1e-12)
        for name in ("r", "g", "x_next", "Fx", "Fu", "forces", "gradient", "hessian"):
            expected = getattr(generic_data, name)
            scale = max(1.0, float(np.abs(expected).max()))
            actual = getattr(data, name)
            np.testing.assert_allclose(actual, expected, rtol=0, atol=1e-12 * scale, err_msg=name)


def test_terminal_knot_has_no_forces_and_force_derivatives_only_where_priced(robot):
    factory = WholeBodyModelFactory(robot)
    terminal = factory.terminal_knot((1, 1, 1, 1))
    data = terminal.create_data()
    terminal.calc(data, robot.x_standing, np.zeros(0))
    np.testing.assert_array_equal(data.forces, 0.0)
    assert factory.running_knot((1, 1, 1, 1)).create_data().dynamics.force_derivatives
    unconstrained = WholeBodyModelFactory(
        robot, WholeBodySettings(constraints=WholeBodyConstraintSettings.unconstrained())
    )
    assert not unconstrained.running_knot((1, 1, 1, 1)).create_data().dynamics.force_derivatives


def test_running_cost_is_half_weighted_square_times_dt(robot):
    factory = WholeBodyModelFactory(
        robot, WholeBodySettings(constraints=WholeBodyConstraintSettings.unconstrained())
    )
    x_ref = robot.x_standing.copy()
    knot = factory.running_knot((1, 1, 1, 1), factory.default_reference(x_ref))
    data = knot.create_data()
    x = x_ref.copy()
    x[2] += 0.1  # base height error 0.1 m, z weight 10
    u = np.full(12, 2.0)  # torque weight 0.1
    knot.calc(data, x, u)
    assert data.cost == pytest.approx(0.01 * 0.5 * (10 * 0.1**2 + 12 * 0.1 * 4.0))
    assert data.constraint_violation == 0.0


def test_reference_update_in_place(robot, factory):
    """The MPC sets references per knot without rebuilding: the next calc sees them."""
    knot = factory.running_knot((1, 1, 1, 1))
    other = factory.running_knot((1, 1, 1, 1))
    assert knot.dynamics is other.dynamics and knot.reference is not other.reference
    data = knot.create_data()
    x, u = robot.x_standing, np.zeros(12)
    knot.calc(data, x, u)
    before = data.cost
    target = robot.x_standing.copy()
    target[2] += 0.05
    knot.reference.set(state=target)
    knot.calc(data, x, u)
    assert data.cost > before
    other_data = other.create_data()
    other.calc(other_data, x, u)
    assert other_data.cost == pytest.approx(before)  # other knots untouched
    with pytest.raises(ValueError):
        knot.reference.set(state=np.zeros(36))
    with pytest.raises(ValueError):
        knot.reference.set(foot_positions=np.zeros((3, 3)))


def test_knot_size_validation(robot, factory):
    knot = factory.running_knot((1, 0, 0, 1))
    data = knot.create_data()
    with pytest.raises(ValueError):
        knot.calc(data, np.zeros(36), np.zeros(12))
    with pytest.raises(ValueError):
        knot.calc(data, robot.x_standing, np.zeros(11))
    terminal = factory.terminal_knot((1, 0, 0, 1))
    assert terminal.nu == 0
    with pytest.raises(ValueError):
        terminal.calc(terminal.create_data(), robot.x_standing, np.zeros(12))
    with pytest.raises(ValueError):  # a terminal knot needs its phase's stance flags
        WholeBodyKnot(robot, None, WholeBodyWeights(), None, factory.default_reference())
    with pytest.raises(ValueError):
        WholeBodyKnot(
            robot, None, WholeBodyWeights(), None, factory.default_reference(), (1, 1, 1, 1), "body"
        )
    with pytest.raises(ValueError):
        factory.running_knot((1, 0, 1))
    with pytest.raises(ValueError):
        factory.running_knot((1, 1, 1, 1), WholeBodyReference(np.zeros(13)))


def test_calc_diff_recomputes_if_calc_was_at_another_point(robot, factory):
    knot = factory.running_knot((1, 1, 0, 0))
    rng = np.random.default_rng(11)
    x1, x2, u = random_state(robot, rng), random_state(robot, rng), rng.standard_normal(12)
    fresh = knot.create_data()
    knot.calc(fresh, x2, u)
    knot.calc_diff(fresh, x2, u)
    stale = knot.create_data()
    knot.calc(stale, x1, u)
    knot.calc_diff(stale, x2, u)
    np.testing.assert_allclose(stale.Fx, fresh.Fx)
    np.testing.assert_allclose(stale.Lx, fresh.Lx)


def test_knots_from_one_prototype_share_data_layout(robot, factory):
    a = factory.running_knot((1, 0, 0, 1))
    b = factory.running_knot((1, 0, 0, 1))
    c = factory.running_knot((0, 1, 1, 0))
    assert a.layout is b.layout and a.layout is not c.layout
    data = a.create_data()
    assert data.layout is b.layout
    b.calc(data, robot.x_standing, np.zeros(12))  # reusable by b
    assert np.isfinite(data.cost)


def test_world_base_error_kernels_match_pinocchio_at_any_rotation(robot):
    """The compiled world base error equals ``log3``/``Jlog3`` of ``R_ref' R`` and the world-frame position
    and velocity errors, from tiny rotations to nearly a half turn (a barrel roll's tracking errors)."""
    from cafe_mpc.dynamics.srb import quaternion_to_rotation
    from cafe_mpc.ocp.kernels import world_base_error, world_base_error_jacobian

    model, nq, nv = robot.model, robot.nq, robot.nv
    rng = np.random.default_rng(21)
    r, log_error, jacobian = np.zeros(2 * nv), np.zeros(4), np.zeros((9, 9))
    for angle in (1e-8, 1e-3, 0.3, 2.0, 3.1):
        for _ in range(10):
            x_ref = random_state(robot, rng, 1.0, 1.0)
            axis = rng.standard_normal(3)
            step = np.zeros(nv)
            step[3:6] = angle * axis / np.linalg.norm(axis)
            step[:3] = rng.standard_normal(3)
            step[6:] = 0.1 * rng.standard_normal(nv - 6)
            x = np.concatenate([pin.integrate(model, x_ref[:nq], step), rng.standard_normal(nv)])
            rotation = quaternion_to_rotation(x[3:7])
            rotation_ref = quaternion_to_rotation(x_ref[3:7])
            world_base_error(x, x_ref, nq, nv, rotation, r, log_error)
            error = rotation_ref.T @ rotation
            np.testing.assert_allclose(r[:3], x[:3] - x_ref[:3], atol=1e-14)
            np.testing.assert_allclose(r[3:6], pin.log3(error), atol=1e-9)
            np.testing.assert_allclose(r[6:nv], x[7:nq] - x_ref[7:nq], atol=1e-14)
            velocity_error = rotation @ x[nq : nq + 3] - rotation_ref @ x_ref[nq : nq + 3]
            np.testing.assert_allclose(r[nv : nv + 3], velocity_error, atol=1e-12)
            world_base_error_jacobian(x, nq, rotation, log_error, jacobian)
            np.testing.assert_allclose(jacobian[3:6, 3:6], pin.Jlog3(error), atol=1e-7)
            np.testing.assert_allclose(jacobian[6:9, 3:6], -rotation @ pin.skew(x[nq : nq + 3]), atol=1e-12)
            np.testing.assert_allclose(jacobian[0:3, 0:3], rotation, atol=0)
