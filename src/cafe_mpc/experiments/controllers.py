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

import numpy as np

from cafe_mpc.config import ConfigError, RunConfig, velocity_command
from cafe_mpc.control.mpc_loop import CafeMpcController, MpcSettings
from cafe_mpc.core.contacts import N_FEET
from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import Plan
from cafe_mpc.dynamics.srb import srb_parameters
from cafe_mpc.mpc.problem import CafeProblemBuilder
from cafe_mpc.ocp.contact_schedule import get_gait
from cafe_mpc.ocp.costs import SRBWeights
from cafe_mpc.ocp.knots import SRBModelFactory, SRBSettings, WholeBodyModelFactory, WholeBodySettings
from cafe_mpc.reference.locomotion import LocomotionReference, VelocityCommand
from cafe_mpc.robots.robot import Robot
from cafe_mpc.wbc.pd import PDController
from cafe_mpc.wbc.riccati import RiccatiController
from cafe_mpc.wbc.vwbc import VWBCController, VWBCSettings

RunController = PDController | CafeMpcController


class LowLevelRecorder(LowLevelController):
    """A ``LowLevelController`` that wraps another and records every call it serves.

    Per call: the time, the torque requested before any clamping (the inner controller's
    ``last_request``: for the Riccati controller its unclamped Eq. (33) torque, for the VWBC its QP torque)
    and the stance flags of the plan knot used. ``traces(times)`` aligns the records with the simulation's
    ticks. ``reset`` and ``statistics`` are the inner controller's (``reset`` also clears the records).

    The records live in preallocated arrays (``capacity`` rows, e.g. the run's tick count; doubled when
    full), so the control-rate path writes into them without allocating per tick. ``times``,
    ``requested`` and ``stances`` are views of the rows recorded so far.
    """

    def __init__(self, inner: LowLevelController, capacity: int = 1024, n_feet: int = N_FEET) -> None:
        self.inner = inner
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


def build_controller(config: RunConfig, robot: Robot) -> RunController:
    """The closed-loop controller named by ``config.wbc`` (``pd``, or CAFE-MPC over ``riccati``/``vwbc``).

    Raises ``ConfigError`` (one line, naming the section) when a setting is rejected by the library.
    """
    if config.wbc == "pd":
        return PDController(
            robot, config.pd.kp, config.pd.kd, gravity_feedforward=config.pd.gravity_feedforward
        )
    gait = config.gait
    if gait is None:  # RunConfig rejects this; kept for configs built with model_construct
        raise ConfigError(f"wbc: {config.wbc!r} needs a gait section")
    try:
        reference = LocomotionReference(
            robot,
            get_gait(gait.name),
            reference_commands(config),
            swing_height=gait.swing_height,
            raibert_gain=gait.raibert_gain,
            start_stance=gait.start_stance,
        )
    except ValueError as error:
        raise ConfigError(f"gait: {error}") from error
    try:
        schedule = config.mpc.model_schedule()
        settings = MpcSettings(
            period=config.mpc.period, latency=config.mpc.latency, fixed_latency=config.mpc.fixed_latency
        )
    except ValueError as error:
        raise ConfigError(f"mpc: {error}") from error
    try:
        running = config.costs.running.to_weights()
        terminal = config.costs.terminal.to_weights()
        srb_running = SRBWeights.from_whole_body(running, force=SRBWeights.regular_running().force)
        srb_terminal = SRBWeights.from_whole_body(terminal, force=SRBWeights.regular_terminal().force)
    except ValueError as error:
        raise ConfigError(f"costs: {error}") from error
    whole_body = WholeBodyModelFactory(
        robot,
        WholeBodySettings(dt=schedule.whole_body_dt, running_weights=running, terminal_weights=terminal),
    )
    srb = SRBModelFactory(
        SRBSettings(
            dt=schedule.srb_dt,
            parameters=srb_parameters(robot),
            running_weights=srb_running,
            terminal_weights=srb_terminal,
        )
    )
    builder = CafeProblemBuilder(whole_body, srb, schedule)
    low_level = build_low_level(config, robot)
    ticks = config.simulation.duration * config.simulation.control_rate_hz  # the run's low-level calls
    recorder = LowLevelRecorder(low_level, capacity=int(np.ceil(ticks)) + 2, n_feet=robot.n_feet)
    return CafeMpcController(robot, reference, builder, recorder, settings)


def build_low_level(config: RunConfig, robot: Robot) -> LowLevelController:
    """The low-level controller named by ``config.wbc`` (PD, Riccati (33) or VWBC (34))."""
    if config.wbc == "pd":
        return PDController(
            robot, config.pd.kp, config.pd.kd, gravity_feedforward=config.pd.gravity_feedforward
        )
    if config.wbc == "riccati":
        return RiccatiController(robot)
    try:
        vwbc_settings = VWBCSettings(
            solver=config.vwbc.solver,
            warm_start=config.vwbc.warm_start,
            stance_source=config.vwbc.stance_source,
        )
    except ValueError as error:
        raise ConfigError(f"vwbc: {error}") from error
    return VWBCController(robot, vwbc_settings)


def recorder_of(controller: RunController) -> LowLevelRecorder | None:
    """The recorder around the low-level controller of a CAFE-MPC run (None for PD standing)."""
    low_level = controller.low_level if isinstance(controller, CafeMpcController) else None
    return low_level if isinstance(low_level, LowLevelRecorder) else None


def low_level_of(controller: RunController) -> LowLevelController:
    """The low-level controller that produced a run's torques: the plan follower under CAFE-MPC (unwrapped
    from its recorder), or the PD controller itself."""
    recorder = recorder_of(controller)
    if recorder is not None:
        return recorder.inner
    return controller.low_level if isinstance(controller, CafeMpcController) else controller
