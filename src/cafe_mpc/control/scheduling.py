"""Where the 500 Hz loop and the MPC process run, and at what priority.

A deployment runs the low-level loop and the planner on separate cores (paper Sec. VI-C): the loop must start
each tick on time, the planner uses whatever the period leaves. Two things make a loop late on an otherwise
idle machine (measured on a 2-core VM, trot, ``cafe-mpc run trot --realtime``): another process of ours on
the loop's core (an MPC process started after the loop had pinned itself inherited the loop's core), the OS
preempting the loop for a millisecond or more, and page faults: a machine that pages out memory not touched
for a while (a kernel's proactive reclaim) makes the loop fault its own code and data back in, in bursts of
ticks each 2-4 times slower than the rest. ``lock_memory`` keeps every page of the process resident
(``mlockall``, as real-time robot software does). ``CpuPlan`` gives each side its own core (the loop the
first of the CPUs the process may use, the MPC processes the last, every thread of them);
``RealTimePriority`` puts the loop's thread in the ``SCHED_FIFO`` class, so that no ordinary process or
thread on its core preempts it (where the OS allows it: root or ``CAP_SYS_NICE``; elsewhere the loop runs at
the normal priority and says so). A ``SCHED_FIFO`` thread must sleep part of each period: Linux keeps 5 % of
each second for the other classes and stops a real-time thread that spins past that for tens of ms.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import os
from dataclasses import dataclass


@dataclass(frozen=True)
class CpuPlan:
    """The loop's core and the MPC processes' core, both None with fewer than two usable CPUs (or where the
    OS has no affinity): then nothing is pinned."""

    loop_cpu: int | None
    mpc_cpu: int | None

    @classmethod
    def of_this_process(cls) -> CpuPlan:
        """The first and the last of the CPUs this process may run on now (call before pinning anything)."""
        try:
            cpus = sorted(os.sched_getaffinity(0))
        except (AttributeError, OSError):
            return cls(None, None)
        if len(cpus) < 2:
            return cls(None, None)
        return cls(cpus[0], cpus[-1])


def usable_cpus() -> int:
    """How many CPUs this machine has (at least 1)."""
    return os.cpu_count() or 1


def pin_this_thread(cpu: int | None) -> None:
    """Pin the calling thread to ``cpu`` (no-op for None or where unsupported)."""
    if cpu is None:
        return
    with contextlib.suppress(AttributeError, OSError):
        os.sched_setaffinity(0, {cpu})


def pin_every_thread(cpu: int | None) -> None:
    """Pin every thread of this process to ``cpu``, those already running (a numerical library's workers
    start at import and keep the mask they were born with) and, through the calling thread, those to come."""
    if cpu is None:
        return
    with contextlib.suppress(OSError):
        for task in os.listdir("/proc/self/task"):
            with contextlib.suppress(AttributeError, OSError, ValueError):
                os.sched_setaffinity(int(task), {cpu})
    pin_this_thread(cpu)


def _set_every_thread_policy(policy: int) -> str | None:
    """Every thread of this process in ``policy`` (priority 0; the calling thread last, so that the threads
    it starts later inherit it); None when granted, else why not."""
    refused = None
    with contextlib.suppress(OSError):
        for task in os.listdir("/proc/self/task"):
            try:
                os.sched_setscheduler(int(task), policy, os.sched_param(0))
            except (AttributeError, OSError, ValueError) as error:
                refused = getattr(error, "strerror", None) or type(error).__name__
    try:
        os.sched_setscheduler(0, policy, os.sched_param(0))
    except (AttributeError, OSError) as error:
        refused = getattr(error, "strerror", None) or type(error).__name__
    return refused


def background_priority() -> str:
    """Every thread of this process in ``SCHED_IDLE``: it runs only when its core has nothing else to run.
    A standby MPC process built while the robot runs builds, makes its first solve and waits so
    (``control.process``): a second or two of CPU on the running MPC process's core that must not slow the
    running process's updates. Returns the class granted, for the record."""
    policy = getattr(os, "SCHED_IDLE", None)
    if policy is None:
        return "normal (no SCHED_IDLE here)"
    refused = _set_every_thread_policy(policy)
    return "SCHED_IDLE" if refused is None else f"normal (SCHED_IDLE refused: {refused})"


def foreground_priority() -> str:
    """Every thread of this process back in the normal class (``SCHED_OTHER``), after
    ``background_priority``. Leaving ``SCHED_IDLE`` needs root, ``CAP_SYS_NICE`` or an ``RLIMIT_NICE`` of
    at least 20 where the nice value is 0; where refused, the process stays in the idle class and says so."""
    refused = _set_every_thread_policy(os.SCHED_OTHER)
    return "normal" if refused is None else f"SCHED_IDLE (leaving it refused: {refused})"


class RealTimePriority:
    """The calling thread in ``SCHED_FIFO`` at ``priority`` (1-99) while held; ``acquire`` says what it got.

    ``granted`` is False where the OS refuses (no permission) or has no such class; ``description`` names the
    class the thread runs in, for the run's record. ``release`` restores the thread's previous policy.
    """

    def __init__(self, priority: int) -> None:
        if not 0 <= int(priority) <= 99:
            raise ValueError(f"real-time priority must be 0 (off) to 99, got {priority}")
        self.priority = int(priority)
        self.granted = False
        self.description = "normal"
        self._previous: tuple[int, int] | None = None

    def acquire(self) -> bool:
        """Switch the calling thread to ``SCHED_FIFO`` (nothing for priority 0); True when granted. With
        ``SCHED_RESET_ON_FORK``: a process it starts (an MPC standby) begins in the normal class. Without it
        the standby inherited the loop's class and core, and its start-up (imports, a second of CPU) held
        the loop's core against the loop at the same priority: a tick 590 ms late."""
        if self.priority == 0:
            self.description = "normal (real-time priority off)"
            return False
        try:
            previous = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
            policy = os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0)
            os.sched_setscheduler(0, policy, os.sched_param(self.priority))
        except (AttributeError, OSError) as error:
            reason = getattr(error, "strerror", None) or type(error).__name__
            self.description = f"normal (SCHED_FIFO {self.priority} refused: {reason})"
            return False
        self._previous = previous
        self.granted = True
        self.description = f"SCHED_FIFO {self.priority}"
        return True

    def release(self) -> None:
        """Back to the policy the thread had before ``acquire`` (idempotent)."""
        if self._previous is None:
            return
        policy, priority = self._previous
        with contextlib.suppress(AttributeError, OSError):
            os.sched_setscheduler(0, policy, os.sched_param(priority))
        self._previous = None
        self.granted = False


MCL_CURRENT, MCL_FUTURE = 1, 2
"""``mlockall`` flags (Linux): the pages mapped now, and those mapped later."""


@functools.cache
def _libc() -> ctypes.CDLL:
    """The C library (``mlockall``, ``munlockall``), loaded once."""
    return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)


def lock_memory() -> str:
    """Lock every page of this process in memory, now and later (``mlockall``), so that no tick of a
    real-time loop waits for a page the OS took away. Needs root, ``CAP_IPC_LOCK`` or a large enough
    ``RLIMIT_MEMLOCK``; elsewhere nothing is locked. Returns what happened, for the run's record."""
    try:
        result = _libc().mlockall(MCL_CURRENT | MCL_FUTURE)
    except (OSError, AttributeError) as error:
        return f"not locked ({type(error).__name__})"
    if result != 0:
        return f"not locked (mlockall: {os.strerror(ctypes.get_errno())})"
    return "locked"


def unlock_memory() -> None:
    """Undo ``lock_memory`` (no-op where it did nothing)."""
    with contextlib.suppress(OSError, AttributeError):
        _libc().munlockall()


def host_steal_seconds() -> float | None:
    """Time the hypervisor ran something else while this machine's CPUs wanted to run, summed over the
    CPUs, s (``steal`` of ``/proc/stat``, 10 ms resolution); None where the OS does not say. The difference
    over a run tells a loop made late by its host from one made late by its own machine."""
    try:
        with open("/proc/stat") as stat:
            fields = stat.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError, AttributeError):
        return None
