"""One interface to a robot's motors and sensors: read the newest low state, write a low command, link health.

``RobotInterface`` is what a deployment (``cafe_mpc.deploy``) runs against, whatever carries the messages:

* ``robot_io.unitree.UnitreeDdsRobot``: Unitree's low-level DDS topics (``rt/lowstate`` in, ``rt/lowcmd``
  out), on a real Go2 or on a simulated robot that speaks the same protocol (``cafe-mpc sim-robot``);
* ``robot_io.inprocess.InProcessRobot``: a plant in the same process, stepped in simulated time (tests).

Everything crossing the interface is in the robot's joint order (``Robot.joint_names``) and the planning
model's conventions; the implementation maps joints to motor slots, signs and zero offsets
(``robot_io.mapping``, from the robot file's ``hardware`` section).

* ``read() -> RobotState | None``: the newest state received (None before the first), its readings
  (``core.sensors.SensorReadings``), when it arrived on the interface's ``clock`` and the robot's own time;
* ``write(command)``: a ``JointCommand`` (per joint: position, velocity, stiffness ``kp``, damping ``kd``,
  feed-forward torque), which the motors hold until the next one: ``tau + kp (q - q_j) + kd (dq - dq_j)``;
* ``health() -> LinkHealth``: the state rate over the last half second, the age of the newest state,
  states received and lost;
* ``clock``: the time base of ``read``, ``health`` and the caller's loop (``Clock``: the wall clock, or
  the simulated time of an in-process plant).
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from cafe_mpc.core.sensors import SensorReadings


class RobotInterfaceError(RuntimeError):
    """The interface cannot reach the robot (a missing extra, a bad network interface, a closed link)."""


@dataclass
class JointCommand:
    """One low-level command, robot joint order: the motors apply ``tau + kp (q - q_j) + kd (dq - dq_j)``
    at their own rate until the next command (``q_j``, ``dq_j``: the joint's measured angle and rate)."""

    q: np.ndarray
    dq: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    tau: np.ndarray

    @classmethod
    def zeros(cls, n_joints: int) -> JointCommand:
        """Zero gains and torque: the motors apply nothing."""
        return cls(*(np.zeros(n_joints) for _ in range(5)))

    def copy_from(self, other: JointCommand) -> None:
        for name in ("q", "dq", "kp", "kd", "tau"):
            np.copyto(getattr(self, name), getattr(other, name))

    def set(
        self,
        q: np.ndarray | float = 0.0,
        dq: np.ndarray | float = 0.0,
        kp: np.ndarray | float = 0.0,
        kd: np.ndarray | float = 0.0,
        tau: np.ndarray | float = 0.0,
    ) -> JointCommand:
        """Overwrite every field (arrays or one value for every joint); returns itself."""
        self.q[:] = q
        self.dq[:] = dq
        self.kp[:] = kp
        self.kd[:] = kd
        self.tau[:] = tau
        return self


@dataclass
class RobotState:
    """The newest low state (``RobotInterface.read``; the interface's own object, overwritten by later
    reads: copy what must outlive the tick)."""

    readings: SensorReadings
    """IMU and joints, robot joint order; ``readings.time`` is ``received`` (the interface's clock)."""
    foot_forces: np.ndarray
    """The robot's foot force sensors, leg order, as it reports them (Unitree: raw counts; a simulated robot:
    the vertical force in N)."""
    received: float = 0.0
    """When this state was taken from the link (s, the interface's ``clock``)."""
    robot_time: float = 0.0
    """The robot's own clock at this state (s)."""
    sequence: int = 0
    """States received so far (this one included)."""

    @classmethod
    def zeros(cls, n_joints: int, n_feet: int) -> RobotState:
        return cls(SensorReadings.zeros(n_joints), np.zeros(n_feet))


@dataclass(frozen=True)
class LinkHealth:
    """How the link to the robot is doing (``RobotInterface.health``)."""

    rate_hz: float
    """States per second over the last ``LinkMonitor.window`` seconds (or since the first state, if later)."""
    age: float
    """Seconds since the newest state arrived (inf before the first)."""
    received: int
    """States received."""
    lost: int
    """States the robot sent that never arrived (gaps in its counter)."""
    rejected: int = 0
    """Messages dropped as malformed (wrong size or encoding)."""
    crc_errors: int = 0
    """States whose checksum did not match (kept: some robots and bridges leave it zero)."""

    def describe(self) -> str:
        return (
            f"{self.rate_hz:.0f} Hz, newest state {self.age * 1e3:.1f} ms old, {self.received} received, "
            f"{self.lost} lost"
        )


class Clock(ABC):
    """The time base of an interface: ``now()`` in seconds, and ``sleep_until(t)``."""

    realtime: bool = False
    """Whether time passes on its own (the wall clock) or only when the caller sleeps (a simulation)."""

    @abstractmethod
    def now(self) -> float: ...

    @abstractmethod
    def sleep_until(self, t: float) -> None:
        """Return at ``t`` (or at once if it has passed)."""


class WallClock(Clock):
    """``time.perf_counter`` (the host's monotonic clock: the same in every process of the machine). Sleeps
    until shortly before the target, then spins: ``time.sleep`` alone wakes a busy machine's process a
    millisecond or more late."""

    realtime = True

    def __init__(self, spin: float = 0.0005) -> None:
        self.spin = spin

    def now(self) -> float:
        return time.perf_counter()

    def sleep_until(self, t: float) -> None:
        remaining = t - time.perf_counter()
        if remaining > self.spin:
            time.sleep(remaining - self.spin)
        while time.perf_counter() < t:
            pass


@dataclass
class LinkMonitor:
    """Counts states as they arrive: the rate over the last ``window`` seconds, the age of the newest, and
    the states lost (gaps in the robot's counter, in units of the smallest step seen)."""

    window: float = 0.5
    received: int = 0
    lost: int = 0
    rejected: int = 0
    crc_errors: int = 0
    newest: float = -np.inf
    first: float = np.inf
    """When the first state arrived (the rate counts over less than ``window`` until then + ``window``)."""
    _arrivals: deque = field(default_factory=lambda: deque(maxlen=4096))
    _last_counter: int | None = None
    _step: int | None = None

    def reset(self) -> None:
        self.received = self.lost = self.rejected = self.crc_errors = 0
        self.newest = -np.inf
        self.first = np.inf
        self._arrivals.clear()
        self._last_counter = None
        self._step = None

    def arrived(self, t: float, counter: int | None = None) -> None:
        """A state arrived at ``t``; ``counter``: the robot's message counter (its tick), if it has one."""
        self.received += 1
        self.newest = t
        self.first = min(self.first, t)
        self._arrivals.append(t)
        if counter is None:
            return
        if self._last_counter is not None:
            gap = counter - self._last_counter
            if gap > 0:
                if self._step is None or gap < self._step:
                    self._step = gap
                missed = round(gap / self._step) - 1
                self.lost += max(missed, 0)
        self._last_counter = counter

    def health(self, now: float) -> LinkHealth:
        arrivals = self._arrivals
        while arrivals and arrivals[0] < now - self.window:
            arrivals.popleft()
        span = min(self.window, now - self.first)
        return LinkHealth(
            rate_hz=len(arrivals) / span if span > 0 else 0.0,
            age=now - self.newest,
            received=self.received,
            lost=self.lost,
            rejected=self.rejected,
            crc_errors=self.crc_errors,
        )


class RobotInterface(ABC):
    """A robot's low level (module docstring). Use as a context manager, or ``open()`` and ``close()``."""

    clock: Clock
    n_joints: int

    @abstractmethod
    def open(self) -> None:
        """Connect (subscribe to the state, prepare the command); idempotent."""

    @abstractmethod
    def read(self) -> RobotState | None:
        """The newest state received so far (None before the first)."""

    @abstractmethod
    def write(self, command: JointCommand) -> None:
        """Send ``command`` (robot joint order) to the motors."""

    @abstractmethod
    def health(self) -> LinkHealth:
        """The link's health now."""

    @abstractmethod
    def close(self) -> None:
        """Disconnect; idempotent. Sends nothing: the motors keep the last command."""

    @property
    def commands_sent(self) -> int:
        """Commands written so far."""
        return 0

    def __enter__(self) -> RobotInterface:
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()
