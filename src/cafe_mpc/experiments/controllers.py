"""The closed-loop controller of a run config: PD standing, or CAFE-MPC over a Riccati or VWBC low level.

``build_controller(config, robot)`` is the one place that turns the config's ``gait``, ``mpc``, ``costs``
and ``vwbc`` sections into objects: the heuristic locomotion reference (Sec. VI-A), the CAFE problem
builder with its model schedule (Sec. IV-D), the MPC loop (Sec. VI-C) and the low-level controller
(Riccati feedback (33) or VWBC (34)). The low-level controller is wrapped in a ``LowLevelRecorder`` so the
run can report what it asked for before clamping (the Riccati controller clamps to the torque limits; the
paper's Fig. 9 shows the unclamped request) and which stance the plan assumed at every tick (for the
friction-cone score of controllers that do not check it themselves).
"""

from __future__ import annotations

import numpy as np

from cafe_mpc.config import ConfigError, RunConfig, velocity_command
from cafe_mpc.mpc.controller import CafeMpcController, LowLevelController, MpcSettings
from cafe_mpc.mpc.plan import Plan
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


class LowLevelRecorder:
    """A plan-following low-level controller (same interface) that records every call it serves.

    Per call: the time, the torque requested before any clamping (for the Riccati controller its
    unclamped Eq. (33) torque; the VWBC's QP already respects the limits, so its output) and the stance
    flags of the plan knot used. ``traces(times)`` aligns the records with the simulation's ticks.

    The records live in preallocated arrays (``capacity`` rows, e.g. the run's tick count; doubled when
    full), so the control-rate path writes into them without allocating per tick. ``times``,
    ``requested`` and ``stances`` are views of the rows recorded so far.
    """

    def __init__(self, inner: RiccatiController | VWBCController, capacity: int = 1024) -> None:
        self.inner = inner
        capacity = max(int(capacity), 1)
        self._times = np.zeros(capacity)
        self._requested = np.zeros((capacity, inner.robot.nu))
        self._stances = np.zeros((capacity, 4), dtype=bool)
        self._count = 0

    @property
    def plan(self) -> Plan | None:
        return self.inner.plan

    @property
    def times(self) -> np.ndarray:
        return self._times[: self._count]

    @property
    def requested(self) -> np.ndarray:
        return self._requested[: self._count]

    @property
    def stances(self) -> np.ndarray:
        return self._stances[: self._count]

    def set_plan(self, plan: Plan) -> None:
        self.inner.set_plan(plan)

    def _grow(self) -> None:
        """Double the capacity (rare: only when the run outlasts the preallocated ticks)."""

        def doubled(array: np.ndarray) -> np.ndarray:
            grown = np.zeros((2 * len(array), *array.shape[1:]), dtype=array.dtype)
            grown[: len(array)] = array
            return grown

        self._times = doubled(self._times)
        self._requested = doubled(self._requested)
        self._stances = doubled(self._stances)

    def compute(self, t: float, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        if self._count == len(self._times):
            self._grow()
        row = self._count
        plan = self.inner.plan
        torques = self.inner.compute(t, q, v)
        riccati = isinstance(self.inner, RiccatiController) and plan is not None
        self._requested[row] = self.inner.requested if riccati else torques
        self._times[row] = t
        if plan is not None:
            self._stances[row] = plan.contacts[plan.knot_at(t)]
        else:
            self._stances[row] = False
        self._count = row + 1
        return torques

    def traces(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Requested torques ``(ticks, nu)`` (NaN where this controller was not called, e.g. before the
        first plan) and planned stance flags ``(ticks, 4)`` (False there), on the tick grid ``times``."""
        times = np.asarray(times, dtype=float)
        requested = np.full((len(times), self._requested.shape[1]), np.nan)
        stance = np.zeros((len(times), 4), dtype=bool)
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
        SRBSettings(dt=schedule.srb_dt, running_weights=srb_running, terminal_weights=srb_terminal)
    )
    builder = CafeProblemBuilder(whole_body, srb, schedule)
    low_level: RiccatiController | VWBCController
    if config.wbc == "riccati":
        low_level = RiccatiController(robot)
    else:
        try:
            vwbc_settings = VWBCSettings(solver=config.vwbc.solver, warm_start=config.vwbc.warm_start)
        except ValueError as error:
            raise ConfigError(f"vwbc: {error}") from error
        low_level = VWBCController(robot, vwbc_settings)
    ticks = config.simulation.duration * config.simulation.control_rate_hz  # the run's low-level calls
    recorder = LowLevelRecorder(low_level, capacity=int(np.ceil(ticks)) + 2)
    return CafeMpcController(robot, reference, builder, recorder, settings)


def low_level_of(controller: RunController) -> LowLevelController | None:
    """The Riccati/VWBC controller under a CAFE-MPC controller (unwrapped), None for PD."""
    if not isinstance(controller, CafeMpcController):
        return None
    low_level = controller.low_level
    return low_level.inner if isinstance(low_level, LowLevelRecorder) else low_level


def recorder_of(controller: RunController) -> LowLevelRecorder | None:
    if isinstance(controller, CafeMpcController) and isinstance(controller.low_level, LowLevelRecorder):
        return controller.low_level
    return None
