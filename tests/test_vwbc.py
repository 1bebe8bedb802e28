"""The value-function whole-body controller (VWBC, paper Eq. (34)) against the Riccati policy (33).

Synthetic plans (``cafe_mpc.low_level.synthetic``) stand in for MPC solutions: standing pose, static stance
torques, random SPD ``Quu`` and ``Qux = -Quu K``.
"""

import importlib.util

import numpy as np
import pinocchio as pin
import pytest

from cafe_mpc.config import VWBCSettings
from cafe_mpc.control.plan_follower import PlanFollower
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.low_level.contact_dynamics import (
    FrictionConeScorer,
    contact_forces_for_torque,
    friction_cone_violation,
)
from cafe_mpc.low_level.riccati import RiccatiController
from cafe_mpc.low_level.synthetic import synthetic_plan
from cafe_mpc.low_level.vwbc import VWBCController
from cafe_mpc.planners.cafe.plan import Plan
from cafe_mpc.planners.resolved import ContactModel
from cafe_mpc_lab.sim.loop import SimulationOptions, simulate
from cafe_mpc_lab.sim.mujoco_plant import MujocoPlant

HAS_DAQP = importlib.util.find_spec("daqp") is not None
SOLVERS = ["proxqp", pytest.param("daqp", marks=pytest.mark.skipif(not HAS_DAQP, reason="daqp missing"))]
FOUR = np.ones(4, dtype=bool)
TROT = np.array([True, False, False, True])
GENEROUS = np.full(12, 1e3)


def measured(q, v, contacts=FOUR):
    """What the plant would report: state ``(q, v)`` and the feet in contact (default: all four)."""
    return Measurement.of_state(q, v, contacts)


def perturbed_state(robot, seed, dq_scale=0.005, v_scale=0.02):
    rng = np.random.default_rng(seed)
    q = pin.integrate(robot.model, robot.q_standing, dq_scale * rng.normal(size=robot.nv))
    return q, v_scale * rng.normal(size=robot.nv)


def unconstrained_policy(controller, plan, q, v, k=0):
    """Eq. (7) with the feed-forward increment: tau* - Quu^{-1} (Qux dx + Qu)."""
    dx = controller.state_error(q, v, plan.xs[k]).copy()
    return plan.us[k] - np.linalg.solve(plan.Quu[k], plan.Qux[k] @ dx + plan.Qu[k])


def dynamics_residual(robot, q, v, qdd, tau, forces, stance):
    """M qdd + h - S' tau - Jc' F (34b), computed independently with RNEA."""
    data = robot.model.createData()
    residual = pin.rnea(robot.model, data, q, v, qdd).copy()
    residual[6:] -= tau
    pin.computeJointJacobians(robot.model, data, q)
    pin.updateFramePlacements(robot.model, data)
    for foot, frame_id in enumerate(robot.foot_frame_ids):
        if stance[foot]:
            J = pin.getFrameJacobian(robot.model, data, frame_id, pin.LOCAL_WORLD_ALIGNED)[:3]
            residual -= J.T @ forces[foot]
    return residual


def foot_accelerations(robot, q, v, qdd, stance):
    """Classical foot accelerations and alpha * foot velocities (for (34c))."""
    data = robot.model.createData()
    pin.forwardKinematics(robot.model, data, q, v, qdd)
    pin.updateFramePlacements(robot.model, data)
    acc, vel = [], []
    for foot, frame_id in enumerate(robot.foot_frame_ids):
        if stance[foot]:
            rf = pin.LOCAL_WORLD_ALIGNED
            acc.append(pin.getFrameClassicalAcceleration(robot.model, data, frame_id, rf).linear)
            vel.append(pin.getFrameVelocity(robot.model, data, frame_id, rf).linear)
    return np.array(acc), np.array(vel)


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("stance", [FOUR, TROT, ~FOUR], ids=["four", "trot", "flight"])
def test_unconstrained_qp_equals_riccati_policy(robot, solver, stance):
    plan = synthetic_plan(robot, stance=stance, seed=3)
    settings = VWBCSettings(solver=solver, eps_abs=1e-10)
    vwbc = VWBCController(robot, settings, torque_limits=GENEROUS)
    riccati = RiccatiController(robot, clamp=False)
    q, v = perturbed_state(robot, seed=1)
    tau = vwbc.compute(0.0, measured(q, v), plan).copy()
    assert vwbc.last_used_qp and vwbc.fallbacks == 0
    # no inequality is active, so the QP is the unconstrained policy (7) = Riccati (33) when Qu = 0
    forces = vwbc.last_forces[stance]
    assert np.all(forces[:, 2] > 1.0)
    assert np.all(np.abs(forces[:, :2]) < 0.6 * forces[:, 2:] - 0.1)
    np.testing.assert_allclose(tau, riccati.torques_at(0.0, q, v, plan), atol=1e-6)
    np.testing.assert_allclose(tau, unconstrained_policy(vwbc, plan, q, v), atol=1e-6)


@pytest.mark.parametrize("solver", SOLVERS)
def test_unconstrained_qp_with_qu_adds_feedforward_increment(robot, solver):
    plan = synthetic_plan(robot, seed=4, qu_scale=0.5)
    vwbc = VWBCController(robot, VWBCSettings(solver=solver, eps_abs=1e-10), torque_limits=GENEROUS)
    riccati = RiccatiController(robot, clamp=False)
    q, v = perturbed_state(robot, seed=2)
    tau = vwbc.compute(0.0, measured(q, v), plan).copy()
    expected = unconstrained_policy(vwbc, plan, q, v)
    np.testing.assert_allclose(tau, expected, atol=1e-6)
    increment = -np.linalg.solve(plan.Quu[0], plan.Qu[0])
    assert np.abs(increment).max() > 0.05  # the test distinguishes (7) with Qu from (33)
    np.testing.assert_allclose(tau - riccati.torques_at(0.0, q, v, plan), increment, atol=1e-6)


@pytest.mark.parametrize("solver", SOLVERS)
def test_torque_limit_is_respected_and_other_joints_redistribute(robot, solver):
    plan = synthetic_plan(robot, seed=5)
    probe = VWBCController(robot, torque_limits=GENEROUS)
    q, v = perturbed_state(robot, seed=6)
    free = unconstrained_policy(probe, plan, q, v)
    joint = int(np.argmax(np.abs(free)))
    limits = GENEROUS.copy()
    limits[joint] = 0.5 * abs(free[joint])
    vwbc = VWBCController(robot, VWBCSettings(solver=solver, eps_abs=1e-10), torque_limits=limits)
    tau = vwbc.compute(0.0, measured(q, v), plan).copy()
    assert vwbc.last_used_qp
    assert np.all(np.abs(tau) <= limits + 1e-9)
    assert tau[joint] == pytest.approx(np.sign(free[joint]) * limits[joint], abs=1e-7)
    # optimal with tau[joint] fixed: the other joints minimise (34a) given it (Quu is not diagonal)
    others = np.arange(12) != joint
    Quu = plan.Quu[0]
    dx = vwbc.state_error(q, v, plan.xs[0]).copy()
    c = plan.Qux[0] @ dx + plan.Qu[0]
    d_joint = tau[joint] - plan.us[0, joint]
    d_others = -np.linalg.solve(Quu[np.ix_(others, others)], c[others] + Quu[others, joint] * d_joint)
    np.testing.assert_allclose(tau[others], plan.us[0, others] + d_others, atol=1e-6)
    clamped = np.clip(free, -limits, limits)  # the clamped Riccati torque keeps the others unchanged
    assert np.abs(tau[others] - clamped[others]).max() > 1e-2


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("stance", [FOUR, TROT], ids=["four", "trot"])
def test_friction_pyramid_and_dynamics_hold(robot, solver, stance):
    mu = 0.05  # makes the pyramid active for this perturbation
    plan = synthetic_plan(robot, stance=stance, seed=7)
    contact = ContactModel(friction=mu)
    vwbc = VWBCController(robot, VWBCSettings(solver=solver, eps_abs=1e-9), GENEROUS, contact)
    q, v = perturbed_state(robot, seed=8, dq_scale=0.02, v_scale=0.1)
    riccati = RiccatiController(robot, clamp=False)
    tau_riccati = riccati.torques_at(0.0, q, v, plan).copy()
    scorer = FrictionConeScorer(robot, mu=mu)
    assert scorer.score(q, v, tau_riccati, stance)  # the Riccati torque leaves the cone ...
    tau = vwbc.compute(0.0, measured(q, v), plan).copy()
    assert vwbc.last_used_qp
    forces = vwbc.last_forces.copy()
    assert friction_cone_violation(forces[stance], mu) < 1e-6  # ... the VWBC's does not
    assert np.all(forces[stance, 2] >= -1e-8)
    assert np.all(forces[~stance] == 0.0)
    assert vwbc.statistics()["friction_cone_violations"] == 0
    assert not scorer.score(q, v, tau, stance)
    assert scorer.violations == 1 and scorer.ticks == 2
    # (34b) whole-body dynamics and (34c) stabilised no-slip
    residual = dynamics_residual(robot, q, v, vwbc.last_qdd, tau, forces, stance)
    assert np.abs(residual).max() < 1e-6
    acc, vel = foot_accelerations(robot, q, v, vwbc.last_qdd, stance)
    np.testing.assert_allclose(acc, -contact.baumgarte_alpha * vel, atol=1e-6)
    # the KKT helper recovers the QP's forces from its torque
    implied = contact_forces_for_torque(robot, q, v, tau, stance, contact.baumgarte_alpha)
    np.testing.assert_allclose(implied, forces, atol=1e-6)


@pytest.mark.parametrize("solver", SOLVERS)
def test_infeasible_qp_falls_back_to_clamped_riccati(robot, solver):
    plan = synthetic_plan(robot, seed=9)
    # Near-zero torques on a nearly frictionless floor cannot hold the robot: the contact forces of (almost)
    # zero torque leave the cone (with the rotor inertia in the model they stay inside mu = 0.6).
    limits, mu = np.full(12, 1e-3), 0.05
    assert (
        friction_cone_violation(
            contact_forces_for_torque(robot, robot.q_standing, np.zeros(18), 0 * limits, FOUR), mu
        )
        > 0.1
    )
    vwbc = VWBCController(robot, VWBCSettings(solver=solver, max_iter=50), limits, ContactModel(friction=mu))
    riccati = RiccatiController(robot, clamp=False)
    q, v = perturbed_state(robot, seed=10)
    tau = vwbc.compute(0.0, measured(q, v), plan).copy()
    assert not vwbc.last_used_qp
    assert np.all(np.isfinite(tau))
    np.testing.assert_allclose(tau, np.clip(riccati.torques_at(0.0, q, v, plan), -limits, limits))
    stats = vwbc.statistics()
    assert stats["fallbacks"] == 1 and stats["ticks"] == 1
    assert sum(stats["fallback_reasons"].values()) == 1
    assert stats["friction_cone_violations"] == 1  # the fallback torque is scored like the Riccati one


def test_nan_state_never_returns_nan(robot):
    plan = synthetic_plan(robot, seed=11)
    vwbc = VWBCController(robot)
    q = robot.q_standing.copy()
    v = np.zeros(robot.nv)
    v[3] = np.nan
    tau = vwbc.compute(0.0, measured(q, v), plan)
    assert np.all(np.isfinite(tau)) and vwbc.fallbacks == 1
    np.testing.assert_allclose(tau, np.clip(plan.us[0], -robot.torque_limits, robot.torque_limits))


def run_sequence(robot, plan, settings, ticks=120, v_scale=0.3, seed=0, limits=None):
    """Nearby ticks: a slowly drifting configuration error and a noisy velocity."""
    vwbc = VWBCController(robot, settings, torque_limits=limits)
    rng = np.random.default_rng(seed)
    dq, v = np.zeros(robot.nv), np.zeros(robot.nv)
    torques = np.zeros((ticks, robot.nu))
    for i in range(ticks):
        dq = 0.98 * dq + 0.002 * rng.normal(size=robot.nv)
        v = 0.9 * v + v_scale * rng.normal(size=robot.nv)
        torques[i] = vwbc.compute(
            0.002 * i, measured(pin.integrate(robot.model, robot.q_standing, dq), v), plan
        )
    return vwbc.statistics(), torques


def mean_iterations(stats):
    histogram = stats["qp_iterations_histogram"]
    return sum(k * n for k, n in histogram.items()) / sum(histogram.values())


def test_proxqp_warm_start_reduces_iterations_versus_cold_start(robot):
    plan = synthetic_plan(robot, knots=20, seed=12)
    cold, tau_cold = run_sequence(robot, plan, VWBCSettings(solver="proxqp", warm_start="none"))
    means = {}
    for mode in ("plan", "previous"):
        warm, tau_warm = run_sequence(robot, plan, VWBCSettings(solver="proxqp", warm_start=mode))
        assert warm["fallbacks"] == cold["fallbacks"] == 0
        means[mode] = mean_iterations(warm)
        assert means[mode] < mean_iterations(cold) - 1.0
        np.testing.assert_allclose(tau_warm, tau_cold, atol=1e-3)  # same QPs, same answers
    # the previous tick's primal-dual pair is a better start than the plan's primal with zero multipliers
    assert means["previous"] < means["plan"]


@pytest.mark.skipif(not HAS_DAQP, reason="daqp missing")
def test_daqp_warm_start_reduces_active_set_iterations(robot):
    plan = synthetic_plan(robot, knots=20, seed=12)
    cold, tau_cold = run_sequence(robot, plan, VWBCSettings(solver="daqp", warm_start="none"))
    warm, tau_warm = run_sequence(robot, plan, VWBCSettings(solver="daqp", warm_start="previous"))
    assert max(cold["qp_iterations_histogram"]) > 1  # constraints do become active in this sequence
    assert mean_iterations(warm) < mean_iterations(cold)
    assert warm["qp_iterations_histogram"].get(1, 0) > cold["qp_iterations_histogram"].get(1, 0)
    np.testing.assert_allclose(tau_warm, tau_cold, atol=1e-6)
    _, tau_proxqp = run_sequence(robot, plan, VWBCSettings(solver="proxqp", eps_abs=1e-9))
    np.testing.assert_allclose(tau_warm, tau_proxqp, atol=1e-4)  # both backends solve the same QP


def test_statistics_interface_and_stance_sources(robot):
    plan = synthetic_plan(robot, seed=13)
    vwbc = VWBCController(robot)
    with pytest.raises(RuntimeError):
        vwbc.compute(0.0, measured(robot.q_standing, np.zeros(robot.nv)), None)
    contacts = np.array([False, True, True, True])
    vwbc.compute(0.0, measured(robot.q_standing, np.zeros(robot.nv), contacts), plan)  # stance from the plan
    assert np.array_equal(vwbc.last_stance, FOUR)
    intersect = VWBCController(robot, VWBCSettings(stance_source="intersect"))
    intersect.compute(0.0, measured(robot.q_standing, np.zeros(robot.nv), contacts), plan)
    assert np.array_equal(intersect.last_stance, contacts)
    assert np.all(intersect.last_forces[0] == 0.0) and intersect.last_forces[1, 2] > 0
    for _ in range(3):
        vwbc.compute(0.01, measured(robot.q_standing, np.zeros(robot.nv)), plan)
    stats = vwbc.statistics()
    assert stats["ticks"] == 4 and sum(stats["qp_iterations_histogram"].values()) == 4
    assert stats["stance_mismatch_ticks"] == 1
    for key in ("qp_solve_time_ms_median", "qp_solve_time_ms_p99", "fallbacks", "friction_cone_violations"):
        assert key in stats
    assert np.isfinite(stats["qp_solve_time_ms_p99"])
    vwbc.reset()
    assert vwbc.statistics()["ticks"] == 0
    with pytest.raises(ValueError):
        VWBCSettings(warm_start="hot")


def test_stance_source_decides_the_torque_when_a_planned_foot_is_not_in_contact(robot):
    """The measured contacts reach the QP: with ``intersect`` a planned stance foot that the plant does not
    measure in contact carries no force and, with the friction pyramid active, the torque differs from the
    plan-stance QP's (without active inequalities both are the policy (7), whatever the stance)."""
    plan = synthetic_plan(robot, seed=21)
    q, v = perturbed_state(robot, seed=8, dq_scale=0.02, v_scale=0.1)
    contacts = np.array([True, True, True, False])  # HR planned in stance, measured in the air
    torques = {}
    for source in ("plan", "intersect"):
        vwbc = VWBCController(robot, VWBCSettings(stance_source=source), contact=ContactModel(friction=0.05))
        torques[source] = vwbc.compute(0.0, measured(q, v, contacts), plan).copy()
        assert vwbc.last_used_qp
        assert (vwbc.last_forces[3, 2] > 1.0) == (source == "plan")
    assert np.abs(torques["plan"] - torques["intersect"]).max() > 0.1
    # all feet measured in contact: the two sources agree
    same = [
        VWBCController(robot, VWBCSettings(stance_source=source), contact=ContactModel(friction=0.05))
        .compute(0.0, measured(q, v), plan)
        .copy()
        for source in ("plan", "intersect")
    ]
    np.testing.assert_allclose(same[0], same[1], atol=1e-9)


def test_vwbc_holds_the_robot_standing_in_closed_loop(robot):
    plan = synthetic_plan(robot, knots=40, seed=14, base_gain_scale=0.0, kp=60.0, kd=1.5)
    vwbc = VWBCController(robot)
    log = simulate(MujocoPlant(robot), PlanFollower(vwbc, plan), SimulationOptions(0.6))
    stats = vwbc.statistics()
    assert not log.fell
    assert stats["fallbacks"] == 0 and stats["friction_cone_violations"] == 0
    assert abs(log.q[-1, 2] - robot.standing_height) < 0.03


FLIGHT = np.zeros(4, dtype=bool)
WARM_STARTS = ["plan", "previous", "equality", "none"]


def multi_pattern_plan(robot, patterns, dt=0.02, seed=0):
    """A plan whose knot ``k`` has the stance ``patterns[k]`` (bounding/pronking-like flight knots)."""
    knots = [synthetic_plan(robot, stance=p, knots=1, dt=dt, seed=seed + i) for i, p in enumerate(patterns)]
    stack = {
        name: np.concatenate([getattr(knot, name) for knot in knots])
        for name in ("us", "K", "Qu", "Quu", "Qux", "contacts", "forces")
    }
    return Plan(
        times=dt * np.arange(len(patterns)),
        xs=np.tile(knots[0].xs[0], (len(patterns) + 1, 1)),
        dt=np.full(len(patterns), dt),
        **stack,
    )


def cold_solution(robot, plan, settings, t, q, v, limits):
    """The tick solved by a fresh controller from a cold start (no state carried over)."""
    cold = VWBCController(robot, settings.model_copy(update={"warm_start": "none"}), torque_limits=limits)
    tau = cold.compute(t, measured(q, v), plan).copy()
    assert cold.last_used_qp
    return tau


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("warm_start", WARM_STARTS)
def test_all_flight_plan_over_several_ticks(robot, solver, warm_start):
    """No stance foot: the QP has only the torque bounds (DAQP: simple bounds, no general constraints)."""
    plan = synthetic_plan(robot, stance=FLIGHT, seed=15)
    settings = VWBCSettings(solver=solver, warm_start=warm_start, eps_abs=1e-10)
    vwbc = VWBCController(robot, settings, torque_limits=GENEROUS)
    for tick in range(6):
        q, v = perturbed_state(robot, seed=20 + tick)
        t = 0.01 * tick
        tau = vwbc.compute(t, measured(q, v), plan).copy()
        assert vwbc.last_used_qp, vwbc.last_status
        assert np.all(vwbc.last_forces == 0.0)
        k = plan.knot_at(t)
        np.testing.assert_allclose(tau, unconstrained_policy(vwbc, plan, q, v, k), atol=1e-6)
    stats = vwbc.statistics()
    assert stats["ticks"] == 6 and stats["fallbacks"] == 0 and stats["qp_exceptions"] == {}


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("warm_start", ["plan", "previous"])
def test_all_flight_plan_with_active_torque_bounds(robot, solver, warm_start):
    plan = synthetic_plan(robot, stance=FLIGHT, seed=16)
    probe = VWBCController(robot, torque_limits=GENEROUS)
    q0, v0 = perturbed_state(robot, seed=30, dq_scale=0.02)
    limits = np.maximum(0.5 * np.abs(unconstrained_policy(probe, plan, q0, v0)), 0.05)
    settings = VWBCSettings(solver=solver, warm_start=warm_start, eps_abs=1e-10)
    vwbc = VWBCController(robot, settings, torque_limits=limits)
    for tick in range(5):
        q, v = perturbed_state(robot, seed=30 + tick, dq_scale=0.02)
        tau = vwbc.compute(0.01 * tick, measured(q, v), plan).copy()
        assert vwbc.last_used_qp, vwbc.last_status
        assert np.all(np.abs(tau) <= limits + 1e-9)
        assert np.any(np.abs(np.abs(tau) - limits) < 1e-7)  # some bound is active
        expected = cold_solution(robot, plan, settings, 0.01 * tick, q, v, limits)
        np.testing.assert_allclose(tau, expected, atol=1e-5)
    assert vwbc.fallbacks == 0


@pytest.mark.parametrize("solver", SOLVERS)
def test_alternating_stance_and_flight_with_previous_warm_start(robot, solver):
    """The QP's size changes between ticks (stance patterns of a bound / pronk); each tick must solve."""
    patterns = [FOUR, FLIGHT, FLIGHT, TROT, FLIGHT, ~TROT, FOUR, FLIGHT, TROT, TROT, FLIGHT, FOUR]
    plan = multi_pattern_plan(robot, patterns, seed=40)
    settings = VWBCSettings(solver=solver, warm_start="previous", eps_abs=1e-10)
    vwbc = VWBCController(robot, settings, torque_limits=GENEROUS)
    seen = []
    for tick in range(2 * len(patterns)):  # two ticks per knot: same-pattern and changed-pattern ticks
        t = 0.01 * tick
        q, v = perturbed_state(robot, seed=50 + tick)
        tau = vwbc.compute(t, measured(q, v), plan).copy()
        assert vwbc.last_used_qp, (tick, vwbc.last_status)
        stance = plan.contacts[plan.knot_at(t)]
        assert np.array_equal(vwbc.last_stance, stance)
        assert np.all(vwbc.last_forces[~stance] == 0.0)
        seen.append(int(stance.sum()))
        expected = cold_solution(robot, plan, settings, t, q, v, GENEROUS)
        np.testing.assert_allclose(tau, expected, atol=1e-5)
    assert {0, 2, 4} <= set(seen)
    assert vwbc.fallbacks == 0
    # alternating whole plans (a new plan every tick, as after each MPC update) with the robot's limits
    flight_plan, stance_plan = synthetic_plan(robot, FLIGHT, seed=60), synthetic_plan(robot, FOUR, seed=61)
    vwbc = VWBCController(robot, settings)
    for tick in range(8):
        vwbc_plan = flight_plan if tick % 2 else stance_plan
        q, v = perturbed_state(robot, seed=70 + tick)
        vwbc.compute(0.002 * tick, measured(q, v), vwbc_plan)
        assert vwbc.last_used_qp, (tick, vwbc.last_status)
    assert vwbc.statistics()["fallbacks"] == 0


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("error", [IndexError, KeyError, ZeroDivisionError])
def test_exception_in_qp_solver_falls_back_and_recovers(robot, solver, error, monkeypatch):
    """Any exception inside the QP falls back to the clamped Riccati torque; the run goes on."""
    plan = synthetic_plan(robot, seed=17)
    limits = np.full(12, 5.0)
    vwbc = VWBCController(robot, VWBCSettings(solver=solver, warm_start="previous"), torque_limits=limits)
    riccati = RiccatiController(robot, clamp=False)
    q, v = perturbed_state(robot, seed=18)
    vwbc.compute(
        0.0, measured(q, v), plan
    )  # a solved tick first: the solver object exists and holds a solution
    assert vwbc.last_used_qp
    backend = type(vwbc._qps[tuple(FOUR)])
    original = backend.solve

    def broken(self, mode):
        raise error("deep inside the solver")

    monkeypatch.setattr(backend, "solve", broken)
    tau = vwbc.compute(0.002, measured(q, v), plan).copy()
    assert not vwbc.last_used_qp and np.all(np.isfinite(tau))
    np.testing.assert_allclose(tau, np.clip(riccati.torques_at(0.002, q, v, plan), -limits, limits))
    stats = vwbc.statistics()
    assert stats["fallbacks"] == 1 and stats["fallback_reasons"] == {"exception": 1}
    assert stats["qp_exceptions"] == {error.__name__: 1}
    assert vwbc.last_error.startswith(error.__name__) and vwbc.last_status == f"exception:{error.__name__}"
    assert tuple(FOUR) not in vwbc._qps  # the possibly half-updated solver is dropped ...
    monkeypatch.setattr(backend, "solve", original)
    tau = vwbc.compute(0.004, measured(q, v), plan).copy()  # ... and rebuilt on the next tick
    assert vwbc.last_used_qp and vwbc.statistics()["fallbacks"] == 1
    np.testing.assert_allclose(tau, cold_solution(robot, plan, vwbc.settings, 0.004, q, v, limits), atol=1e-4)


def moving_plan(robot, touchdown=False):
    """A two-knot plan (dt 0.02 s) whose second state is away from the first (configuration and velocity);
    ``touchdown``: the first knot is a flight knot, so its interval ends in a touchdown."""
    plan = synthetic_plan(robot, knots=2, dt=0.02, seed=4)
    nq = robot.nq
    rng = np.random.default_rng(5)
    xs = plan.xs.copy()
    xs[1, :nq] = pin.integrate(robot.model, xs[0, :nq], 0.05 * rng.normal(size=robot.nv))
    xs[1, nq:] = xs[0, nq:] + rng.normal(size=robot.nv)
    xs[2] = xs[1]
    contacts = plan.contacts.copy()
    if touchdown:
        contacts[0] = False
    return Plan(plan.times, xs, plan.us, plan.K, plan.Qu, plan.Quu, plan.Qux, contacts, plan.forces, plan.dt)


def test_plan_state_at_interpolates_inside_the_knot(robot):
    """``Plan.state_at``: the configuration on the manifold and the velocity linearly between the knot's state
    and the next; the velocity held over an interval that ends in a touchdown; clamped to the interval."""
    nq = robot.nq
    out = np.zeros(nq + robot.nv)
    plan = moving_plan(robot)
    x0, x1 = plan.xs[0], plan.xs[1]
    np.testing.assert_allclose(plan.state_at(robot.model, 0.0, 0, out), x0)
    middle = plan.state_at(robot.model, 0.015, 0, out).copy()
    np.testing.assert_allclose(middle[:nq], pin.interpolate(robot.model, x0[:nq], x1[:nq], 0.75))
    np.testing.assert_allclose(middle[nq:], 0.25 * x0[nq:] + 0.75 * x1[nq:])
    np.testing.assert_allclose(plan.state_at(robot.model, 0.5, 0, out), x1)  # clamped to the interval
    landing = moving_plan(robot, touchdown=True)
    state = landing.state_at(robot.model, 0.015, 0, out)
    np.testing.assert_allclose(state[:nq], middle[:nq])
    np.testing.assert_allclose(state[nq:], x0[nq:])  # the next state holds the velocity after the impact


@pytest.mark.parametrize("solver", SOLVERS)
def test_interpolated_state_reference_follows_the_plan_inside_the_knot(robot, solver):
    """With ``state_reference: interpolated`` a robot exactly on the plan's state at t (between two knots)
    gets the knot's planned torque, as one on ``x*_k`` at the knot's start does; measured against the held
    ``x*_k`` (the default) the same robot gets a feedback torque."""
    plan = moving_plan(robot)
    q, v = np.split(plan.state_at(robot.model, 0.015, 0, np.zeros(robot.nq + robot.nv)), [robot.nq])
    interpolated = VWBCController(
        robot, VWBCSettings(solver=solver, eps_abs=1e-10, state_reference="interpolated"), GENEROUS
    )
    held = VWBCController(robot, VWBCSettings(solver=solver, eps_abs=1e-10), GENEROUS)
    on_knot = VWBCController(robot, VWBCSettings(solver=solver, eps_abs=1e-10), GENEROUS)
    x0 = plan.xs[0]
    reference = on_knot.compute(0.0, measured(x0[: robot.nq], x0[robot.nq :]), plan).copy()
    tau = interpolated.compute(0.015, measured(q, v), plan).copy()
    assert interpolated.last_used_qp and on_knot.last_used_qp
    np.testing.assert_allclose(tau, reference, atol=1e-6)
    assert np.max(np.abs(held.compute(0.015, measured(q, v), plan) - reference)) > 1.0
