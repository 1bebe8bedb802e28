"""The sensing front end, and a controller fed by sensor readings behind it.

``SensorFrontEnd(estimator, limits)`` is what stands between a robot's sensors and its controller, in the
simulation (``SensingController``) and in the library (``cafe_mpc.Controller.measurement_from_sensors``):

1. every reading is checked sample by sample (``core.sensors.SensorGuard``): a missing or late sample, a
   non-finite or out-of-range value is rejected and counted, the last good value held;
2. the state estimator turns the checked reading into a ``Measurement``;
3. an estimate that diverged (non-finite, or a base faster than ``estimate_speed_max``) restarts the
   estimator from the robot standing where it was (its velocity from the stance legs), counted; so does the
   end of an IMU outage that was long enough to hold the robot off its plans (the attitude and the velocity
   integrated without it are stale; the robot stands in the balance stance). An encoder's outage needs no
   restart: the other legs carried the estimate, and the leg is read again.

``fault(t)`` says when the controller should hold the robot off its plans: a sensor out for longer than
``outage_limit``, or the estimator restarted less than ``outage_limit`` ago; ``modelled(t)`` whether the
estimate stands in for it (the IMU with the model's attitude), so that the robot may first be stopped on its
plans (the safe ladder's ``stop`` step). ``record()`` is the ``sensors``
part of a run's ``faults`` block.

``SensingController(inner, estimator, limits=...)`` is what the closed loop calls when the controller must
see sensors (``estimator: kinematic_kf``): every tick it runs the front end on the readings, with the stance
flags of the plan ``inner`` follows now (``inner.plan``, if it has one: both MPC loops, ``control.inline``
and ``control.process``, do), tells ``inner`` of a sensor fault (``inner.report_sensors``, if it has one)
and hands the estimate to ``inner.compute``. It runs in the caller's thread at the control rate, in every
timing mode and in ``--realtime`` (where ``inner`` publishes the estimate to the MPC process). Readings
stamped earlier than the tick (a late sample) give an estimate of their own time, which is carried to the
tick at constant velocity before the controller sees it. The estimate of every tick is recorded in
preallocated arrays (``trace``) for the run's log and metrics.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import pinocchio as pin

from cafe_mpc.config import SensorLimits
from cafe_mpc.core.controller import Controller
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import KnotPlan
from cafe_mpc.core.sensors import ImuMounting, SensorGuard, SensorReadings
from cafe_mpc.estimation.estimator import StateEstimator

logger = logging.getLogger(__name__)

IMU_OUTAGE_END = "the end of an IMU outage"
"""Why the estimator restarts when the IMU is back after an outage that held or stopped the robot."""

LATE = 1e-6
"""s: readings older than the tick by more than this are brought forward to it."""


class SensorFrontEnd:
    """Readings -> ``SensorGuard`` -> ``StateEstimator`` -> divergence check -> ``Measurement`` (module
    docstring). ``limits``: the config's ``recovery.sensors`` (default: ``SensorLimits()``)."""

    def __init__(self, estimator: StateEstimator, limits: SensorLimits | None = None) -> None:
        robot = estimator.robot
        self.estimator = estimator
        self.limits = limits if limits is not None else SensorLimits()
        self.guard = SensorGuard(
            self.limits, robot.position_lower, robot.position_upper, robot.velocity_limits, robot.joint_names
        )
        rotation = robot.imu_rotation
        self.mounting = ImuMounting(rotation, robot.nu) if ImuMounting.needed(rotation) else None
        """The IMU's readings into the base frame, for an IMU mounted turned (None: on the base's axes)."""
        self.position_xy = np.zeros(2)
        self._last_xy = np.zeros(2)
        self.imu_outage_limit = self.limits.imu_outage_limit if estimator.imu_outage is not None else None
        """s the IMU may be out before the robot is held off its plans, when the estimator integrates the
        attitude without it (None: ``outage_limit``, as any sensor)."""
        self._imu_limit = (
            self.imu_outage_limit if self.imu_outage_limit is not None else self.limits.outage_limit
        )
        self.reset()

    def reset(self, position_xy: tuple[float, float] | np.ndarray = (0.0, 0.0)) -> None:
        """A new run: the estimator starts with the robot standing at ``position_xy`` at the next reading."""
        self.position_xy[:] = position_xy
        self._last_xy[:] = position_xy
        self.estimator.reset(self.position_xy)
        self.guard.reset()
        self.estimator_resets: list[dict] = []
        """When the estimator was restarted, and why (``t``, ``why``)."""
        self._imu_out = False

    def measure(
        self, readings: SensorReadings, plan: KnotPlan | None, plan_time: float | None = None
    ) -> Measurement:
        """The estimate of ``readings`` (checked first), with the stance of ``plan`` looked up at
        ``plan_time`` (default: the readings' time)."""
        checked = self.guard.check(readings)
        if self.mounting is not None:
            checked = self.mounting.to_base(checked)
        t = float(checked.time)
        imu_out = self.guard.imu_out_for(t) > self._imu_limit
        if self._imu_out and not imu_out:
            self._restart(t, IMU_OUTAGE_END)
        self._imu_out = imu_out
        guard = self.guard
        measurement = self.estimator.update(checked, plan, plan_time, guard.imu_out, guard.imu_sample_time)
        if not self._plausible(measurement):
            self._restart(t, "the estimate diverged")
            measurement = self.estimator.update(
                checked, plan, plan_time, guard.imu_out, guard.imu_sample_time
            )
        else:
            self._last_xy[:] = measurement.q[:2]
        return measurement

    def _restart(self, t: float, why: str) -> None:
        """Restart the estimator standing where the last plausible estimate had the robot."""
        self.estimator_resets.append({"t": round(t, 6), "why": why})
        logger.warning("t = %.3f s: the state estimator restarts standing (%s)", t, why)
        self.estimator.reset(self._last_xy, moving=True)

    def _plausible(self, measurement: Measurement) -> bool:
        velocity = self.estimator.world_velocity
        speed = math.sqrt(float(np.dot(velocity, velocity)))
        return (
            speed <= self.limits.estimate_speed_max  # NaN fails too
            and bool(np.all(np.isfinite(measurement.q)))
            and bool(np.all(np.isfinite(measurement.v)))
        )

    def fault(self, t: float) -> str | None:
        """Why the robot should be held off its plans at ``t`` (a sensor out too long, the estimator
        restarting), else None."""
        outage = self.guard.outage(t, self.imu_outage_limit)
        if outage is not None:
            return outage
        if self.estimator_resets and t - self.estimator_resets[-1]["t"] <= self.limits.outage_limit:
            last = self.estimator_resets[-1]
            return f"the state estimator restarted at t = {last['t']:.3f} s ({last['why']})"
        return None

    def modelled(self, t: float) -> bool:
        """Whether the estimate stands in for what ``fault(t)`` reports, so that the robot may stay on plans
        that stop it (``recovery.sensors.imu_outage_response: stop``): the IMU out while the estimator
        integrates the attitude from the model, or the estimator restarted at the end of such an outage; no
        encoder out too long, and no restart for a diverged estimate."""
        if self.estimator.imu_outage is None or self.limits.imu_outage_response != "stop":
            return False
        if self.guard.encoders_out(t):
            return False
        recent = self.estimator_resets and t - self.estimator_resets[-1]["t"] <= self.limits.outage_limit
        return not recent or self.estimator_resets[-1]["why"] == IMU_OUTAGE_END

    @property
    def eventful(self) -> bool:
        """Whether any sample was rejected or the estimator restarted."""
        return bool(self.guard.counts or self.guard.outages or self.estimator_resets)

    def record(self) -> dict:
        """Rejected samples by kind, the sensors' outages, the estimator's restarts."""
        return {**self.guard.summary(), "estimator_resets": [dict(reset) for reset in self.estimator_resets]}


class SensingController:
    """Sensor readings -> ``SensorFrontEnd`` (``estimator``, ``limits``) -> ``inner`` (see the module
    docstring).

    ``capacity``: ticks to preallocate for the record (it grows if a run outlasts it); ``position_xy``: the
    base's x-y where the run starts (the odometry origin, ``StateEstimator.reset``).
    """

    def __init__(
        self,
        inner: Controller,
        estimator: StateEstimator,
        capacity: int = 0,
        position_xy: tuple[float, float] = (0.0, 0.0),
        limits: SensorLimits | None = None,
    ) -> None:
        self.inner = inner
        self.front_end = SensorFrontEnd(estimator, limits)
        self.estimator = estimator
        self.position_xy = (float(position_xy[0]), float(position_xy[1]))
        robot = self.estimator.robot
        capacity = max(int(capacity), 1)
        self._q = np.zeros((capacity, robot.nq))
        self._v = np.zeros((capacity, robot.nv))
        self._contacts = np.zeros((capacity, robot.n_feet), dtype=bool)
        self._trust = np.zeros((capacity, robot.n_feet))
        self._count = 0
        self._reported: tuple[str | None, bool] = (None, False)
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
        self.front_end.reset(self.position_xy)
        self._count = 0
        self._reported = (None, False)
        self.late_ticks = 0

    def compute(self, t: float, readings: SensorReadings) -> np.ndarray:
        measurement = self.front_end.measure(readings, self.plan)
        measurement.height_map = readings.height_map  # placed at the estimated pose by the controller
        if t - measurement.time > LATE:
            self._bring_forward(measurement, t)
        self.last_measurement = measurement
        self._record(measurement)
        front_end = self.front_end
        fault = front_end.fault(t)
        reported = (fault, fault is not None and front_end.modelled(t))
        if reported != self._reported:
            report = getattr(self.inner, "report_sensors", None)
            if report is not None:
                report(t, *reported)
            self._reported = reported
        return self.inner.compute(t, measurement)

    def fault_record(self) -> dict | None:
        """The ``sensors`` part of the run's ``faults`` block (``SensorFrontEnd.record``), None when every
        sample was good."""
        return self.front_end.record() if self.front_end.eventful else None

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
