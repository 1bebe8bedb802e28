"""The template-MPC baseline (paper Sec. VII-C): stance torque map, plan message, SRB problem, closed loop.

``planner: template`` plans over the SRB only (``planners.template``) and follows the plan with planned GRFs
on the stance legs and joint PD on the swing legs (``planners.template.low_level``).
"""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest

from cafe_mpc.assembly import load_run_config, resolve
from cafe_mpc.assembly.controllers import build_planner
from cafe_mpc.config import ConfigError, TemplateSettings
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.dynamics.statics import static_stance_torques
from cafe_mpc.ocp.contact_schedule import GAITS
from cafe_mpc.planners.template.low_level import TemplateLowLevelController, stance_torques
from cafe_mpc.planners.template.plan import TemplatePlan
from cafe_mpc.planners.template.planner import TemplateMpc
from cafe_mpc.planners.template.problem import TemplateProblemBuilder, VerticalOscillation
from cafe_mpc.robots.robot import load_robot
from cafe_mpc_lab.experiments.run import run_metrics, simulate_run
from cafe_mpc_lab.experiments.sweep import run_experiment
from cafe_mpc_lab.experiments.template_gaits import pitch_swing, vertical_force_capacity

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


# ------------------------------------------------------------------------------------ stance torque map
def test_stance_torques_are_the_static_equilibrium(robot):
    """Vertical GRFs that carry the weight: J' F plus leg gravity equals ``static_stance_torques``."""
    q = robot.q_standing
    weight = robot.total_mass * GRAVITY
    forces = np.zeros((4, 3))
    forces[:, 2] = weight / 4
    np.testing.assert_allclose(
        stance_torques(robot, q, forces, np.ones(4, dtype=bool)), static_stance_torques(robot, q), atol=1e-10
    )
    # a trot pair carrying half the weight each (the gait's average stance force)
    stance = np.array([True, False, False, True])
    forces = np.zeros((4, 3))
    forces[stance, 2] = weight / 2
    np.testing.assert_allclose(
        stance_torques(robot, q, forces, stance),
        static_stance_torques(robot, q, stance, weight / 2),
        atol=1e-10,
    )


def test_stance_torques_are_minus_jacobian_transpose(robot):
    """Without leg gravity: tau_leg = -J_foot' F on stance legs (the force on the foot), zero on swing legs;
    checked at a random configuration against Pinocchio's frame Jacobians."""
    rng = np.random.default_rng(3)
    q = robot.q_standing.copy()
    q[7:] += rng.uniform(-0.3, 0.3, robot.nu)
    q[3:7] = pin.Quaternion(pin.exp3(rng.uniform(-0.3, 0.3, 3))).coeffs()
    forces = rng.uniform(-20, 20, (4, 3))
    stance = np.array([True, False, True, True])
    torques = stance_torques(robot, q, forces, stance, leg_gravity=False)
    model, data = robot.model, robot.model.createData()
    expected = np.zeros(robot.nu)
    for foot, frame_id in enumerate(robot.foot_frame_ids):
        if stance[foot]:
            jacobian = pin.computeFrameJacobian(model, data, q, frame_id, LWA)[:3, 6:]
            expected -= jacobian.T @ forces[foot]
    np.testing.assert_allclose(torques, expected, atol=1e-10)
    np.testing.assert_allclose(torques[3:6], 0.0, atol=1e-12)  # FR swings


# -------------------------------------------------------------------------------------------- the plan
def test_template_plan_holds_forces_and_interpolates_feet():
    times = np.array([0.0, 0.004, 0.014])
    dt = np.array([0.004, 0.01, 0.01])
    forces = np.arange(3 * 4 * 3, dtype=float).reshape(3, 4, 3)
    knot_times = np.append(times, 0.024)
    # a cubic in time is reproduced exactly by the Hermite interpolation of positions and velocities
    positions = np.zeros((4, 4, 3))
    velocities = np.zeros((4, 4, 3))
    positions[:, 0, 2] = 2.0 * knot_times**3 - knot_times
    velocities[:, 0, 2] = 6.0 * knot_times**2 - 1.0
    plan = TemplatePlan(
        times, dt, np.zeros((4, 13)), forces, np.ones((3, 4), dtype=bool), positions, velocities
    )
    assert plan.knot_at(-1.0) == 0
    assert plan.knot_at(0.0039) == 0
    assert plan.knot_at(0.004) == 1  # zero-order hold: the interval that starts at t
    assert plan.knot_at(0.02) == 2
    assert plan.knot_at(1.0) == 2
    assert plan.end_time == pytest.approx(0.024)
    p, v = np.zeros((4, 3)), np.zeros((4, 3))
    for t in (0.001, 0.009, 0.017):
        plan.feet_at(t, p, v)
        assert p[0, 2] == pytest.approx(2.0 * t**3 - t, abs=1e-12)
        assert v[0, 2] == pytest.approx(6.0 * t**2 - 1.0, abs=1e-10)
    with pytest.raises(ValueError, match="base_states"):
        TemplatePlan(times, dt, np.zeros((3, 13)), forces, np.ones((3, 4), dtype=bool), positions, velocities)


# ----------------------------------------------------------------------------------------- the problem
def _template_mpc(robot, preset="trot", overrides=()):
    config = load_run_config(preset, ["mpc.latency=fixed", *overrides])
    builder = TemplateProblemBuilder(robot, TemplateSettings())
    return TemplateMpc(robot, build_planner(resolve(config, robot)).reference, builder, config.mpc)


def test_knots_lie_on_the_absolute_grid_and_switch_with_the_gait(robot):
    mpc = _template_mpc(robot)
    times = mpc.builder.knot_times(0.123)
    assert times[0] == 0.123
    np.testing.assert_allclose(times[1:4], [0.13, 0.14, 0.15])
    assert len(times) == 51
    built = mpc.builder.build(0.123, robot.x_standing, mpc.reference)
    # the trot switches its diagonal pairs every 0.25 s: exactly at knot 0.25 (no straddling interval)
    switch = int(np.argmin(np.abs(built.times - 0.25)))
    assert built.times[switch] == pytest.approx(0.25)
    assert tuple(built.contacts[switch - 1]) == mpc.reference.stance_at(0.2499)
    assert tuple(built.contacts[switch]) == mpc.reference.stance_at(0.2501)
    assert built.problem.x0[2] == pytest.approx(robot.q_standing[2] + mpc.builder.com_offset[2])


def test_knots_split_at_contact_switches_off_the_grid(robot):
    """MIT's bound switches every 26 ms segment boundary (0.104 s stance, 0.026 s flight after the 0.2 s
    stand): off the 10 ms grid, each switch gets a knot of its own and the stance flags change there."""
    mpc = _template_mpc(robot, "bound", ["gait.name=bound_short_flight"])
    built = mpc.builder.build(0.25, robot.x_standing, mpc.reference)
    for switch in (0.304, 0.330, 0.434, 0.460, 0.564, 0.590, 0.694, 0.720):
        k = int(np.argmin(np.abs(built.times - switch)))
        assert built.times[k] == pytest.approx(switch, abs=1e-9)
        assert tuple(built.contacts[k - 1]) == mpc.reference.stance_at(switch - 1e-4)
        assert tuple(built.contacts[k]) == mpc.reference.stance_at(switch + 1e-4)
        assert tuple(built.contacts[k - 1]) != tuple(built.contacts[k])
    grid = built.times[1:][np.abs(built.times[1:] / 0.01 - np.round(built.times[1:] / 0.01)) < 1e-6]
    np.testing.assert_allclose(np.diff(grid), 0.01, atol=1e-9)  # the 10 ms grid is kept around them
    assert built.times[-1] == pytest.approx(0.75)


def test_vertical_oscillation_is_the_motion_the_force_references_imply():
    """Under ``support_factor * m g`` per stance foot the body accelerates at ``g (n s - 1)``: the oscillation
    integrates that with zero mean height and speed, periodically; none for a trot (always two feet at s =
    1/2)."""
    for name in ("pronk", "bound", "bound_short_flight", "pronk_short_flight"):
        gait = GAITS[name]
        oscillation = VerticalOscillation(gait)
        times = np.linspace(0.0, gait.period, 2601)
        values = np.array([oscillation.at(float(t)) for t in times])
        assert abs(np.mean(values[:-1, 0])) < 1e-6 and abs(np.mean(values[:-1, 1])) < 1e-4
        np.testing.assert_allclose(values[0], values[-1], atol=1e-9)  # periodic
        step = times[1] - times[0]
        np.testing.assert_allclose(np.gradient(values[:, 0], step)[5:-5], values[5:-5, 1], atol=2e-3)
        for t in (0.01, 0.5 * gait.period + 0.01):
            flags = gait.flags_at(t)
            expected = GRAVITY * (sum(flags) * gait.support_factor - 1.0)
            rate = (oscillation.at(t + 1e-5)[1] - oscillation.at(t - 1e-5)[1]) / 2e-5
            assert rate == pytest.approx(expected, rel=1e-6)
    trot = VerticalOscillation(GAITS["trot"])
    assert trot.at(0.1) == pytest.approx((0.0, 0.0), abs=1e-12)
    # the paper's pronk: apex g Tf^2 / 8 above touchdown (0.2 s flight), lowest point (2 g) Ts^2 / 8 below it
    heights = [VerticalOscillation(GAITS["pronk"]).at(float(t))[0] for t in np.linspace(0, 0.3, 3001)]
    assert np.ptp(heights) == pytest.approx(GRAVITY * 0.2**2 / 8 + 2 * GRAVITY * 0.1**2 / 8, rel=1e-4)


def test_updates_start_from_the_measured_centroidal_state(robot):
    """The SRB's initial state: the robot's centre of mass and its velocity, and the angular velocity whose
    SRB momentum is the centroidal angular momentum (legs included), about the base orientation."""
    mpc = _template_mpc(robot)
    rng = np.random.default_rng(3)
    q = robot.q_standing.copy()
    q[3:7] = pin.Quaternion(pin.exp3(np.array([0.05, -0.1, 0.3]))).coeffs()
    q[7:] += rng.uniform(-0.2, 0.2, robot.nu)
    v = rng.uniform(-1.0, 1.0, robot.nv)
    state = mpc.builder.initial_state(np.concatenate([q, v]))
    data = robot.model.createData()
    np.testing.assert_allclose(state[0:3], pin.centerOfMass(robot.model, data, q, v), atol=1e-12)
    np.testing.assert_allclose(state[7:10], data.vcom[0], atol=1e-12)
    np.testing.assert_allclose(state[3:7], q[3:7])
    momentum = pin.computeCentroidalMomentum(robot.model, data, q, v).angular
    inertia = np.asarray(mpc.builder.parameters.inertia)
    rotation = pin.Quaternion(q[6], q[3], q[4], q[5]).toRotationMatrix()
    np.testing.assert_allclose(rotation @ inertia @ state[10:13], momentum, atol=1e-10)
    # legs at rest: the base's own angular velocity is the SRB's up to the legs' share of the inertia
    v[6:] = 0.0
    rested = mpc.builder.initial_state(np.concatenate([q, v]))
    assert np.dot(rested[10:13], v[3:6]) > 0.5 * np.dot(v[3:6], v[3:6])


def test_latency_prediction_runs_the_plan_in_effect(robot):
    """``predict_start``: the SRB state where the next plan takes effect, under the previous plan's forces.
    Standing, the plan's forces carry the weight (the state stays put); with them zeroed, the body falls
    freely over the predicted 20 ms."""
    mpc = _template_mpc(robot, "trot", ["gait.name=stand", "gait.commands.0.vx=0"])
    assert mpc.expected_latency() == pytest.approx(0.02)  # fixed latency
    mpc.update(0.0, robot.q_standing, np.zeros(robot.nv))
    start = mpc.builder.initial_state(robot.x_standing)
    held = mpc.predict_start(0.0, 0.02, start)
    assert abs(held[2] - start[2]) < 1e-3 and abs(held[9]) < 0.02
    mpc.previous[1].phases[0].us[:] = 0.0
    falling = mpc.predict_start(0.0, 0.02, start)
    assert falling[9] == pytest.approx(-GRAVITY * 0.02, rel=1e-6)
    assert 0.0 < start[2] - falling[2] <= 0.5 * GRAVITY * 0.02**2 + 1e-9  # (explicit Euler: below it)
    built = mpc._build(0.0)  # the next problem starts at the predicted time, from the predicted state
    assert built.times[0] == pytest.approx(0.02)
    np.testing.assert_allclose(built.problem.x0, falling)
    # measured latency: the in-loop updates' median wall time, not the cold first solve's
    standing = ["gait.name=stand", "gait.commands.0.vx=0", "mpc.latency=measured"]
    measured = _template_mpc(robot, "trot", standing)
    measured.update(0.0, robot.q_standing, np.zeros(robot.nv))
    assert measured.expected_latency() == 0.0
    for t in (0.02, 0.04, 0.06):
        measured.update(t, robot.q_standing, np.zeros(robot.nv))
    assert measured.expected_latency() == pytest.approx(np.median(measured.statistics.update_times[1:]))


def test_standing_plan_carries_the_weight_inside_the_cone(robot):
    mpc = _template_mpc(robot, "trot", ["gait.name=stand", "gait.commands.0.vx=0"])
    plan = mpc.update(0.0, robot.q_standing, np.zeros(robot.nv))
    assert plan is not None and plan.contacts.all()
    weight = mpc.builder.weight
    np.testing.assert_allclose(plan.forces[:, :, 2].sum(axis=1), weight, rtol=0.05)
    assert np.all(plan.forces[:, :, 2] > 0)
    assert np.all(np.abs(plan.forces[:, :, :2]) <= 0.6 * plan.forces[:, :, 2:3])


def test_low_level_needs_a_template_plan(robot):
    controller = TemplateLowLevelController(robot)
    measurement = Measurement.of_state(robot.q_standing, np.zeros(robot.nv), np.ones(4, dtype=bool))
    with pytest.raises(RuntimeError, match="TemplatePlan"):
        controller.compute(0.0, measurement, None)


# ---------------------------------------------------------------------------------------------- config
def test_planner_is_validated():
    assert load_run_config("trot").planner == "cafe"
    assert load_run_config("trot", ["planner=template"]).planner == "template"
    with pytest.raises(ConfigError, match="planner"):
        load_run_config("trot", ["planner=hkd"])
    with pytest.raises(ConfigError, match="whole number of milliseconds"):
        load_run_config("trot", ["planner=template", "template.dt=0.0125"])


# ------------------------------------------------------------------------------------------ closed loop
DURATION = 1.5


def test_template_trot_stays_up_and_moves_forward():
    config = load_run_config(
        "trot",
        [f"simulation.duration={DURATION}", "planner=template", "output.plots=false", "mpc.latency=fixed"],
    )
    resolved, controller, log = simulate_run(config)
    robot = resolved.robot
    metrics = run_metrics(resolved, controller, log)
    assert not log.fell, log.fall_reason
    assert metrics["controller"] == "template" and metrics["planner"] == "template"
    assert metrics["base_height_min"] > 0.2
    assert log.q[-1, 0] - log.q[0, 0] > 0.5 * 0.5 * DURATION  # at least half the commanded distance
    assert abs(log.q[-1, 1] - log.q[0, 1]) < 0.1
    assert metrics["vx_mean"] > 0.3
    assert metrics["mpc"]["failures"] == 0 and metrics["mpc"]["pd_fallback_ticks"] == 0
    assert np.all(np.abs(log.torque_command) <= robot.torque_limits + 1e-6)


def test_template_bounds_with_the_short_flight_timing():
    """MIT's bound timing (0.104 s stance, 0.026 s flights), fixed latency, planned with the floor's friction
    (0.6): the template bounds for 2 s (1.3 s at the full 0.5 m/s), with a pitch oscillation that stays
    bounded. With the controller's default margin (``mpc.friction`` 0.4) the template falls at 1.55 s
    (measured, not analysed further)."""
    duration = 2.0
    config = load_run_config(
        "bound",
        [
            f"simulation.duration={duration}",
            "planner=template",
            "gait.name=bound_short_flight",
            "output.plots=false",
            "mpc.latency=fixed",
            "mpc.friction=0.6",
        ],
    )
    resolved, controller, log = simulate_run(config)
    metrics = run_metrics(resolved, controller, log)
    assert not log.fell, log.fall_reason
    assert metrics["base_height_min"] > 0.18
    assert metrics["pitch_abs_max_rad"] < 0.3
    late = log.time >= 1.0
    assert (log.q[late][-1, 0] - log.q[late][0, 0]) / (log.time[late][-1] - log.time[late][0]) > 0.35
    flights = ~log.extra["planned_stance"].any(axis=1)
    assert 0.05 < np.mean(flights[late]) < 0.4  # two 26 ms flights per 0.26 s cycle planned: 0.2
    assert metrics["mpc"]["failures"] == 0 and metrics["mpc"]["pd_fallback_ticks"] == 0


# -------------------------------------------------------------------------------- template-gaits experiment
def test_leg_capacity_and_forced_pitch_rate(robot):
    """The diagnosis' static numbers: the motor limits (26 Nm knees) give a leg more vertical force than the
    plan's 17 Nm; only the bound (front and hind pairs apart) forces a pitch rate, less with MIT's shorter
    stances, and much less pitch is turned in its 26 ms flights."""
    capacity = vertical_force_capacity(robot)
    assert 60.0 < capacity < 200.0
    assert vertical_force_capacity(robot, robot.plant.motor_torque_limits) > capacity
    paper, paper_turn = pitch_swing(GAITS["bound"], robot, 0.6)
    mit, mit_turn = pitch_swing(GAITS["bound_short_flight"], robot, 0.6)
    assert paper > mit > 0.0 and paper_turn > 3.0 * mit_turn > 0.0
    for name in ("trot", "pace", "pronk", "pronk_short_flight"):
        assert pitch_swing(GAITS[name], robot, 0.6) == (0.0, 0.0)
    assert pitch_swing(GAITS["bound"], robot, 5.0) == (0.0, 0.0)  # friction enough to cancel the moment


def test_template_gaits_experiment_reports_both_timings(tmp_path):
    """A short run of the experiment (the start stand only): the variants, the per-gait demand and the
    comparison files."""
    out = tmp_path / "gaits"
    run_experiment(
        "template-gaits",
        out,
        duration=0.3,
        overrides=["mpc.latency=fixed"],
        scheduler="synchronous",
        gaits="bound,bound-mit",
        planners="template",
    )
    comparison = json.loads((out / "comparison.json").read_text())
    rows = comparison["variants"]
    assert set(rows) == {"bound-template", "bound-mit-template"}
    weight = load_robot("mini_cheetah").total_mass * GRAVITY
    assert rows["bound-template"]["demand_per_foot_n"] == pytest.approx(weight)
    assert rows["bound-mit-template"]["demand_per_foot_n"] == pytest.approx(0.625 * weight)
    assert rows["bound-template"]["pitch_rate_swing"] > rows["bound-mit-template"]["pitch_rate_swing"]
    for row in rows.values():
        assert row["status"] == "ok" and row["timing_mode"] == "fixed" and not row["fell"]
        assert row["planned_force_max_n"] > 0.0
    text = (out / "comparison.md").read_text()
    assert "bound_short_flight" in text and "demand / capacity" in text
    assert (out / "comparison.png").is_file()
