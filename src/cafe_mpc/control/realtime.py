"""Real-time CAFE-MPC: the MPC in its own process, the low-level controller at 500 Hz in the main process.

The shape of a deployment (paper Sec. VI-C and Fig. 2; OCS2's MPC/MRT split): the low-level controller
(VWBC) runs on the robot against the wall clock and never waits for the solver; the MPC runs beside it,
as fast as the period allows, always from the newest measurement. The two exchange data asynchronously
through shared memory:

* **measurement ring** (main -> MPC): time, ``q``, ``v``, contacts of the last ``RING_TICKS`` control ticks,
  one slot per tick, so the MPC can read the measurement of the tick it prepared for even after newer ones
  arrived;
* **plan channel** (MPC -> main): the newest ``Plan`` (fixed capacity), the time of the measurement it was
  solved from and its update's wall time.

Each slot and channel is a seqlock (a counter that is odd while the writer writes): readers copy and retry
or skip when the counter moved, so neither side ever blocks the other.

The MPC process runs the scheme of its settings (``MpcSettings.scheme``). Real-time iteration: after
publishing a plan it picks the next update time ``t_next`` (``control.update_clock``: one period later,
or later when its preparations take longer), prepares that update from the state the new plan
predicts there, waits for the measurement of the tick at ``t_next`` and runs only the feedback phase on it
before publishing (the latency the robot sees). One-phase: it takes the newest measurement, at most once
per period, and runs the whole update. A process (not a thread) because the solver
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
import secrets
import signal
import time
from collections.abc import Callable
from multiprocessing import shared_memory

import numpy as np

from cafe_mpc.control.commands import COMMAND_SIZE, CommandChannel, apply_command
from cafe_mpc.control.plan_follower import NewestPlanFollower
from cafe_mpc.control.update_clock import UpdateClock
from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import KnotPlan, PlanFormat
from cafe_mpc.core.progress import stage
from cafe_mpc.planners.base import MpcStatistics, Planner
from cafe_mpc.robots.robot import Robot

logger = logging.getLogger(__name__)

MpcFactory = Callable[[], Planner]
"""Builds the MPC inside the worker process (must be picklable: a module-level function or a partial)."""


class MpcProcessError(RuntimeError):
    """The MPC process died, failed to start, or stopped delivering plans."""


# ------------------------------------------------------------------------------------------ channels
def shared_block_prefix(pid: int | None = None) -> str:
    """Prefix of the shared-memory blocks a process creates (``/dev/shm/<prefix>...`` on Linux): the
    creator's pid in the name tells its blocks from other programs' (a test checks that none outlive a
    run)."""
    return f"cafe_mpc_{os.getpid() if pid is None else pid}_"


def _new_block(name: str | None, size: int) -> shared_memory.SharedMemory:
    """Attach to the block ``name``, or create a zero-filled one named ``shared_block_prefix()...``."""
    if name is not None:
        return shared_memory.SharedMemory(name=name, create=False, size=size)
    name = shared_block_prefix() + secrets.token_hex(6)
    block = shared_memory.SharedMemory(name=name, create=True, size=size)
    block.buf[:size] = bytes(size)
    return block


class _SeqLockArray:
    """A float64 array in shared memory with a seqlock counter in element 0 (payload from element 1)."""

    def __init__(self, size: int, name: str | None = None) -> None:
        self.memory = _new_block(name, 8 * (size + 1))
        self.array = np.ndarray((size + 1,), dtype=np.float64, buffer=self.memory.buf)
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


COMMAND_OFFSET = 3
"""The control block: [sequence, stop flag, ready flag], then the runtime command channel
(``control.commands``: its own seqlock counter and ``COMMAND_SIZE`` values)."""
CONTROL_SIZE = COMMAND_OFFSET - 1 + 1 + COMMAND_SIZE
"""Payload floats of the control block (after its own seqlock counter)."""

RING_TICKS = 256
"""Control ticks the measurement ring keeps (0.5 s at 500 Hz)."""


class MeasurementRing:
    """The last ``RING_TICKS`` measurements in shared memory, one seqlock slot per control tick.

    Element 0 holds the newest tick index written (-1 before the first); slot ``i`` (from element 1) holds
    ``[sequence, tick, t, q, v, contacts]`` of a tick ``k`` with ``k % RING_TICKS == i``.
    """

    def __init__(self, nq: int, nv: int, n_feet: int, name: str | None = None) -> None:
        self.nq, self.nv, self.n_feet = nq, nv, n_feet
        self.slot = 3 + nq + nv + n_feet
        size = 8 * (1 + RING_TICKS * self.slot)
        self.memory = _new_block(name, size)
        self.array = np.ndarray((1 + RING_TICKS * self.slot,), dtype=np.float64, buffer=self.memory.buf)
        if name is None:
            self.array[0] = -1.0
        self.slots = self.array[1:].reshape(RING_TICKS, self.slot)

    @property
    def name(self) -> str:
        return self.memory.name

    @property
    def newest(self) -> int:
        """Index of the newest tick written (-1 before the first)."""
        return int(self.array[0])

    def write(self, tick: int, t: float, q: np.ndarray, v: np.ndarray, contacts: np.ndarray) -> None:
        slot = self.slots[tick % RING_TICKS]
        nq, nv = self.nq, self.nv
        slot[0] += 1.0  # odd: writing
        slot[1] = tick
        slot[2] = t
        slot[3 : 3 + nq] = q
        slot[3 + nq : 3 + nq + nv] = v
        slot[3 + nq + nv :] = contacts
        slot[0] += 1.0  # even: consistent
        self.array[0] = tick

    def read(self, tick: int, out: np.ndarray) -> bool:
        """Copy ``[t, q, v, contacts]`` of ``tick`` into ``out``; ``False`` if that tick is not (or no longer)
        in the ring or was being written."""
        slot = self.slots[tick % RING_TICKS]
        before = float(slot[0])
        if int(before) % 2 or int(slot[1]) != tick:
            return False
        np.copyto(out, slot[2:])
        return float(slot[0]) == before and int(slot[1]) == tick

    def close(self, unlink: bool) -> None:
        self.slots = None  # type: ignore[assignment]
        self.array = None  # type: ignore[assignment]
        with contextlib.suppress(Exception):
            self.memory.close()
        if unlink:
            with contextlib.suppress(FileNotFoundError):
                self.memory.unlink()


class PlanLayout:
    """Offsets of a plan of at most ``plan_format.capacity`` knots in a flat float64 buffer: a header, then
    each array field of the plan type at its shape for that many knots (``core.plan.PlanFormat``)."""

    HEADER = 6  # n_knots, measurement time, update wall time, iterations, solves, failures

    def __init__(self, plan_format: PlanFormat) -> None:
        self.format = plan_format
        self.capacity = plan_format.capacity
        self.fields: dict[str, tuple[int, tuple[int, ...]]] = {}
        offset = self.HEADER
        for name, shape in plan_format.shapes(self.capacity).items():
            self.fields[name] = (offset, shape)
            offset += int(np.prod(shape))
        self.size = offset

    def views(self, buffer: np.ndarray, knots: int) -> dict[str, np.ndarray]:
        """Each field of a plan of ``knots`` knots inside ``buffer`` (views of its first rows)."""
        views = {}
        for name, rows in self._rows(knots).items():
            offset, shape = self.fields[name]
            views[name] = buffer[offset : offset + int(np.prod(shape))].reshape(shape)[:rows]
        return views

    def _rows(self, knots: int) -> dict[str, int]:
        return {name: shape[0] for name, shape in self.format.shapes(knots).items()}

    def write(self, buffer: np.ndarray, plan: KnotPlan, measured_at: float, stats: tuple[float, ...]) -> None:
        n = len(plan.times)
        if n > self.capacity:
            raise ValueError(f"plan has {n} knots, the channel holds {self.capacity}")
        buffer[0] = n
        buffer[1] = measured_at
        buffer[2 : self.HEADER] = stats
        for name, view in self.views(buffer, n).items():
            view[...] = getattr(plan, name)

    def read(self, buffer: np.ndarray) -> tuple[KnotPlan, float, float]:
        """A plan copied out of ``buffer``, its measurement time and its update's wall time."""
        n = int(buffer[0])
        dtypes = self.format.dtypes
        fields = {
            name: (view > 0.5 if dtypes.get(name) is bool else view.copy())
            for name, view in self.views(buffer, n).items()
        }
        return self.format.make(**fields), float(buffer[1]), float(buffer[2])


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
    dimensions: tuple[int, int, int],
    plan_name: str,
    layout: PlanLayout,
    control_name: str,
    control_period: float,
    period: float,
    parent_pid: int,
    results,
) -> None:
    """The MPC process: measurements -> updates -> plans (module docstring), until told to stop."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the main process owns Ctrl-C and stops us
    _pin_to_cpu(-1)  # the last CPU; the 500 Hz loop keeps the first (see RealtimeMpcController)
    nq, nv, n_feet = dimensions
    ring = MeasurementRing(nq, nv, n_feet, measurement_name)
    plan_channel = _SeqLockArray(layout.size, plan_name)
    control = _SeqLockArray(CONTROL_SIZE, control_name)  # [stop flag, ready flag, command channel]
    statistics = None
    worker = None
    try:
        mpc = factory()
        control.array[2] = 1.0  # ready (built; numba kernels loaded)
        worker = _Worker(mpc, ring, plan_channel, layout, control, control_period, period, parent_pid)
        worker.commands = CommandChannel(control.array[COMMAND_OFFSET:])
        worker.run()
        statistics = mpc.statistics
    except BaseException as error:  # report, then exit: the main process turns it into MpcProcessError
        results.send(("error", f"{type(error).__name__}: {error}"))
        raise
    finally:
        if statistics is not None:
            with contextlib.suppress(Exception):
                results.send(("statistics", statistics))
        ring.close(unlink=False)
        if worker is not None:
            worker.commands = None  # drop its view of the control block before closing it
        for channel in (plan_channel, control):
            channel.close(unlink=False)


class _Worker:
    """The loop of the MPC process (``_worker_main``): one-phase or real-time-iteration updates."""

    def __init__(
        self,
        mpc: Planner,
        ring: MeasurementRing,
        plan_channel: _SeqLockArray,
        layout: PlanLayout,
        control: _SeqLockArray,
        control_period: float,
        period: float,
        parent_pid: int,
    ) -> None:
        self.mpc, self.ring, self.plan_channel, self.layout = mpc, ring, plan_channel, layout
        self.control = control
        self.control_period = control_period
        self.period = period
        self.parent_pid = parent_pid
        self.buffer = np.zeros(ring.slot - 2)
        self.nq, self.nv = ring.nq, ring.nv
        self.clock = UpdateClock(period, control_period)
        self.commands: CommandChannel | None = None
        """Runtime commands from the main process (``RealtimeMpcController.commands``)."""

    def running(self) -> bool:
        """Until the stop flag is set or the main process is gone (do not outlive it)."""
        return self.control.array[1] == 0.0 and os.getppid() == self.parent_pid

    def run(self) -> None:
        mpc = self.mpc
        rti = mpc.settings.scheme == "rti" and mpc.supports_rti
        last_tick = -1
        while self.running():
            newest = self.ring.newest
            if newest < 0 or newest == last_tick:
                time.sleep(0.0002)
                continue
            if not mpc.started:  # the cold solve, on the first measurement
                if self.ring.read(newest, self.buffer):
                    last_tick = newest
                    self._publish(self._state_update(newest), newest)
                continue
            last_tick = self._rti_update(last_tick) if rti else self._one_phase_update(last_tick, newest)

    def _take_command(self, t: float) -> None:
        """Apply a runtime command posted since the last update, from ``t`` on."""
        command = self.commands.take() if self.commands is not None else None
        if command is not None:
            apply_command(self.mpc.reference, t, command)

    def _state_update(self, tick: int) -> KnotPlan | None:
        """A one-phase update from the measurement of ``tick`` (in ``buffer``)."""
        nq, nv = self.nq, self.nv
        self._take_command(float(self.buffer[0]))
        return self.mpc.update(
            float(self.buffer[0]), self.buffer[1 : 1 + nq], self.buffer[1 + nq : 1 + nq + nv]
        )

    def _one_phase_update(self, last_tick: int, newest: int) -> int:
        """The newest measurement, at most once per period."""
        ticks_per_period = max(round(self.period / self.control_period), 1)
        if newest < last_tick + ticks_per_period:
            time.sleep(0.0002)
            return last_tick
        if not self.ring.read(newest, self.buffer):
            return last_tick
        self._publish(self._state_update(newest), newest)
        return newest

    def _rti_update(self, last_tick: int) -> int:
        """Prepare the update at the next tick ``t_next``, wait for its measurement, feed it back."""
        mpc, control_period = self.mpc, self.control_period
        newest = self.ring.newest
        following = self.clock.next_update(last_tick * control_period, newest * control_period)
        tick = max(round(following / control_period), last_tick + 1)
        t_next = tick * control_period
        self._take_command(t_next)
        predicted = mpc.predict(t_next)
        prepared = False
        if predicted is not None:
            prepared = mpc.prepare(t_next, predicted[: self.nq], predicted[self.nq :])
            if prepared:
                self.clock.record_preparation(mpc.statistics.prepare_times[-1])
        while self.ring.newest < tick:
            if not self.running():
                return last_tick
            time.sleep(0.0001)
        nq, nv = self.nq, self.nv
        if not self.ring.read(tick, self.buffer):  # overwritten (the prepare outlasted the ring): newest
            tick = self.ring.newest
            if not self.ring.read(tick, self.buffer):
                return last_tick
            prepared = False
        t = float(self.buffer[0])
        q, v = self.buffer[1 : 1 + nq], self.buffer[1 + nq : 1 + nq + nv]
        plan = mpc.feedback(t, q, v) if prepared else mpc.update(t, q, v)
        self._publish(plan, tick)
        return tick

    def _publish(self, plan: KnotPlan | None, tick: int) -> None:
        if plan is None:
            return
        stats = self.mpc.statistics
        channel = self.plan_channel
        channel.begin_write()
        self.layout.write(
            channel.payload,
            plan,
            tick * self.control_period,
            (stats.update_times[-1], stats.iterations[-1], stats.solves, stats.failures),
        )
        channel.end_write()


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
        plan_format: PlanFormat,
        startup_timeout: float = 120.0,
        stall_timeout: float | None = None,
        control_period: float = 0.002,
        scheme: str = "rti",
    ) -> None:
        self.robot = robot
        self.low_level = low_level
        self.follower = NewestPlanFollower(robot, low_level)
        self.period = period
        self.startup_timeout = startup_timeout
        self.stall_timeout = stall_timeout if stall_timeout is not None else max(0.5, 10 * period)
        if not control_period > 0:
            raise ValueError(f"control period must be positive, got {control_period}")
        self.control_period = float(control_period)
        self.scheme = scheme
        """The MPC process's scheme (``MpcSettings.scheme``), for the run's records."""
        nq, nv, n_feet = robot.nq, robot.nv, robot.n_feet
        self.layout = PlanLayout(plan_format)
        self._measurement = MeasurementRing(nq, nv, n_feet)
        self._plan_channel = _SeqLockArray(self.layout.size)
        self._control = _SeqLockArray(CONTROL_SIZE)
        self.commands = CommandChannel(self._control.array[COMMAND_OFFSET:])
        """Runtime commands for the MPC process (``control.commands``), taken at its next update."""
        self._plan_buffer = np.zeros(self.layout.size)
        self._plan_sequence = 0.0
        self.plan: KnotPlan | None = None
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
                (nq, nv, n_feet),
                self._plan_channel.name,
                self.layout,
                self._control.name,
                self.control_period,
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
        stage("first (cold) MPC solve, in the MPC process")
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
        self.commands = CommandChannel()  # a detached channel: the shared view is released before closing
        for channel in (self._measurement, self._plan_channel, self._control):
            channel.close(unlink=True)

    # ------------------------------------------------------------------------------------ control tick
    def reset(self) -> None:
        self.follower.reset()

    def publish(self, t: float, measurement: Measurement) -> None:
        """Write the measurement of the tick at ``t`` into the ring for the MPC process (never blocks)."""
        tick = round(t / self.control_period)
        self._measurement.write(tick, t, measurement.q, measurement.v, measurement.contacts)

    def compute(self, t: float, measurement: Measurement) -> np.ndarray:
        self.publish(t, measurement)
        self._poll_plan(t, record=True)
        plan = self.plan
        if plan is not None and t - self._last_plan_time > self.stall_timeout and self.failure is None:
            self._check_alive()
            if self.failure is None:
                self.failure = f"the MPC process delivered no plan for {t - self._last_plan_time:.2f} s"
        if plan is not None and t >= plan.end_time and self.failure is None:
            self._check_alive()
        before = self.follower.fallback_ticks
        torques = self.follower.compute(t, measurement, plan)
        self.statistics.fallback_ticks += self.follower.fallback_ticks - before
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
