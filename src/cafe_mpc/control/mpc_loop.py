"""The policy side of CAFE-MPC in simulated time: when MPC updates start and when their plans take effect.

The closed-loop composition of the MPC (``cafe_mpc.mpc.RecedingHorizonMpc``) and a ``LowLevelController``
(``cafe_mpc.wbc``: Riccati (33), VWBC (34), PD) at the control rate, with one MPC worker:

* an update starts from the newest measurement when the worker is free and at least one MPC period has
  passed since the previous start (the paper's 33-50 Hz);
* its plan takes effect after its latency: the **measured** wall-clock time of the update (default; what a
  robot sees when the MPC runs beside it) or a **fixed** constant (deterministic; the paper's C++ budget);
  the worker is busy until then, so a slow update delays the next one (nothing runs in parallel);
* the very first (cold) solve runs before the clock starts, as on the robot, where the MPC is started while
  the robot stands; its plan is active from t = 0.

The low-level controller follows the newest plan at every tick (the knot closest in time). A failed update
keeps the previous plan; with no plan, or once the plan's horizon has run out, the robot is held by the PD
standing controller (damped stance), counted in ``pd_fallback_ticks``. The wall-clock real-time mode with
the MPC in its own process is ``cafe_mpc.control.realtime``. The same loop runs the template-MPC baseline
(``mpc.template.TemplateMpc``, whose ``TemplatePlan`` its own low level ``wbc.template_low_level`` follows).
"""

from __future__ import annotations

import logging

import numpy as np

from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import Plan
from cafe_mpc.core.template_plan import TemplatePlan
from cafe_mpc.mpc.problem import CafeProblemBuilder
from cafe_mpc.mpc.receding_horizon import MpcSettings, MpcStatistics, RecedingHorizonMpc
from cafe_mpc.mpc.template import TemplateMpc, TemplateProblemBuilder
from cafe_mpc.reference.base import Reference
from cafe_mpc.robots.robot import Robot
from cafe_mpc.wbc.pd import PDController

__all__ = ["CafeMpcController", "MpcSettings", "MpcStatistics"]

logger = logging.getLogger(__name__)


class CafeMpcController:
    """Closed-loop CAFE-MPC in simulated time (the simulation's ``Controller``); see the module docstring."""

    def __init__(
        self,
        robot: Robot,
        reference: Reference,
        builder: CafeProblemBuilder | TemplateProblemBuilder,
        low_level: LowLevelController,
        settings: MpcSettings | None = None,
        mpc: RecedingHorizonMpc | TemplateMpc | None = None,
    ) -> None:
        self.robot = robot
        self.mpc = mpc if mpc is not None else RecedingHorizonMpc(robot, reference, builder, settings)
        self.settings = self.mpc.settings
        self.low_level = low_level
        self.fallback = PDController(robot)
        self.plan: Plan | TemplatePlan | None = None
        self.pending: tuple[float, float, Plan | TemplatePlan | None] | None = None
        """(time it takes effect, its measurement time, plan) of the update the worker is busy with."""
        self.next_update = 0.0

    @property
    def reference(self) -> Reference:
        return self.mpc.reference

    @property
    def builder(self) -> CafeProblemBuilder | TemplateProblemBuilder:
        return self.mpc.builder

    @property
    def statistics(self) -> MpcStatistics:
        return self.mpc.statistics

    # -------------------------------------------------------------------------------------- interface
    def reset(self) -> None:
        self.plan, self.pending = None, None
        self.mpc.reset()
        self.next_update = 0.0
        self.fallback.reset()
        self.low_level.reset()

    def start(self, t: float, state: Measurement) -> None:
        """Run the cold first solve now, from ``state`` at time ``t`` (before the clock starts, as on the
        robot); without it the first ``compute`` does. A no-op once the MPC has started."""
        if not self.mpc.started:
            self._update(t, state)

    def compute(self, t: float, state: Measurement) -> np.ndarray:
        # A plan that comes due now takes effect before the worker starts the next update.
        self._activate_pending(t)
        if self.pending is None and t + 1e-9 >= self.next_update:
            self._update(t, state)
            self._activate_pending(t)
        plan = self.plan
        if plan is None or t >= plan.end_time:
            self.statistics.fallback_ticks += 1
            return self.fallback.compute(t, state, None)
        torques = self.low_level.compute(t, state, plan)
        if not np.all(np.isfinite(torques)):
            self.statistics.fallback_ticks += 1
            return self.fallback.compute(t, state, None)
        return torques

    def _activate_pending(self, t: float) -> None:
        if self.pending is not None and t + 1e-9 >= self.pending[0]:
            _, start, plan = self.pending
            self.pending = None
            if plan is not None:
                self.plan = plan
                self.statistics.latencies.append(t - start)

    # ----------------------------------------------------------------------------------------- updates
    def _update(self, t: float, state: Measurement) -> None:
        before_clock = not self.mpc.started
        plan = self.mpc.update(t, state.q, state.v)
        statistics = self.statistics
        settings = self.settings
        if before_clock:
            # The cold solve runs before the clock starts: its plan acts at once, the next update follows
            # one period later (a failed cold solve is retried next period, the PD stance holds meanwhile).
            if plan is not None:
                self.plan = plan
                statistics.latencies.append(0.0)
            self.next_update = t + settings.period
            return
        elapsed = statistics.update_times[-1] if statistics.update_times else 0.0
        latency = elapsed if settings.latency == "measured" else settings.fixed_latency
        # The worker is busy until the plan takes effect; it starts again then, at most once per period.
        self.pending = (t + latency, t, plan)
        self.next_update = t + max(settings.period, latency)
