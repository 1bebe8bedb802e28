"""When the next real-time-iteration update happens (one rule for simulated time and the wall clock).

The preparation of an update starts right after the previous plan is published and must be finished when
the update's measurement is taken, or that measurement waits (it is older by the time the feedback runs:
latency). So the next update is one MPC period after the last, or later when the recent preparations took
longer: ``PREPARATION_QUANTILE`` of the last ``PREPARATION_HISTORY`` preparation times after the plan was
published. A slow computer then lowers the MPC rate instead of raising the robot's latency; an occasional
slower preparation still costs latency.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

PREPARATION_HISTORY = 20
"""Preparations the estimate of the next one's duration is taken over."""
PREPARATION_QUANTILE = 75.0
"""Percentile of the recent preparation times the next update leaves room for (75: a quarter of the
preparations, the slow ones, overrun and cost latency; a higher one lowers the rate for every update)."""


class UpdateClock:
    """Next update times on the control ticks (module docstring)."""

    def __init__(self, period: float, control_period: float) -> None:
        if not (period > 0 and control_period > 0):
            raise ValueError("MPC and control periods must be positive")
        self.period = float(period)
        self.control_period = float(control_period)
        self._preparations: deque[float] = deque(maxlen=PREPARATION_HISTORY)

    def reset(self) -> None:
        self._preparations.clear()

    def record_preparation(self, duration: float) -> None:
        """A preparation's duration (s, in the loop's time: measured wall time, scaled)."""
        self._preparations.append(float(duration))

    @property
    def expected_preparation(self) -> float:
        """The duration the next preparation is given (0 before the first)."""
        if not self._preparations:
            return 0.0
        return float(np.percentile(self._preparations, PREPARATION_QUANTILE))

    def next_update(self, last_update: float, published: float) -> float:
        """The control tick of the next update: at least one period after ``last_update`` and the expected
        preparation time after ``published`` (when the plan of the last update was out)."""
        earliest = max(last_update + self.period, published + self.expected_preparation)
        return self.tick_at_or_after(earliest)

    def tick_at_or_after(self, t: float) -> float:
        """The first control tick at or after ``t``."""
        return math.ceil(t / self.control_period - 1e-6) * self.control_period
