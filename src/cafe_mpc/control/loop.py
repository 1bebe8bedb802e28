"""The MPC loop: a planner and a low level closed around the robot, behind one interface, two transports.

``MpcLoop[PlanT]`` is what a run, the library front end (``cafe_mpc.Controller``) and the experiment harness
see of CAFE-MPC or any other planner (``planners.base.Planner``) over a low level of its plan type, whatever
carries the plans between them:

* ``control.inline.InlineMpcLoop``: the planner in the calling thread, in simulated (or the caller's) time,
  with fixed or measured latency;
* ``control.process.ProcessMpcLoop``: the planner in its own process against the wall clock, plans and
  measurements through shared memory (``control.ipc``).

Both follow the newest plan with the same follower and its safe ladder (``control.plan_follower``: the last
plan while it lasts, then the balance stance, then the damped stance) and take runtime commands through the
same channel (``commands``, ``control.commands``). The interface:

* ``reset()``: make ready for a run (the follower's counters; inline also the plans and the planner's warm
  starts, so that the next ``start`` or ``compute`` is a cold solve);
* ``start(t, measurement)``: the cold first solve before the clock starts, as on the robot (process: start the
  MPC process, or a new one, and wait for its first plan);
* ``compute(t, measurement) -> torques``: at the control rate;
* ``plan``: the plan the low level follows (None before the first, and while the safe ladder holds the
  robot off the plans); ``reference``: the reference the run tracks;
  ``scheme``: the update scheme in use (``rti`` or ``one_phase``); ``low_level``;
* ``statistics``: the planner's per-update records (``MpcStatistics``; process: the MPC process's, once it
  has stopped), ``summary(duration)``: the ``mpc`` block of a run's metrics;
* ``report_sensors(t, fault, stop)``: the sensing front end says a sensor has been out too long (``fault``:
  what), or that all are back (None): the robot is held off the plans meanwhile, or (``stop``: the estimate
  stands in for the sensor) stopped on them;
* ``fault_record(control_period)``: what the safe ladder (and the MPC process's supervision) did, for
  ``metrics.json``'s ``faults`` block; None when nothing happened;
* ``failure`` and ``should_stop(t)``: why the run must end (the MPC process could not be kept running), and
  when;
* ``close()`` (also ``with``): stop what the loop started; idempotent.
"""

from __future__ import annotations

import logging
import math
from abc import ABC, abstractmethod
from typing import Generic

import numpy as np

from cafe_mpc.control.commands import CommandChannel
from cafe_mpc.control.plan_follower import NewestPlanFollower
from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import PlanT
from cafe_mpc.planners.base import MpcStatistics
from cafe_mpc.reference.base import Reference

logger = logging.getLogger(__name__)


class GaitRestart:
    """Restarts the gait from the stance the robot stands in after the safe ladder held it (docs/faults.md),
    on the MPC's side of either transport, at its updates: told with each measurement whether the robot was
    off the plans then (``held``), the first update from a held measurement makes the reference stand from
    its time until further notice (``restart_gait(t, inf)``: the plans that take the robot back stand where
    it stands, not mid-cycle in a gait it is no longer in); the first from a measurement after the robot was
    taken back makes it stand ``stand`` s more and then start the gait from its first phase
    (``restart_gait(t, stand)``). ``stand`` None: the reference's own start stance. A reference without
    ``restart_gait`` (a stored trajectory, a composed task) goes on as it is; so does every reference with
    ``enabled`` False."""

    def __init__(self, reference: Reference, stand: float | None, enabled: bool = True) -> None:
        self.restart = getattr(reference, "restart_gait", None) if enabled else None
        self.rest = getattr(reference, "rest_commands", None)
        self.stand = float(stand if stand is not None else getattr(reference, "start_stance", 0.0))
        self.held = False
        self.stopping = False

    def observe(self, t: float, held: bool, stopping: bool = False) -> bool:
        """The update at ``t`` is solved from a measurement taken while the robot was ``held`` off the plans
        (or was ``stopping`` on them: the commands rest from then, ``rest_commands``, and come back when the
        stop ends on the plans): whether the reference was restarted or its commands changed now (a
        preparation made before is stale)."""
        changed = False
        if stopping != self.stopping and self.rest is not None:
            self.stopping = stopping
            if stopping or not held:  # held after a stop: the restart below rests the commands
                self.rest(t, stopping)
                changed = True
                logger.info("t = %.3f s: the commands %s", t, "rest" if stopping else "come back")
        if held == self.held or self.restart is None:
            return changed
        self.held = held
        self.restart(t, math.inf if held else self.stand)
        logger.info(
            "t = %.3f s: the gait %s",
            t,
            "stands until the robot is taken back" if held else "restarts from stance",
        )
        return True


class MpcLoop(ABC, Generic[PlanT]):
    """A planner's MPC loop over a low level (module docstring)."""

    low_level: LowLevelController[PlanT]
    """What follows the plan at the control rate."""
    follower: NewestPlanFollower[PlanT]
    """The low level on the newest plan, with the safe ladder."""
    commands: CommandChannel
    """Runtime commands (``cafe_mpc.Controller.set_command``, teleop), taken at the planner's next update."""
    failure: str | None = None
    """Why the run must end (the MPC process could not be kept running); None while all is well."""
    _plan: PlanT | None = None

    @property
    def plan(self) -> PlanT | None:
        """The plan the low level follows now (None before the first, and while the safe ladder holds the
        robot off the plans)."""
        return self._plan if self.follower.following else None

    @property
    def newest_plan(self) -> PlanT | None:
        """The newest plan received, followed or not."""
        return self._plan

    @property
    @abstractmethod
    def reference(self) -> Reference | None:
        """The reference the run tracks (the planner's)."""

    @property
    @abstractmethod
    def scheme(self) -> str:
        """The update scheme in use: ``rti`` (real-time iteration) or ``one_phase``."""

    @property
    @abstractmethod
    def statistics(self) -> MpcStatistics | None:
        """The planner's per-update records (None where they are not available yet)."""

    @abstractmethod
    def reset(self) -> None:
        """Make ready for a run (module docstring)."""

    @abstractmethod
    def start(self, t: float, measurement: Measurement) -> None:
        """The cold first solve from ``measurement`` at ``t``, before the clock starts."""

    @abstractmethod
    def compute(self, t: float, measurement: Measurement) -> np.ndarray:
        """Joint torques for time ``t`` (owned by the loop's low level, overwritten on the next call)."""

    @abstractmethod
    def summary(self, duration: float | None = None) -> dict:
        """The ``mpc`` block of a run's metrics (update times, iterations, latency, fallback ticks); with the
        run's ``duration``, also the achieved update rate ``rate_hz``."""

    def report_sensors(self, t: float, fault: str | None, stop: bool = False) -> None:
        """A sensor has been out for too long (``fault``: which, since when): hold the robot off the plans
        (balance) until all are back (``None``); plans count again once measured after that. ``stop``: the
        estimate stands in for the sensor (``SensorFrontEnd.modelled``): the robot stays on the plans, whose
        commands rest, until it is slow (the follower's ``stop`` step), and only then balances."""
        self.follower.hold(t, "sensors", None if stop else fault)
        self.follower.stop(t, "sensors", fault if stop else None)

    def fault_record(self, control_period: float) -> dict | None:
        """What the safe ladder did (``NewestPlanFollower.record``), None when it never left the plans."""
        if not self.follower.eventful:
            return None
        return {"ladder": self.follower.record(control_period)}

    def should_stop(self, t: float) -> bool:
        """Whether the run should end at ``t`` (after a ``failure``)."""
        return False

    def close(self) -> None:
        """Stop what the loop started (nothing inline); idempotent."""

    def __enter__(self) -> MpcLoop[PlanT]:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
