"""Faults injected into a run (the config's ``plant.faults``; docs/faults.md), so that tests and experiments
can see what the controller does about them.

* ``FaultySensors`` wraps the robot's sensors (``sim.sensors.SensorSuite``): an IMU that stops sampling
  (``imu_dropout``: the driver repeats the last sample, with its old time stamp), a joint encoder that does
  (``encoder_freeze``), one bad sample of a sensor every ``period`` s (``nan_sample``: NaN;
  ``out_of_range``: ``value``). The controller's sensing front end (``estimation.controller``) has to notice.
* ``ProcessFaults`` signals the MPC process of a real-time run (``control.process``): ``mpc_kill`` (SIGKILL at
  ``start``), ``mpc_stall`` (SIGSTOP at ``start``, SIGCONT ``duration`` s later). It is called at the start of
  every control tick (``SimulationOptions.before_tick``); ``close`` continues a process it left stopped.
* ``PlanPause`` withholds the plans of the MPC in simulated time (``mpc_pause``: none from ``start`` for
  ``duration`` s, then a cold solve; ``control.inline.InlineMpcLoop.withhold_plans``): a stall or a restart
  of the planner, deterministic with a fixed latency, so that a take-back can be tested.

Both keep what they did (``applied``) for the run's ``faults`` block.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import signal
from collections.abc import Callable, Sequence

import numpy as np

from cafe_mpc.config import INLINE_MPC_FAULTS, MPC_FAULTS, SENSOR_FAULTS, FaultConfig
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.sensors import SensorReadings
from cafe_mpc_lab.sim.plant import Plant, PlantSensors

logger = logging.getLogger(__name__)

OUT_OF_RANGE_DEFAULT = 1e3
"""What an ``out_of_range`` sample reads unless the fault says (far outside every sensor's range)."""


def joint_index(joint: int | str | None, joint_names: Sequence[str]) -> int | None:
    """The index of ``joint`` (an index or a name; None stays None); ``ValueError`` naming the joints."""
    if joint is None:
        return None
    if isinstance(joint, int):
        if joint >= len(joint_names):
            raise ValueError(f"joint index {joint} is out of range: the robot has {len(joint_names)} joints")
        return joint
    if joint not in joint_names:
        raise ValueError(f"unknown joint {joint!r}; joints: {', '.join(joint_names)}")
    return joint_names.index(joint)


class FaultySensors:
    """The robot's sensors with ``plant.faults``' sensor faults (module docstring); a ``PlantSensors``."""

    def __init__(
        self, inner: PlantSensors, faults: Sequence[FaultConfig], joint_names: Sequence[str]
    ) -> None:
        self.inner = inner
        self.faults = [fault for fault in faults if fault.kind in SENSOR_FAULTS]
        self.joints = [joint_index(fault.joint, joint_names) for fault in self.faults]
        n_joints = len(joint_names)
        self._imu = SensorReadings.zeros(n_joints)  # the last reading before a dropout: what is repeated
        self._encoders = SensorReadings.zeros(n_joints)
        self.reset()

    def reset(self) -> None:
        self.inner.reset()
        self._next_bad = [
            fault.start + fault.period if fault.period is not None else math.inf for fault in self.faults
        ]
        self._imu_frozen = False
        self._frozen = np.zeros(len(self._encoders.joint_positions), dtype=bool)
        self.applied: list[dict] = []
        self._counts = [0] * len(self.faults)

    def measure(self, tick: int, plant: Plant, state: Measurement) -> SensorReadings:
        readings = self.inner.measure(tick, plant, state)
        t = readings.time
        imu_out = False
        frozen = np.zeros_like(self._frozen)
        for index, fault in enumerate(self.faults):
            if not fault.start <= t < fault.end:
                continue
            joint = self.joints[index]
            if fault.kind == "imu_dropout":
                imu_out = True
            elif fault.kind == "encoder_freeze":
                frozen[joint] = True
            elif t + 1e-9 >= self._next_bad[index]:
                self._next_bad[index] += fault.period
                value = math.nan if fault.kind == "nan_sample" else (fault.value or OUT_OF_RANGE_DEFAULT)
                self._bad_sample(readings, fault.sensor, joint, value)
                self._counts[index] += 1
        self._dropout(readings, imu_out)
        self._freeze(readings, frozen)
        return readings

    def _dropout(self, readings: SensorReadings, out: bool) -> None:
        """While the IMU is out, repeat its last sample (and time stamp); else remember this one."""
        held = self._imu
        if out:
            if not self._imu_frozen:
                self._imu_frozen = True
                self.applied.append({"kind": "imu_dropout", "t": round(float(readings.time), 6)})
            np.copyto(readings.orientation, held.orientation)
            np.copyto(readings.gyro, held.gyro)
            np.copyto(readings.accelerometer, held.accelerometer)
            readings.imu_time = held.time
        else:
            self._imu_frozen = False
            held.time = readings.time
            np.copyto(held.orientation, readings.orientation)
            np.copyto(held.gyro, readings.gyro)
            np.copyto(held.accelerometer, readings.accelerometer)

    def _freeze(self, readings: SensorReadings, frozen: np.ndarray) -> None:
        """Frozen encoders repeat their last sample (and time stamp); the others are remembered."""
        held = self._encoders
        for joint in np.flatnonzero(frozen & ~self._frozen):
            self.applied.append(
                {"kind": "encoder_freeze", "t": round(float(readings.time), 6), "joint": int(joint)}
            )
        self._frozen[:] = frozen
        live = ~frozen
        np.copyto(held.joint_positions, readings.joint_positions, where=live)
        np.copyto(held.joint_velocities, readings.joint_velocities, where=live)
        np.copyto(held.joint_times, readings.time, where=live)
        if frozen.any():
            np.copyto(readings.joint_positions, held.joint_positions, where=frozen)
            np.copyto(readings.joint_velocities, held.joint_velocities, where=frozen)
            np.copyto(readings.joint_times, held.joint_times, where=frozen)

    @staticmethod
    def _bad_sample(readings: SensorReadings, sensor: str, joint: int | None, value: float) -> None:
        if sensor in ("orientation", "gyro", "accelerometer"):
            getattr(readings, sensor)[:] = value
            return
        target = readings.joint_positions if sensor == "joint_position" else readings.joint_velocities
        if joint is None:
            target[:] = value
        else:
            target[joint] = value

    def log_extra(self) -> dict:
        extra = dict(self.inner.log_extra())
        applied = list(self.applied)
        for fault, count in zip(self.faults, self._counts, strict=True):
            if count:
                applied.append({"kind": fault.kind, "sensor": fault.sensor, "samples": count})
        extra["faults_applied"] = applied
        return extra


class ProcessFaults:
    """Signals the MPC process at the times of ``plant.faults``' MPC faults (module docstring). ``pid_of``
    returns the pid of the MPC process now (None when there is none)."""

    def __init__(self, faults: Sequence[FaultConfig], pid_of: Callable[[], int | None]) -> None:
        self.faults = [fault for fault in faults if fault.kind in MPC_FAULTS]
        self.pid_of = pid_of
        self._done = [False] * len(self.faults)
        self._stopped: dict[int, int] = {}  # fault index -> pid it stopped
        self.applied: list[dict] = []

    def __call__(self, t: float) -> None:
        for index, fault in enumerate(self.faults):
            if self._done[index] or t + 1e-9 < fault.start:
                continue
            if index in self._stopped:
                if t + 1e-9 >= fault.end:
                    self._signal(self._stopped.pop(index), signal.SIGCONT, "mpc_continue", t)
                    self._done[index] = True
                continue
            pid = self.pid_of()
            if pid is None:
                continue  # no MPC process now (being restarted): the fault waits for one
            if fault.kind == "mpc_kill":
                self._signal(pid, signal.SIGKILL, "mpc_kill", t)
                self._done[index] = True
            else:
                self._signal(pid, signal.SIGSTOP, "mpc_stall", t)
                self._stopped[index] = pid

    def _signal(self, pid: int, number: int, kind: str, t: float) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, number)
        self.applied.append({"kind": kind, "t": round(float(t), 6), "pid": pid})
        logger.warning("t = %.3f s: injected fault %s (pid %d)", t, kind, pid)

    def close(self) -> None:
        """Continue any process still stopped (the run ended inside a stall)."""
        for pid in self._stopped.values():
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGCONT)
        self._stopped.clear()


class PlanPause:
    """Withholds the plans of an MPC loop in simulated time at the times of ``plant.faults``' ``mpc_pause``
    faults (module docstring): each is handed to ``withhold(start, end)`` when its start comes (called at
    the start of every control tick, ``SimulationOptions.before_tick``)."""

    def __init__(self, faults: Sequence[FaultConfig], withhold: Callable[[float, float], None]) -> None:
        self.faults = [fault for fault in faults if fault.kind in INLINE_MPC_FAULTS]
        self.withhold = withhold
        self._done = [False] * len(self.faults)
        self.applied: list[dict] = []

    def __call__(self, t: float) -> None:
        for index, fault in enumerate(self.faults):
            if self._done[index] or t + 1e-9 < fault.start:
                continue
            self._done[index] = True
            self.withhold(t, t + (fault.end - fault.start))
            self.applied.append({"kind": fault.kind, "t": round(float(t), 6), "until": round(fault.end, 6)})
            logger.warning("t = %.3f s: injected fault %s: no plan until %.3f s", t, fault.kind, fault.end)

    def close(self) -> None:
        """Nothing to undo (the interval ends by itself)."""
