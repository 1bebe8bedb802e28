"""The channels between the control loop and the MPC process (``control.process``), in shared memory.

* ``MeasurementRing`` (loop -> MPC): time, ``q``, ``v``, contacts of the last ``RING_TICKS`` control ticks
  and whether the safe ladder held the robot off the plans then (``held``), one seqlock slot per tick, so
  the MPC can read the measurement of the tick it prepared for even after newer ones arrived;
* ``PlanChannel`` (MPC -> loop): the newest plan, the time of the measurement it was solved from and its
  update's statistics, behind one seqlock; any plan type, laid out by its ``core.plan.PlanFormat``
  (``PlanLayout``);
* ``ControlBlock`` (both ways): the stop flag, the ready flag, the scheme the MPC process runs, how often it
  solved cold again after a gap (``resyncs``), which MPC process may run (``active``, with a standby waiting
  built beside it) and the runtime command channel (``control.commands``).
"""

from __future__ import annotations

import numpy as np

from cafe_mpc.control.commands import COMMAND_SIZE, CommandChannel
from cafe_mpc.control.ipc.seqlock import SeqLock
from cafe_mpc.control.ipc.shared import SharedArray
from cafe_mpc.core.plan import KnotPlan, PlanFormat

RING_TICKS = 256
"""Control ticks the measurement ring keeps (0.5 s at 500 Hz)."""


class MeasurementRing:
    """The last ``RING_TICKS`` measurements, one seqlock slot per control tick (module docstring).

    Element 0 holds the newest tick index written (-1 before the first); slot ``i`` (from element 1) holds
    ``[sequence, tick, t, q, v, contacts, held]`` of a tick ``k`` with ``k % RING_TICKS == i``; ``read``
    copies ``[t, q, v, contacts, held]``, ``held`` at ``HELD`` (1: the robot was off the plans, 2: it was
    being stopped on them).
    """

    def __init__(self, nq: int, nv: int, n_feet: int, name: str | None = None) -> None:
        self.nq, self.nv, self.n_feet = nq, nv, n_feet
        self.slot = 4 + nq + nv + n_feet
        self.HELD = self.slot - 3
        """Index of ``held`` in what ``read`` copies."""
        self.shared = SharedArray(1 + RING_TICKS * self.slot, name)
        self.array = self.shared.array
        if name is None:
            self.array[0] = -1.0
        slots = self.array[1:].reshape(RING_TICKS, self.slot)
        self._locks = [SeqLock(slots[index]) for index in range(RING_TICKS)]

    @property
    def name(self) -> str:
        return self.shared.name

    @property
    def newest(self) -> int:
        """Index of the newest tick written (-1 before the first)."""
        return int(self.array[0])

    def clear(self) -> None:
        """Forget the ticks written (a new run's ticks start again at 0)."""
        self.array[0] = -1.0

    def write(
        self, tick: int, t: float, q: np.ndarray, v: np.ndarray, contacts: np.ndarray, held: float = 0.0
    ) -> None:
        """``held``: 0 on the gait, 1 held off the plans, 2 being stopped on them (``control.process``)."""
        lock = self._locks[tick % RING_TICKS]
        slot = lock.array
        nq, nv = self.nq, self.nv
        lock.begin_write()
        slot[1] = tick
        slot[2] = t
        slot[3 : 3 + nq] = q
        slot[3 + nq : 3 + nq + nv] = v
        slot[3 + nq + nv : -1] = contacts
        slot[-1] = float(held)
        lock.end_write()
        self.array[0] = tick

    def read(self, tick: int, out: np.ndarray) -> bool:
        """Copy ``[t, q, v, contacts, held]`` of ``tick`` into ``out``; ``False`` if that tick is not (or no
        longer) in the ring or was being written."""
        lock = self._locks[tick % RING_TICKS]
        slot = lock.array
        before = lock.begin_read()
        if before is None or int(slot[1]) != tick:
            return False
        np.copyto(out, slot[2:])
        return lock.end_read(before) and int(slot[1]) == tick

    def close(self, unlink: bool) -> None:
        self._locks = []
        self.array = None  # type: ignore[assignment]
        self.shared.close(unlink)


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
        for name, shape in self.format.shapes(knots).items():
            offset, full = self.fields[name]
            views[name] = buffer[offset : offset + int(np.prod(full))].reshape(full)[: shape[0]]
        return views

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
            name: view > 0.5 if dtypes.get(name) is bool else view.copy()
            for name, view in self.views(buffer, n).items()
        }
        return self.format.make(**fields), float(buffer[1]), float(buffer[2])


class PlanChannel:
    """The newest plan behind one seqlock (module docstring): ``publish`` on the MPC side, ``receive`` on the
    loop's (each plan once)."""

    def __init__(self, layout: PlanLayout, name: str | None = None) -> None:
        self.layout = layout
        self.shared = SharedArray(1 + layout.size, name)
        self.lock = SeqLock(self.shared.array)
        self._copy = np.zeros(layout.size)
        self._seen = 0.0

    @property
    def name(self) -> str:
        return self.shared.name

    def publish(self, plan: KnotPlan, measured_at: float, stats: tuple[float, ...]) -> None:
        """Write ``plan``, the time of its measurement and ``stats`` (update wall time, iterations, solves,
        failures) in place."""
        lock = self.lock
        lock.begin_write()
        self.layout.write(lock.payload, plan, measured_at, stats)
        lock.end_write()

    def receive(self) -> tuple[KnotPlan, float, float] | None:
        """The plan published since the last ``receive`` (a copy), its measurement time and its update's wall
        time; None when there is none, or it was being written (then the next call takes it)."""
        if self.lock.sequence == self._seen:
            return None
        sequence = self.lock.read_into(self._copy, newer_than=self._seen)
        if sequence is None:
            return None
        self._seen = sequence
        return self.layout.read(self._copy)

    def abandon_write(self) -> None:
        """The writer died (a killed MPC process): close a write it left under way, so that the next writer's
        plans read again, without ever reading the torn one."""
        lock = self.lock
        if int(lock.sequence) % 2:
            lock.end_write()
            self._seen = lock.sequence

    def close(self, unlink: bool) -> None:
        self.lock = None  # type: ignore[assignment]
        self.shared.close(unlink)


class ControlBlock:
    """``[stop, ready, rti, resyncs, active, standby_ready, command channel]`` (module docstring): the loop
    sets ``stop`` and ``active`` (the generation of the MPC process that may run; a standby process waits,
    built, until it is its own), the running MPC process sets ``ready`` once its planner is built, ``rti``
    when it runs the real-time iteration and counts its cold solves after a gap in ``resyncs``, a standby
    sets ``standby_ready`` once built; the command channel (``COMMAND_SIZE`` + 1 values) carries runtime
    commands to the MPC process."""

    STOP, READY, RTI, RESYNCS, ACTIVE, STANDBY_READY = 0, 1, 2, 3, 4, 5
    COMMANDS = 6

    def __init__(self, name: str | None = None) -> None:
        self.shared = SharedArray(self.COMMANDS + 1 + COMMAND_SIZE, name)
        self.array = self.shared.array

    @property
    def name(self) -> str:
        return self.shared.name

    def commands(self) -> CommandChannel:
        """A command channel over this block's (a view: drop it before ``close``)."""
        return CommandChannel(self.array[self.COMMANDS :])

    def close(self, unlink: bool) -> None:
        self.array = None  # type: ignore[assignment]
        self.shared.close(unlink)
