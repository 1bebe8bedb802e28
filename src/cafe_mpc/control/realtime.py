"""Real-time CAFE-MPC: the MPC in its own process, the low-level controller at 500 Hz in the main process.

The shape of a deployment (paper Sec. VI-C and Fig. 2; OCS2's MPC/MRT split): the low-level controller
(VWBC) runs on the robot against the wall clock and never waits for the solver; the MPC runs beside it,
as fast as the period allows, always from the newest measurement. The two exchange data asynchronously
through shared memory:

* **measurement channel** (main -> MPC): time, ``q``, ``v``, contacts, written every control tick;
* **plan channel** (MPC -> main): the newest ``Plan`` (fixed capacity), the time of the measurement it was
  solved from and its update's wall time.

Each channel is a seqlock (a counter that is odd while the writer writes): readers copy and retry or skip
when the counter moved, so neither side ever blocks the other. A process (not a thread) because the solver
would otherwise hold Python's global interpreter lock against the 500 Hz loop.

``RealtimeMpcController`` is the main-process side (the simulation's ``Controller``): it publishes each
measurement, takes the newest plan as soon as it appears, runs the low-level controller on it, and falls
back to a damped PD stance when there is no plan or the plan's horizon has run out. If the MPC process dies
or stops delivering plans, the run keeps the last plan while it lasts, then holds the stance, and the run
ends with ``MpcProcessError``. ``close()`` (also on errors and Ctrl-C, via ``with``) stops the process and
frees the shared memory; no process is left behind.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import signal
import time
from collections.abc import Callable
from multiprocessing import shared_memory

import numpy as np

from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import Plan
from cafe_mpc.mpc.receding_horizon import MpcStatistics, RecedingHorizonMpc
from cafe_mpc.robots.robot import Robot
from cafe_mpc.wbc.pd import PDController

logger = logging.getLogger(__name__)

MpcFactory = Callable[[], RecedingHorizonMpc]
"""Builds the MPC inside the worker process (must be picklable: a module-level function or a partial)."""


class MpcProcessError(RuntimeError):
    """The MPC process died, failed to start, or stopped delivering plans."""


# ------------------------------------------------------------------------------------------ channels
class _SeqLockArray:
    """A float64 array in shared memory with a seqlock counter in element 0 (payload from element 1)."""

    def __init__(self, size: int, name: str | None = None) -> None:
        create = name is None
        self.memory = shared_memory.SharedMemory(name=name, create=create, size=8 * (size + 1))
        self.array = np.ndarray((size + 1,), dtype=np.float64, buffer=self.memory.buf)
        if create:
            self.array[:] = 0.0
        self.payload = self.array[1:]

    @property
    def name(self) -> str:
        return self.memory.name

    @property
    def sequence(self) -> float:
        return float(self.array[0])

    def begin_write(self) -> None:
        self.array[0] += 1.0  # odd: writing

    def end_write(self) -> None:
        self.array[0] += 1.0  # even: consistent

    def read_into(self, out: np.ndarray) -> float | None:
        """Copy the payload into ``out`` if consistent: its sequence number, or ``None`` (retry later)."""
        before = float(self.array[0])
        if int(before) % 2:
            return None
        np.copyto(out, self.payload[: len(out)])
        if float(self.array[0]) != before:
            return None
        return before

    def close(self, unlink: bool) -> None:
        self.payload = None  # type: ignore[assignment]
        self.array = None  # type: ignore[assignment]
        with contextlib.suppress(Exception):
            self.memory.close()
        if unlink:
            with contextlib.suppress(FileNotFoundError):
                self.memory.unlink()


class PlanLayout:
    """Offsets of a plan of at most ``capacity`` whole-body knots in a flat float64 buffer."""

    HEADER = 6  # n_knots, measurement time, update wall time, iterations, solves, failures

    def __init__(self, capacity: int, nx: int, nu: int, ndx: int, n_feet: int) -> None:
        self.capacity, self.nx, self.nu, self.ndx, self.n_feet = capacity, nx, nu, ndx, n_feet
        n = capacity
        shapes = {
            "times": (n,),
            "dt": (n,),
            "xs": (n + 1, nx),
            "us": (n, nu),
            "K": (n, nu, ndx),
            "Qu": (n, nu),
            "Quu": (n, nu, nu),
            "Qux": (n, nu, ndx),
            "contacts": (n, n_feet),
            "forces": (n, n_feet, 3),
        }
        self.fields: dict[str, tuple[int, tuple[int, ...]]] = {}
        offset = self.HEADER
        for name, shape in shapes.items():
            self.fields[name] = (offset, shape)
            offset += int(np.prod(shape))
        self.size = offset

    def view(self, buffer: np.ndarray, name: str, knots: int) -> np.ndarray:
        """The first ``knots`` rows of field ``name`` inside ``buffer`` (a view)."""
        offset, shape = self.fields[name]
        full = buffer[offset : offset + int(np.prod(shape))].reshape(shape)
        return full[: knots + 1] if name == "xs" else full[:knots]

    def write(self, buffer: np.ndarray, plan: Plan, measured_at: float, stats: tuple[float, ...]) -> None:
        n = len(plan.times)
        if n > self.capacity:
            raise ValueError(f"plan has {n} knots, the channel holds {self.capacity}")
        buffer[0] = n
        buffer[1] = measured_at
        buffer[2 : self.HEADER] = stats
        for name in ("times", "dt", "xs", "us", "K", "Qu", "Quu", "Qux", "forces"):
            self.view(buffer, name, n)[...] = getattr(plan, name)
        self.view(buffer, "contacts", n)[...] = plan.contacts

    def read(self, buffer: np.ndarray) -> tuple[Plan, float, float]:
        """A ``Plan`` copied out of ``buffer``, its measurement time and its update's wall time."""
        n = int(buffer[0])
        fields = {name: self.view(buffer, name, n).copy() for name in self.fields}
        fields["contacts"] = fields["contacts"] > 0.5
        return Plan(**fields), float(buffer[1]), float(buffer[2])


def _pin_to_cpu(index: int) -> None:
    """Pin this process to one of the CPUs it may use (``index`` into them), when there are at least two: the
    500 Hz loop and the MPC then do not migrate between cores or share one. No-op where unsupported."""
    with contextlib.suppress(AttributeError, OSError):
        cpus = sorted(os.sched_getaffinity(0))
        if len(cpus) >= 2:
            os.sched_setaffinity(0, {cpus[index]})


# ------------------------------------------------------------------------------------- worker process
def _worker_main(
    factory: MpcFactory,
    measurement_name: str,
    measurement_size: int,
    plan_name: str,
    layout: PlanLayout,
    control_name: str,
    nq: int,
    nv: int,
    period: float,
    parent_pid: int,
    results,
) -> None:
    """The MPC process: newest measurement -> update -> plan, at most once per period, until told to stop."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the main process owns Ctrl-C and stops us
    _pin_to_cpu(-1)  # the last CPU; the 500 Hz loop keeps the first (see RealtimeMpcController)
    measurement = _SeqLockArray(measurement_size, measurement_name)
    plan_channel = _SeqLockArray(layout.size, plan_name)
    control = _SeqLockArray(2, control_name)  # [stop flag, ready flag]
    statistics = None
    try:
        mpc = factory()
        control.array[2] = 1.0  # ready (built; numba kernels loaded)
        buffer = np.zeros(measurement_size)
        last_sequence = -1.0
        last_start = -np.inf
        while control.array[1] == 0.0:
            if os.getppid() != parent_pid:
                break  # the main process is gone: do not outlive it
            sequence = measurement.read_into(buffer)
            wait = last_start + period - time.perf_counter()
            fresh = sequence is not None and sequence > 0.0 and sequence != last_sequence  # 0: never written
            if not fresh or wait > 0.0:
                time.sleep(min(max(wait, 0.0), 0.0005) if wait > 0.0 else 0.0002)
                continue
            last_sequence = sequence
            last_start = time.perf_counter()
            t = float(buffer[0])
            plan = mpc.update(t, buffer[1 : 1 + nq], buffer[1 + nq : 1 + nq + nv])
            if plan is None:
                continue
            stats = mpc.statistics
            plan_channel.begin_write()
            layout.write(
                plan_channel.payload,
                plan,
                t,
                (stats.update_times[-1], stats.iterations[-1], stats.solves, stats.failures),
            )
            plan_channel.end_write()
        statistics = mpc.statistics
    except BaseException as error:  # report, then exit: the main process turns it into MpcProcessError
        results.send(("error", f"{type(error).__name__}: {error}"))
        raise
    finally:
        if statistics is not None:
            with contextlib.suppress(Exception):
                results.send(("statistics", statistics))
        for channel in (measurement, plan_channel, control):
            channel.close(unlink=False)


# ------------------------------------------------------------------------------------ policy side
class RealtimeMpcController:
    """The main-process side of real-time CAFE-MPC (see the module docstring).

    Use as a context manager (or call ``close()``): it owns a process and shared memory.
    """

    def __init__(
        self,
        robot: Robot,
        factory: MpcFactory,
        low_level: LowLevelController,
        period: float,
        plan_capacity: int,
        startup_timeout: float = 120.0,
        stall_timeout: float | None = None,
    ) -> None:
        self.robot = robot
        self.low_level = low_level
        self.fallback = PDController(robot)
        self.period = period
        self.startup_timeout = startup_timeout
        self.stall_timeout = stall_timeout if stall_timeout is not None else max(0.5, 10 * period)
        nq, nv, nu, n_feet = robot.nq, robot.nv, robot.nu, robot.n_feet
        self.layout = PlanLayout(plan_capacity, nq + nv, nu, 2 * nv, n_feet)
        self._measurement_size = 1 + nq + nv + n_feet
        self._measurement = _SeqLockArray(self._measurement_size)
        self._plan_channel = _SeqLockArray(self.layout.size)
        self._control = _SeqLockArray(2)
        self._plan_buffer = np.zeros(self.layout.size)
        self._outgoing = np.zeros(self._measurement_size)
        self._plan_sequence = 0.0
        self.plan: Plan | None = None
        self.statistics = MpcStatistics()
        self.worker_statistics: MpcStatistics | None = None
        self.worker_error: str | None = None
        self.failure: str | None = None
        """Why the run must end (the MPC process died or stalled), ``None`` while all is well."""
        self._last_plan_time = 0.0
        self._failure_time: float | None = None
        self.reference = None
        """The reference the run tracks, if the caller sets it (reports only; the MPC process has its own)."""
        context = multiprocessing.get_context("spawn")
        self._results, child_end = context.Pipe(duplex=False)
        self.process = context.Process(
            target=_worker_main,
            args=(
                factory,
                self._measurement.name,
                self._measurement_size,
                self._plan_channel.name,
                self.layout,
                self._control.name,
                nq,
                nv,
                period,
                os.getpid(),
                child_end,
            ),
            name="cafe-mpc-solver",
            daemon=True,
        )
        self.process.start()
        child_end.close()
        self._affinity = None
        with contextlib.suppress(AttributeError, OSError):
            self._affinity = os.sched_getaffinity(0)
        _pin_to_cpu(0)
        self._closed = False

    # ------------------------------------------------------------------------------------- lifecycle
    def __enter__(self) -> RealtimeMpcController:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def wait_ready(self, measurement: Measurement) -> None:
        """Start the MPC on the first measurement and wait for its first plan (the cold solve runs before the
        clock starts, while the robot stands, as on hardware)."""
        deadline = time.perf_counter() + self.startup_timeout
        self.publish(0.0, measurement)
        while self.plan is None:
            self._poll_plan(0.0, record=False)
            if self.plan is not None:
                break
            self._check_alive()
            if self.failure is not None:
                raise MpcProcessError(self.failure)
            if time.perf_counter() > deadline:
                raise MpcProcessError(f"the MPC process sent no plan within {self.startup_timeout:.0f} s")
            time.sleep(0.002)
        self._last_plan_time = 0.0

    def close(self) -> None:
        """Stop the MPC process (politely, then by force) and free the shared memory. Idempotent."""
        if self._closed:
            return
        self._closed = True
        with contextlib.suppress(Exception):
            self._control.array[1] = 1.0  # stop flag
        # Read what the worker sends while it exits (its statistics can exceed the pipe's buffer: joining
        # first would deadlock), then make sure it is gone.
        deadline = time.perf_counter() + 5.0
        while time.perf_counter() < deadline:
            if self._results.poll(0.02):
                if not self._receive():
                    break  # the worker closed its end
            elif not self.process.is_alive():
                break
        self.process.join(timeout=1.0)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(timeout=2.0)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(timeout=2.0)
        self._results.close()
        if self._affinity is not None:
            with contextlib.suppress(OSError):
                os.sched_setaffinity(0, self._affinity)
        for channel in (self._measurement, self._plan_channel, self._control):
            channel.close(unlink=True)

    # ------------------------------------------------------------------------------------ control tick
    def reset(self) -> None:
        self.fallback.reset()
        self.low_level.reset()

    def publish(self, t: float, measurement: Measurement) -> None:
        """Write the newest measurement for the MPC process (never blocks)."""
        nq, nv = self.robot.nq, self.robot.nv
        out = self._outgoing
        out[0] = t
        out[1 : 1 + nq] = measurement.q
        out[1 + nq : 1 + nq + nv] = measurement.v
        out[1 + nq + nv :] = measurement.contacts
        channel = self._measurement
        channel.begin_write()
        channel.payload[:] = out
        channel.end_write()

    def compute(self, t: float, measurement: Measurement) -> np.ndarray:
        self.publish(t, measurement)
        self._poll_plan(t, record=True)
        plan = self.plan
        if plan is not None and t - self._last_plan_time > self.stall_timeout and self.failure is None:
            self._check_alive()
            if self.failure is None:
                self.failure = f"the MPC process delivered no plan for {t - self._last_plan_time:.2f} s"
        if plan is None or t >= plan.end_time:
            if plan is not None and self.failure is None:
                self._check_alive()
            self.statistics.fallback_ticks += 1
            return self.fallback.compute(t, measurement, None)
        torques = self.low_level.compute(t, measurement, plan)
        if not np.all(np.isfinite(torques)):
            self.statistics.fallback_ticks += 1
            return self.fallback.compute(t, measurement, None)
        return torques

    def should_stop(self, t: float) -> bool:
        """End the run 0.5 s after a failure (the damped stance holds the robot meanwhile)."""
        if self.failure is None:
            return False
        if self._failure_time is None:
            self._failure_time = t
        return t - self._failure_time > 0.5

    def _poll_plan(self, t: float, record: bool) -> None:
        channel = self._plan_channel
        if channel.sequence == self._plan_sequence:
            return
        sequence = channel.read_into(self._plan_buffer)
        if sequence is None or sequence == self._plan_sequence:
            return
        self._plan_sequence = sequence
        plan, measured_at, wall = self.layout.read(self._plan_buffer)
        self.plan = plan
        self._last_plan_time = t
        if record:
            self.statistics.latencies.append(t - measured_at)
            self.statistics.start_times.append(measured_at)
            self.statistics.update_times.append(wall)

    def _receive(self) -> bool:
        """Take one message from the worker; ``False`` once its end of the pipe is closed."""
        try:
            kind, payload = self._results.recv()
        except (EOFError, OSError):
            return False
        if kind == "statistics":
            self.worker_statistics = payload
        elif kind == "error":
            self.worker_error = payload
        return True

    def _check_alive(self) -> None:
        if not self.process.is_alive() and self.failure is None:
            detail = ""
            if self._results.poll(0):
                self._receive()
            if self.worker_error:
                detail = f": {self.worker_error}"
            self.failure = f"the MPC process exited (code {self.process.exitcode}){detail}"
