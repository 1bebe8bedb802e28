"""A deployment: the controller on a robot behind a ``RobotInterface``, from lying on the floor to lying
again.

``Deployment(interface, controller, settings).run()`` goes through the sequence a robot needs:

1. **wait** for the first state (``state_timeout``), then measure the link over ``link_window``;
2. **check** it (``deploy.startup``): link rate, joints inside their ranges, trunk upright. A refusal is one
   ``StartupRefused`` line and nothing was commanded. ``dry_run`` stops here;
3. **stand up** slowly from where the robot lies to the standing pose (motor PD, the robot file's
   ``hardware.stance_kp``/``stance_kd``, a smooth ramp over ``stand_duration``), then **hold** it;
4. **start the MPC** (``Controller.reset``: its own process and its cold solve) while the stance holds, and
   hand over from the stance's PD to the MPC's torques over ``blend_duration``;
5. **run** the MPC for ``duration`` s (or until interrupted), one command per control period (a link loss
   and the MPC's restart after it do not count);
6. **lie down** to the robot file's ``hardware.lying_pose`` and **damp** the motors.

Safety, on every tick: every command goes through ``deploy.limits.CommandLimiter`` (gains, positions, rates,
torques, rate of change). A state older than ``stale_after`` (link loss) puts the robot in the **damped
stance** (motor PD holding the standing pose: the motors run it on their own encoders, with no state needed);
once states flow again for ``resume_after`` s the MPC starts again from the robot's state (a new cold solve,
the stance holding meanwhile); after ``max_link_loss`` s without a state the robot lies down. A trunk
tilted beyond ``fall_tilt`` is a fall: the motors only damp, then the deployment ends. A failed MPC process
(``Controller.failure``) holds the stance and lies the robot down. ``stop()`` (Ctrl-C, SIGTERM) ends the
MPC phase early and lies the robot down.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from cafe_mpc.api import Controller
from cafe_mpc.control.scheduling import RealTimePriority, lock_memory, unlock_memory
from cafe_mpc.deploy.limits import CommandLimiter
from cafe_mpc.deploy.settings import DeploySettings
from cafe_mpc.deploy.startup import StartupRefused, check_joints, check_link, check_upright, tilt_of
from cafe_mpc.robot_io.interface import JointCommand, RobotInterface, RobotState

logger = logging.getLogger(__name__)

LATENESS_WINDOW = 30_000
STATE_LEAD = 0.1
"""Periods before a state is expected that a state-synchronised tick starts waiting for it."""
STATE_WAIT = 0.5
"""Periods past a tick's time that a state-synchronised tick waits for the next state before it runs on
the newest one it has (a state lost or late)."""
STATE_POLL = 1e-4
"""s between two looks for the next state while a state-synchronised tick waits."""
"""Ticks whose lateness the report summarises (the last minute at 500 Hz: a long run keeps no more)."""


@dataclass
class DeploymentReport:
    """What a deployment did (``Deployment.run``); ``outcome``: ``completed``, ``dry-run``, ``stopped``
    (interrupted, lay down), ``fell``, ``mpc-failed`` or ``link-lost`` (the link did not come back)."""

    outcome: str = "running"
    message: str = ""
    phases: list[tuple[str, float]] = field(default_factory=list)
    """(phase, start time s from the first state) in order."""
    ticks: int = 0
    late_ticks: int = 0
    """Ticks that started more than half a period late."""
    lateness_ms_p50: float | None = None
    lateness_ms_p99: float | None = None
    """How late the ticks started (median, 99th percentile) over the last ``LATENESS_WINDOW`` ticks."""
    tick_cpu_ms_p50: float | None = None
    tick_cpu_ms_p99: float | None = None
    """CPU time of a tick's work (read, command, limits, write; the loop's thread only), same ticks: what
    the loop needs of a core, whatever else the machine runs."""
    mpc_ticks: int = 0
    link_losses: int = 0
    """Times the link went stale (the damped stance was entered)."""
    mpc_starts: int = 0
    link: dict = field(default_factory=dict)
    clamps: dict = field(default_factory=dict)
    mpc: dict = field(default_factory=dict)
    scheduling: str = "normal"
    """The loop thread's scheduling class (``control.scheduling.RealTimePriority``)."""
    memory: str = "not locked"
    """Whether the deployment's memory was locked (``control.scheduling.lock_memory``)."""

    def as_dict(self) -> dict:
        return {
            "outcome": self.outcome,
            "message": self.message,
            "phases": self.phases,
            "ticks": self.ticks,
            "late_ticks": self.late_ticks,
            "lateness_ms_p50": self.lateness_ms_p50,
            "lateness_ms_p99": self.lateness_ms_p99,
            "tick_cpu_ms_p50": self.tick_cpu_ms_p50,
            "tick_cpu_ms_p99": self.tick_cpu_ms_p99,
            "mpc_ticks": self.mpc_ticks,
            "link_losses": self.link_losses,
            "mpc_starts": self.mpc_starts,
            "link": self.link,
            "clamps": self.clamps,
            "mpc": self.mpc,
            "scheduling": self.scheduling,
            "memory": self.memory,
        }


class _Fell(Exception):
    """The trunk tilted beyond ``fall_tilt``."""


class Deployment:
    """The controller on ``interface`` (module docstring). ``controller``: a ``cafe_mpc.Controller`` in
    ``process`` mode, built for the interface's robot; ``say``: where progress lines go."""

    def __init__(
        self,
        interface: RobotInterface,
        controller: Controller,
        settings: DeploySettings | None = None,
        say: Callable[[str], None] = print,
    ) -> None:
        robot = controller.robot
        if robot.hardware is None:
            raise ValueError(
                f"robot {robot.name!r} has no hardware section in its robot file (docs/deploy.md)"
            )
        if interface.n_joints != robot.nu:
            raise ValueError(
                f"the interface has {interface.n_joints} joints, robot {robot.name!r} {robot.nu}"
            )
        self.interface = interface
        self.controller = controller
        self.robot = robot
        self.settings = settings or DeploySettings()
        self.say = say
        self.period = controller.control_period
        self.limiter = CommandLimiter(robot, self.settings, self.period)
        self.report = DeploymentReport()
        self._priority: RealTimePriority | None = None
        self.standing = np.array(robot.q_standing[7:], dtype=float)
        self.lying = np.array(robot.hardware.lying_pose, dtype=float)
        self._command = JointCommand.zeros(robot.nu)
        self._stop = threading.Event()
        self._start_time = 0.0
        self._next_tick: float | None = None
        self._last_sequence = -1
        self._lateness: deque[float] = deque(maxlen=LATENESS_WINDOW)
        self._cpu: deque[float] = deque(maxlen=LATENESS_WINDOW)

    # ------------------------------------------------------------------------------------- control
    def stop(self) -> None:
        """End the MPC phase at the next tick and lie the robot down (safe from a signal handler)."""
        self._stop.set()

    def run(self, dry_run: bool = False) -> DeploymentReport:
        """The whole sequence (module docstring). ``StartupRefused`` when a start-up check fails (nothing
        commanded); otherwise the report says how it ended."""
        report = self.report
        with self.interface:
            try:
                state = self._wait_and_check()
                if dry_run:
                    report.outcome = "dry-run"
                    report.message = "checks passed; nothing commanded"
                    return report
                self._real_time()
                self._stand_up(state)
                if self._hold(self.settings.hold_duration) and self._start_mpc():
                    self._run_mpc()
                if self._stop.is_set() and report.outcome == "running":
                    report.outcome, report.message = "stopped", "stopped: lying down"
                if report.outcome in ("running", "stopped", "mpc-failed", "link-lost"):
                    self._lie_down()
            except _Fell:
                report.outcome = "fell"
                report.message = "the trunk tilted beyond fall_tilt: motors damped"
                self._damp(self.settings.damp_duration)
            except StartupRefused:
                raise
            except KeyboardInterrupt:  # no signal handler (the command line has one): lie down all the same
                report.outcome, report.message = "stopped", "interrupted: lying down"
                if report.ticks:
                    self._lie_down()
            except Exception as error:  # a bug or a broken link mid-run: damp the motors, then report it
                report.outcome = "error"
                report.message = f"{type(error).__name__}: {error}"
                if report.ticks:
                    self._damp_safely()
                raise
            finally:
                if self._priority is not None:
                    self._priority.release()
                if self.report.memory == "locked":
                    unlock_memory()
                self._finish()
        return report

    def _real_time(self) -> None:
        """Against a wall clock: the loop's thread at real-time priority and the memory locked
        (``control.scheduling``), where the OS allows it; the report says what it got. Nothing in simulated
        time (a loop that never sleeps must not hold a real-time class)."""
        settings, report = self.settings, self.report
        if not getattr(self.interface.clock, "realtime", False):
            return
        report.memory = lock_memory() if settings.lock_memory else "not locked (off)"
        self._priority = RealTimePriority(settings.realtime_priority)
        self._priority.acquire()
        report.scheduling = self._priority.description

    # ------------------------------------------------------------------------------------ start-up
    def _wait_and_check(self) -> RobotState:
        settings, interface = self.settings, self.interface
        clock = interface.clock
        self._phase("wait")
        deadline = clock.now() + settings.state_timeout
        state = interface.read()
        while state is None:
            if clock.now() > deadline:
                raise StartupRefused(
                    f"no state from the robot within {settings.state_timeout:.1f} s on {self._where()}"
                )
            clock.sleep_until(clock.now() + 0.002)
            state = interface.read()
        window_end = clock.now() + settings.link_window
        while clock.now() < window_end:  # states are counted as they are taken: take them as they come
            clock.sleep_until(clock.now() + 0.5 * self.period)
            interface.read()
        self._phase("check")
        health = interface.health()
        check_link(health, settings.min_link_rate_hz, self._where())
        state = interface.read()
        check_joints(state, self.robot, settings.joint_range_tolerance)
        check_upright(state, settings.max_start_tilt)
        self.say(f"robot state: {health.describe()}; joints in range; trunk upright")
        return state

    def _where(self) -> str:
        where = getattr(self.interface, "where", None)
        return where() if callable(where) else type(self.interface).__name__

    # ------------------------------------------------------------------------------------ the ticks
    def _tick(self, command_of: Callable[[float, RobotState, bool], JointCommand | None]) -> bool:
        """One control tick: wait for it, read the state, ask ``command_of(t, state, stale)`` for the
        command, hold it to the limits and send it. False when ``command_of`` returned None (phase over).

        Against a wall clock with ``sync_to_state`` the tick starts when the robot's next state arrives
        (``_wait_for_state``) and the next one is scheduled a period after that arrival: the loop locks
        onto the robot's clock, so that a command answers the newest state at once instead of up to a
        period later (a free-running loop's phase against the robot's is arbitrary)."""
        clock = self.interface.clock
        if self._next_tick is None:
            self._next_tick = clock.now()
        clock.sleep_until(self._next_tick)
        synced = self.settings.sync_to_state and clock.realtime
        scheduled = self._next_tick + (STATE_LEAD * self.period if synced else 0.0)
        state = self._wait_for_state() if synced else self.interface.read()
        now = clock.now()
        lateness = max(now - scheduled, 0.0)
        self._lateness.append(lateness)
        if lateness > 0.5 * self.period:
            self.report.late_ticks += 1
        if synced and state.sequence != self._last_sequence:
            self._next_tick = max(state.received + (1.0 - STATE_LEAD) * self.period, now)
        else:
            self._next_tick = max(self._next_tick + self.period, now - 0.5 * self.period)
        self._last_sequence = state.sequence
        cpu_start = time.thread_time()
        stale = now - state.received > self.settings.stale_after
        command = command_of(now, state, stale)
        if command is None:
            return False
        readings = state.readings
        self.limiter.apply(command, readings.joint_positions, readings.joint_velocities)
        self.interface.write(command)
        self.report.ticks += 1
        self._cpu.append(time.thread_time() - cpu_start)
        return True

    def _wait_for_state(self) -> RobotState:
        """The robot's next state, or the newest one after ``STATE_WAIT`` periods past the tick (a state
        lost or late: the tick runs on what it has, and the stale check sees its age)."""
        interface = self.interface
        clock = interface.clock
        deadline = self._next_tick + STATE_WAIT * self.period
        state = interface.read()
        while state.sequence == self._last_sequence and clock.now() < deadline:
            clock.sleep_until(clock.now() + STATE_POLL)
            state = interface.read()
        return state

    def _check_fall(self, state: RobotState, stale: bool) -> None:
        if not stale and tilt_of(state.readings.orientation) > self.settings.fall_tilt:
            raise _Fell()

    def _stance(self, target: np.ndarray, scale: float = 1.0) -> JointCommand:
        spec = self.robot.hardware
        return self._command.set(q=target, kp=scale * spec.stance_kp, kd=scale * spec.stance_kd)

    def _move(self, start: np.ndarray, goal: np.ndarray, duration: float, phase: str) -> None:
        """The stance PD's target from ``start`` to ``goal`` over ``duration`` (smooth: zero rate at both
        ends)."""
        self._phase(phase)
        clock = self.interface.clock
        t0 = clock.now()
        target = np.empty_like(start)

        def command_of(now: float, state: RobotState, stale: bool) -> JointCommand | None:
            s = min((now - t0) / duration, 1.0)
            if s >= 1.0:
                return None
            self._check_fall(state, stale)
            blend = 0.5 - 0.5 * np.cos(np.pi * s)
            np.multiply(goal - start, blend, out=target)
            np.add(target, start, out=target)
            return self._stance(target)

        while self._tick(command_of):
            pass

    def _stand_up(self, state: RobotState) -> None:
        start = np.array(state.readings.joint_positions)
        self.limiter.reset()
        self._move(start, self.standing, self.settings.stand_duration, "stand")

    def _hold(self, duration: float, until: Callable[[], bool] | None = None) -> bool:
        """Hold the damped stance for ``duration`` (or until ``until()``); False if stopped meanwhile."""
        self._phase("hold")
        clock = self.interface.clock
        t0 = clock.now()

        def command_of(now: float, state: RobotState, stale: bool) -> JointCommand | None:
            done = until() if until is not None else now - t0 >= duration
            if done or self._stop.is_set():
                return None
            self._check_fall(state, stale)
            return self._stance(self.standing)

        while self._tick(command_of):
            pass
        return not self._stop.is_set()

    def _start_mpc(self) -> bool:
        """Start the MPC (its process and cold solve, in a thread) while the stance holds. False if it
        failed or the deployment was stopped meanwhile."""
        self._phase("mpc-start")
        controller = self.controller
        state = self.interface.read()
        readings = state.readings
        t = self.interface.clock.now()
        controller.reset_estimator()
        measurement = controller.measurement_from_sensors(
            t,
            readings.orientation,
            readings.gyro,
            readings.accelerometer,
            readings.joint_positions,
            readings.joint_velocities,
            readings.joint_torques,
        )
        error: list[BaseException] = []

        def start() -> None:
            try:
                controller.reset(measurement, t)
            except BaseException as failure:  # reported by the main thread
                error.append(failure)

        if self.interface.clock.realtime:  # the stance holds the robot while the MPC starts
            starter = threading.Thread(target=start, name="mpc-start", daemon=True)
            starter.start()
            self._hold(float("inf"), until=lambda: not starter.is_alive())
            starter.join()
        else:  # simulated time stands still meanwhile
            start()
        if error:
            self.report.outcome = "mpc-failed"
            self.report.message = f"the MPC did not start: {error[0]}"
            self.say(self.report.message)
            return False
        if self._stop.is_set():
            return False
        controller.restart_clock(self.interface.clock.now())
        controller.reset_estimator()
        self.report.mpc_starts += 1
        return True

    def _run_mpc(self) -> None:
        """The MPC phase (module docstring), until ``duration`` or ``stop``."""
        settings, controller, report = self.settings, self.controller, self.report
        self._phase("mpc")
        self.say("MPC running")
        clock = self.interface.clock
        duration = (
            settings.duration if settings.duration is not None else controller.config.simulation.duration
        )
        t_end = clock.now() + duration if duration and duration > 0 else float("inf")
        hardware = self.robot.hardware
        blend_start = clock.now()
        suspended_since: float | None = None
        healthy_since: float | None = None

        def command_of(now: float, state: RobotState, stale: bool) -> JointCommand | None:
            nonlocal suspended_since, healthy_since
            if self._stop.is_set() or (suspended_since is None and now >= t_end):
                return None
            if stale and suspended_since is not None and now - suspended_since > settings.max_link_loss:
                report.outcome = "link-lost"
                report.message = f"no state for {settings.max_link_loss:.1f} s: lying down"
                return None
            if stale:
                if suspended_since is None:
                    suspended_since = now
                    report.link_losses += 1
                    self.say(
                        f"link lost: newest state {1e3 * (now - state.received):.0f} ms old: damped stance"
                    )
                healthy_since = None
                return self._stance(self.standing)
            self._check_fall(state, stale)
            if suspended_since is not None:
                healthy_since = now if healthy_since is None else healthy_since
                if now - healthy_since < settings.resume_after:
                    return self._stance(self.standing)
                return None  # the link is back: restart the MPC (below)
            if controller.failure is not None:
                report.outcome = "mpc-failed"
                report.message = controller.failure
                return None
            readings = state.readings
            measurement = controller.measurement_from_sensors(
                now,
                readings.orientation,
                readings.gyro,
                readings.accelerometer,
                readings.joint_positions,
                readings.joint_velocities,
                readings.joint_torques,
            )
            torques = controller.compute(now, measurement)
            report.mpc_ticks += 1
            weight = (
                min((now - blend_start) / settings.blend_duration, 1.0) if settings.blend_duration else 1.0
            )
            command = self._command
            command.set(
                q=self.standing if weight < 1.0 else readings.joint_positions,
                dq=0.0 if weight < 1.0 else readings.joint_velocities,
                kp=(1.0 - weight) * hardware.stance_kp,
                kd=(1.0 - weight) * hardware.stance_kd + weight * settings.mpc_kd,
                tau=weight * torques,
            )
            return command

        while True:
            while self._tick(command_of):
                pass
            if suspended_since is None or self._stop.is_set() or report.outcome != "running":
                break
            self.say("link back: restarting the MPC from the robot's state")
            if not self._start_mpc():
                break
            self._phase("mpc")
            self.say("MPC running")
            t_end += clock.now() - suspended_since  # ``duration`` counts the time under the MPC
            suspended_since = healthy_since = None
            blend_start = clock.now()
        if self._stop.is_set() and report.outcome == "running":
            report.outcome = "stopped"
            report.message = "stopped: lying down"

    def _lie_down(self) -> None:
        start = np.array(self.interface.read().readings.joint_positions)
        self.limiter.reset()
        self._move(start, self.lying, self.settings.lie_duration, "lie")
        self._damp(self.settings.damp_duration)
        if self.report.outcome == "running":
            self.report.outcome = "completed"

    def _damp(self, duration: float) -> None:
        """Motor damping only (no stiffness, no torque) for ``duration``."""
        self._phase("damp")
        clock = self.interface.clock
        t0 = clock.now()
        kd = self.robot.hardware.stance_kd

        def command_of(now: float, state: RobotState, stale: bool) -> JointCommand | None:
            if now - t0 >= duration:
                return None
            return self._command.set(q=state.readings.joint_positions, kd=kd)

        self.limiter.reset()
        while self._tick(command_of):
            pass

    def _damp_safely(self) -> None:
        """Motor damping after an error, as far as the interface still allows."""
        try:
            self._damp(self.settings.damp_duration)
        except Exception:  # the interface itself failed: the motors keep the last command
            logger.exception("could not damp the motors after an error")

    # -------------------------------------------------------------------------------------- records
    def _phase(self, name: str) -> None:
        now = self.interface.clock.now()
        if not self.report.phases:
            self._start_time = now
        self.report.phases.append((name, round(now - self._start_time, 3)))
        logger.info("deploy: %s", name)

    def _finish(self) -> None:
        report = self.report
        if self._lateness:
            lateness = np.asarray(self._lateness) * 1e3
            report.lateness_ms_p50 = float(np.median(lateness))
            report.lateness_ms_p99 = float(np.percentile(lateness, 99))
        if self._cpu:
            cpu = np.asarray(self._cpu) * 1e3
            report.tick_cpu_ms_p50 = float(np.median(cpu))
            report.tick_cpu_ms_p99 = float(np.percentile(cpu, 99))
        health = self.interface.health()
        report.link = {
            "rate_hz": health.rate_hz,
            "received": health.received,
            "lost": health.lost,
            "rejected": health.rejected,
            "crc_errors": health.crc_errors,
        }
        report.clamps = dict(self.limiter.clamps)
        if report.mpc_starts:
            report.mpc = self.controller.statistics()
