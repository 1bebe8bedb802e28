"""The controller interfaces.

``LowLevelController``: what runs at the control rate under a plan (PD, Riccati feedback (33), VWBC (34)).
The caller owns the plan and passes it on every tick (there is no ``set_plan``).

* ``reset()`` forgets per-run state (previous solutions, warm starts, counters);
* ``compute(t, measurement, plan) -> torques`` returns the joint torques to send (an array the controller
  owns and overwrites on its next call); ``plan`` is of the plan type the controller follows (generic:
  ``LowLevelController[PlanT]``; a planner pairs with the low levels of its plan type), ``None`` only for
  controllers that need none (PD);
* ``statistics() -> dict`` reports per-run counters as plain data;
* ``last_request`` holds the torque the last ``compute`` asked for *before* any clamping to the limits
  (equal to the output for controllers that respect the limits by construction), so that a recorder can
  log it without knowing the controller's type.

``Controller``: what the closed-loop simulation calls (``reset()`` once, then ``compute(t, measurement)`` at
the control rate). A ``LowLevelController`` that needs no plan (PD) is one; the MPC loop in
``cafe_mpc.control`` is one.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Generic, Protocol

import numpy as np

from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import PlanT


class LowLevelController(ABC, Generic[PlanT]):
    """Joint torques at the control rate from a measurement and a plan of type ``PlanT`` (module
    docstring)."""

    last_request: np.ndarray
    """Torque the last ``compute`` asked for before clamping to the limits (nu,)."""

    @abstractmethod
    def reset(self) -> None:
        """Forget everything from a previous run (warm starts, counters)."""

    @abstractmethod
    def compute(self, t: float, measurement: Measurement, plan: PlanT | None) -> np.ndarray:
        """Torques to send at time ``t`` (owned by the controller, overwritten on the next call)."""

    @abstractmethod
    def statistics(self) -> dict:
        """Per-run counters as plain data (empty when the controller has none)."""


class Controller(Protocol):
    """A closed-loop controller: ``reset()`` once, then ``compute(t, measurement)`` at the control rate."""

    def reset(self) -> None: ...

    def compute(self, t: float, measurement: Measurement) -> np.ndarray: ...
