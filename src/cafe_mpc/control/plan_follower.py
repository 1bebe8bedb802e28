"""A low-level controller closed around a fixed plan (synthetic plans, offline trajectories)."""

from __future__ import annotations

import numpy as np

from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import Plan


class PlanFollower:
    """The closed-loop ``Controller`` that runs ``low_level`` on ``plan`` at every tick."""

    def __init__(self, low_level: LowLevelController, plan: Plan) -> None:
        self.low_level = low_level
        self.plan = plan

    def reset(self) -> None:
        self.low_level.reset()

    def compute(self, t: float, measurement: Measurement) -> np.ndarray:
        return self.low_level.compute(t, measurement, self.plan)
