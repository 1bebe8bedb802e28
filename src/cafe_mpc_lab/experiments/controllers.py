"""The controller of a run as the experiment harness sees it: the assembly's, its low level recorded.

``build_run_controller(run)`` is ``assembly.build_controller`` with the low-level controller
wrapped in a ``LowLevelRecorder`` (any ``LowLevelController``: it reads ``last_request``), so the run can
report what it asked for before clamping (the Riccati controller clamps to the torque limits; the paper's
Fig. 9 shows the unclamped request) and which stance the plan assumed at every tick (for the friction-cone
score of controllers that do not check it themselves). The rest reads what ``metrics.json`` reports of a
run's controller: how time was modelled (``timing_of``), the MPC's statistics (``mpc_summary``), the
reference it tracked.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cafe_mpc.assembly.controllers import (
    RunController,
    build_controller,
    build_low_level,
    build_mpc_loop,
    runs_alone,
)
from cafe_mpc.config import RunConfig
from cafe_mpc.control.loop import MpcLoop
from cafe_mpc.core.contacts import N_FEET
from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import KnotPlan
from cafe_mpc.planners.resolved import ResolvedRun


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

    def compute(self, t: float, measurement: Measurement, plan: KnotPlan | None) -> np.ndarray:
        if self._count == len(self._times):
            self._grow()
        row = self._count
        torques = self.inner.compute(t, measurement, plan)
        self._requested[row] = self.inner.last_request
        self._times[row] = t
        if plan is not None:
            self._stances[row] = plan.contacts[plan.knot_at(t)]
            if self.record_plans and plan is not self._last_plan:
                self._record_plan(t, plan, len(measurement.q))
        else:
            self._stances[row] = False
        self._count = row + 1
        return torques

    def _record_plan(self, t: float, plan: KnotPlan, nq: int) -> None:
        """Keep a plan the video can draw (one with the robot's configurations at its knots)."""
        configurations = plan.knot_configurations(nq)
        if configurations is None:
            return
        self._last_plan = plan
        self.plans.append(
            RecordedPlan(
                t, plan.times.copy(), configurations.copy(), plan.contacts.copy(), plan.forces.copy()
            )
        )

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


def build_recorder(run: ResolvedRun) -> LowLevelRecorder:
    """The run's low-level controller (``assembly.build_low_level``) wrapped in a recorder sized for the
    run's ticks."""
    config = run.config
    ticks = config.simulation.duration * config.simulation.control_rate_hz  # the run's low-level calls
    return LowLevelRecorder(
        build_low_level(run),
        capacity=int(np.ceil(ticks)) + 2,
        n_feet=run.robot.n_feet,
        record_plans=config.output.render,  # the video draws the plan in effect at every frame
    )


def build_run_controller(run: ResolvedRun) -> RunController:
    """The controller of a run in simulated time (``assembly.build_controller``), its low level recorded."""
    if runs_alone(run.config):
        return build_controller(run)
    return build_controller(run, low_level=build_recorder(run))


def build_run_process_loop(run: ResolvedRun) -> MpcLoop:
    """The MPC loop of a run against the wall clock, the planner in its own process
    (``assembly.build_mpc_loop``), its low level recorded."""
    return build_mpc_loop(run, "process", low_level=build_recorder(run))


def reference_of(controller: RunController):
    """The reference an MPC run tracked (None for PD standing)."""
    return controller.reference if is_mpc(controller) else None


def timing_of(config: RunConfig, controller: RunController) -> dict:
    """How time was modelled in a run (recorded in ``metrics.json``): ``realtime`` (wall clock, MPC process),
    ``measured`` (simulated time, plans act after their measured update time) or ``fixed``."""
    if not is_mpc(controller):
        return {"mode": "none (PD standing)"}
    mode = "realtime" if config.simulation.realtime else config.mpc.latency
    if mode == "realtime":  # the MPC process always runs with its wall-clock budget
        config = config.model_copy(update={"mpc": config.mpc.model_copy(update={"latency": "measured"})})
    settings = config.mpc
    return {
        "mode": mode,
        "scheme": controller.scheme,
        "period_s": config.mpc.period,
        "fixed_latency_s": config.mpc.fixed_latency if mode == "fixed" else None,
        "compute_scale": config.mpc.compute_scale if mode == "measured" else None,
        "time_budget_ms": settings.budget * 1e3 if settings.budget is not None else None,
        "max_iterations": settings.max_iterations,
    }


def mpc_summary(controller: RunController, log) -> dict | None:
    """The ``mpc`` block of ``metrics.json``: update-time breakdown, iterations, latency, achieved rate."""
    if not is_mpc(controller):
        return None
    return controller.summary(float(log.time[-1]) if len(log.time) else 0.0)


def mpc_statistics_of(controller: RunController):
    """The MPC's per-update records (the MPC process's in real-time runs), None for PD standing."""
    return controller.statistics if is_mpc(controller) else None


def is_mpc(controller: RunController) -> bool:
    """Whether the run is an MPC run (simulated time or real time), not PD standing."""
    return isinstance(controller, MpcLoop)


def recorder_of(controller: RunController) -> LowLevelRecorder | None:
    """The recorder around the low-level controller of an MPC run (None for PD standing)."""
    low_level = controller.low_level if is_mpc(controller) else None
    return low_level if isinstance(low_level, LowLevelRecorder) else None


def low_level_of(controller: RunController) -> LowLevelController:
    """The low-level controller that produced a run's torques: the plan follower's under an MPC loop
    (unwrapped from its recorder), or the PD controller itself."""
    recorder = recorder_of(controller)
    if recorder is not None:
        return recorder.inner
    return controller.low_level if is_mpc(controller) else controller
