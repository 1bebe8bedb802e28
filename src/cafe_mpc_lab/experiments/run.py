"""One run: config -> controller -> closed-loop simulation -> config, metrics, log and plots on disk.

The controller comes from the assembly (``assembly.build_controller``: PD standing, or CAFE-MPC over the
Riccati or VWBC low level), its low level recorded (``experiments.controllers``); metrics from
``report.metrics``, plots from ``report.plots``.

Every run leaves its record: config.yaml (written first), run.log (as it runs), metrics.json, log.npz and the
plots, also when it ends in an error or is interrupted (Ctrl-C): then with what was simulated up to that
point, and ``metrics.json`` says so (``status``: ``failed`` or ``interrupted``, ``error``: why; a run that
completed has no ``status``). Injected faults and what the controller did about them are its ``faults`` block
(``fault_block``; docs/faults.md). The files are written into a hidden ``.<name>.partial`` folder, renamed
to ``<name>`` once the record is complete: a ``.partial`` folder is a record that could not be finished
(the process was killed while writing it).
"""

from __future__ import annotations

import json
import logging
import shutil
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import yaml

from cafe_mpc.assembly.checks import robot_of
from cafe_mpc.assembly.controllers import RunController, build_sensing_controller, low_level_name
from cafe_mpc.assembly.resolve import resolve
from cafe_mpc.config import INLINE_MPC_FAULTS, MPC_FAULTS, RunConfig
from cafe_mpc.control.plan_follower import SafetyStep
from cafe_mpc.control.process import MpcProcessError
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.planners.resolved import ResolvedRun
from cafe_mpc.robots.robot import Robot
from cafe_mpc.robots.scaling import reference_scales
from cafe_mpc_lab import LOGGERS
from cafe_mpc_lab.experiments.controllers import (
    build_run_controller,
    build_run_process_loop,
    is_mpc,
    low_level_of,
    mpc_statistics_of,
    mpc_summary,
    recorder_of,
    reference_of,
    timing_of,
)
from cafe_mpc_lab.sim.assembly import PlantSetup, build_plant
from cafe_mpc_lab.sim.faults import PlanPause, ProcessFaults
from cafe_mpc_lab.sim.loop import Simulation, SimulationLog
from cafe_mpc_lab.sim.scene import scene_of

if TYPE_CHECKING:
    from cafe_mpc.estimation.controller import SensingController
    from cafe_mpc_lab.sim.viewer import LiveViewer

logger = logging.getLogger(__name__)


@dataclass
class RunResult:
    config: RunConfig
    robot: Robot
    log: SimulationLog
    metrics: dict
    out_dir: Path | None
    controller: RunController | None = None


@dataclass
class RunState:
    """What a run has built and simulated so far (``simulate_run`` fills it as it goes): enough for its record
    when it ends early. ``log``: every tick simulated (None before the loop started)."""

    config: RunConfig
    robot: Robot | None = None
    resolved: ResolvedRun | None = None
    """The config resolved against its robot (``assembly.resolve``): what the controller was built with."""
    controller: RunController | None = None
    log: SimulationLog | None = None
    sensing: SensingController | None = None
    live: LiveViewer | None = None
    process_faults: ProcessFaults | PlanPause | None = None
    extras_done: bool = field(default=False, repr=False)


def simulate_run(
    config: RunConfig, progress=None, viewer: bool = False, state: RunState | None = None
) -> tuple[ResolvedRun, RunController, SimulationLog]:
    """Resolve ``config`` against its robot once (``assembly.resolve``), build the controller and the plant
    from that, and run the closed loop (no files written). Returns the resolved run (its robot, and what the
    controller was built with, for the metrics), the controller and the log.

    ``config.estimator``: ``ground_truth`` hands the controller the plant's state; ``kinematic_kf`` hands it
    the robot's sensor readings (``config.plant.sensors``, ``sim.sensors``) through the sensing front end and
    the state estimator (``estimation``), in every timing mode and in real time; the log's ``extra`` then
    holds the estimate of every tick (``estimate_q``, ``estimate_v``, ``estimated_contacts``,
    ``estimate_trust``; ``log.npz``: ``extra_<name>``). The returned controller is the one behind the
    estimator.

    ``config.simulation.realtime``: against the wall clock with the MPC in its own process (the process is
    stopped before this returns, also on errors). For CAFE-MPC runs the log's ``extra`` holds per-tick
    ``torque_requested`` (before clamping), ``planned_stance`` (the plan knot's stance used by the low-level
    controller) and ``gait_stance`` (the reference's contact schedule); they are saved in ``log.npz`` as
    ``extra_<name>``. The MPC process is restarted when it dies and taken back when it stalls and resumes
    (``recovery``); raises ``MpcProcessError`` when it could not be kept running (the robot was held in the
    damped stance). ``config.plant`` varies the simulated robot and its sensors only
    (``sim.randomization``) and injects its ``faults`` (``sim.faults``); the controller is built from the
    nominal robot. When anything happened, the log's ``extra`` holds ``faults`` (``fault_block``) and, when
    the safe ladder left the plans, ``safety_step`` per tick (0 plan, 1 last_plan, 2 stop, 3 balance,
    4 damped).

    ``viewer``: watch the run in MuJoCo's viewer with the current plan drawn (``sim.viewer.LiveViewer``;
    ``ViewerUnavailable`` without a display, before anything is built); ``log.extra["viewer"]`` then says
    what it showed. ``state``: filled as the run goes (``RunState``), so that a caller still has the run
    so far when this raises.
    """
    if viewer:
        from cafe_mpc_lab.sim.viewer import check_display

        check_display()
    state = state if state is not None else RunState(config)
    robot = robot_of(config)  # a config built in code gets the same checks as a loaded one
    resolved = resolve(config, robot)
    state.robot, state.resolved = robot, resolved
    # the plant (its scene, variation and sensors: domain randomisation) and the loop's options; the
    # controller's robot stays nominal
    setup = build_plant(resolved)
    try:
        if config.simulation.realtime:
            with build_run_process_loop(resolved) as controller:
                state.controller = controller
                q0 = setup.options.initial_q
                controller.start(
                    0.0, Measurement.of_state(q0, np.zeros(robot.nv), np.ones(robot.n_feet, bool))
                )
                _closed_loop(resolved, setup, controller, progress, viewer, state, realtime=True)
            if controller.failure is not None:
                raise MpcProcessError(
                    f"{controller.failure} (the run ended at t = {state.log.time[-1]:.2f} s)"
                )
        else:
            controller = build_run_controller(resolved)
            state.controller = controller
            _closed_loop(resolved, setup, controller, progress, viewer, state, realtime=False)
    finally:
        setup.plant.close()
        _log_extras(state)
    return resolved, controller, state.log


def _log_extras(state: RunState) -> None:
    """The log's ``extra`` besides the plant's (``simulate_run``), once, for the ticks simulated."""
    log, controller, config, robot = state.log, state.controller, state.config, state.robot
    if log is None or state.extras_done:
        return
    state.extras_done = True
    if state.live is not None:
        log.extra["viewer"] = state.live.summary()
    log.extra["estimator"] = config.estimator
    if state.sensing is not None:
        log.extra.update({name: values[: log.ticks] for name, values in state.sensing.trace().items()})
    recorder = recorder_of(controller) if controller is not None else None
    if recorder is not None:
        requested, planned = recorder.traces(log.time)
        log.extra["torque_requested"] = requested
        log.extra["planned_stance"] = planned
    reference = reference_of(controller) if controller is not None else None
    if reference is not None:
        stance = [reference.stance_at(float(t)) for t in log.time]
        log.extra["gait_stance"] = np.array(stance, dtype=bool).reshape(-1, robot.n_feet)
    block = fault_block(state)
    if block is not None:
        log.extra["faults"] = block
        steps = (block.get("ladder") or {}).get("steps")
        if steps:
            log.extra["safety_step"] = safety_steps(log.time, steps)


def fault_block(state: RunState) -> dict | None:
    """``metrics.json``'s ``faults`` block (docs/faults.md), None when no fault was injected and nothing went
    wrong: ``injected`` (``plant.faults``) and ``applied`` (what the injectors did, when), ``ladder`` (the
    safe ladder: its steps with their times, the seconds on each, every episode off the plans and how long
    until a fresh plan took the robot back), ``mpc`` (real time: the MPC process's events, restarts with
    their durations, cold re-solves after a stall, the failure) and ``sensors`` (rejected samples by kind,
    outages, estimator restarts)."""
    config, log, controller = state.config, state.log, state.controller
    block: dict = {}
    if config.plant.faults:
        block["injected"] = [fault.model_dump(mode="json") for fault in config.plant.faults]
    applied = list(log.extra.get("faults_applied", [])) if log is not None else []
    if state.process_faults is not None:
        applied += state.process_faults.applied
    if applied:
        block["applied"] = sorted(applied, key=lambda item: item.get("t", 0.0))
    record = controller.fault_record(1.0 / config.simulation.control_rate_hz) if is_mpc(controller) else None
    block.update(record or {})
    sensors = state.sensing.fault_record() if state.sensing is not None else None
    if sensors is not None:
        block["sensors"] = sensors
    return block or None


def safety_steps(times: np.ndarray, steps: list[dict]) -> np.ndarray:
    """The safe ladder's step at each tick (0 plan, 1 last_plan, 2 balance, 3 damped) from its changes."""
    order = list(SafetyStep)
    codes = np.zeros(len(times), dtype=np.int8)
    for change in steps:
        codes[times >= change["t"] - 1e-9] = order.index(SafetyStep(change["step"]))
    return codes


def _closed_loop(
    run: ResolvedRun,
    setup: PlantSetup,
    controller: RunController,
    progress,
    viewer: bool,
    state: RunState,
    realtime: bool,
) -> None:
    """Simulate ``controller`` on the plant of ``setup``: through the sensing front end and the state
    estimator when the controller reads the robot's sensors, watched by the live viewer when asked, with the
    MPC process's faults injected (``realtime``: the real-time controller, which says when to stop; the pacer
    holds the wall clock already). Fills ``state``: the front end, the viewer, the injector and the log,
    also when the loop raises."""
    config, robot = run.config, run.robot
    if config.estimator != "ground_truth":
        q0 = setup.options.initial_q
        state.sensing = build_sensing_controller(run, controller, (float(q0[0]), float(q0[1])))
    if viewer:
        from cafe_mpc_lab.sim.viewer import LiveViewer

        state.live = LiveViewer.following(robot, controller, realtime=not realtime)
    stop = controller.should_stop if realtime else None
    before_tick = None
    if realtime and any(fault.kind in MPC_FAULTS for fault in config.plant.faults):
        state.process_faults = ProcessFaults(config.plant.faults, lambda: _mpc_pid(controller))
        before_tick = state.process_faults
    elif any(fault.kind in INLINE_MPC_FAULTS for fault in config.plant.faults):
        state.process_faults = PlanPause(config.plant.faults, controller.withhold_plans)
        before_tick = state.process_faults
    options = replace(
        setup.options, progress=progress, stop=stop, observer=state.live, before_tick=before_tick
    )
    simulation = Simulation(setup.plant, controller if state.sensing is None else state.sensing, options)
    try:
        simulation.run()
    finally:
        state.log = simulation.log
        if state.live is not None:
            state.live.close()
        if state.process_faults is not None:
            state.process_faults.close()


def _mpc_pid(controller) -> int | None:
    """The pid of a real-time run's MPC process now (None while there is none alive)."""
    process = getattr(controller, "process", None)
    return process.pid if process is not None and process.is_alive() else None


def simulate_config(config: RunConfig, progress=None) -> tuple[Robot, SimulationLog]:
    """Build robot and controller from ``config`` and run the closed loop (no files written)."""
    resolved, _, log = simulate_run(config, progress)
    return resolved.robot, log


def run_metrics(run: ResolvedRun, controller: RunController, log: SimulationLog) -> dict:
    """Everything ``metrics.json`` reports: base metrics, tracking, the ``mpc`` and ``wbc`` blocks. What the
    controller ran with (the command profile, the schedule and gaits, the torque limits, the contact model)
    is read from the run it was built from (``simulate_run``'s resolved run), not derived again."""
    from cafe_mpc_lab.report.metrics import (
        METRICS_WINDOW_START_S,
        base_metrics,
        tracking_metrics,
        wbc_metrics,
    )

    config, robot = run.config, run.robot
    metrics = base_metrics(robot, log, run.control_period)
    metrics["robot"] = robot.name
    metrics["controller"] = low_level_name(config)
    metrics["planner"] = config.planner
    metrics["gait"] = config.gait.name if config.gait is not None else None
    profile = run.command_profile
    metrics.update(tracking_metrics(robot, log, profile))  # the whole run, start included
    steady = tracking_metrics(robot, log, profile, window_start=METRICS_WINDOW_START_S)
    metrics["steady_state"] = steady  # the paper's steady-state window (the start from rest skipped)
    metrics["timing"] = timing_of(config, controller)
    metrics["scaling"] = scaling_block(run)
    metrics["mpc"] = mpc_summary(controller, log)
    # kernels compiled after the clock started (core.compilation): 0 unless a first run missed one
    metrics.update(log.extra.get("compilation", {}))
    if "realtime" in log.extra:
        metrics["realtime"] = log.extra["realtime"]
    if "sensor" in log.extra:
        metrics["sensor"] = log.extra["sensor"]
    if "viewer" in log.extra:
        metrics["viewer"] = log.extra["viewer"]
    if "faults" in log.extra:
        metrics["faults"] = log.extra["faults"]
    from cafe_mpc_lab.report.estimation import estimator_metrics

    metrics["estimator"] = estimator_metrics(config.estimator, log)
    metrics["wbc"] = wbc_metrics(
        robot,
        log,
        metrics["controller"],
        low_level_statistics=low_level_of(controller).statistics(),
        planned_stance=log.extra.get("planned_stance"),
        torque_limits=run.torque_limits,
        contact=run.contact,
    )
    if config.reference is not None:  # acrobatic task (stored trajectory with a flight): report.task_metrics
        from cafe_mpc_lab.experiments.tasks import task_block

        metrics["task"] = task_block(run, log, reference_of(controller))
    return metrics


def scaling_block(run: ResolvedRun) -> dict:
    """``metrics.json``'s ``scaling``: the mode, the robot's factors against the reference robot, the
    horizons and gait timing the run resolved."""
    config, robot = run.config, run.robot
    block = {
        "mode": config.scaling,
        "reference": reference_scales(),
        "robot_leg_length": robot.leg_length,
        "robot_mass": robot.mass,
        "factors": run.scale.summary(),
        "whole_body_horizon_s": run.schedule.whole_body_horizon,
        "srb_horizon_s": run.schedule.srb_horizon,
    }
    if run.gait is not None:
        block["gait_period_s"] = run.gait.cycle.period
        block["swing_height_m"] = run.gait.swing_height
    return block


def _release_loggers(
    loggers: list[logging.Logger], levels: list[int], handler: logging.Handler | None
) -> None:
    """Detach a run's log file from the package loggers and restore their levels."""
    for package_logger, level in zip(loggers, levels, strict=True):
        if handler is not None:
            package_logger.removeHandler(handler)
        package_logger.setLevel(level)
    if handler is not None:
        handler.close()


def default_out_dir(config: RunConfig, root: Path = Path("runs")) -> Path:
    return root / f"{time.strftime('%Y%m%d-%H%M%S')}-{config.name}"


def run(
    config: RunConfig, out_dir: Path | None, show_progress: bool = False, viewer: bool = False
) -> RunResult:
    """Run ``config``; when ``out_dir`` is given write config.yaml, metrics.json, log.npz, run.log, plots
    (module docstring: also when the run fails or is interrupted, then marked so in ``metrics.json`` and
    the error raised again once the record is written). ``viewer``: watch it live in MuJoCo's viewer
    (``simulate_run``)."""
    if viewer:  # before anything is written: a missing display is one clear line, not a failed run's record
        from cafe_mpc_lab.sim.viewer import check_display

        check_display()
    partial: Path | None = None
    handler: logging.Handler | None = None
    package_loggers = [logging.getLogger(name) for name in LOGGERS]
    previous_levels = [package_logger.level for package_logger in package_loggers]
    if out_dir is not None:
        out_dir = Path(out_dir)
        if out_dir.exists() and any(out_dir.iterdir()):
            raise FileExistsError(f"output folder {out_dir} exists and is not empty; choose another --out")
        partial = out_dir.parent / f".{out_dir.name}.partial"
        shutil.rmtree(partial, ignore_errors=True)
        partial.mkdir(parents=True)
        with open(partial / "config.yaml", "w") as handle:
            yaml.safe_dump(config.model_dump(mode="json"), handle, sort_keys=False)
        handler = logging.FileHandler(partial / "run.log")
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
        handler.setLevel(logging.INFO)
        for package_logger in package_loggers:
            package_logger.addHandler(handler)
            if package_logger.getEffectiveLevel() > logging.INFO:  # restored in ``finally``
                package_logger.setLevel(logging.INFO)
    bars: list = []  # the progress bar, made when the run proper starts
    state = RunState(config)
    try:
        logger.info(
            "run %s: robot %s, controller %s, %.2f s",
            config.name,
            config.robot,
            config.wbc,
            config.simulation.duration,
        )
        progress = None
        if show_progress and config.simulation.duration > 1.0 and not config.simulation.realtime:
            from tqdm import tqdm

            def progress(dt: float) -> None:
                # the bar starts with the run proper, after the set-up's stage lines (never among them)
                if not bars:
                    bars.append(
                        tqdm(
                            total=round(config.simulation.duration, 3),
                            unit="sim s",
                            bar_format="{l_bar}{bar}| {n:.2f}/{total:.2f} sim s [{elapsed}<{remaining}]",
                        )
                    )
                bar = bars[0]
                # float steps add up past the total by rounding: tqdm warned "clamping frac to range [0, 1]"
                bar.update(min(dt, max(bar.total - bar.n, 0.0)))

        ended: BaseException | None = None
        try:
            simulate_run(config, progress, viewer=viewer, state=state)
        except BaseException as error:  # the record first, then the error again
            ended = error
        if bars:
            bars.pop().close()
        metrics = _record_metrics(state, ended)
        if partial is not None:
            _write_record(config, state, metrics, partial, strict=ended is None)
        if handler is not None:
            _release_loggers(package_loggers, previous_levels, handler)
            handler = None
        if partial is not None and out_dir is not None:
            if out_dir.exists():
                out_dir.rmdir()
            partial.rename(out_dir)
        if ended is not None:
            where = f"; its record ({metrics['status']}) is in {out_dir}" if out_dir is not None else ""
            logger.warning("run %s %s at t = %s%s", config.name, metrics["status"], _end_time(state), where)
            raise ended
        return RunResult(config, state.robot, state.log, metrics, out_dir, state.controller)
    finally:
        if bars:
            bars.pop().close()
        _release_loggers(package_loggers, previous_levels, handler)


def _end_time(state: RunState) -> str:
    log = state.log
    return f"{log.time[-1]:.2f} s" if log is not None and log.ticks else "0 s (before the loop started)"


def _record_metrics(state: RunState, ended: BaseException | None) -> dict:
    """``metrics.json`` of the run so far: ``run_metrics``; for a run that did not complete also ``status``
    (``failed`` or ``interrupted``) and ``error``, and, when the run ended before metrics could be computed
    (nothing simulated), only those and the ``faults`` block."""
    log = state.log
    metrics: dict = {}
    if ended is None:
        metrics = run_metrics(state.resolved, state.controller, log)
    else:
        if log is not None and log.ticks > 0 and state.controller is not None:
            try:
                metrics = run_metrics(state.resolved, state.controller, log)
            except Exception as error:  # a partial run's metrics are best effort: the record matters
                logger.warning("metrics of the ended run are incomplete: %s", error)
        metrics["status"] = "interrupted" if isinstance(ended, KeyboardInterrupt) else "failed"
        metrics["error"] = f"{type(ended).__name__}: {ended}".splitlines()[0]
        if "faults" not in metrics and log is not None and "faults" in log.extra:
            metrics["faults"] = log.extra["faults"]
    if "fell" in metrics:
        logger.info(
            "metrics: fell=%s, base height mean %.3f m, vx mean %.3f m/s, real-time factor %.2f",
            metrics["fell"],
            metrics["base_height_mean"] or float("nan"),
            metrics["vx_mean"] if metrics["vx_mean"] is not None else float("nan"),
            metrics["real_time_factor"] or float("nan"),
        )
        if metrics["mpc"] is not None:
            logger.info("mpc: %s", metrics["mpc"])
        logger.info("wbc: %s", metrics["wbc"])
    if metrics.get("faults"):
        logger.info("faults: %s", metrics["faults"])
    return metrics


def _write_record(config: RunConfig, state: RunState, metrics: dict, partial: Path, strict: bool) -> None:
    """metrics.json, log.npz, the plots (and the video) of the run into ``partial``. ``strict``: a plot that
    fails is an error (a completed run); else it is logged and skipped (a run that ended early keeps the rest
    of its record)."""
    robot, log, controller = state.robot, state.log, state.controller
    with open(partial / "metrics.json", "w") as handle:
        json.dump(metrics, handle, indent=2)
    if log is None:
        return
    statistics = mpc_statistics_of(controller) if controller is not None else None
    if statistics is not None:
        log.sampled.update({f"mpc_{name}": values for name, values in statistics.arrays().items()})
    log.save(str(partial / "log.npz"))
    try:
        if config.output.plots and log.ticks > 1:
            _write_plots(state.resolved, log, controller, metrics, partial)
        if config.output.render:
            _write_video(config, robot, log, controller, metrics, partial)
    except Exception as error:
        if strict:
            raise
        logger.warning("plots of the ended run are incomplete: %s", error)


def _write_plots(
    resolved: ResolvedRun,
    log: SimulationLog,
    controller: RunController,
    metrics: dict,
    partial: Path,
) -> None:
    from cafe_mpc_lab.report.plots import plot_run

    config, robot = resolved.config, resolved.robot
    plot_run(
        robot,
        log,
        partial,
        commands=resolved.command_profile,
        mpc_statistics=mpc_statistics_of(controller),
        mpc_period=config.mpc.period,
    )
    if "estimate_q" in log.extra:  # estimator: kinematic_kf
        from cafe_mpc_lab.report.estimation import plot_estimate

        plot_estimate(robot, log, partial / "estimator.png")
    if metrics.get("faults"):
        from cafe_mpc_lab.report.fault_plots import plot_run_faults

        plot_run_faults(log, metrics["faults"], partial / "faults.png", config.name)
    if metrics.get("task"):
        from cafe_mpc_lab.report.task_metrics import task_from_reference
        from cafe_mpc_lab.report.task_plots import plot_task, plot_task_torques

        reference = reference_of(controller)
        task = task_from_reference(reference)
        if reference is not None and task is not None:
            plot_task(
                robot,
                log,
                reference,
                task,
                partial / "task.png",
                metrics["task"],
                resolved.control_period,
            )
            plot_task_torques(robot, log, task, partial / "task_torques.png", resolved.torque_limits)


def _write_video(
    config: RunConfig,
    robot: Robot,
    log: SimulationLog,
    controller: RunController,
    metrics: dict,
    partial: Path,
) -> None:
    from cafe_mpc_lab.report.video import RenderUnavailable, render_run

    try:
        recorder = recorder_of(controller)
        video = render_run(
            robot,
            log,
            partial / "run.mp4",
            config.output.render_fps,
            plans=recorder.plans if recorder is not None else None,
            mjcf=scene_of(config.scene).mjcf(robot),
        )
        logger.info("video written to %s", video.name)
        if metrics.get("task"):  # acrobatic task: a strip of frames across the roll
            from cafe_mpc_lab.report.task_plots import render_task_frames

            render_task_frames(
                robot,
                log,
                metrics["task"],
                partial / "frames.png",
                mjcf=scene_of(config.scene).mjcf(robot),
            )
    except RenderUnavailable as error:  # said once: in metrics.json and the run's summary
        logger.info("no video: %s", error)
        metrics["render_error"] = str(error)
        with open(partial / "metrics.json", "w") as handle:
            json.dump(metrics, handle, indent=2)
