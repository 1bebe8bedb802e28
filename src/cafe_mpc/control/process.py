"""The MPC loop with the planner in its own process, the low-level controller at 500 Hz in the caller's.

The shape of a deployment (paper Sec. VI-C and Fig. 2; OCS2's MPC/MRT split): the low-level controller
(VWBC) runs on the robot against the wall clock and never waits for the solver; the planner runs beside it,
as fast as the period allows, always from the newest measurement. The two exchange data asynchronously
through shared memory (``control.ipc``): the measurement ring (main -> MPC), the plan channel (MPC -> main:
the newest plan of the planner's type, laid out by its ``PlanFormat``) and the control block (stop, ready,
runtime commands). Neither side ever blocks the other. A process (not a thread) because the solver would
otherwise hold Python's global interpreter lock against the 500 Hz loop.

The MPC process runs the scheme of its settings (``MpcSettings.scheme``; one-phase for a planner without the
real-time iteration). Real-time iteration: after publishing a plan it picks the next update time ``t_next``
(``control.update_clock``: one period later, or later when its preparations take longer), prepares that
update from the state the new plan predicts there, waits for the measurement of the tick at ``t_next`` and
runs only the feedback phase on it before publishing (the latency the robot sees). One-phase: it takes the
newest measurement, at most once per period, and runs the whole update.

``ProcessMpcLoop`` is the main-process side (``control.loop.MpcLoop``; the simulation's ``Controller``):
``start`` starts the MPC process (a new one on a later ``start``: a new planner, no stale warm start) and
waits for its first plan; ``compute`` publishes each measurement, takes the newest plan as soon as it
appears and runs the low-level controller on it, or, when there is no fresh plan or the plan's
horizon has run out, the safe ladder (``control.plan_follower``). The MPC process is supervised
(``_supervise``, every tick): one that died is restarted, one that sends no plan for ``stall_timeout`` is
stalled, taken back when its plans are fresh again or restarted after ``recovery.stall_restart_after``.
A restart hands over to the standby, a second MPC process built beside the running one and waiting
(``recovery.standby``; a new one is built ``STANDBY_AFTER`` s after the takeover), else starts a new process;
either solves cold from the newest measurement. A standby is built and makes its first solve (kernels, solver
data: ``_Worker.prepare_standby``) before it waits; one built while the robot runs does so in the idle
scheduling class (``background_priority``), so that it takes no time from the running process on their
shared core, and takes over in the normal class.
Past ``recovery.max_restarts_per_minute`` the robot stays in the damped stance and ``failure`` says why (the
run then ends with ``MpcProcessError``). ``close()`` (also on errors and Ctrl-C, via ``with``) stops the
processes and frees the shared memory; no process is left behind.
"""

from __future__ import annotations

import contextlib
import logging
import math
import multiprocessing
import os
import signal
import time
from collections.abc import Callable

import numpy as np

from cafe_mpc.config import RecoveryConfig
from cafe_mpc.control.commands import CommandChannel, apply_command
from cafe_mpc.control.ipc.channels import ControlBlock, MeasurementRing, PlanChannel, PlanLayout
from cafe_mpc.control.loop import GaitRestart, MpcLoop
from cafe_mpc.control.plan_follower import NewestPlanFollower
from cafe_mpc.control.scheduling import (
    CpuPlan,
    background_priority,
    foreground_priority,
    lock_memory,
    pin_every_thread,
    pin_this_thread,
)
from cafe_mpc.control.update_clock import UpdateClock
from cafe_mpc.core.compilation import CompileWatch
from cafe_mpc.core.controller import LowLevelController
from cafe_mpc.core.measurement import Measurement
from cafe_mpc.core.plan import PlanFormat, PlanT
from cafe_mpc.core.progress import stage
from cafe_mpc.planners.base import MpcStatistics, Planner, forget_warm_start
from cafe_mpc.reference.base import Reference
from cafe_mpc.robots.robot import Robot

logger = logging.getLogger(__name__)

STOPPING = 2.0
"""The ring's ``held`` value of a measurement taken while the robot was being stopped on the plans."""
STANDBY_POLL = 0.005
"""s between a standby MPC process's looks at whether it is its turn (the takeover's delay at most)."""
STANDBY_AFTER = 2.0
"""s after an MPC process took over (its first plan) before a new standby is built beside it: the build
takes a few seconds of CPU, not while the gait resumes (idle class or not)."""

PlannerFactory = Callable[[], Planner]
"""Builds the planner inside the MPC process (must be picklable: a module-level function or a partial)."""


class MpcProcessError(RuntimeError):
    """The MPC process died, failed to start, or stopped delivering plans."""


# ------------------------------------------------------------------------------------- MPC process
def _worker_main(
    factory: PlannerFactory,
    measurement_name: str,
    dimensions: tuple[int, int, int],
    plan_name: str,
    layout: PlanLayout,
    control_name: str,
    control_period: float,
    period: float,
    resync_after: float,
    restart: tuple[bool, float | None],
    parent_pid: int,
    generation: int,
    cpu: int | None,
    lock: bool,
    background: bool,
    results,
) -> None:
    """The MPC process: measurements -> updates -> plans (module docstring), until told to stop. A standby
    (``generation`` is not the control block's ``active``) builds its planner, makes its first solve
    (``_Worker.prepare_standby``), says so and waits until it is made the active one (or told to stop); with
    ``background`` (a standby built while the robot runs) it does all that in the idle scheduling class and
    runs in the normal class once active. Every thread of it runs on ``cpu`` (``CpuPlan.mpc_cpu``:
    not the 500 Hz loop's core; None: anywhere); with ``lock`` its memory is locked (``lock_memory``)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the main process owns Ctrl-C and stops us
    pin_every_thread(cpu)
    if lock:
        logger.debug("MPC process memory: %s", lock_memory())
    nq, nv, n_feet = dimensions
    ring = MeasurementRing(nq, nv, n_feet, measurement_name)
    plans = PlanChannel(layout, plan_name)
    control = ControlBlock(control_name)
    statistics = None
    worker = None
    if background:  # a standby built while the robot runs: on what the running process leaves of its core
        background = background_priority() == "SCHED_IDLE"
    try:
        planner = factory()
        worker = _Worker(
            planner,
            ring,
            plans,
            control,
            control_period,
            period,
            resync_after,
            restart,
            parent_pid,
            generation,
        )
        if control.array[ControlBlock.ACTIVE] != generation:
            if not worker.prepare_standby():
                return
            control.array[ControlBlock.STANDBY_READY] = 1.0  # built, solver data made, numba kernels loaded
            if not worker.wait_turn():
                return
        if background:
            priority = foreground_priority()
            if priority != "normal":
                logger.warning("the standby MPC process took over in %s", priority)
        control.array[ControlBlock.RTI] = 1.0 if worker.rti else 0.0
        control.array[ControlBlock.READY] = 1.0  # built; numba kernels loaded
        try:
            worker.run()  # starts ``worker.compiles`` once the first plan is out
        finally:
            worker.compiles.stop()
        statistics = planner.statistics
    except BaseException as error:  # report, then exit: the main process turns it into MpcProcessError
        results.send(("error", f"{type(error).__name__}: {error}"))
        raise
    finally:
        if statistics is not None:
            with contextlib.suppress(Exception):
                results.send(("statistics", statistics))
                results.send(("compilation", worker.compiles.summary()))
        if worker is not None:
            worker.commands = None  # drop its view of the control block before closing it
        for channel in (ring, plans, control):
            channel.close(unlink=False)


class _Worker:
    """The loop of the MPC process (``_worker_main``): one-phase or real-time-iteration updates."""

    def __init__(
        self,
        planner: Planner,
        ring: MeasurementRing,
        plans: PlanChannel,
        control: ControlBlock,
        control_period: float,
        period: float,
        resync_after: float,
        restart: tuple[bool, float | None],
        parent_pid: int,
        generation: int,
    ) -> None:
        self.planner, self.ring, self.plans, self.control = planner, ring, plans, control
        self.generation = float(generation)
        self.control_period = control_period
        self.period = period
        self.resync_ticks = max(round(resync_after / control_period), 1)
        """A gap of more ticks than this between two looks at the measurements: solve cold (``_stopped``)."""
        self._looked = -1
        """The newest measurement's tick when this process last looked (``_stopped``)."""
        self.parent_pid = parent_pid
        self.buffer = np.zeros(ring.slot - 2)
        self.nq, self.nv = ring.nq, ring.nv
        self.clock = UpdateClock(period, control_period)
        self.rti = planner.settings.scheme == "rti" and planner.supports_rti
        self.commands: CommandChannel | None = control.commands()
        """Runtime commands from the main process (``ProcessMpcLoop.commands``)."""
        self.compiles = CompileWatch()
        """Kernels compiled (or loaded) in this process after its cold solve (``core.compilation``)."""
        self._warm_from_gait = False
        """Whether the warm start descends from a cold solve on a measurement of the gait, not held."""
        self.gait_restart = GaitRestart(planner.reference, restart[1], restart[0])
        """The gait restarted from stance after an episode off the plans (``control.loop.GaitRestart``;
        ``restart``: ``recovery.restart_gait`` and ``restart_stand``)."""

    def running(self) -> bool:
        """Until the stop flag is set, another process is made the active one, or the main process is gone
        (do not outlive it)."""
        array = self.control.array
        return (
            array[ControlBlock.STOP] == 0.0
            and array[ControlBlock.ACTIVE] == self.generation
            and os.getppid() == self.parent_pid
        )

    def wait_turn(self) -> bool:
        """A standby: wait until this process is made the active one (True) or told to stop (False)."""
        array = self.control.array
        while array[ControlBlock.STOP] == 0.0 and os.getppid() == self.parent_pid:
            if array[ControlBlock.ACTIVE] == self.generation:
                return True
            time.sleep(STANDBY_POLL)
        return False

    def prepare_standby(self) -> bool:
        """A standby's first solve, made while it waits: a cold solve on the newest measurement, its kernels
        and its warm-up's solver data (``MpcSettings.warm_up``), then its warm start and records dropped
        (``Planner.reset``). Its takeover is then a cold solve alone (0.1-0.2 s on a bound), not that and the
        start-up's kernels and warm-up (0.5-0.9 s measured, most of which the robot spent in the balance
        stance). False when told to stop first; True at once when made the active one before a measurement
        came (the first update then makes all of it)."""
        array, ring, planner = self.control.array, self.ring, self.planner
        while True:
            if array[ControlBlock.STOP] != 0.0 or os.getppid() != self.parent_pid:
                return False
            if array[ControlBlock.ACTIVE] == self.generation:
                return True
            newest = ring.newest
            if newest >= 0 and ring.read(newest, self.buffer):
                break
            time.sleep(STANDBY_POLL)
        nq, nv = self.nq, self.nv
        planner.update(float(self.buffer[0]), self.buffer[1 : 1 + nq], self.buffer[1 + nq : 1 + nq + nv])
        planner.reset()
        planner.settings.warm_up = 0.0  # its solver data exist: the takeover's cold solve alone
        return True

    def run(self) -> None:
        planner = self.planner
        last_tick = -1
        while self.running():
            if self._stopped() and planner.started:
                self._resync()  # this process was stopped: its warm start is stale
            newest = self._looked
            if newest < 0 or newest == last_tick:
                time.sleep(0.0002)
                continue
            if not planner.started:  # the cold solve, on the first measurement (or after a resync)
                if self.ring.read(newest, self.buffer):
                    last_tick = newest
                    self._publish(self._state_update(newest), newest)
                    if planner.started:  # the clock starts once the first plan is out
                        self.compiles.start()
            elif self.rti:
                last_tick = self._rti_update(last_tick)
            else:
                last_tick = self._one_phase_update(last_tick, newest)
            self._looked = self.ring.newest  # an update's own time is no gap

    def _stopped(self) -> bool:
        """Whether the measurements moved on by more than ``resync_after`` since this process last looked
        (between two looks it only sleeps a moment or runs an update: a longer gap means it was stopped, a
        SIGSTOP or a machine that did not run it); look now (``_looked``). A slow update is no gap: a cold
        solve that outlasts ``resync_after`` must not cause the next one."""
        newest = self.ring.newest
        gap = self._looked >= 0 and newest - self._looked > self.resync_ticks
        self._looked = newest
        return gap

    def _resync(self) -> None:
        """Forget the warm start (the planner's records stay): the next update is a cold solve from the
        newest measurement (without the warm-up: its solver's data exist already)."""
        forget_warm_start(self.planner)
        self.planner.settings.warm_up = 0.0  # its solver's data exist already: the cold solve alone
        self.clock.reset()
        self.control.array[ControlBlock.RESYNCS] += 1.0

    def _take_command(self, t: float) -> None:
        """Apply a runtime command posted since the last update, from ``t`` on."""
        command = self.commands.take() if self.commands is not None else None
        if command is not None:
            apply_command(self.planner.reference, t, command)

    def _held(self) -> bool:
        """Whether the measurement in ``buffer`` was taken while the robot was held off the plans."""
        return 0.5 < self.buffer[self.ring.HELD] < 1.5

    def _stopping(self) -> bool:
        """Whether the measurement in ``buffer`` was taken while the robot was being stopped on the plans."""
        return self.buffer[self.ring.HELD] > 1.5

    def _observe_hold(self, t: float) -> bool:
        """Tell the gait restart whether the measurement in ``buffer`` was held off the plans; True when the
        reference restarted. When the robot has just been held off the plans, the warm start is of the motion
        it left (a standby that took over solved cold from a measurement of the gait, feet in the air): it is
        dropped, so the plans that take the robot back are solved cold from the stance it stands in (without
        the warm-up: the solver's data exist); once per cold solve from the gait (``_warm_from_gait``), so
        that a robot held again while that solve runs does not start another."""
        held = self._held()
        restarted = self.gait_restart.observe(t, held, self._stopping())
        if restarted and held and self.planner.started and self._warm_from_gait:
            forget_warm_start(self.planner)
            self.planner.settings.warm_up = 0.0
        if not self.planner.started:
            self._warm_from_gait = not held  # the cold solve to come: from the gait or the held stance
        return restarted

    def _state_update(self, tick: int):
        """A one-phase update from the measurement of ``tick`` (in ``buffer``)."""
        nq, nv = self.nq, self.nv
        self._take_command(float(self.buffer[0]))
        self._observe_hold(float(self.buffer[0]))
        return self.planner.update(
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
        planner, control_period = self.planner, self.control_period
        newest = self.ring.newest
        following = self.clock.next_update(last_tick * control_period, newest * control_period)
        tick = max(round(following / control_period), last_tick + 1)
        t_next = tick * control_period
        self._take_command(t_next)
        predicted = planner.predict(t_next)
        prepared = False
        if predicted is not None:
            prepared = planner.prepare(t_next, predicted[: self.nq], predicted[self.nq :])
            if prepared:
                self.clock.record_preparation(planner.statistics.prepare_times[-1])
        self._looked = self.ring.newest  # the preparation's own time is no gap
        stopped = False
        while not stopped and self.ring.newest < tick:
            if not self.running():
                return last_tick
            stopped = self._stopped()
            time.sleep(0.0001)
        nq, nv = self.nq, self.nv
        if stopped or self._stopped():  # stopped while waiting: solve cold from the newest next
            self._resync()
            return tick
        if not self.ring.read(tick, self.buffer):  # overwritten (the prepare outlasted the ring): newest
            tick = self.ring.newest
            if not self.ring.read(tick, self.buffer):
                return last_tick
            prepared = False
        q, v = self.buffer[1 : 1 + nq], self.buffer[1 + nq : 1 + nq + nv]
        # the tick's measurement is the state at the tick (a robot's clock stamps it a little off the grid)
        t = t_next if prepared else float(self.buffer[0])
        if self._observe_hold(t):
            prepared = False  # made for the gait before the restart: a one-phase update
        plan = planner.feedback(t, q, v) if prepared else planner.update(t, q, v)
        self._publish(plan, tick)
        return tick

    def _publish(self, plan, tick: int) -> None:
        if plan is None:
            return
        stats = self.planner.statistics
        self.plans.publish(
            plan,
            tick * self.control_period,
            (stats.update_times[-1], stats.iterations[-1], stats.solves, stats.failures),
        )


# ------------------------------------------------------------------------------------ control loop
class ProcessMpcLoop(MpcLoop[PlanT]):
    """The main-process side of the MPC loop with the planner in its own process (module docstring).

    ``factory`` builds the planner in the MPC process; ``plan_format``: how its plans travel (the plan
    channel's layout, ``core.plan.PlanFormat``); ``period``: the MPC period; ``scheme``: the scheme the
    planner is set to run (the MPC process reports the one it runs once it is ready); ``recovery``,
    ``balance`` and ``damped``: the safe ladder's settings, balance controller and damped stance, and the
    supervision's (stall timeout, restarts). ``lock_memory``: each MPC process locks its memory
    (``control.scheduling.lock_memory``). Use as a context manager (or call ``close()``): it owns shared
    memory and, once started, a process.
    """

    def __init__(
        self,
        robot: Robot,
        factory: PlannerFactory,
        low_level: LowLevelController[PlanT],
        plan_format: PlanFormat[PlanT],
        period: float,
        control_period: float = 0.002,
        scheme: str = "rti",
        startup_timeout: float = 120.0,
        recovery: RecoveryConfig | None = None,
        balance: LowLevelController | None = None,
        damped: LowLevelController | None = None,
        lock_memory: bool = False,
    ) -> None:
        if not control_period > 0:
            raise ValueError(f"control period must be positive, got {control_period}")
        self.robot = robot
        self.factory = factory
        self.low_level = low_level
        self.recovery = recovery if recovery is not None else RecoveryConfig()
        self.follower = NewestPlanFollower(robot, low_level, self.recovery, balance, damped)
        self.period = period
        self.control_period = float(control_period)
        self.startup_timeout = startup_timeout
        self.lock_memory = lock_memory
        stall = self.recovery.stall_timeout
        self.stall_timeout = stall if stall is not None else max(0.5, 10 * period)
        self._scheme = scheme
        self.layout = PlanLayout(plan_format)
        self._measurements = MeasurementRing(robot.nq, robot.nv, robot.n_feet)
        self._plans = PlanChannel(self.layout)
        self._control = ControlBlock()
        self.commands = self._control.commands()
        """Runtime commands for the MPC process (``control.commands``), taken at its next update; a command
        posted before a (re)start is taken by the new process's first update."""
        self._plan: PlanT | None = None
        self.received = MpcStatistics()
        """The plans as this side received them: latencies, measurement times, update wall times, and the
        ticks of the safe ladder off the plans."""
        self.worker_statistics: MpcStatistics | None = None
        """The MPC process's own records, sent when it stops (the last process's, after restarts)."""
        self.worker_compilation: dict | None = None
        """What the MPC process compiled after its cold solve (``core.compilation``), once it stopped (the
        last process's, after restarts)."""
        self.worker_error: str | None = None
        self.failure: str | None = None
        self.process: multiprocessing.process.BaseProcess | None = None
        """The MPC process that runs (its plans are followed)."""
        self._results = None
        self.standby: multiprocessing.process.BaseProcess | None = None
        """With ``recovery.standby``: an MPC process built beside it, waiting to take over at once."""
        self._standby_results = None
        self._standby_generation = 0
        self._generation = 0
        self._reference: Reference | None = None
        self._affinity = None
        self._cpus: CpuPlan | None = None
        self._closed = False
        self._new_run()

    def _new_run(self) -> None:
        """Forget a previous run's supervision records."""
        self.events: list[dict] = []
        """What happened to the MPC process: ``{"t", "event", "detail"}`` (exited, stalled, resumed,
        restarting, restarted, failed)."""
        self.restarts: list[dict] = []
        """Each restart: when (``t``), why, when the new process was built (``ready_at``) and sent its
        first plan (``first_plan_at``), and ``restart_s`` between the two ends."""
        self.processes = 0
        """MPC processes started (standbys included)."""
        self._restarting: dict | None = None
        self._standby_due = math.inf
        self._standby_exits: list[float] = []
        self._stalled_at: float | None = None
        self._last_plan_time = 0.0
        self._failure_time: float | None = None
        self._cold_hold = False
        """Whether the robot is held off the plans while the MPC solves cold (``_hold_for_cold_solve``)."""
        self._resyncs_seen = 0

    # ------------------------------------------------------------------------------------ interface
    @property
    def reference(self) -> Reference | None:
        """The reference the run tracks, if the caller set it (reports only; the MPC process has its own)."""
        return self._reference

    @reference.setter
    def reference(self, reference: Reference | None) -> None:
        self._reference = reference

    @property
    def scheme(self) -> str:
        return self._scheme

    @property
    def statistics(self) -> MpcStatistics | None:
        """The MPC process's records (once it has stopped: ``close``), else None."""
        return self.worker_statistics

    def summary(self, duration: float | None = None) -> dict:
        worker = self.worker_statistics
        summary = worker.summary() if worker is not None else {}
        latencies = self.received.latencies
        summary["latency_ms_median"] = float(np.median(latencies)) * 1e3 if latencies else None
        summary["latency_ms_p99"] = float(np.percentile(latencies, 99)) * 1e3 if latencies else None
        summary["plans_received"] = len(latencies)
        if duration is not None:
            summary["rate_hz"] = len(latencies) / duration if duration > 0 else None
        summary["pd_fallback_ticks"] = self.received.fallback_ticks
        summary["stale_plans"] = self.received.stale_plans
        summary["worker_error"] = self.worker_error
        if self.worker_compilation is not None:  # the MPC process's own (core.compilation)
            summary["mpc_process_compiles_during_run"] = self.worker_compilation["compiles_during_run"]
            summary["mpc_process_kernels_loaded_during_run"] = self.worker_compilation[
                "kernels_loaded_during_run"
            ]
        return summary

    def reset(self) -> None:
        """The follower's counters; the plan received at ``start`` stays in effect."""
        self.follower.reset()

    def start(self, t: float, measurement: Measurement) -> None:
        """Start the MPC process (after stopping the one a previous ``start`` started) on ``measurement``
        and wait for its first plan, and for the standby to be built (``recovery.standby``): the cold solve
        runs before the clock starts, while the robot stands, as on hardware."""
        if self._closed:
            raise RuntimeError("this MPC loop is closed")
        if self.process is not None or self.standby is not None:
            self._stop_processes()
            self._measurements.clear()
            self._plans.receive()  # a plan the stopped process published unread: not the new one's first
            self._control.array[: ControlBlock.COMMANDS] = 0.0
            self._plan, self.failure = None, None
            self.received, self.worker_statistics, self.worker_error = MpcStatistics(), None, None
            self.worker_compilation = None
            self._new_run()
        self._spawn()
        if self.recovery.standby:  # before the clock starts: built at the normal priority
            self._spawn_standby(background=False)
        deadline = time.perf_counter() + self.startup_timeout
        stage("first (cold) MPC solve, in the MPC process")
        self.publish(t, measurement)
        while self._plan is None:
            self._poll_plan(t, record=False)
            if self._plan is not None:
                break
            if not self.process.is_alive():
                self._read_results()
                detail = f": {self.worker_error}" if self.worker_error else ""
                raise MpcProcessError(f"the MPC process exited (code {self.process.exitcode}){detail}")
            if time.perf_counter() > deadline:
                raise MpcProcessError(f"the MPC process sent no plan within {self.startup_timeout:.0f} s")
            time.sleep(0.002)
        while self.standby is not None and self._control.array[ControlBlock.STANDBY_READY] != 1.0:
            if not self.standby.is_alive():
                self._discard_standby()
                detail = f": {self.worker_error}" if self.worker_error else ""
                raise MpcProcessError(f"the standby MPC process exited while it was built{detail}")
            if time.perf_counter() > deadline:
                raise MpcProcessError(
                    f"the standby MPC process was not built within {self.startup_timeout:.0f} s"
                )
            time.sleep(0.005)
        self._scheme = "rti" if self._control.array[ControlBlock.RTI] == 1.0 else "one_phase"
        self._last_plan_time = t

    def compute(self, t: float, measurement: Measurement) -> np.ndarray:
        self.publish(t, measurement)
        self._poll_plan(t, record=True)
        self._supervise(t)
        before = self.follower.fallback_ticks
        torques = self.follower.compute(t, measurement, self._plan)
        self.received.fallback_ticks += self.follower.fallback_ticks - before
        return torques

    def should_stop(self, t: float) -> bool:
        """End the run 0.5 s after a failure (the damped stance holds the robot meanwhile)."""
        if self.failure is None:
            return False
        if self._failure_time is None:
            self._failure_time = t
        return t - self._failure_time > 0.5

    def fault_record(self, control_period: float) -> dict | None:
        """The safe ladder's record and the MPC process's: its events, restarts (with how long each took from
        the exit to the new process's first plan), how often it solved cold after being stopped, and the
        failure if it could not be kept running; None when nothing happened."""
        resyncs = int(self._control.array[ControlBlock.RESYNCS]) if not self._closed else self._resyncs
        if not (self.follower.eventful or self.events or resyncs):
            return None
        record = {"ladder": self.follower.record(control_period)}
        record["mpc"] = {
            "processes": self.processes,
            "events": list(self.events),
            "restarts": list(self.restarts),
            "resyncs": resyncs,
            "stall_timeout_s": self.stall_timeout,
            "failure": self.failure,
        }
        return record

    def close(self) -> None:
        """Stop the MPC process (politely, then by force) and free the shared memory. Idempotent."""
        if self._closed:
            return
        self._resyncs = int(self._control.array[ControlBlock.RESYNCS])
        self._closed = True
        self._stop_processes()
        if self._affinity is not None:
            with contextlib.suppress(OSError):
                os.sched_setaffinity(0, self._affinity)
        self.commands = CommandChannel()  # a detached channel: the shared view is released before closing
        for channel in (self._measurements, self._plans, self._control):
            channel.close(unlink=True)

    _resyncs = 0

    def publish(self, t: float, measurement: Measurement) -> None:
        """Write the measurement of the tick at ``t`` into the ring for the MPC process (never blocks), with
        whether the safe ladder holds the robot off the plans (the MPC restarts the gait from stance:
        ``control.loop.GaitRestart``)."""
        tick = round(t / self.control_period)
        follower = self.follower
        held = STOPPING if follower.stopping else float(not follower.following)
        self._measurements.write(tick, t, measurement.q, measurement.v, measurement.contacts, held)

    # ------------------------------------------------------------------------------------ supervision
    def _event(self, t: float, event: str, detail: str = "") -> None:
        """Record (and log) what happened to the MPC process at ``t``."""
        self.events.append({"t": round(float(t), 6), "event": event, "detail": detail})
        logger.warning(
            "t = %.3f s: MPC process %s%s", t, event.removeprefix("mpc_"), f": {detail}" * bool(detail)
        )

    def _supervise(self, t: float) -> None:
        """Every tick: a dead process is restarted (or the loop fails, past the restart limit), one that
        sends no plan for ``stall_timeout`` counts as stalled and, after ``recovery.stall_restart_after``
        more, is killed and restarted; a new process that sends no plan within ``startup_timeout`` too."""
        process = self.process
        if self.failure is not None or process is None:
            return
        self._supervise_standby(t)
        if not process.is_alive():
            self._read_results()
            detail = f"code {process.exitcode}" + (f", {self.worker_error}" if self.worker_error else "")
            self._event(t, "mpc_exited", detail)
            self._restart(t, f"the MPC process exited ({detail})")
            return
        resyncs = int(self._control.array[ControlBlock.RESYNCS])
        if resyncs > self._resyncs_seen:  # the process was stopped and solves cold again
            self._resyncs_seen = resyncs
            self._hold_for_cold_solve(t, "the MPC process solves cold again after a gap")
        restarting = self._restarting
        if restarting is not None:
            if restarting["ready_at"] is None and self._control.array[ControlBlock.READY] == 1.0:
                restarting["ready_at"] = round(float(t), 6)
            if t - restarting["t"] > self.startup_timeout:
                self._restart(t, f"the new MPC process sent no plan within {self.startup_timeout:g} s")
            return
        silence = t - self._last_plan_time
        if self._stalled_at is None and silence > self.stall_timeout:
            self._stalled_at = t
            self._event(t, "mpc_stalled", f"no plan for {silence:.2f} s")
        elif self._stalled_at is not None and t - self._stalled_at > self.recovery.stall_restart_after:
            self._restart(t, f"the MPC process sent no plan for {silence:.2f} s")

    def _supervise_standby(self, t: float) -> None:
        """A standby that died is noted (and replaced, unless ``max_restarts_per_minute`` standbys died in the
        last minute); a new standby is built ``STANDBY_AFTER`` s after a takeover."""
        standby = self.standby
        if standby is not None and not standby.is_alive():
            self._discard_standby()
            self._standby_exits.append(t)
            recent = sum(1 for exit_time in self._standby_exits if exit_time > t - 60.0)
            replace = recent <= self.recovery.max_restarts_per_minute
            self._event(
                t,
                "mpc_standby_exited",
                f"code {standby.exitcode}" + ("" if replace else "; no standby from now on"),
            )
            self._standby_due = t + STANDBY_AFTER if replace else math.inf
        elif (
            standby is None and self.recovery.standby and self._restarting is None and t >= self._standby_due
        ):
            self._standby_due = math.inf
            self._spawn_standby(background=True)
            logger.info("t = %.3f s: a new standby MPC process is being built", t)

    def _restart(self, t: float, reason: str) -> None:
        """Replace the MPC process: the standby takes over when there is one (built, or still being built),
        else a new process is started; either solves cold from the newest measurement. Unless
        ``recovery.max_restarts_per_minute`` restarts happened in the last 60 s: then the loop fails and the
        robot stays in the damped stance."""
        self._poll_plan(t, record=True)  # the old process's last plan, if it sent one we have not read
        recent = sum(1 for restart in self.restarts if restart["t"] > t - 60.0)
        limit = self.recovery.max_restarts_per_minute
        self._discard_process()
        if recent >= limit:
            self.failure = (
                f"{reason}; {recent} restart(s) in the last minute, the limit "
                f"(recovery.max_restarts_per_minute) is {limit}: the robot is held in the damped stance"
            )
            self.follower.fail(t, self.failure)
            self._event(t, "mpc_failed", self.failure)
            return
        self._plans.abandon_write()
        self._hold_for_cold_solve(t, "the MPC process restarts: its first plan is a cold solve")
        control = self._control.array
        control[ControlBlock.STOP] = 0.0
        control[ControlBlock.READY] = 0.0
        self._stalled_at = None
        self._standby_due = math.inf
        standby = self.standby is not None and self.standby.is_alive()
        if standby:
            self._event(t, "mpc_restarting", f"{reason}; the standby MPC process takes over")
            self.process, self._results = self.standby, self._standby_results
            self.standby, self._standby_results = None, None
            control[ControlBlock.STANDBY_READY] = 0.0
            control[ControlBlock.ACTIVE] = float(self._standby_generation)
        else:
            self._event(t, "mpc_restarting", reason)
            self._discard_standby()
            self._spawn()
        self._restarting = {
            "t": round(float(t), 6),
            "reason": reason,
            "standby": standby,
            "ready_at": None,
            "first_plan_at": None,
            "restart_s": None,
        }
        self.restarts.append(self._restarting)

    def _hold_for_cold_solve(self, t: float, reason: str) -> None:
        """Hold the robot off the plans (the balance stance) until the next plan arrives: the MPC solves
        cold from a measurement taken while the robot is held, so that its plans restart the gait from the
        stance (``control.loop.GaitRestart``) and take the robot back. A cold solve from a measurement of the
        gait (a foot in the air, 30-90 iterations, rarely converged) that the robot followed from its last
        plan made a trot and a bound fall (2 of 15 process kills)."""
        self._cold_hold = True
        self.follower.hold(t, "mpc", reason)

    def _discard_process(self) -> None:
        """Kill the current MPC process if it still runs (a stopped one too), reap it, read what it sent."""
        process = self.process
        if process is None:
            return
        if process.is_alive():
            process.kill()
        process.join(timeout=2.0)
        self._read_results()
        with contextlib.suppress(Exception):
            self._results.close()

    def _discard_standby(self) -> None:
        """Kill the standby if it still runs, reap it, read what it sent (an error while it was built)."""
        standby, results = self.standby, self._standby_results
        if standby is None:
            return
        self.standby, self._standby_results = None, None
        if standby.is_alive():
            standby.kill()
        standby.join(timeout=2.0)
        with contextlib.suppress(OSError, ValueError, EOFError):
            while results.poll(0):
                kind, payload = results.recv()
                if kind == "error":
                    self.worker_error = payload
        with contextlib.suppress(Exception):
            results.close()

    # ----------------------------------------------------------------------------------- the process
    def _spawn(self) -> None:
        """Start the MPC process that runs (the control block's ``active`` generation)."""
        self._generation += 1
        self._control.array[ControlBlock.ACTIVE] = float(self._generation)
        self.process, self._results = self._launch(self._generation, background=False)

    def _spawn_standby(self, background: bool) -> None:
        """Start a standby MPC process: it builds its planner, makes its first solve and waits until it is
        made the active one; ``background``: in the idle scheduling class until then (the robot runs)."""
        self._generation += 1
        self._control.array[ControlBlock.STANDBY_READY] = 0.0
        self._standby_generation = self._generation
        self.standby, self._standby_results = self._launch(self._generation, background)

    def _launch(self, generation: int, background: bool):
        """Start an MPC process of ``generation`` (``background``: in the idle scheduling class until it is
        the active one); its process and the pipe of what it sends."""
        if self._cpus is None:  # before this process pins itself: the CPUs it was given
            self._cpus = CpuPlan.of_this_process()
            with contextlib.suppress(AttributeError, OSError):
                self._affinity = os.sched_getaffinity(0)
        context = multiprocessing.get_context("spawn")
        results, child_end = context.Pipe(duplex=False)
        process = context.Process(
            target=_worker_main,
            args=(
                self.factory,
                self._measurements.name,
                (self.robot.nq, self.robot.nv, self.robot.n_feet),
                self._plans.name,
                self.layout,
                self._control.name,
                self.control_period,
                self.period,
                self.recovery.resync_after,
                (self.recovery.restart_gait, self.recovery.restart_stand),
                os.getpid(),
                generation,
                self._cpus.mpc_cpu,
                self.lock_memory,
                background,
                child_end,
            ),
            name="cafe-mpc-solver",
            daemon=True,
        )
        process.start()  # started: from now on ``close`` stops it (the caller keeps it)
        self.processes += 1
        child_end.close()
        pin_this_thread(self._cpus.loop_cpu)  # the 500 Hz loop's thread (the caller's)
        return process, results

    def _stop_processes(self) -> None:
        """Stop the MPC process and the standby (the stop flag tells both), reap them."""
        if self.process is not None:
            self._stop_process()
        standby = self.standby
        if standby is not None:
            standby.join(timeout=1.0)  # a built standby exits on the stop flag; one being built is killed
            self._discard_standby()

    def _stop_process(self) -> None:
        """Set the stop flag, read what the process sends while it exits (its statistics can exceed the
        pipe's buffer: joining first would deadlock), then make sure it is gone. A stopped process (SIGSTOP)
        is continued first."""
        with contextlib.suppress(Exception):
            self._control.array[ControlBlock.STOP] = 1.0
        if self.process.is_alive():
            with contextlib.suppress(OSError):
                os.kill(self.process.pid, signal.SIGCONT)
        deadline = time.perf_counter() + 5.0
        while time.perf_counter() < deadline:
            try:
                if self._results.poll(0.02):
                    if not self._receive():
                        break  # the process closed its end
                elif not self.process.is_alive():
                    break
            except (OSError, ValueError):  # its pipe is closed already (a discarded process)
                break
        self.process.join(timeout=1.0)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(timeout=2.0)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(timeout=2.0)
        with contextlib.suppress(Exception):
            self._results.close()

    def _poll_plan(self, t: float, record: bool) -> None:
        received = self._plans.receive()
        if received is None:
            return
        plan, measured_at, wall = received
        self._last_plan_time = t
        if record and t - measured_at > self.recovery.stale_after:
            # solved from a measurement older than the ladder calls a plan stale (the cold solve of a
            # standby that took over, or after a stall): not followed, the next update's is. A trot took
            # such a plan 0.17 s after its measurement, from the last plan, and fell 0.18 s later.
            self.received.stale_plans += 1
        else:
            self._plan = plan
            self.follower.new_plan(t, measured_at)
        if self._cold_hold and record:  # the cold solve is out: plans measured from now on take it back
            self._cold_hold = False
            self.follower.hold(t, "mpc", None)
        if record:
            self.received.latencies.append(t - measured_at)
            self.received.start_times.append(measured_at)
            self.received.update_times.append(wall)
        restarting = self._restarting
        if restarting is not None:
            restarting["first_plan_at"] = round(float(t), 6)
            restarting["restart_s"] = round(float(t - restarting["t"]), 6)
            self._restarting = None
            self._standby_due = t + STANDBY_AFTER
            self._scheme = "rti" if self._control.array[ControlBlock.RTI] == 1.0 else "one_phase"
            self._event(t, "mpc_restarted", f"first plan {restarting['restart_s']:.2f} s after the restart")
        elif self._stalled_at is not None:
            self._event(t, "mpc_resumed", f"a plan again, {t - self._stalled_at:.2f} s after the stall")
            self._stalled_at = None

    def _read_results(self) -> None:
        """Take every message the process has sent so far (never blocks)."""
        with contextlib.suppress(OSError, ValueError, EOFError):
            while self._results.poll(0):
                if not self._receive():
                    break

    def _receive(self) -> bool:
        """Take one message from the process; ``False`` once its end of the pipe is closed."""
        try:
            kind, payload = self._results.recv()
        except (EOFError, OSError):
            return False
        if kind == "statistics":
            self.worker_statistics = payload
        elif kind == "compilation":
            self.worker_compilation = payload
        elif kind == "error":
            self.worker_error = payload
        return True
