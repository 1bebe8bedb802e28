"""Closed-loop simulation: a controller called at a fixed rate around a plant (``sim.plant.Plant``).

The controller sees what the plant's sensors give it (``Plant.sensors``: the state, perturbed or not, as a
``Measurement``, or the robot's sensor readings) and returns joint torques, which are held (zero-order
hold) until its next call. Push disturbances are world-frame forces on the base over time intervals. Every
control tick is logged into preallocated arrays; the log records the plant's true state. The plant comes
built (its scene, variation and sensors: ``sim.assembly.build_plant`` for a run config); what the loop does
to it is a ``SimulationOptions``. ``Simulation`` keeps its log when the run ends early, by an error or
Ctrl-C: ``simulation.log`` then holds every tick simulated (a run's record up to that point).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from cafe_mpc.control.scheduling import (
    RealTimePriority,
    host_steal_seconds,
    lock_memory,
    unlock_memory,
    usable_cpus,
)
from cafe_mpc.core.compilation import CompileWatch
from cafe_mpc.core.controller import Controller
from cafe_mpc.core.progress import stage
from cafe_mpc.core.sensors import SensorReadings
from cafe_mpc_lab.sim.plant import Plant

logger = logging.getLogger(__name__)

INTERRUPT = threading.Event()
"""Set by the command line's SIGINT handler (Ctrl-C), cleared when the interrupt is handled: the closed loop
raises ``KeyboardInterrupt`` at its next tick while it is set. The handler raises it too, but a SIGINT that
lands while numba compiles or loads a kernel is swallowed in llvmlite's ctypes callback ("Exception ignored
on calling ctypes callback function"), and the run went on to its end."""


class SensorController(Protocol):
    """A controller fed by sensor readings (``estimation.controller.SensingController``): ``reset()`` once,
    then ``compute(t, readings)`` at the control rate."""

    def reset(self) -> None: ...

    def compute(self, t: float, readings: SensorReadings) -> np.ndarray: ...


class ControllerError(RuntimeError):
    """A controller returned something that cannot be sent to the motors (wrong size, NaN)."""


class Observer(Protocol):
    """Watches the plant during a run (``sim.viewer.LiveViewer``): ``start(plant)`` once before the first
    tick, ``update(t, plant)`` after every control tick; ``update`` returning False ends the run early
    (``stop_reason`` says why, e.g. the viewer window was closed)."""

    stop_reason: str

    def start(self, plant: Plant) -> None: ...

    def update(self, t: float, plant: Plant) -> bool: ...


@dataclass(frozen=True)
class Push:
    """A world-frame force (N) on the base during ``[start, start + duration)`` seconds."""

    start: float
    duration: float
    force: tuple[float, float, float]

    def active(self, t: float) -> bool:
        return self.start <= t < self.start + self.duration


@dataclass
class SimulationLog:
    """States, torques and contact forces at every control tick (rows), trimmed to ``ticks``."""

    time: np.ndarray
    q: np.ndarray
    v: np.ndarray
    torque_command: np.ndarray
    torque_applied: np.ndarray
    foot_forces: np.ndarray
    contacts: np.ndarray
    external_force: np.ndarray
    ticks: int = 0
    fell: bool = False
    fall_time: float | None = None
    fall_reason: str = ""
    wall_time: float = 0.0
    extra: dict = field(default_factory=dict)
    sampled: dict[str, np.ndarray] = field(default_factory=dict)
    """Arrays recorded at their own rate rather than per tick (the height maps, ``sim.height_map``), with
    their own times; saved whole in ``log.npz`` as ``sampled_<name>``."""

    @classmethod
    def allocate(cls, ticks: int, nq: int, nv: int, nu: int, n_feet: int) -> SimulationLog:
        return cls(
            time=np.zeros(ticks),
            q=np.zeros((ticks, nq)),
            v=np.zeros((ticks, nv)),
            torque_command=np.zeros((ticks, nu)),
            torque_applied=np.zeros((ticks, nu)),
            foot_forces=np.zeros((ticks, n_feet, 3)),
            contacts=np.zeros((ticks, n_feet), dtype=bool),
            external_force=np.zeros((ticks, 3)),
        )

    def trimmed(self) -> SimulationLog:
        n = self.ticks
        return SimulationLog(
            self.time[:n],
            self.q[:n],
            self.v[:n],
            self.torque_command[:n],
            self.torque_applied[:n],
            self.foot_forces[:n],
            self.contacts[:n],
            self.external_force[:n],
            n,
            self.fell,
            self.fall_time,
            self.fall_reason,
            self.wall_time,
            self.extra,
            self.sampled,
        )

    def save(self, path: str) -> None:
        """Write the log as a compressed ``.npz`` file (per-tick arrays of ``extra`` as ``extra_<name>``, the
        ``sampled`` arrays as ``sampled_<name>``)."""
        extras = {
            f"extra_{name}": value[: self.ticks]
            for name, value in self.extra.items()
            if isinstance(value, np.ndarray) and value.ndim >= 1 and len(value) >= self.ticks
        }
        sampled = {f"sampled_{name}": value for name, value in self.sampled.items()}
        np.savez_compressed(
            path,
            **extras,
            **sampled,
            time=self.time[: self.ticks],
            q=self.q[: self.ticks],
            v=self.v[: self.ticks],
            torque_command=self.torque_command[: self.ticks],
            torque_applied=self.torque_applied[: self.ticks],
            foot_forces=self.foot_forces[: self.ticks],
            contacts=self.contacts[: self.ticks],
            external_force=self.external_force[: self.ticks],
        )


@dataclass(frozen=True)
class FallCriteria:
    """When the run counts as a fall: base too low, tilted too far, or the trunk hit the floor.

    ``ground_height(x, y)``: the height the base's height is measured from, the terrain under it with gaps
    bridged (``sim.terrain.support_height``); None: the floor at 0."""

    min_base_height: float = 0.10
    max_tilt_rad: float = 1.2  # angle between base z axis and world z
    ground_height: Callable[[float, float], float] | None = None

    def reason(self, q: np.ndarray, trunk_touched_floor: bool) -> str:
        """Why the robot at ``q`` counts as fallen ("" when it does not): its base too low, tilted too far,
        or its trunk on the ground (``trunk_touched_floor``)."""
        if self.ground_height is None:
            if q[2] < self.min_base_height:
                return f"base height {q[2]:.3f} m below {self.min_base_height} m"
        else:
            ground = self.ground_height(float(q[0]), float(q[1]))
            if q[2] - ground < self.min_base_height:
                return (
                    f"base {q[2] - ground:.3f} m above the terrain under it (at {ground:.3f} m), below "
                    f"{self.min_base_height} m"
                )
        if base_tilt(q) > self.max_tilt_rad:
            return f"base tilt {base_tilt(q):.2f} rad above {self.max_tilt_rad} rad"
        if trunk_touched_floor:
            return "trunk touched the floor"
        return ""


def base_tilt(q: np.ndarray) -> float:
    """Angle (rad) between the base's z axis and the world z axis, from the quaternion (x, y, z, w)."""
    x, y = q[3], q[4]
    z_axis_z = 1.0 - 2.0 * (x * x + y * y)
    return float(np.arccos(np.clip(z_axis_z, -1.0, 1.0)))


@dataclass(frozen=True)
class SimulationOptions:
    """What ``simulate`` does with a plant: how long, how often the controller runs, where the robot starts,
    the pushes, when it counts as a fall, and the run's companions.

    ``initial_q``/``initial_v``: the start state (None: the robot's standing pose, at rest). ``fall``: None
    never checks. ``progress(dt)``: called after each tick with the simulated time it advanced. ``pacer``:
    run against the wall clock (tick ``k`` starts ``k / control_rate_hz`` seconds after the clock starts;
    ``WallClockPacer``), the real-time mode; without it the simulation runs as fast as it can. ``stop(t)``:
    end the run early when it returns true (checked after each tick). ``observer``: watches the plant after
    every tick (the live viewer) and may end the run early. ``before_tick(t)``: called at the start of each
    tick, before the plant is read (fault injection, ``sim.faults``).
    """

    duration: float
    control_rate_hz: float = 500.0
    initial_q: np.ndarray | None = None
    initial_v: np.ndarray | None = None
    pushes: tuple[Push, ...] = ()
    fall: FallCriteria | None = FallCriteria()
    stop_on_fall: bool = True
    progress: Callable[[float], None] | None = None
    pacer: WallClockPacer | None = None
    stop: Callable[[float], bool] | None = None
    observer: Observer | None = None
    before_tick: Callable[[float], None] | None = None

    def __post_init__(self) -> None:
        if not self.duration > 0:
            raise ValueError(f"duration must be positive, got {self.duration}")
        if not self.control_rate_hz > 0:
            raise ValueError(f"control rate must be positive, got {self.control_rate_hz}")
        object.__setattr__(self, "pushes", tuple(self.pushes))
        for push in self.pushes:
            if push.duration <= 0 or push.start < 0 or not np.all(np.isfinite(push.force)):
                raise ValueError(f"invalid push {push}: start >= 0, duration > 0 and a finite force required")


def simulate(
    plant: Plant, controller: Controller | SensorController, options: SimulationOptions
) -> SimulationLog:
    """Run ``controller`` on ``plant`` for ``options.duration`` seconds of simulated time (``Simulation``)."""
    return Simulation(plant, controller, options).run()


class Simulation:
    """One closed-loop run of ``controller`` on ``plant`` (``run``).

    The controller gets what ``plant.sensors`` measure (a ``SensorController`` when they are the robot's
    sensor readings, ``sim.sensors.SensorSuite``); their summary goes into the log's ``extra``. With a bar
    in the plant's scene (``sim.bar``) the log's ``extra`` holds ``bar_contact`` (per tick: a robot geom
    touched it) and ``bar`` (``touched_by``: those geoms). A plant with a height-map sensor
    (``Plant.height_map``) measures its maps at their rate; each goes to the controller with the readings of
    its tick (``height_map``: relative to the base, ``HeightMapSensor.relative``) and the log's ``sampled``
    holds them (world frame). Kernels
    compiled once the run proper has started are in the log's ``extra["compilation"]``
    (``core.compilation``). ``log``: None before ``run``; after it returns or raises, the log of every tick
    simulated.
    """

    def __init__(
        self, plant: Plant, controller: Controller | SensorController, options: SimulationOptions
    ) -> None:
        self.plant = plant
        self.controller = controller
        self.options = options
        self.log: SimulationLog | None = None
        self.compiles = CompileWatch()

    def run(self) -> SimulationLog:
        plant, controller, options = self.plant, self.controller, self.options
        robot = plant.robot
        control_period = 1.0 / options.control_rate_hz
        substeps = round(control_period / plant.timestep)
        if substeps < 1 or abs(substeps * plant.timestep - control_period) > 1e-9:
            raise ValueError(
                f"control period {control_period} s must be a whole multiple of the plant step "
                f"{plant.timestep} s"
            )
        sensors, height_maps = plant.sensors, plant.height_map
        plant.reset(robot.q_standing if options.initial_q is None else options.initial_q, options.initial_v)
        if options.observer is not None:
            options.observer.start(plant)
        controller.reset()
        sensors.reset()
        if height_maps is not None:
            height_maps.reset()
        ticks = round(options.duration * options.control_rate_hz)
        log = SimulationLog.allocate(ticks, robot.nq, robot.nv, robot.nu, robot.n_feet)
        bar_contact = np.zeros(ticks, dtype=bool)
        if plant.bar is not None:  # sim.bar: which ticks a robot geom touched the bar (extra_bar_contact)
            log.extra["bar_contact"] = bar_contact
        if options.pacer is not None:
            options.pacer.start(control_period, ticks)
        start_wall = time.perf_counter()
        try:
            self._ticks(log, bar_contact, ticks, control_period, substeps)
        finally:
            self.compiles.stop()
            log.wall_time = time.perf_counter() - start_wall
            if options.pacer is not None:
                log.extra["realtime"] = options.pacer.summary(log.ticks)
            log.extra.update(sensors.log_extra())
            log.extra["compilation"] = self.compiles.summary()
            if height_maps is not None:
                log.sampled.update(height_maps.log_arrays())
            if plant.bar is not None:
                log.extra["bar"] = {"touched_by": plant.bar_touched_by()}
            self.log = log.trimmed()
        return self.log

    def _ticks(
        self, log: SimulationLog, bar_contact: np.ndarray, ticks: int, control_period: float, substeps: int
    ) -> None:
        plant, controller, options = self.plant, self.controller, self.options
        robot = plant.robot
        fall, pacer, observer = options.fall, options.pacer, options.observer
        progress, stop, before_tick = options.progress, options.stop, options.before_tick
        sensors, height_maps = plant.sensors, plant.height_map
        external = np.zeros(3)
        for tick in range(ticks):
            t = tick * control_period
            if INTERRUPT.is_set():
                raise KeyboardInterrupt
            if pacer is not None:
                pacer.wait(tick)
            if before_tick is not None:
                before_tick(t)
            state = plant.read_state()
            height_map = height_maps.observe(t, state.q) if height_maps is not None else None
            measured = sensors.measure(tick, plant, state)
            # a new map goes with this tick's readings, as the trunk's sensor sees it: relative to the base
            measured.height_map = None if height_map is None else height_maps.relative(height_map, state.q)
            if pacer is not None:
                pacer.mark(tick, TickPart.SENSE)
            torques = np.asarray(controller.compute(t, measured), dtype=float)  # type: ignore[arg-type]
            if pacer is not None:
                pacer.mark(tick, TickPart.CONTROL)
            if torques.shape != (robot.nu,) or not np.all(np.isfinite(torques)):
                raise ControllerError(f"controller returned invalid torques at t = {t:.3f} s: {torques}")
            external[:] = 0.0
            for push in options.pushes:
                if push.active(t):
                    external += push.force
            plant.set_external_force(external)
            log.time[tick] = t
            log.q[tick] = state.q
            log.v[tick] = state.v
            log.contacts[tick] = state.contacts
            log.foot_forces[tick] = state.foot_forces
            log.torque_command[tick] = torques
            log.torque_applied[tick] = plant.applied(torques)
            log.external_force[tick] = external
            if plant.bar is not None:
                bar_contact[tick] = plant.bar_in_contact
            log.ticks = tick + 1
            if fall is not None and not log.fell:
                reason = fall.reason(state.q, plant.trunk_touched_floor)
                if reason:
                    log.fell, log.fall_time, log.fall_reason = True, t, reason
                    logger.warning("robot fell at t = %.3f s: %s", t, reason)
                    if options.stop_on_fall:
                        break
            plant.step(torques, substeps)
            if pacer is not None:
                pacer.mark(tick, TickPart.STEP)
            if tick == 0:  # the first tick ran the cold solve (and the warm-up): the run proper starts now
                stage(f"running {options.duration:g} s of simulated time")
                self.compiles.start()
            if progress is not None:
                progress(control_period)
            if stop is not None and stop(t):
                break
            if observer is not None and not observer.update(t + control_period, plant):
                logger.warning("run stopped at t = %.3f s: %s", t + control_period, observer.stop_reason)
                break


class TickPart:
    """The parts of a control tick whose wall time ``WallClockPacer.mark`` records (column indices)."""

    SENSE = 0
    """Reading the plant's state and the sensors (from the tick's start)."""
    CONTROL = 1
    """The controller: estimator, plan lookup, low level (from the end of SENSE)."""
    STEP = 2
    """Logging and the plant's MuJoCo steps (from the end of CONTROL)."""
    NAMES = ("sense", "control", "step")


class WallClockPacer:
    """Starts each control tick at its wall-clock time and records how late each tick started.

    Sleeps until shortly before the tick (``spin``), then spins: ``time.sleep`` alone overshoots, and a busy
    machine wakes a sleeping process late by a millisecond or more (measured: with a 0.4 ms spin window, 1-8
    of 5000 ticks started 1.5-5.7 ms late while the MPC process ran on the other core). With ``priority``
    (1-99) and two CPUs or more, the loop's thread runs in ``SCHED_FIFO``
    (``control.scheduling.RealTimePriority``) where the OS allows it: no ordinary thread on its core preempts
    it, it wakes on time from a short sleep, and it spins only ``fifo_spin`` (a real-time thread that never
    sleeps is throttled by Linux). With ``lock_pages`` the process's memory is locked for the run
    (``control.scheduling.lock_memory``: no page faults in bursts of slow ticks on a machine that reclaims
    idle pages). The schedule starts after
    tick 0, which runs the controller's first step (``first_tick_ms``). A tick that starts more than
    ``miss_threshold`` after its slot counts as missed; the simulation still advances one control period
    per tick (the plant is not slowed down to hide it). ``work`` records how long each tick's own work took,
    which tells a tick that was too slow from a process that was not scheduled. Python's garbage collector
    is paused during the run (``gc.freeze`` keeps the objects made during set-up out of later collections).
    """

    def __init__(
        self,
        miss_threshold: float = 0.001,
        spin: float = 0.0015,
        priority: int = 0,
        fifo_spin: float = 0.0003,
        lock_pages: bool = False,
    ) -> None:
        self.miss_threshold = miss_threshold
        self.spin = spin
        self.fifo_spin = fifo_spin
        self.priority = RealTimePriority(priority)
        self.lock_pages = lock_pages
        self.memory = "not locked (off)"
        self.lateness = np.zeros(0)
        self.first_tick = 0.0
        """Wall time of tick 0 (the controller's first step), s: before the schedule starts."""
        self._period = 0.0
        self._start = 0.0
        self._spin = spin
        self._steal: float | None = None
        self._gc_was_enabled = False

    def start(self, period: float, ticks: int) -> None:
        import gc

        self._period = period
        self.lateness = np.zeros(ticks)
        self.work = np.zeros(ticks)
        """Wall time each tick's own work took (state read, controller, log, plant step)."""
        self.parts = np.zeros((ticks, len(TickPart.NAMES)))
        """Wall time of each part of each tick's work (``TickPart``)."""
        self._mark = 0.0
        self._gc_was_enabled = gc.isenabled()
        gc.collect()
        gc.freeze()
        gc.disable()
        if self.lock_pages:
            self.memory = lock_memory()
        # SCHED_FIFO only with a core left for the MPC process: on one CPU the loop would starve it
        fifo = usable_cpus() >= 2 and self.priority.acquire()
        self._spin = self.fifo_spin if fifo else self.spin
        self._steal = host_steal_seconds()
        self._start = time.perf_counter()

    def wait(self, tick: int) -> None:
        if tick == 1:  # the schedule starts once tick 0 (the controller's first step) is done
            now = time.perf_counter()
            self.first_tick = self.work[0] = now - self._start
            self._start = now - self._period
        target = self._start + tick * self._period
        if tick > 1:
            self.work[tick - 1] = time.perf_counter() - (target - self._period + self.lateness[tick - 1])
        remaining = target - time.perf_counter()
        if remaining > self._spin:
            time.sleep(remaining - self._spin)
        while time.perf_counter() < target:
            pass
        now = time.perf_counter()
        self.lateness[tick] = now - target
        self._mark = now

    def mark(self, tick: int, part: int) -> None:
        """Record the wall time since the previous mark (or the tick's start) as ``part`` of ``tick``
        (``TickPart``): which part of a tick's work made it long."""
        now = time.perf_counter()
        self.parts[tick, part] = now - self._mark
        self._mark = now

    def summary(self, ticks: int) -> dict:
        import gc

        self.priority.release()
        steal = host_steal_seconds()
        if self.memory == "locked":
            unlock_memory()
        if self._gc_was_enabled:
            gc.enable()
        gc.unfreeze()
        lateness = self.lateness[:ticks]
        work = self.work[1 : max(ticks - 1, 1)]
        missed = lateness > self.miss_threshold
        # a late tick whose predecessor's own work fitted in the period: the process was not running
        # (another process or the host had the CPU), not too slow
        preempted = missed[2:] & (work < self._period) if ticks > 2 else np.zeros(0, dtype=bool)
        return {
            "control_rate_hz": 1.0 / self._period if self._period else None,
            "scheduling": self.priority.description,
            "memory": self.memory,
            "host_steal_ms": (steal - self._steal) * 1e3
            if steal is not None and self._steal is not None
            else None,
            "first_tick_ms": self.first_tick * 1e3,
            "ticks": int(ticks),
            "missed_ticks": int(np.sum(missed)),
            "missed_ticks_not_scheduled": int(np.sum(preempted)),
            "tick_work_ms_median": float(np.median(work)) * 1e3 if work.size else None,
            "tick_work_ms_max": float(np.max(work)) * 1e3 if work.size else None,
            "tick_lateness_ms_median": float(np.median(lateness)) * 1e3 if ticks else None,
            "tick_lateness_ms_p99": float(np.percentile(lateness, 99)) * 1e3 if ticks else None,
            "tick_lateness_ms_max": float(np.max(lateness)) * 1e3 if ticks else None,
            **self._parts_summary(ticks),
        }

    def _parts_summary(self, ticks: int) -> dict:
        """``tick_<part>_ms_median``, ``_p99`` and ``_max`` of each part of the ticks' work (``TickPart``)."""
        summary = {}
        for index, name in enumerate(TickPart.NAMES):
            values = self.parts[:ticks, index] * 1e3
            for label, value in (
                ("median", np.median),
                ("p99", lambda v: np.percentile(v, 99)),
                ("max", np.max),
            ):
                summary[f"tick_{name}_ms_{label}"] = float(value(values)) if ticks else None
        return summary
