"""Following plans: the low-level controller on the newest plan, and the safe ladder when there is none.

``NewestPlanFollower`` is what both MPC loops (in simulated time, ``control.inline``; with the planner in its
own process, ``control.process``) run at every control tick, on any plan type. While no fresh plan arrives
it steps down a ladder of safe behaviours (``SafetyStep``; docs/faults.md):

1. ``plan``: the low level follows the newest plan;
2. ``last_plan``: no new plan for ``recovery.stale_after`` s; the last one is still followed while it lasts;
3. ``stop``: a sensor the estimator stands in for (the IMU, its attitude from the model) has been out too
   long (``stop``): the low level follows the plans, and the MPC, told that the robot is stopping
   (``stopping``), brings it to rest on its gait's steps (``control.loop.GaitRestart``: the commands rest);
   once the base is slower than ``recovery.stop_speed`` (or after ``recovery.stop_timeout``) the balance
   stance takes over (a stance that does not step cannot take a bound's 0.85 m/s); lifted before that, the
   commands come back;
4. ``balance``: the plan has run out (or there is none, or the low level returned non-finite torques, or
   the loop holds the robot: its sensors are out): the balance controller (``low_level.balance``) holds the
   current stance, all feet down and the base level;
5. ``damped``: the balance controller held for ``recovery.balance_timeout`` s without a plan, or could not
   reach its stance, or the loop failed for good (``fail``): the damped PD stance (``low_level.pd``).

Plans take the robot back (to ``plan``) once they are fresh again: ``recovery.take_back_plans`` in a row,
each solved from a measurement taken after the robot was taken off the plans (``new_plan``'s
``measured_at``; the gait resumes from the stance the ladder holds) and each within ``stale_after`` of the
one before (a planner that is keeping up again, not one lucky plan from a struggling one). Every step is
recorded with its time and reason (``steps``; ``logging`` warnings), and ``record`` summarises them for
``metrics.json``. While the low level follows plans nothing of this changes what it does.

``PlanFollower`` closes a low level around one fixed plan (synthetic plans, offline trajectories).
"""

from __future__ import annotations

import logging
import math
from enum import StrEnum
from typing import Generic

import numpy as np

from cafe_mpc.config import RecoveryConfig
from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import PlanT
from cafe_mpc.low_level.balance import BalanceController
from cafe_mpc.low_level.pd import PDController
from cafe_mpc.robots.robot import Robot

logger = logging.getLogger(__name__)


class SafetyStep(StrEnum):
    """The rungs of the safe ladder, from following plans down to the damped stance."""

    PLAN = "plan"
    LAST_PLAN = "last_plan"
    STOP = "stop"
    BALANCE = "balance"
    DAMPED = "damped"


FOLLOWING = (SafetyStep.PLAN, SafetyStep.LAST_PLAN, SafetyStep.STOP)
"""The steps on which the low level follows a plan."""
ON_GAIT = (SafetyStep.PLAN, SafetyStep.LAST_PLAN)
"""The steps on which the robot is on its gait (anything else is an episode off it)."""
STOPPED = "the base has slowed down"
"""The reason the stop step hands over to the balance stance."""


class NewestPlanFollower(Generic[PlanT]):
    """The low level on the newest plan, or the safe ladder (module docstring).

    ``balance``: the balance controller (default: ``BalanceController(robot)``); ``damped``: the damped
    stance (default: ``PDController(robot)``). ``fallback_ticks`` counts the ticks on neither plan step. The
    loop tells it of every plan it receives (``new_plan``), of holds (``hold``) and of a failure for good
    (``fail``).
    """

    def __init__(
        self,
        robot: Robot,
        low_level: LowLevelController[PlanT],
        recovery: RecoveryConfig | None = None,
        balance: LowLevelController | None = None,
        damped: LowLevelController | None = None,
    ) -> None:
        self.low_level = low_level
        self.recovery = recovery if recovery is not None else RecoveryConfig()
        self.balance = balance if balance is not None else BalanceController(robot)
        self.fallback = damped if damped is not None else PDController(robot)
        self.fallback_ticks = 0
        self._reset_ladder()

    def _reset_ladder(self) -> None:
        self.step = SafetyStep.PLAN
        self.steps: list[dict] = []
        """Each change of step: ``{"t", "step", "reason"}``."""
        self.ticks = dict.fromkeys(SafetyStep, 0)
        """Ticks spent on each step."""
        self.nonfinite_ticks = 0
        self.failure: str | None = None
        self._holds: dict[str, str] = {}
        self._stops: dict[str, str] = {}
        self._stopped = False
        self._stop_since = 0.0
        self._last_plan_time: float | None = None
        self._resume_after = -math.inf
        self._plan_fresh = True
        self._fresh_in_a_row = 0
        self._balance_since = 0.0

    def reset(self) -> None:
        self.fallback.reset()
        self.balance.reset()
        self.low_level.reset()
        self.fallback_ticks = 0
        self._reset_ladder()

    # ----------------------------------------------------------------------------------- what it hears
    def new_plan(self, t: float, measured_at: float) -> None:
        """A plan solved from the measurement of ``measured_at`` arrived at ``t``. Off the plans, plans take
        the robot back once ``take_back_plans`` in a row were measured after it left them (and after the last
        hold), each within ``stale_after`` of the one before."""
        recovery = self.recovery
        if measured_at < self._resume_after - 1e-9:
            self._fresh_in_a_row = 0
        elif (
            self._fresh_in_a_row > 0
            and self._last_plan_time is not None
            and t - self._last_plan_time <= recovery.stale_after
        ):
            self._fresh_in_a_row += 1
        else:
            self._fresh_in_a_row = 1
        self._last_plan_time = t
        self._plan_fresh = self._fresh_in_a_row >= recovery.take_back_plans

    def hold(self, t: float, source: str, reason: str | None) -> None:
        """``source`` (``sensors``, ``mpc``) asks to hold the robot off the plans (``reason``), or lets go
        (``None``): plans count again once measured after that."""
        if reason is not None:
            self._holds[source] = reason
        elif self._holds.pop(source, None) is not None:
            self._off_plans_since(t)

    def stop(self, t: float, source: str, reason: str | None) -> None:
        """``source`` (``sensors``) asks that the robot be brought to rest on the plans and then held in the
        balance stance (``reason``: the ``stop`` step, then ``balance``), or lets go (``None``)."""
        if reason is not None:
            self._stops[source] = reason
        elif self._stops.pop(source, None) is not None and not self._stops and self._stopped:
            self._stopped = False
            self._off_plans_since(t)

    def fail(self, t: float, reason: str) -> None:
        """Hold the damped stance for good: the loop gave up (``reason``)."""
        if self.failure is None:
            self.failure = reason
            self._off_plans_since(math.inf)

    def _off_plans_since(self, t: float) -> None:
        """Plans measured before ``t`` take the robot back no more."""
        self._resume_after = max(self._resume_after, t)
        self._plan_fresh = False
        self._fresh_in_a_row = 0

    @property
    def following(self) -> bool:
        """Whether the low level follows a plan (the plan, last_plan or stop step)."""
        return self.step in FOLLOWING

    @property
    def stopping(self) -> bool:
        """Whether the robot is being brought to rest on the plans (the ``stop`` step): the MPC is told with
        every measurement, and rests the commands meanwhile (``control.loop.GaitRestart``)."""
        return self.step == SafetyStep.STOP

    # ------------------------------------------------------------------------------------------ compute
    def compute(self, t: float, measurement: Measurement, plan: PlanT | None) -> np.ndarray:
        if self._stops and not self._stopped and self.step == SafetyStep.STOP:
            self._stopped = self._slow(t, measurement)
        usable = (
            plan is not None
            and t < plan.end_time
            and not self._holds
            and not self._stopped
            and self.failure is None
            and (self.step in FOLLOWING or self._plan_fresh)
        )
        if usable:
            stale = self._last_plan_time is not None and t - self._last_plan_time > self.recovery.stale_after
            if self._stops:
                if self.step != SafetyStep.STOP:
                    self._stop_since = t
                self._go(t, SafetyStep.STOP, "; ".join(self._stops.values()), measurement)
            elif stale:
                self._go(t, SafetyStep.LAST_PLAN, "no new plan", measurement)
            else:
                self._go(t, SafetyStep.PLAN, "a fresh plan", measurement)
            torques = self.low_level.compute(t, measurement, plan)
            if np.all(np.isfinite(torques)):
                self.ticks[self.step] += 1
                return torques
            self.nonfinite_ticks += 1
            self._go(t, SafetyStep.BALANCE, "the low level returned non-finite torques", measurement)
        else:
            step, reason = self._safe_step(t, plan)
            self._go(t, step, reason, measurement)
        self.fallback_ticks += 1
        return self._safe_torques(t, measurement)

    def _safe_step(self, t: float, plan: PlanT | None) -> tuple[SafetyStep, str]:
        """Off the plans: balance, or damped once balance has held too long or after a failure (never back up
        from damped to balance: only a plan takes the robot back); and why."""
        if self.failure is not None:
            return SafetyStep.DAMPED, self.failure
        if self.step == SafetyStep.DAMPED:
            return SafetyStep.DAMPED, ""
        timeout = self.recovery.balance_timeout
        if self.step == SafetyStep.BALANCE and t - self._balance_since > timeout:
            return SafetyStep.DAMPED, f"no plan for {timeout:g} s in the balance stance"
        if self._holds:
            return SafetyStep.BALANCE, "; ".join(self._holds.values())
        if self._stopped:
            return SafetyStep.BALANCE, f"{'; '.join(self._stops.values())}; {STOPPED}"
        if plan is None:
            return SafetyStep.BALANCE, "no plan"
        if t >= plan.end_time:
            return SafetyStep.BALANCE, "the plan ran out"
        return SafetyStep.BALANCE, "no plan measured since the robot left the plans"

    def _slow(self, t: float, measurement: Measurement) -> bool:
        """Whether the stop has brought the base below ``stop_speed`` (horizontal, base frame), or has lasted
        ``stop_timeout``."""
        recovery = self.recovery
        vx, vy = float(measurement.v[0]), float(measurement.v[1])
        return vx * vx + vy * vy < recovery.stop_speed**2 or t - self._stop_since >= recovery.stop_timeout

    def _safe_torques(self, t: float, measurement: Measurement) -> np.ndarray:
        if self.step == SafetyStep.BALANCE:
            torques = self.balance.compute(t, measurement, None)
            if np.all(np.isfinite(torques)):
                self.ticks[SafetyStep.BALANCE] += 1
                return torques
            self._go(t, SafetyStep.DAMPED, "the balance controller returned non-finite torques", measurement)
        torques = self.fallback.compute(t, measurement, None)
        self.ticks[SafetyStep.DAMPED] += 1
        if not np.all(np.isfinite(torques)):  # a non-finite measurement: never send NaN torques
            torques[:] = 0.0
        return torques

    def _go(self, t: float, step: SafetyStep, reason: str, measurement: Measurement) -> None:
        """Move to ``step`` (a no-op when there): leaving the plans starts a wait for a fresh one; entering
        balance engages it on ``measurement`` (damped when its stance is out of reach)."""
        if step == self.step:
            return
        previous = self.step
        if previous in FOLLOWING and step not in FOLLOWING:
            self._off_plans_since(t)
        if step == SafetyStep.BALANCE:
            self._balance_since = t
            engage = getattr(self.balance, "engage", None)
            if engage is not None and not engage(measurement):
                step = SafetyStep.DAMPED
                reason += "; the balance stance is out of the legs' reach"
        self.step = step
        self.steps.append({"t": round(float(t), 6), "step": str(step), "reason": reason})
        quiet = SafetyStep.LAST_PLAN in (step, previous) and SafetyStep.PLAN in (step, previous)
        (logger.info if quiet else logger.warning)(
            "t = %.3f s: safe ladder %s -> %s (%s)", t, previous, step, reason
        )

    # ------------------------------------------------------------------------------------------ record
    @property
    def eventful(self) -> bool:
        """Whether the ladder ever left the plan step."""
        return bool(self.steps) or self.nonfinite_ticks > 0

    def record(self, control_period: float) -> dict:
        """The ladder's part of ``metrics.json``'s ``faults`` block: every step with its time, the seconds
        spent on each, and each episode off the gait (when it began and why, the lowest step, when the robot
        was back on its plans' gait and how long after; ``back_at`` None: it never was)."""
        episodes: list[dict] = []
        current: dict | None = None
        order = list(SafetyStep)
        for change in self.steps:
            step = SafetyStep(change["step"])
            if step not in ON_GAIT:
                if current is None:
                    current = {"off_at": change["t"], "reason": change["reason"], "lowest": str(step)}
                    episodes.append(current)
                elif order.index(step) > order.index(SafetyStep(current["lowest"])):
                    current["lowest"] = str(step)
            elif current is not None:
                current["back_at"] = change["t"]
                current["recovery_s"] = change["t"] - current["off_at"]
                current = None
        if current is not None:
            current["back_at"] = None
            current["recovery_s"] = None
        return {
            "steps": list(self.steps),
            "time_s": {str(step): ticks * control_period for step, ticks in self.ticks.items()},
            "episodes": episodes,
            "nonfinite_low_level_ticks": self.nonfinite_ticks,
            "failure": self.failure,
        }


class PlanFollower(Generic[PlanT]):
    """The closed-loop ``Controller`` that runs ``low_level`` on ``plan`` at every tick."""

    def __init__(self, low_level: LowLevelController[PlanT], plan: PlanT) -> None:
        self.low_level = low_level
        self.plan = plan

    def reset(self) -> None:
        self.low_level.reset()

    def compute(self, t: float, measurement: Measurement) -> np.ndarray:
        return self.low_level.compute(t, measurement, self.plan)
