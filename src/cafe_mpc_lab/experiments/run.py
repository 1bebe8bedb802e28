"""One run: config -> controller -> closed-loop simulation -> config, metrics, log and plots on disk.

The controller comes from the assembly (``assembly.build_controller``: PD standing, or CAFE-MPC over the
Riccati or VWBC low level), its low level recorded (``experiments.controllers``); metrics from
``report.metrics``, plots from ``report.plots``.

Results are written to a hidden ``.<name>.partial`` folder and renamed only when everything succeeded,
so a failed run never leaves a folder that looks like a result.
"""

from __future__ import annotations

import json
import logging
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import yaml

from cafe_mpc.assembly.checks import robot_of
from cafe_mpc.assembly.controllers import RunController, build_sensing_controller, low_level_name
from cafe_mpc.assembly.resolve import resolve
from cafe_mpc.config import RunConfig
from cafe_mpc.control.process import MpcProcessError
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.planners.resolved import ResolvedRun
from cafe_mpc.robots.robot import Robot
from cafe_mpc.robots.scaling import reference_scales
from cafe_mpc_lab import LOGGERS
from cafe_mpc_lab.experiments.controllers import (
    build_run_controller,
    build_run_process_loop,
    low_level_of,
    mpc_statistics_of,
    mpc_summary,
    recorder_of,
    reference_of,
    timing_of,
)
from cafe_mpc_lab.sim.assembly import PlantSetup, build_plant
from cafe_mpc_lab.sim.loop import SimulationLog, simulate
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


def simulate_run(
    config: RunConfig, progress=None, viewer: bool = False
) -> tuple[ResolvedRun, RunController, SimulationLog]:
    """Resolve ``config`` against its robot once (``assembly.resolve``), build the controller and the plant
    from that, and run the closed loop (no files written). Returns the resolved run (its robot, and what the
    controller was built with, for the metrics), the controller and the log.

    ``config.estimator``: ``ground_truth`` hands the controller the plant's state; ``kinematic_kf`` hands it
    the robot's sensor readings (``config.plant.sensors``, ``sim.sensors``) through the state estimator
    (``estimation``), in every timing mode and in real time; the log's ``extra`` then holds the estimate of
    every tick (``estimate_q``, ``estimate_v``, ``estimated_contacts``, ``estimate_trust``; ``log.npz``:
    ``extra_<name>``). The returned controller is the one behind the estimator.

    ``config.simulation.realtime``: against the wall clock with the MPC in its own process (the process is
    stopped before this returns, also on errors). For CAFE-MPC runs the log's ``extra`` holds per-tick
    ``torque_requested`` (before clamping), ``planned_stance`` (the plan knot's stance used by the low-level
    controller) and ``gait_stance`` (the reference's contact schedule); they are saved in ``log.npz`` as
    ``extra_<name>``. Raises ``MpcProcessError`` when the real-time MPC process died or stalled (the robot
    was held in a damped stance once the last plan ran out). ``config.plant`` varies the simulated robot and
    its sensors only (``sim.randomization``); the controller is built from the nominal robot.

    ``viewer``: watch the run in MuJoCo's viewer with the current plan drawn (``sim.viewer.LiveViewer``;
    ``ViewerUnavailable`` without a display, before anything is built); ``log.extra["viewer"]`` then says
    what it showed.
    """
    if viewer:
        from cafe_mpc_lab.sim.viewer import check_display

        check_display()
    robot = robot_of(config)  # a config built in code gets the same checks as a loaded one
    resolved = resolve(config, robot)
    # the plant (its scene, variation and sensors: domain randomisation) and the loop's options; the
    # controller's robot stays nominal
    setup = build_plant(resolved)
    try:
        if config.simulation.realtime:
            with build_run_process_loop(resolved) as controller:
                q0 = setup.options.initial_q
                controller.start(
                    0.0, Measurement.of_state(q0, np.zeros(robot.nv), np.ones(robot.n_feet, bool))
                )
                log, sensing, live = _closed_loop(
                    resolved, setup, controller, progress, viewer, realtime=True
                )
            if controller.failure is not None:
                raise MpcProcessError(
                    f"{controller.failure}; the robot was held in a damped stance once the last plan ran out "
                    f"(at t = {log.time[-1]:.2f} s)"
                )
        else:
            controller = build_run_controller(resolved)
            log, sensing, live = _closed_loop(resolved, setup, controller, progress, viewer, realtime=False)
    finally:
        setup.plant.close()
    if live is not None:
        log.extra["viewer"] = live.summary()
    log.extra["estimator"] = config.estimator
    if sensing is not None:
        log.extra.update({name: values[: log.ticks] for name, values in sensing.trace().items()})
    recorder = recorder_of(controller)
    if recorder is not None:
        requested, planned = recorder.traces(log.time)
        log.extra["torque_requested"] = requested
        log.extra["planned_stance"] = planned
    reference = reference_of(controller)
    if reference is not None:
        stance = [reference.stance_at(float(t)) for t in log.time]
        log.extra["gait_stance"] = np.array(stance, dtype=bool).reshape(-1, robot.n_feet)
    return resolved, controller, log


def _closed_loop(
    run: ResolvedRun,
    setup: PlantSetup,
    controller: RunController,
    progress,
    viewer: bool,
    realtime: bool,
) -> tuple[SimulationLog, SensingController | None, LiveViewer | None]:
    """Simulate ``controller`` on the plant of ``setup``: through the state estimator when the controller
    reads the robot's sensors, watched by the live viewer when asked (``realtime``: the real-time
    controller, which says when to stop; the pacer holds the wall clock already). Returns the log, the
    estimating front end and the viewer (None when not used)."""
    sensing = live = None
    if run.config.estimator != "ground_truth":
        q0 = setup.options.initial_q
        sensing = build_sensing_controller(run, controller, (float(q0[0]), float(q0[1])))
    if viewer:
        from cafe_mpc_lab.sim.viewer import LiveViewer

        live = LiveViewer.following(run.robot, controller, realtime=not realtime)
    stop = controller.should_stop if realtime else None
    options = replace(setup.options, progress=progress, stop=stop, observer=live)
    try:
        log = simulate(setup.plant, controller if sensing is None else sensing, options)
    finally:
        if live is not None:
            live.close()
    return log, sensing, live


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
    """Run ``config``; when ``out_dir`` is given write config.yaml, metrics.json, log.npz, run.log, plots.
    ``viewer``: watch it live in MuJoCo's viewer (``simulate_run``)."""
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
        handler = logging.FileHandler(partial / "run.log")
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
        handler.setLevel(logging.INFO)
        for package_logger in package_loggers:
            package_logger.addHandler(handler)
            if package_logger.getEffectiveLevel() > logging.INFO:  # restored in ``finally``
                package_logger.setLevel(logging.INFO)
    bars: list = []  # the progress bar, made when the run proper starts
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

        resolved, controller, log = simulate_run(config, progress, viewer=viewer)
        robot = resolved.robot
        metrics = run_metrics(resolved, controller, log)
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
        if partial is not None:
            with open(partial / "config.yaml", "w") as handle:
                yaml.safe_dump(config.model_dump(mode="json"), handle, sort_keys=False)
            with open(partial / "metrics.json", "w") as handle:
                json.dump(metrics, handle, indent=2)
            log.save(str(partial / "log.npz"))
            if config.output.plots and log.ticks > 1:
                from cafe_mpc_lab.report.plots import plot_run

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
                        plot_task_torques(
                            robot, log, task, partial / "task_torques.png", resolved.torque_limits
                        )
            if config.output.render:
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
        if bars:
            bars.pop().close()
        if handler is not None:
            _release_loggers(package_loggers, previous_levels, handler)
            handler = None
        if partial is not None and out_dir is not None:
            if out_dir.exists():
                out_dir.rmdir()
            partial.rename(out_dir)
        return RunResult(config, robot, log, metrics, out_dir, controller)
    except BaseException:
        if partial is not None:
            shutil.rmtree(partial, ignore_errors=True)
        raise
    finally:
        if bars:
            bars.pop().close()
        _release_loggers(package_loggers, previous_levels, handler)
