"""The template-MPC baseline (paper Sec. VII-C): stance torque map, plan message, SRB problem, closed loop.

``planner: template`` plans over the SRB only (``mpc.template``) and follows the plan with planned GRFs on
the stance legs and joint PD on the swing legs (``wbc.template_low_level``).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from cafe_mpc.assembly import load_run_config
from cafe_mpc.assembly.controllers import build_mpc
from cafe_mpc.config import ConfigError
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.physics import GRAVITY
from cafe_mpc.core.template_plan import TemplatePlan
from cafe_mpc.dynamics.statics import static_stance_torques
from cafe_mpc.experiments.run import run_metrics, simulate_run
from cafe_mpc.mpc.template import (
    ConstrainedSRBKnot,
    TemplateMpc,
    TemplateProblemBuilder,
    TemplateSettings,
    template_srb,
)
from cafe_mpc.wbc.template_low_level import TemplateLowLevelController, stance_torques

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
    parameters, offset = template_srb(robot)
    builder = TemplateProblemBuilder(robot, TemplateSettings(parameters=parameters), offset)
    return TemplateMpc(robot, build_mpc(config, robot).reference, builder, config.mpc)


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


def test_constraint_barrier_gradient_matches_finite_differences(robot):
    mpc = _template_mpc(robot)
    built = mpc.builder.build(0.0, robot.x_standing, mpc.reference)
    mpc.builder.update_torque_maps(built, built.reference_states)
    knot: ConstrainedSRBKnot = built.knots[0]
    data = knot.create_data()
    x = built.reference_states[0]
    u = np.tile([3.0, -2.0, 60.0], 4)  # inside the cone, near the torque limits
    knot.calc(data, x, u)
    knot.calc_diff(data, x, u)
    gradient = data.Lu.copy()
    step = 1e-6
    numeric = np.zeros(12)
    for i in range(12):
        up, down = u.copy(), u.copy()
        up[i] += step
        down[i] -= step
        knot.calc(data, x, up)
        cost_up = data.cost
        knot.calc(data, x, down)
        numeric[i] = (cost_up - data.cost) / (2 * step)
    np.testing.assert_allclose(gradient, numeric, rtol=1e-5, atol=1e-7)


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
    with pytest.raises(ConfigError, match="simulated time only"):
        load_run_config("trot", ["planner=template", "simulation.realtime=true"])
    with pytest.raises(ConfigError, match="whole number of milliseconds"):
        load_run_config("trot", ["planner=template", "template.dt=0.0125"])


# ------------------------------------------------------------------------------------------ closed loop
DURATION = 1.5


def test_template_trot_stays_up_and_moves_forward():
    config = load_run_config(
        "trot",
        [f"simulation.duration={DURATION}", "planner=template", "output.plots=false", "mpc.latency=fixed"],
    )
    robot, controller, log = simulate_run(config)
    metrics = run_metrics(config, robot, controller, log)
    assert not log.fell, log.fall_reason
    assert metrics["controller"] == "template" and metrics["planner"] == "template"
    assert metrics["base_height_min"] > 0.2
    assert log.q[-1, 0] - log.q[0, 0] > 0.5 * 0.5 * DURATION  # at least half the commanded distance
    assert abs(log.q[-1, 1] - log.q[0, 1]) < 0.1
    assert metrics["vx_mean"] > 0.3
    assert metrics["mpc"]["failures"] == 0 and metrics["mpc"]["pd_fallback_ticks"] == 0
    assert np.all(np.abs(log.torque_command) <= robot.torque_limits + 1e-6)
