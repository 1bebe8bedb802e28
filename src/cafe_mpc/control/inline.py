"""The MPC loop in simulated time (or the caller's): the planner in the calling thread (``control.loop``).

``InlineMpcLoop`` closes any planner (``planners.base.Planner``) and a ``LowLevelController`` of its plan type
(``low_level``: Riccati (33), VWBC (34); the template's own) at the control rate, with one MPC worker, and
decides when updates happen and when their plans take effect. Two schemes (``MpcSettings.scheme``; a
planner without the real-time iteration runs one-phase updates):

* **real-time iteration** (``rti``, default): an update at time ``t`` takes the measurement of ``t`` and runs
  only the *feedback* phase (``Planner.feedback``); its plan takes effect after the feedback's time. Right
  after it, the worker *prepares* the next update, for the time ``t_next`` at which the measurement will be
  taken, from the state the new plan predicts there (``predict``), while the plan drives the robot.
  ``t_next`` is one MPC period later, or later still when the preparation is expected to take longer
  (``control.update_clock``): then the rate drops, not the latency. A preparation that runs past ``t_next``
  anyway delays that update's feedback (its measurement is then older: the delay counts in its latency).
* **one-phase** (``one_phase``): an update starts from the newest measurement when the worker is free and at
  least one period has passed since the previous start; the whole update runs after the measurement, and
  the worker is busy until its plan takes effect (a slow update delays the next one).

With a fixed latency the real-time iteration compensates it (``MpcSettings.delay_compensation``, default
on), with the planner's own prediction: the problem of the update measured at ``t`` starts where the planner
says for a plan that takes effect at ``t + fixed_latency`` (``Planner.problem_start``; CAFE-MPC: the last
whole-body knot time at or before it), and its feedback embeds the measured state carried there along the
plans in effect meanwhile (``Planner.carry``; CAFE-MPC: ``planners.cafe.prediction``).

Latency: **measured** (default): each phase takes its measured wall-clock time in simulated time (times
``compute_scale``: a computer that much slower), what a robot sees when the MPC runs beside it; or **fixed**:
a plan takes effect ``fixed_latency`` after its measurement (deterministic; in the real-time iteration a
transport delay: updates still start every period, several plans may be in flight). The very first (cold)
solve runs before the clock starts, as on the robot, where the MPC is started while the robot stands; its
plan is active from t = 0 (and the first preparation is made then too).

The low-level controller follows the newest plan at every tick. A failed update keeps the previous plan;
with no plan, or once the plan's horizon has run out, the safe ladder holds the robot (the balance stance,
then the damped one; ``control.plan_follower``), counted in ``pd_fallback_ticks``, until a plan measured
since takes it back. The same interface with the planner in its own process against the wall clock is
``control.process``.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from cafe_mpc.config import MpcSettings, RecoveryConfig
from cafe_mpc.control.commands import CommandChannel, apply_command
from cafe_mpc.control.loop import GaitRestart, MpcLoop
from cafe_mpc.control.plan_follower import NewestPlanFollower
from cafe_mpc.control.update_clock import UpdateClock
from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import PlanT
from cafe_mpc.core.progress import stage
from cafe_mpc.planners.base import PLANNER_ERRORS, MpcStatistics, Planner, forget_warm_start
from cafe_mpc.reference.base import Reference
from cafe_mpc.robots.robot import Robot

logger = logging.getLogger(__name__)


class InlineMpcLoop(MpcLoop[PlanT]):
    """A planner's MPC loop in simulated time (the simulation's ``Controller``); see the module docstring.

    ``control_period``: the period of the ticks ``compute`` is called at (updates happen on ticks: a
    preparation is made for the tick its measurement will come from). ``recovery``, ``balance`` and
    ``damped``: the safe ladder's settings, balance controller and damped stance (``control.plan_follower``;
    defaults: ``RecoveryConfig()``, ``BalanceController(robot)``, ``PDController(robot)``).
    """

    def __init__(
        self,
        robot: Robot,
        planner: Planner[PlanT],
        low_level: LowLevelController[PlanT],
        control_period: float = 0.002,
        recovery: RecoveryConfig | None = None,
        balance: LowLevelController | None = None,
        damped: LowLevelController | None = None,
    ) -> None:
        if not control_period > 0:
            raise ValueError(f"control period must be positive, got {control_period}")
        self.robot = robot
        self.planner = planner
        self.settings: MpcSettings = planner.settings
        self._scheme = self.settings.scheme if planner.supports_rti else "one_phase"
        self.low_level = low_level
        self.control_period = float(control_period)
        self.follower = NewestPlanFollower(robot, low_level, recovery, balance, damped)
        self._plan: PlanT | None = None
        self.pending: list[tuple[float, float, PlanT | None]] = []
        """(time it takes effect, its measurement time, plan) of the updates not yet in effect."""
        self.next_update = 0.0
        self.worker_free = 0.0
        """Simulated time at which the MPC worker finishes what it is doing (real-time iteration)."""
        self.clock = UpdateClock(self.settings.period, self.control_period)
        self.delay = self._compensated_delay()
        """How long after its measurement an update's plan takes effect when the loop compensates it (the
        fixed latency with ``MpcSettings.delay_compensation``), else 0."""
        self.commands = CommandChannel()
        """Runtime commands (``cafe_mpc.Controller.set_command``, teleop), taken at the next MPC update."""
        recovery = self.follower.recovery
        self.gait_restart = GaitRestart(planner.reference, recovery.restart_stand, recovery.restart_gait)
        """The gait restarted from stance after an episode off the plans (``control.loop.GaitRestart``)."""
        self._withheld = (math.inf, math.inf)
        self._cold_after_withholding = False
        self._cold_in_loop = False
        """The planner was made to solve cold after withheld plans: its cold solve runs in the loop, its plan
        takes effect after the update's latency (not at once, as the first one's before the clock)."""

    @property
    def reference(self) -> Reference:
        return self.planner.reference

    @property
    def scheme(self) -> str:
        """The scheme this run uses (a planner without the real-time iteration runs one-phase updates)."""
        return self._scheme

    @property
    def statistics(self) -> MpcStatistics:
        return self.planner.statistics

    def summary(self, duration: float | None = None) -> dict:
        statistics = self.statistics
        summary = statistics.summary()
        if duration is not None:
            summary["rate_hz"] = (len(statistics.latencies) - 1) / duration if duration > 0 else None
        return summary

    def _problem_start(self, t: float) -> float:
        """Where the problem of the update measured at ``t`` starts (the planner's ``problem_start``)."""
        return self.planner.problem_start(t, self.delay)

    def _compensated_delay(self) -> float:
        settings = self.settings
        compensated = settings.delay_compensation and settings.latency == "fixed" and self.scheme == "rti"
        return settings.fixed_latency if compensated else 0.0

    @property
    def _scale(self) -> float:
        """Factor from measured wall time to simulated time (``compute_scale`` in measured mode)."""
        return self.settings.compute_scale

    # -------------------------------------------------------------------------------------- interface
    def reset(self) -> None:
        self._plan, self.pending = None, []
        self.planner.reset()
        self.next_update = 0.0
        self.worker_free = 0.0
        self.clock.reset()
        self.follower.reset()
        self._cold_after_withholding = self._cold_in_loop = False

    def withhold_plans(self, start: float, end: float) -> None:
        """Withhold the plans on ``[start, end)``: no update starts and no plan takes effect (those in flight
        are lost), what a stalled or restarting MPC process does to the robot, here in simulated time (the
        lab's ``mpc_pause`` fault); the first update after ``end`` solves cold from its measurement, its plan
        after the update's latency, as a stalled process that resumes (``control.process``)."""
        if not (math.isfinite(start) and math.isfinite(end) and 0.0 <= start < end):
            raise ValueError(f"plans can be withheld on a finite interval, got [{start}, {end})")
        self._withheld = (float(start), float(end))

    def start(self, t: float, state: Measurement) -> None:
        """Run the cold first solve now, from ``state`` at time ``t`` (before the clock starts, as on the
        robot); without it the first ``compute`` does. A no-op once the planner has started."""
        if not self.planner.started:
            self._update(t, state)

    def compute(self, t: float, state: Measurement) -> np.ndarray:
        if state.height_map is not None:  # a new height map: the reference plans on it from now
            self.reference.observe_height_map(state.height_map, state.q, state.v)
        self.reference.observe_estimate(t, state.q, state.v)
        withheld_from, withheld_until = self._withheld
        if withheld_from - 1e-9 <= t < withheld_until - 1e-9:
            self.pending.clear()
            self._cold_after_withholding = True
        else:
            if self._cold_after_withholding:
                self._cold_after_withholding = False
                forget_warm_start(self.planner)
                self._cold_in_loop = True
                self.clock.reset()
                self.next_update = self.worker_free = t
            # A plan that comes due now takes effect before the worker starts the next update.
            self._activate_pending(t)
            idle = self.scheme == "rti" or not self.pending
            if idle and t + 1e-9 >= self.next_update:
                self._update(t, state)
                self._activate_pending(t)
        before = self.follower.fallback_ticks
        torques = self.follower.compute(t, state, self._plan)
        self.statistics.fallback_ticks += self.follower.fallback_ticks - before
        return torques

    def _activate_pending(self, t: float) -> None:
        while self.pending and t + 1e-9 >= self.pending[0][0]:
            _, start, plan = self.pending.pop(0)
            if plan is not None:
                self._plan = plan
                self.follower.new_plan(t, start)
                self.statistics.latencies.append(t - start)

    # ----------------------------------------------------------------------------------------- updates
    def _update(self, t: float, state: Measurement) -> None:
        command = self.commands.take()
        if command is not None:  # from this update on (with rti: the preparation made after its feedback)
            apply_command(self.reference, t, command)
        follower = self.follower
        restarted = self.gait_restart.observe(t, not follower.following, follower.stopping)
        if self._cold_in_loop and not self.planner.started:
            self._update_one_phase(t, state)
            return
        before_clock = not self.planner.started
        if before_clock:
            # The cold solve runs before the clock starts: its plan acts at once, the next update follows
            # one period later (a failed cold solve is retried next period, the PD stance holds meanwhile).
            stage("first (cold) MPC solve")
            plan = self.planner.update(t, state.q, state.v)
            if plan is not None:
                self._plan = plan
                self.follower.new_plan(t, t)
                self.statistics.latencies.append(0.0)
                if self.scheme == "rti":
                    self._prepare(self.clock.tick_at_or_after(t + self.settings.period))
            self.next_update = t + self.settings.period
            return
        if self.scheme == "rti":
            self._update_rti(t, state, restarted)
        else:
            self._update_one_phase(t, state)

    def _update_one_phase(self, t: float, state: Measurement) -> None:
        plan = self.planner.update(t, state.q, state.v)
        statistics = self.statistics
        settings = self.settings
        elapsed = statistics.update_times[-1] if statistics.update_times else 0.0
        latency = elapsed * self._scale if settings.latency == "measured" else settings.fixed_latency
        # The worker is busy until the plan takes effect; it starts again then, at most once per period.
        self.pending.append((t + latency, t, plan))
        self.next_update = t + max(settings.period, latency)

    def _update_rti(self, t: float, state: Measurement, restarted: bool = False) -> None:
        """Feedback for the measurement of ``t`` (or a one-phase update when no preparation waits for it, or
        the gait was ``restarted`` since it was made), then the preparation of the next update (module
        docstring)."""
        planner, settings, statistics = self.planner, self.settings, self.statistics
        measured = settings.latency == "measured"
        start = self._problem_start(t)
        prepared_time = planner.prepared_time
        prepared = not restarted and prepared_time is not None and abs(prepared_time - start) <= 1e-9
        if prepared:
            plan = self._feedback(t, start, state)
            work = statistics.feedback_times[-1] if plan is not None else 0.0
        else:
            plan = planner.update(t, state.q, state.v)
            work = statistics.update_times[-1] if statistics.update_times else 0.0
        if measured:
            begin = max(t, self.worker_free)
            effective = begin + work * self._scale
        else:
            effective = t + settings.fixed_latency
        self.pending.append((effective, t, plan))
        self.pending.sort(key=lambda entry: entry[0])
        # fixed latency: a transport delay, the MPC itself is ready at once
        following = self.clock.next_update(t, effective if measured else t)
        self.worker_free = effective
        self._prepare(following)
        self.next_update = following

    def _feedback(self, t: float, start: float, state: Measurement) -> PlanT | None:
        """The feedback phase of the update prepared for ``start``, from the measurement of ``t``: with
        delay compensation, the measured state carried to ``start`` first (``Planner.carry``; its time
        counts in the feedback's). A failed carry falls back to the measured state, and says so."""
        if self.delay <= 0:
            return self.planner.feedback(start, state.q, state.v)
        began = time.perf_counter()
        q, v = state.q, state.v
        try:
            carried = self.planner.carry(q, v, t, start, self._plan_in_effect)
            if np.all(np.isfinite(carried)):
                q, v = carried[: self.robot.nq], carried[self.robot.nq :]
            else:
                logger.warning("delay compensation at t = %.3f s: non-finite state; using the measured", t)
        except PLANNER_ERRORS as error:
            logger.warning("delay compensation at t = %.3f s failed (%s); using the measured state", t, error)
        carry_time = time.perf_counter() - began
        plan = self.planner.feedback(start, q, v)
        if plan is not None:
            self.statistics.feedback_times[-1] += carry_time
            self.statistics.update_times[-1] += carry_time
        return plan

    def _plan_in_effect(self, t: float) -> PlanT | None:
        """The plan the low level follows at ``t`` given the plans published and in flight now."""
        plan = self._plan
        for effective, _, pending in self.pending:
            if effective <= t + 1e-9 and pending is not None:
                plan = pending
        return plan

    def _prepare(self, t_next: float) -> None:
        """Prepare the update at ``t_next`` from the newest plan's prediction (the worker is busy then)."""
        start = self._problem_start(t_next)
        predicted = self.planner.predict(start)
        if predicted is None:
            return
        nq = self.robot.nq
        prepared = self.planner.prepare(start, predicted[:nq], predicted[nq:])
        if prepared and self.settings.latency == "measured":  # fixed: the update times are the period's
            elapsed = self.statistics.prepare_times[-1] * self._scale
            self.clock.record_preparation(elapsed)
            self.worker_free += elapsed
