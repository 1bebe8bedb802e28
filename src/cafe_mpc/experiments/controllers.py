"""The closed-loop controller of a run config: PD standing, or CAFE-MPC over a Riccati or VWBC low level.

``build_controller(config, robot)`` is the one place that turns the config's ``gait``, ``mpc``, ``costs``
and ``vwbc`` sections into objects: the heuristic locomotion reference (Sec. VI-A), the CAFE problem
builder with its model schedule (Sec. IV-D), the MPC loop (Sec. VI-C) and the low-level controller
(Riccati feedback (33) or VWBC (34)). The low-level controller is wrapped in a ``LowLevelRecorder`` (any
``LowLevelController``: it reads ``last_request``) so the run can report what it asked for before clamping
(the Riccati controller clamps to the torque limits; the paper's Fig. 9 shows the unclamped request) and
which stance the plan assumed at every tick (for the friction-cone score of controllers that do not check
it themselves). The SRB tail gets the robot's own mass and inertia (``dynamics.srb.srb_parameters``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from cafe_mpc.config import ConfigError, RunConfig, velocity_command
from cafe_mpc.control.mpc_loop import CafeMpcController, MpcSettings
from cafe_mpc.control.realtime import RealtimeMpcController
from cafe_mpc.core.contacts import N_FEET
from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import Plan
from cafe_mpc.dynamics.srb import srb_parameters
from cafe_mpc.estimation.controller import SensingController
from cafe_mpc.estimation.estimator import StateEstimator
from cafe_mpc.experiments.scaling import (
    run_scale,
    scaled_gait,
    scaled_schedule,
    scaled_srb_weights,
    scaled_weights,
)
from cafe_mpc.experiments.tasks import (
    minimum_base_height,
    task_reference,
    task_weight_sets,
    torque_limits_of,
)
from cafe_mpc.mpc.problem import CafeProblemBuilder
from cafe_mpc.mpc.receding_horizon import RecedingHorizonMpc
from cafe_mpc.mpc.template import TemplateMpc, TemplateProblemBuilder, TemplateSettings, template_srb
from cafe_mpc.ocp.constraints import WholeBodyConstraintSettings
from cafe_mpc.ocp.knots import SRBModelFactory, SRBSettings, WholeBodyModelFactory, WholeBodySettings
from cafe_mpc.reference.locomotion import (
    FOOTHOLD_BOX,
    CommandProfile,
    LocomotionReference,
    VelocityCommand,
)
from cafe_mpc.robots.robot import Robot, load_robot
from cafe_mpc.wbc.pd import PDController
from cafe_mpc.wbc.riccati import RiccatiController
from cafe_mpc.wbc.template_low_level import TemplateLowLevelController, TemplateLowLevelSettings
from cafe_mpc.wbc.vwbc import VWBCController, VWBCSettings

RunController = PDController | CafeMpcController | RealtimeMpcController


@dataclass(frozen=True)
class RecordedPlan:
    """A plan as the run video draws it: first used at ``t``; knot times, configurations (n + 1, nq),
    stance flags and planned forces."""

    t: float
    times: np.ndarray
    configurations: np.ndarray
    contacts: np.ndarray
    forces: np.ndarray


class LowLevelRecorder(LowLevelController):
    """A ``LowLevelController`` that wraps another and records every call it serves.

    Per call: the time, the torque requested before any clamping (the inner controller's
    ``last_request``: for the Riccati controller its unclamped Eq. (33) torque, for the VWBC its QP torque)
    and the stance flags of the plan knot used. ``traces(times)`` aligns the records with the simulation's
    ticks. ``reset`` and ``statistics`` are the inner controller's (``reset`` also clears the records).

    The records live in preallocated arrays (``capacity`` rows, e.g. the run's tick count; doubled when
    full), so the control-rate path writes into them without allocating per tick. ``times``,
    ``requested`` and ``stances`` are views of the rows recorded so far.

    ``record_plans``: also keep every plan the controller followed (``plans``: the time it was first used
    and its knot times, configurations, stance flags and forces), for the run video's plan overlay
    (``robots.plan_overlay``); a few kB per MPC update, so only when a video is made.
    """

    def __init__(
        self,
        inner: LowLevelController,
        capacity: int = 1024,
        n_feet: int = N_FEET,
        record_plans: bool = False,
    ) -> None:
        self.inner = inner
        self.record_plans = record_plans
        self.plans: list[RecordedPlan] = []
        self._last_plan: object | None = None
        capacity = max(int(capacity), 1)
        self._times = np.zeros(capacity)
        self._requested = np.zeros((capacity, len(inner.last_request)))
        self._stances = np.zeros((capacity, n_feet), dtype=bool)
        self._count = 0

    @property
    def last_request(self) -> np.ndarray:  # type: ignore[override]
        return self.inner.last_request

    @property
    def times(self) -> np.ndarray:
        return self._times[: self._count]

    @property
    def requested(self) -> np.ndarray:
        return self._requested[: self._count]

    @property
    def stances(self) -> np.ndarray:
        return self._stances[: self._count]

    def reset(self) -> None:
        self.inner.reset()
        self._count = 0
        self.plans.clear()
        self._last_plan = None

    def statistics(self) -> dict:
        return self.inner.statistics()

    def _grow(self) -> None:
        """Double the capacity (rare: only when the run outlasts the preallocated ticks)."""

        def doubled(array: np.ndarray) -> np.ndarray:
            grown = np.zeros((2 * len(array), *array.shape[1:]), dtype=array.dtype)
            grown[: len(array)] = array
            return grown

        self._times = doubled(self._times)
        self._requested = doubled(self._requested)
        self._stances = doubled(self._stances)

    def compute(self, t: float, measurement: Measurement, plan: Plan | None) -> np.ndarray:
        if self._count == len(self._times):
            self._grow()
        row = self._count
        torques = self.inner.compute(t, measurement, plan)
        self._requested[row] = self.inner.last_request
        self._times[row] = t
        if plan is not None:
            self._stances[row] = plan.contacts[plan.knot_at(t)]
            if self.record_plans and plan is not self._last_plan and isinstance(plan, Plan):
                self._last_plan = plan
                nq = len(measurement.q)
                self.plans.append(
                    RecordedPlan(
                        t, plan.times.copy(), plan.xs[:, :nq].copy(), plan.contacts.copy(), plan.forces.copy()
                    )
                )
        else:
            self._stances[row] = False
        self._count = row + 1
        return torques

    def traces(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Requested torques ``(ticks, nu)`` (NaN where this controller was not called, e.g. before the
        first plan) and planned stance flags ``(ticks, n_feet)`` (False there), on the tick grid ``times``."""
        times = np.asarray(times, dtype=float)
        requested = np.full((len(times), self._requested.shape[1]), np.nan)
        stance = np.zeros((len(times), self._stances.shape[1]), dtype=bool)
        if len(times) == 0 or self._count == 0:
            return requested, stance
        recorded = self.times
        rows = np.searchsorted(times, recorded - 1e-9)
        keep = (rows < len(times)) & (np.abs(times[np.minimum(rows, len(times) - 1)] - recorded) < 1e-9)
        requested[rows[keep]] = self.requested[keep]
        stance[rows[keep]] = self.stances[keep]
        return requested, stance


def reference_commands(config: RunConfig) -> list[VelocityCommand]:
    """The commands the run tracks: the gait's, or standing still at the standing height (PD)."""
    if config.gait is None:
        return [VelocityCommand()]
    return [velocity_command(command) for command in config.gait.commands]


def reference_profile(config: RunConfig, robot: Robot) -> CommandProfile:
    """What the run commands over time (``CommandProfile``): the gait's commands, ramped from rest after the
    start stance when ``gait.command_ramp`` > 0; standing still for PD and composed references."""
    gait = config.gait
    if gait is None:
        return CommandProfile(reference_commands(config), robot.standing_height)
    return CommandProfile(
        reference_commands(config), robot.standing_height, gait.command_ramp, gait.start_stance
    )


def build_controller(config: RunConfig, robot: Robot) -> RunController:
    """The closed-loop controller named by ``config.wbc`` (``pd``, or CAFE-MPC over ``riccati``/``vwbc``) in
    simulated time (fixed or measured latency).

    Raises ``ConfigError`` (one line, naming the section) when a setting is rejected by the library.
    """
    if config.wbc == "pd":
        return _pd_controller(config, robot)
    if config.planner == "template":
        return build_template_controller(config, robot)
    mpc = build_mpc(config, robot)
    return CafeMpcController(
        robot,
        mpc.reference,
        mpc.builder,
        build_recorder(config, robot),
        mpc=mpc,
        control_period=1.0 / config.simulation.control_rate_hz,
    )


def build_template_controller(config: RunConfig, robot: Robot) -> CafeMpcController:
    """The template-MPC baseline (``planner: template``, paper Sec. VII-C): the SRB-only plan
    (``mpc.template``) over its stance ``J' F`` / swing PD low level (``wbc.template_low_level``), with the
    CAFE run's reference (``build_mpc``'s) and receding-horizon settings (period, latency, iterations)."""
    reference = build_mpc(config, robot).reference
    parameters, com_offset = template_srb(robot)
    section = config.template
    limits = torque_limits_of(config, robot)
    try:
        settings = TemplateSettings(
            horizon=section.horizon,
            dt=section.dt,
            parameters=parameters,
            leg_torque_limits=section.leg_torque_limits,
            predict_latency=section.predict_latency,
            centroidal_state=section.centroidal_state,
            vertical_reference=section.vertical_reference,
            torque_limits=tuple(limits.tolist()),
            friction_coefficient=config.mpc.friction,
        )
        scale = run_scale(config, robot)
        low_level = TemplateLowLevelController(
            robot,
            TemplateLowLevelSettings(scale.stiffness(section.swing_kp), scale.damping(section.swing_kd)),
            torque_limits=limits,
        )
    except ValueError as error:
        raise ConfigError(f"template: {error}") from error
    builder = TemplateProblemBuilder(robot, settings, com_offset)
    mpc = TemplateMpc(robot, reference, builder, mpc_settings(config))
    ticks = config.simulation.duration * config.simulation.control_rate_hz
    recorder = LowLevelRecorder(low_level, capacity=int(np.ceil(ticks)) + 2, n_feet=robot.n_feet)
    return CafeMpcController(
        robot, reference, builder, recorder, mpc=mpc, control_period=1.0 / config.simulation.control_rate_hz
    )


def build_recorder(config: RunConfig, robot: Robot) -> LowLevelRecorder:
    """The run's low-level controller wrapped in a recorder sized for the run's ticks."""
    ticks = config.simulation.duration * config.simulation.control_rate_hz  # the run's low-level calls
    return LowLevelRecorder(
        build_low_level(config, robot),
        capacity=int(np.ceil(ticks)) + 2,
        n_feet=robot.n_feet,
        record_plans=config.output.render,  # the video draws the plan in effect at every frame
    )


def mpc_settings(config: RunConfig) -> MpcSettings:
    try:
        return MpcSettings(
            period=config.mpc.period,
            latency=config.mpc.latency,
            fixed_latency=config.mpc.fixed_latency,
            time_budget=config.mpc.time_budget,
            max_iterations=config.mpc.max_iterations,
            touchdown_max_penalty=config.mpc.touchdown_max_penalty,
            final_policy=config.mpc.final_policy,
            warm_up=config.mpc.warm_up,
            scheme=config.mpc.scheme,
            rti_line_search=config.mpc.rti_line_search,
            rti_feedback=config.mpc.rti_feedback,
            compute_scale=config.mpc.compute_scale,
            threads=config.mpc.threads,
        )
    except ValueError as error:
        raise ConfigError(f"mpc: {error}") from error


def build_mpc(config: RunConfig, robot: Robot) -> RecedingHorizonMpc:
    """The MPC side of a run: reference (Sec. VI-A), CAFE problem builder with its model schedule (Sec. IV-D),
    receding-horizon settings."""
    gait = config.gait
    scale = run_scale(config, robot)  # the tuned values are the reference robot's (robots.scaling)
    if config.reference is not None:  # a composed reference (stand, stored trajectory, ...): Sec. VII-C
        reference = task_reference(config.reference, robot, scale)
    elif gait is None:  # RunConfig rejects this; kept for configs built with model_construct
        raise ConfigError(f"wbc: {config.wbc!r} needs a gait section")
    else:
        try:
            reference = LocomotionReference(
                robot,
                scaled_gait(gait.name, scale),
                reference_commands(config),
                swing_height=scale.distance(gait.swing_height),
                raibert_gain=scale.duration(gait.raibert_gain),
                foothold_box=tuple(scale.distance(v) for v in FOOTHOLD_BOX),
                start_stance=gait.start_stance,
                command_ramp=gait.command_ramp,
            )
        except ValueError as error:
            raise ConfigError(f"gait: {error}") from error
    try:
        schedule = scaled_schedule(config.mpc.model_schedule(), scale)
    except ValueError as error:
        raise ConfigError(f"mpc: {error}") from error
    settings = mpc_settings(config)
    try:
        running = scaled_weights(config.costs.running.to_weights(), scale)
        terminal = scaled_weights(config.costs.terminal.to_weights(), scale)
        srb_running = scaled_srb_weights(config.costs.srb_running.to_weights(), scale)
        srb_terminal = scaled_srb_weights(config.costs.srb_terminal.to_weights(), scale)
    except ValueError as error:
        raise ConfigError(f"costs: {error}") from error
    limits = None if config.torque_limits == "plan" else tuple(torque_limits_of(config, robot).tolist())
    whole_body = WholeBodyModelFactory(
        robot,
        WholeBodySettings(
            dt=schedule.whole_body_dt,
            baumgarte_alpha=scale.rate(WholeBodySettings().baumgarte_alpha),
            running_weights=running,
            terminal_weights=terminal,
            constraints=WholeBodyConstraintSettings(
                friction_coefficient=config.mpc.friction,
                torque_limit_values=limits,
                minimum_base_height=minimum_base_height(scale),
            ),
        ),
    )
    srb = SRBModelFactory(
        SRBSettings(
            dt=schedule.srb_dt,
            parameters=srb_parameters(robot),
            running_weights=srb_running,
            terminal_weights=srb_terminal,
        )
    )
    builder = CafeProblemBuilder(whole_body, srb, schedule, weights=task_weight_sets(config, robot, schedule))
    return RecedingHorizonMpc(robot, reference, builder, settings)


def realtime_mpc(config_data: dict) -> RecedingHorizonMpc:
    """Builds the MPC inside the real-time mode's MPC process, from the run config as plain data (picklable):
    its own robot model, reference and solver; measured latency, so the solve keeps the wall-clock budget."""
    config = RunConfig.model_validate(config_data)
    robot = load_robot(config.robot)
    config = config.model_copy(update={"mpc": config.mpc.model_copy(update={"latency": "measured"})})
    return build_mpc(config, robot)


def build_realtime_controller(
    config: RunConfig, robot: Robot, low_level: LowLevelController | None = None
) -> RealtimeMpcController:
    """CAFE-MPC against the wall clock: the MPC in its own process (``control.realtime``), the recorded
    low-level controller here (or ``low_level``). Close it (``with``) to stop the process."""
    if config.wbc == "pd":
        raise ConfigError("simulation.realtime needs an MPC run (wbc: vwbc or riccati), not wbc: pd")
    schedule = scaled_schedule(config.mpc.model_schedule(), run_scale(config, robot))
    factory = functools.partial(realtime_mpc, config.model_dump(mode="json"))
    if low_level is None:
        low_level = build_recorder(config, robot)
    # knots: the whole-body grid knots plus the splits at contact switches (a few per horizon)
    controller = RealtimeMpcController(
        robot,
        factory,
        low_level,
        config.mpc.period,
        schedule.whole_body_knots + 16,
        control_period=1.0 / config.simulation.control_rate_hz,
        scheme=config.mpc.scheme if config.planner != "template" else "one_phase",
    )
    controller.reference = build_mpc(config, robot).reference  # for the run's report (gait stance)
    return controller


def build_sensing_controller(
    config: RunConfig, robot: Robot, inner: RunController, position_xy: tuple[float, float] = (0.0, 0.0)
) -> SensingController:
    """``inner`` behind the state estimator (``estimator: kinematic_kf``): the closed loop hands it sensor
    readings, the estimator turns them into the measurement ``inner`` gets (``estimation.controller``).
    ``position_xy``: where the robot is placed (the estimator's odometry origin)."""
    try:
        estimator = StateEstimator(robot, config.kinematic_kf.settings())
    except ValueError as error:
        raise ConfigError(f"kinematic_kf: {error}") from error
    ticks = int(np.ceil(config.simulation.duration * config.simulation.control_rate_hz)) + 2
    return SensingController(inner, estimator, capacity=ticks, position_xy=position_xy)


def build_low_level(config: RunConfig, robot: Robot) -> LowLevelController:
    """The low-level controller named by ``config.wbc`` (PD, Riccati (33) or VWBC (34))."""
    if config.wbc == "pd":
        return _pd_controller(config, robot)
    if config.wbc == "riccati":
        riccati = RiccatiController(robot)
        riccati.limits = torque_limits_of(config, robot)
        return riccati
    try:
        scale = run_scale(config, robot)
        vwbc_settings = VWBCSettings(
            solver=config.vwbc.solver,
            warm_start=config.vwbc.warm_start,
            stance_source=config.vwbc.stance_source,
            mu=config.mpc.friction,
            alpha=scale.rate(VWBCSettings.alpha),
            cone_tolerance=scale.force(VWBCSettings.cone_tolerance),
        )
    except ValueError as error:
        raise ConfigError(f"vwbc: {error}") from error
    return VWBCController(robot, vwbc_settings, torque_limits=torque_limits_of(config, robot))


def _pd_controller(config: RunConfig, robot: Robot) -> PDController:
    """Joint PD standing with the config's gains scaled to the robot (torque scale; damping also by time)."""
    scale = run_scale(config, robot)
    return PDController(
        robot,
        scale.stiffness(config.pd.kp),
        scale.damping(config.pd.kd),
        gravity_feedforward=config.pd.gravity_feedforward,
    )


def reference_of(controller: RunController):
    """The reference a CAFE-MPC run tracked (None for PD standing)."""
    return getattr(controller, "reference", None) if is_mpc(controller) else None


def timing_of(config: RunConfig, controller: RunController) -> dict:
    """How time was modelled in a run (recorded in ``metrics.json``): ``realtime`` (wall clock, MPC process),
    ``measured`` (simulated time, plans act after their measured update time) or ``fixed``."""
    if not is_mpc(controller):
        return {"mode": "none (PD standing)"}
    mode = "realtime" if config.simulation.realtime else config.mpc.latency
    if mode == "realtime":  # the MPC process always runs with its wall-clock budget
        config = config.model_copy(update={"mpc": config.mpc.model_copy(update={"latency": "measured"})})
    settings = mpc_settings(config)
    scheme = getattr(controller, "scheme", config.mpc.scheme)
    return {
        "mode": mode,
        "scheme": scheme,
        "period_s": config.mpc.period,
        "fixed_latency_s": config.mpc.fixed_latency if mode == "fixed" else None,
        "compute_scale": config.mpc.compute_scale if mode == "measured" else None,
        "time_budget_ms": settings.budget * 1e3 if settings.budget is not None else None,
        "max_iterations": settings.max_iterations,
    }


def mpc_summary(controller: RunController, log) -> dict | None:
    """The ``mpc`` block of ``metrics.json``: update-time breakdown, iterations, latency, achieved rate."""
    if isinstance(controller, CafeMpcController):
        summary = controller.statistics.summary()
        duration = float(log.time[-1]) if len(log.time) else 0.0
        summary["rate_hz"] = (len(controller.statistics.latencies) - 1) / duration if duration > 0 else None
        return summary
    if isinstance(controller, RealtimeMpcController):
        worker = controller.worker_statistics
        summary = worker.summary() if worker is not None else {}
        main = controller.statistics
        duration = float(log.time[-1]) if len(log.time) else 0.0
        summary["latency_ms_median"] = float(np.median(main.latencies)) * 1e3 if main.latencies else None
        summary["latency_ms_p99"] = float(np.percentile(main.latencies, 99)) * 1e3 if main.latencies else None
        summary["plans_received"] = len(main.latencies)
        summary["rate_hz"] = len(main.latencies) / duration if duration > 0 else None
        summary["pd_fallback_ticks"] = main.fallback_ticks
        summary["worker_error"] = controller.worker_error
        return summary
    return None


def mpc_statistics_of(controller: RunController):
    """The MPC's per-update records (the worker's in real-time runs), None for PD standing."""
    if isinstance(controller, CafeMpcController):
        return controller.statistics
    if isinstance(controller, RealtimeMpcController):
        return controller.worker_statistics
    return None


def is_mpc(controller: RunController) -> bool:
    """Whether the run is a CAFE-MPC run (simulated time or real time), not PD standing."""
    return isinstance(controller, CafeMpcController | RealtimeMpcController)


def recorder_of(controller: RunController) -> LowLevelRecorder | None:
    """The recorder around the low-level controller of a CAFE-MPC run (None for PD standing)."""
    low_level = controller.low_level if is_mpc(controller) else None
    return low_level if isinstance(low_level, LowLevelRecorder) else None


def low_level_of(controller: RunController) -> LowLevelController:
    """The low-level controller that produced a run's torques: the plan follower under CAFE-MPC (unwrapped
    from its recorder), or the PD controller itself."""
    recorder = recorder_of(controller)
    if recorder is not None:
        return recorder.inner
    return controller.low_level if is_mpc(controller) else controller
