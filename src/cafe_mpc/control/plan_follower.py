"""Following plans: the low-level controller on the newest plan, with one safe fallback.

``NewestPlanFollower`` is what both MPC loops (in simulated time, ``control.inline``; with the planner in its
own process, ``control.process``) run at every control tick, on any plan type; ``PlanFollower`` closes a low
level around one fixed plan (synthetic plans, offline trajectories).
"""

from __future__ import annotations

from typing import Generic

import numpy as np

from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import PlanT
from cafe_mpc.low_level.pd import PDController
from cafe_mpc.robots.robot import Robot


class NewestPlanFollower(Generic[PlanT]):
    """The low-level controller on a plan, or the damped PD standing controller when there is no plan, the
    plan's horizon has run out, or the low level returned non-finite torques (``fallback_ticks`` counts those
    ticks). The one fallback of every MPC loop."""

    def __init__(self, robot: Robot, low_level: LowLevelController[PlanT]) -> None:
        self.low_level = low_level
        self.fallback = PDController(robot)
        self.fallback_ticks = 0

    def reset(self) -> None:
        self.fallback.reset()
        self.low_level.reset()
        self.fallback_ticks = 0

    def compute(self, t: float, measurement: Measurement, plan: PlanT | None) -> np.ndarray:
        if plan is not None and t < plan.end_time:
            torques = self.low_level.compute(t, measurement, plan)
            if np.all(np.isfinite(torques)):
                return torques
        self.fallback_ticks += 1
        return self.fallback.compute(t, measurement, None)


class PlanFollower(Generic[PlanT]):
    """The closed-loop ``Controller`` that runs ``low_level`` on ``plan`` at every tick."""

    def __init__(self, low_level: LowLevelController[PlanT], plan: PlanT) -> None:
        self.low_level = low_level
        self.plan = plan

    def reset(self) -> None:
        self.low_level.reset()

    def compute(self, t: float, measurement: Measurement) -> np.ndarray:
        return self.low_level.compute(t, measurement, self.plan)
