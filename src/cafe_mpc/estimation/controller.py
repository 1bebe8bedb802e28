"""A controller fed by sensor readings: the state estimator in front of any ``core.controller.Controller``.

``SensingController(inner, estimator)`` is what the closed loop calls when the controller must see sensors
(``estimator: kinematic_kf``): every tick it runs the estimator on the readings, with the stance flags of the
plan ``inner`` follows now (``inner.plan``, if it has one: both MPC loops, ``control.inline`` and
``control.process``, do), and hands the estimate to ``inner.compute``. It runs in the caller's thread at the
control rate, in every timing mode and in ``--realtime`` (where ``inner`` publishes the estimate to the MPC
process). Readings stamped earlier than the tick (a late sample) give an estimate of their own time, which is
carried to the tick at constant velocity before the controller sees it. The estimate of every tick is
recorded in preallocated arrays (``trace``) for the run's log and metrics.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from cafe_mpc.core.controller import Controller
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.sensors import SensorReadings
from cafe_mpc.estimation.estimator import StateEstimator

LATE = 1e-6
"""s: readings older than the tick by more than this are brought forward to it."""


class SensingController:
    """Sensor readings -> ``StateEstimator`` -> ``inner`` (see the module docstring).

    ``capacity``: ticks to preallocate for the record (it grows if a run outlasts it); ``position_xy``: the
    base's x-y where the run starts (the odometry origin, ``StateEstimator.reset``).
    """

    def __init__(
        self,
        inner: Controller,
        estimator: StateEstimator,
        capacity: int = 0,
        position_xy: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        self.inner = inner
        self.estimator = estimator
        self.position_xy = (float(position_xy[0]), float(position_xy[1]))
        robot = estimator.robot
        capacity = max(int(capacity), 1)
        self._q = np.zeros((capacity, robot.nq))
        self._v = np.zeros((capacity, robot.nv))
        self._contacts = np.zeros((capacity, robot.n_feet), dtype=bool)
        self._trust = np.zeros((capacity, robot.n_feet))
        self._count = 0
        self._step = np.zeros(robot.nv)
        self.late_ticks = 0
        """Ticks whose readings were older than the tick and were brought forward (``_bring_forward``)."""
        self.last_measurement: Measurement | None = None

    @property
    def plan(self):
        """The plan ``inner`` follows now (None without one)."""
        return getattr(self.inner, "plan", None)

    def reset(self) -> None:
        self.inner.reset()
        self.estimator.reset(self.position_xy)
        self._count = 0
        self.late_ticks = 0

    def compute(self, t: float, readings: SensorReadings) -> np.ndarray:
        measurement = self.estimator.update(readings, self.plan)
        if t - measurement.time > LATE:
            self._bring_forward(measurement, t)
        self.last_measurement = measurement
        self._record(measurement)
        return self.inner.compute(t, measurement)

    def _bring_forward(self, measurement: Measurement, t: float) -> None:
        """A late sample (its readings stamped ``measurement.time``, ``t`` now: a bus or a driver delayed
        them) carried to ``t`` at constant velocity on the configuration manifold (``pin.integrate``: the
        base screw-moves with its measured twist, the joints move at their rates), so that the low level and
        the MPC act on the state of now; the velocities are kept."""
        model = self.estimator.robot.model
        np.multiply(measurement.v, t - measurement.time, out=self._step)
        measurement.q[:] = pin.integrate(model, measurement.q, self._step)
        measurement.time = float(t)
        self.late_ticks += 1

    def _record(self, measurement: Measurement) -> None:
        if self._count == len(self._q):
            self._grow()
        row = self._count
        self._q[row] = measurement.q
        self._v[row] = measurement.v
        self._contacts[row] = measurement.contacts
        self._trust[row] = self.estimator.trust
        self._count = row + 1

    def _grow(self) -> None:
        """Double the capacity (rare: only when a run outlasts the preallocated ticks)."""

        def doubled(array: np.ndarray) -> np.ndarray:
            grown = np.zeros((2 * len(array), *array.shape[1:]), dtype=array.dtype)
            grown[: len(array)] = array
            return grown

        self._q, self._v = doubled(self._q), doubled(self._v)
        self._contacts, self._trust = doubled(self._contacts), doubled(self._trust)

    def trace(self) -> dict[str, np.ndarray]:
        """The estimate of every tick so far: ``estimate_q``, ``estimate_v`` (planning coordinates),
        ``estimated_contacts`` and ``estimate_trust`` (per foot)."""
        n = self._count
        return {
            "estimate_q": self._q[:n].copy(),
            "estimate_v": self._v[:n].copy(),
            "estimated_contacts": self._contacts[:n].copy(),
            "estimate_trust": self._trust[:n].copy(),
        }
