"""Gait run configs (validation, presets, controller construction) and the run metrics on synthetic logs.

No closed-loop gait runs here (those are in the MPC tests): every test is construction or arithmetic.
"""

import logging
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from cafe_mpc.assembly import load_run_config, resolve
from cafe_mpc.config import ConfigError, VelocityCommand, available_presets
from cafe_mpc.control.inline import InlineMpcLoop
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.dynamics.srb import srb_parameters
from cafe_mpc.low_level.motor_strength import MotorStrengthCompensation, OnlineSupportCompensation
from cafe_mpc.low_level.pd import PDController
from cafe_mpc.low_level.riccati import RiccatiController
from cafe_mpc.low_level.synthetic import synthetic_plan
from cafe_mpc.low_level.vwbc import VWBCController
from cafe_mpc.planners.cafe.setup import model_schedule
from cafe_mpc.reference.locomotion import quaternion_from_yaw
from cafe_mpc.robots.robot import load_robot
from cafe_mpc_lab.cli import main
from cafe_mpc_lab.experiments.controllers import LowLevelRecorder, build_run_controller, low_level_of
from cafe_mpc_lab.experiments.run import run
from cafe_mpc_lab.report.metrics import (
    METRICS_WINDOW_START_S,
    foot_slip_max,
    foot_trajectories,
    tracking_metrics,
    wbc_metrics,
)
from cafe_mpc_lab.sim.loop import SimulationLog

GAIT_PRESETS = ["trot", "pace", "bound", "pronk", "flying-trot", "trot-commands", "bound-push"]


# ------------------------------------------------------------------------------------------- config
@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["gait.name=gallop"], "gait.name: unknown gait 'gallop'"),
        (["gait.commands.0.vx=10"], "gait.commands.0: command vx = 10"),
        (["gait.commands.0.height=0.6"], "gait.commands.0: command height = 0.6"),
        (["gait.commands=[{start: 1.0, vx: 0.2}]"], "first command must start at 0"),
        (["gait.commands=[{vx: 0.2}, {start: 2, vx: 0.3}, {start: 1, vx: 0.4}]"], "increase strictly"),
        (["gait.swing_height=0.5"], "gait.swing_height"),
        (["gait.start_stance=-0.1"], "gait.start_stance: Input should be greater than or equal to 0"),
        (["gait.start_stance=.nan"], "gait.start_stance"),
        (["gait.start_stance=.inf"], "gait.start_stance"),
        (["gait.start_stance=soon"], "gait.start_stance"),
        (["mpc.schedule=S7"], "mpc.schedule: unknown model schedule 'S7'"),
        (["mpc.srb_horizon=0.3"], "give either schedule"),
        (
            ["mpc.schedule=null", "mpc.whole_body_horizon=0.005", "mpc.srb_horizon=0.3"],
            "shorter than one whole-body knot",
        ),
        (
            ["mpc.schedule=null", "mpc.whole_body_horizon=0.25"],
            "give both whole_body_horizon and srb_horizon",
        ),
        (["mpc.period=-0.02"], "mpc.period: Input should be greater than 0"),
        (["mpc.period=0.001"], "shorter than the control period"),
        (["mpc.latency=sometimes"], "mpc.latency"),
        (["wbc=osc"], "wbc: Input should be 'pd', 'balance', 'riccati' or 'vwbc'"),
        (["wbc=pd"], "wbc: 'pd' stands in place"),
        (["gait=null"], "needs a gait section"),
        (["vwbc.solver=qpoases"], "vwbc.solver"),
        (["costs.running.torque=-1"], "costs.running: torque: weights must be finite and non-negative"),
        (["costs.terminal.base_position=[1, 2]"], "costs.terminal.base_position"),
        (["gait.commands.0.speed=1"], "unknown config key 'gait.commands.0.speed'"),
    ],
)
def test_bad_gait_config_names_the_key(overrides, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(")) as error:
        load_run_config("bound", overrides)
    assert "\n" not in str(error.value)


def test_gait_names_overrides_and_defaults():
    config = load_run_config("stand", ["wbc=riccati", "gait.name=flying-trot", "gait.commands.0.vx=0.8"])
    assert config.gait is not None and config.gait.name == "flying_trot"
    assert config.gait.commands[0].vx == 0.8
    config = load_run_config("stand", ["wbc=vwbc", "gait={name: pace}"])
    assert config.gait.commands[0].vx == 0.5  # default command
    assert config.vwbc.solver == "daqp" and config.vwbc.warm_start == "previous"
    config = load_run_config(
        "bound", ["mpc.schedule=null", "mpc.whole_body_horizon=0.2", "mpc.srb_horizon=0.3"]
    )
    schedule = model_schedule(config.mpc)
    assert (schedule.whole_body_knots, schedule.srb_knots) == (20, 6)
    stand = load_run_config("stand")
    assert stand.wbc == "pd" and stand.gait is None
    # the authors' regular weights are the cost defaults
    assert tuple(stand.costs.running.base_position) == (0.0, 0.0, 10.0, 1.0, 2.0, 2.0)
    assert stand.costs.terminal.torque == 0.0


@pytest.mark.parametrize("preset", sorted(set(available_presets()) | set(GAIT_PRESETS)))
def test_every_preset_loads_and_builds_its_controller(robot, preset):
    config = load_run_config(preset)
    controller = build_run_controller(resolve(config, robot))
    if config.wbc == "pd":
        assert isinstance(controller, PDController)
        return
    assert isinstance(controller, InlineMpcLoop)
    expected = {"riccati": RiccatiController, "vwbc": VWBCController}[config.wbc]
    low_level = low_level_of(controller)
    while isinstance(low_level, (MotorStrengthCompensation, OnlineSupportCompensation)):
        low_level = low_level.inner  # the commands for the motors (calibration, its online estimate)
    assert isinstance(low_level, expected)
    assert controller.planner.builder.schedule == model_schedule(config.mpc)
    assert controller.settings.period == config.mpc.period
    if config.gait is not None:  # presets with a reference section (barrel-roll) have no gait
        assert controller.reference.commands[0].vx == config.gait.commands[0].vx


def test_gait_presets_match_the_issues():
    for preset in ("trot", "pace", "bound", "pronk", "flying-trot"):
        config = load_run_config(preset)
        assert config.wbc == "vwbc" and config.mpc.schedule == "S4"
        assert config.simulation.duration == 10.0
        assert [(c.start, c.vx, c.vy, c.yaw_rate) for c in config.gait.commands] == [(0.0, 0.5, 0.0, 0.0)]
    commands = load_run_config("trot-commands").gait.commands
    assert max(c.vx for c in commands) == 0.8
    assert any(c.vy == 0.3 for c in commands) and any(c.yaw_rate == 0.5 for c in commands)
    push = load_run_config("bound-push")
    assert push.gait.name == "bound" and push.gait.commands[0].vx == 0.5
    assert push.simulation.duration == 5.0
    assert (push.pushes[0].start, push.pushes[0].duration) == (2.0, 0.05)
    assert push.pushes[0].velocity_change == (1.5, 0.0, 0.0)


@pytest.mark.slow
def test_go1_plans_its_srb_tail_with_its_own_mass_and_inertia(robot):
    go1 = load_robot("go1")
    controller = build_run_controller(
        resolve(load_run_config("trot", ["robot=go1", "simulation.duration=1"]), go1)
    )
    own = srb_parameters(go1)
    factory = controller.planner.builder.srb
    assert factory.settings.parameters == own
    assert factory.weight == pytest.approx(go1.total_mass * 9.81)
    built = controller.planner.builder.build(0.0, go1.x_standing, controller.reference)
    srb_phase = built.problem.phases[-1]
    assert built.phases[-1].kind == "srb"
    dynamics = srb_phase.running_models[0].dynamics
    assert dynamics.mass == pytest.approx(own.mass) and dynamics.mass > 12.0
    np.testing.assert_allclose(dynamics.inertia, own.inertia_matrix)
    # and the Mini Cheetah's own: the authors' mass, its lumped inertia
    mini = build_run_controller(
        resolve(load_run_config("trot"), robot)
    ).planner.builder.srb.settings.parameters
    assert mini.mass == pytest.approx(8.912) and mini == srb_parameters(robot)


def test_overrides_reach_the_controller(robot):
    config = load_run_config(
        "bound", ["wbc=riccati", "mpc.schedule=S0", "costs.running.torque=0.3", "gait.swing_height=0.08"]
    )
    controller = build_run_controller(resolve(config, robot))
    assert isinstance(low_level_of(controller), RiccatiController)
    assert controller.planner.builder.schedule.srb_knots == 0
    assert controller.planner.builder.whole_body.settings.running_weights.torque == 0.3
    assert controller.reference.swing_height == 0.08


def test_start_stance_reaches_the_reference(robot):
    gait_presets = ("trot", "pace", "bound", "bound-push", "pronk", "flying-trot", "trot-commands")
    for preset in gait_presets:  # every gait starts from a short stand, then ramps in its commands
        assert load_run_config(preset).gait.start_stance == 0.2
        assert load_run_config(preset).gait.command_ramp == 0.5
    assert load_run_config("stand", ["wbc=riccati", "gait.name=pace"]).gait.start_stance == 0.0  # the default
    assert load_run_config("stand", ["wbc=riccati", "gait.name=pace"]).gait.command_ramp == 0.0
    config = load_run_config("trot", ["gait.start_stance=0.35"])
    assert config.gait.start_stance == 0.35
    reference = build_run_controller(resolve(config, robot)).reference
    assert reference.start_stance == 0.35 and reference.cycle_start == 0.35
    assert (
        build_run_controller(
            resolve(load_run_config("trot", ["gait.start_stance=0"]), robot)
        ).reference.start_stance
        == 0.0
    )


def test_run_help_lists_presets(capsys):
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    out = capsys.readouterr().out
    for preset in GAIT_PRESETS:
        assert preset in out


# ------------------------------------------------------------------------------------------ metrics
def synthetic_log(robot, q: np.ndarray, v: np.ndarray, dt: float = 0.002, contacts=None) -> SimulationLog:
    ticks = len(q)
    log = SimulationLog.allocate(ticks, robot.nq, robot.nv, robot.nu, robot.n_feet)
    log.time[:] = dt * np.arange(ticks)
    log.q[:] = q
    log.v[:] = v
    log.contacts[:] = True if contacts is None else contacts
    log.ticks = ticks
    return log


def straight_line(robot, speed: float, yaw: float, seconds: float = 1.0, dt: float = 0.002):
    """Base moving at ``speed`` along its heading ``yaw`` at the standing height (base-frame velocity)."""
    ticks = round(seconds / dt)
    q = np.tile(robot.q_standing, (ticks, 1))
    distance = speed * dt * np.arange(ticks)
    q[:, 0], q[:, 1] = distance * math.cos(yaw), distance * math.sin(yaw)
    q[:, 3:7] = quaternion_from_yaw(yaw)
    v = np.zeros((ticks, robot.nv))
    v[:, 0] = speed
    return q, v


@pytest.mark.parametrize("yaw", [0.0, 1.2])
def test_tracking_of_a_constant_velocity_log_is_exact(robot, yaw):
    q, v = straight_line(robot, 0.5, yaw)
    log = synthetic_log(robot, q, v)
    metrics = tracking_metrics(
        robot, log, [VelocityCommand(start=0.0, vx=0.5)], window_start=METRICS_WINDOW_START_S
    )
    assert metrics["metrics_window_start_s"] == 0.5
    whole = tracking_metrics(robot, log, [VelocityCommand(start=0.0, vx=0.5)])  # the default: the whole run
    assert whole["metrics_window_start_s"] == 0.0 and whole["vx_rms_error"] == pytest.approx(0.0, abs=1e-9)
    assert metrics["vx_mean"] == pytest.approx(0.5)
    for key in ("vx_rms_error", "vy_rms_error", "yaw_rate_rms_error", "height_rms_error"):
        assert metrics[key] == pytest.approx(0.0, abs=1e-9), key
    assert metrics["pitch_rms"] == pytest.approx(0.0, abs=1e-9)
    assert metrics["pitch_rate_rms"] == pytest.approx(0.0, abs=1e-9)


def test_tracking_errors_against_changing_commands(robot):
    q, v = straight_line(robot, 0.5, 0.0, seconds=2.0)
    v[:, 5] = 0.2  # yaw rate about the (level) body z axis
    commands = [
        VelocityCommand(start=0.0, vx=0.5),
        VelocityCommand(start=1.0, vx=0.8, yaw_rate=0.2, height=0.27),
    ]
    metrics = tracking_metrics(
        robot, synthetic_log(robot, q, v), commands, window_start=METRICS_WINDOW_START_S
    )
    # from 0.5 s: 0.5 s at zero error, 1 s at 0.3 m/s error -> RMS 0.3 sqrt(2/3)
    assert metrics["vx_rms_error"] == pytest.approx(0.3 * math.sqrt(2.0 / 3.0), rel=1e-2)
    assert metrics["yaw_rate_rms_error"] == pytest.approx(0.2 * math.sqrt(1.0 / 3.0), rel=1e-2)
    assert metrics["height_rms_error"] == pytest.approx(0.02 * math.sqrt(2.0 / 3.0), rel=1e-2)
    short = tracking_metrics(
        robot, synthetic_log(robot, q[:100], v[:100]), commands, window_start=METRICS_WINDOW_START_S
    )
    assert short["metrics_window_start_s"] == 0.0 and short["vx_mean"] == pytest.approx(0.5)
    # the whole run: 1 s at zero error, 1 s at 0.3 m/s -> RMS 0.3 sqrt(1/2); the largest yaw-rate error 0.2
    whole = tracking_metrics(robot, synthetic_log(robot, q, v), commands)
    assert whole["vx_rms_error"] == pytest.approx(0.3 * math.sqrt(0.5), rel=1e-2)
    assert whole["yaw_rate_error_abs_max"] == pytest.approx(0.2, rel=1e-6)


def test_foot_slip_is_the_largest_slide_within_one_contact(robot):
    ticks = 10
    q = np.tile(robot.q_standing, (ticks, 1))
    q[:, 0] = np.linspace(0.0, 0.09, ticks)  # the whole robot (and so every foot) slides 1 cm per tick
    contacts = np.ones((ticks, 4), dtype=bool)
    contacts[5] = False  # lift-off at tick 5: stances are ticks 0-4 (4 cm) and 6-9 (3 cm)
    contacts[:, 1] = False  # a foot that never touches does not count
    feet = foot_trajectories(robot, q)
    assert np.allclose(feet[0], robot.foot_positions(robot.q_standing))
    assert foot_slip_max(feet, contacts) == pytest.approx(0.04)
    assert foot_slip_max(feet, np.zeros((ticks, 4), dtype=bool)) == 0.0
    metrics = wbc_metrics(
        robot, synthetic_log(robot, q, np.zeros((ticks, robot.nv)), contacts=contacts), "pd"
    )
    assert metrics["foot_slip_max_m"] == pytest.approx(0.04)
    assert metrics["controller"] == "pd" and metrics["torque_limit_violations"] == 0
    for key in ("qp_iterations_histogram", "qp_solve_time_ms_median", "qp_solve_time_ms_p99", "fallbacks"):
        assert metrics[key] is None


def test_wbc_metrics_count_limit_and_cone_violations(robot):
    ticks = 3
    q = np.tile(robot.q_standing, (ticks, 1))
    log = synthetic_log(robot, q, np.zeros((ticks, robot.nv)))
    log.torque_command[1, 2] = 30.0  # over the 17 Nm limit; with four feet on the ground the cone holds
    log.torque_command[2, :] = np.tile([8.0, 0.0, 0.0], 4)  # large abduction torques push the feet sideways
    metrics = wbc_metrics(robot, log, "pd")
    assert metrics["torque_limit_violations"] == 1
    assert metrics["friction_cone_violations"] >= 1
    given = wbc_metrics(
        robot,
        log,
        "vwbc",
        low_level_statistics={
            "torque_limit_violations": 0,
            "friction_cone_violations": 4,
            "qp_iterations_histogram": {1: 10, 2: 3},
            "qp_solve_time_ms_median": 0.1,
            "qp_solve_time_ms_p99": float("nan"),
            "fallbacks": 2,
        },
    )
    assert given["friction_cone_violations"] == 4 and given["fallbacks"] == 2
    assert given["qp_iterations_histogram"] == {"1": 10, "2": 3}
    assert given["qp_solve_time_ms_p99"] is None


def test_recorder_keeps_the_unclamped_riccati_request(robot):
    plan = synthetic_plan(robot, stance=(True, False, False, True), kp=400.0)
    recorder = LowLevelRecorder(RiccatiController(robot))
    q = robot.q_standing.copy()
    q[7:] += 0.2  # far from the plan: the feedback exceeds the limits
    sent = recorder.compute(0.002, Measurement.of_state(q, np.zeros(robot.nv), [True] * 4), plan).copy()
    requested, stance = recorder.traces(np.array([0.0, 0.002, 0.004]))
    assert np.all(np.abs(sent) <= robot.torque_limits + 1e-9)
    assert np.max(np.abs(requested[1]) - robot.torque_limits) > 0
    assert np.all(np.isnan(requested[[0, 2]]))
    assert stance[1].tolist() == [True, False, False, True] and not stance[0].any()
    assert recorder.inner.limit_violations == 1
    assert recorder.statistics()["torque_limit_violations"] == 1  # the inner controller's statistics
    recorder.reset()
    assert len(recorder.times) == 0 and recorder.statistics()["torque_limit_violations"] == 0


def test_recorder_preallocates_and_grows(robot):
    plan = synthetic_plan(robot, stance=(True, False, False, True))
    recorder = LowLevelRecorder(VWBCController(robot), capacity=3)
    buffers = (recorder._times, recorder._requested, recorder._stances)
    measurement = Measurement.of_state(robot.q_standing, np.zeros(robot.nv), [True] * 4)
    sent = [recorder.compute(0.002 * i, measurement, plan).copy() for i in (1, 2, 3)]
    current = (recorder._times, recorder._requested, recorder._stances)
    assert all(a is b for a, b in zip(current, buffers, strict=True))  # written in place, no new arrays
    for i in range(4, 7):  # past the capacity: the buffers double
        sent.append(recorder.compute(0.002 * i, measurement, plan).copy())
    assert len(recorder._times) == 6 and len(recorder.times) == 6
    grid = 0.002 * np.arange(9)
    requested, stance = recorder.traces(grid)
    np.testing.assert_allclose(requested[1:7], np.array(sent))  # the VWBC's output is its request
    assert np.all(np.isnan(requested[[0, 7, 8]])) and not stance[[0, 7, 8]].any()  # ticks not served
    assert np.all(stance[1:7] == [True, False, False, True])
    # a run's recorder is sized for its ticks
    controller = build_run_controller(resolve(load_run_config("trot", ["simulation.duration=1.5"]), robot))
    assert len(controller.low_level._times) >= 750


@pytest.mark.slow
def test_imports_and_runs_leave_global_state_alone(tmp_path):
    """No ``matplotlib.use`` at import (the plots draw on their own Agg canvases), and a run that logs to
    its folder restores the package logger's level."""
    code = (
        "import matplotlib\n"
        "import cafe_mpc_lab.experiments.catalog, cafe_mpc_lab.experiments.sweep, cafe_mpc_lab.report.plots\n"
        "import cafe_mpc_lab.cli\n"
        "cafe_mpc_lab.experiments.catalog.experiments()\n"
        "print(matplotlib.get_backend())\n"
    )
    environment = {**os.environ, "MPLBACKEND": "svg"}
    backend = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=environment, check=True
    ).stdout.strip()
    assert backend == "svg"
    package_logger = logging.getLogger("cafe_mpc")
    before = package_logger.level
    config = load_run_config("stand", ["simulation.duration=0.05", "output.plots=true"])
    result = run(config, tmp_path / "run")
    assert (tmp_path / "run" / "base_height.png").is_file() and (tmp_path / "run" / "run.log").is_file()
    assert package_logger.level == before and result.metrics["fell"] is False
