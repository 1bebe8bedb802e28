"""A simulated robot on the wire (``cafe-mpc sim-robot``): our MuJoCo plant speaking Unitree's low-level DDS
protocol, so that a deployment (``cafe-mpc deploy``) runs against it exactly as against the real robot.

Every ``1 / rate_hz`` s of wall time the server

1. takes the ``rt/lowcmd`` messages that arrived (``robot_io.unitree.UnitreeDdsRobotSide``), drops those
   with a wrong checksum (as the robot does) and keeps the newest;
2. steps the physics one period with the motors applying the newest command at every physics step
   (``MujocoMotorPlant.step_command``: PD + feed-forward, saturated);
3. publishes the robot's state on ``rt/lowstate`` (IMU, joints, foot forces, ``tick``: ms of simulated
   time).

A ``LinkModel`` can delay both directions (``latency`` plus uniform ``jitter``), lose a fraction of the
messages (``loss``) and stop publishing states inside ``outages`` (link loss); SIGUSR1 starts an outage of
``signal_outage`` s then and there (to cut the link at a chosen moment of a deployment). The server
measures the round trip (a state published -> the first command that echoes its tick in
``LowCmd_.reserve`` received) and records the true base motion; ``SimRobotSummary`` (``--out``: JSON)
says what happened. It starts with the robot lying on the floor (``MujocoMotorPlant.lie_down``) and stops
after ``duration`` s or on SIGINT / SIGTERM.
"""

from __future__ import annotations

import json
import signal
from collections import deque
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from cafe_mpc.control.scheduling import RealTimePriority
from cafe_mpc.robot_io.interface import JointCommand, RobotState, WallClock
from cafe_mpc.robot_io.unitree.messages import WireFormatError
from cafe_mpc.robot_io.unitree.robot import UnitreeDdsRobotSide
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.sim.motor_plant import MujocoMotorPlant
from cafe_mpc_lab.sim.viewer import LiveViewer

TRACE_RATE_HZ = 50.0


@dataclass(frozen=True)
class LinkModel:
    """What the link does to messages: ``latency`` + uniform ``[0, jitter]`` s of delay each way, ``loss``
    (fraction of messages dropped, each direction), ``outages``: ``(start, duration)`` s of simulated time
    during which no state is published."""

    latency: float = 0.0
    jitter: float = 0.0
    loss: float = 0.0
    outages: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        if self.latency < 0 or self.jitter < 0:
            raise ValueError("link latency and jitter must be non-negative")
        if not 0.0 <= self.loss < 1.0:
            raise ValueError(f"link loss must be in [0, 1), got {self.loss}")
        for start, length in self.outages:
            if start < 0 or length <= 0:
                raise ValueError(
                    f"an outage needs a start >= 0 and a positive duration, got {start}:{length}"
                )

    def in_outage(self, t: float) -> bool:
        return any(start <= t < start + length for start, length in self.outages)


@dataclass
class SimRobotSummary:
    """What a simulated robot saw (``--out``)."""

    duration: float = 0.0
    """Simulated s."""
    wall_time: float = 0.0
    states_published: int = 0
    states_dropped: int = 0
    commands_received: int = 0
    commands_dropped: int = 0
    crc_errors: int = 0
    malformed: int = 0
    late_ticks: int = 0
    round_trip_ms_p50: float | None = None
    round_trip_ms_p99: float | None = None
    viewer_frames: int | None = None
    """Frames the viewer drew (None: no viewer)."""
    scheduling: str = "normal"
    """The physics loop's scheduling class (``realtime_priority``)."""
    outages: list = field(default_factory=list)
    """(start, end) s of simulated time of the outages SIGUSR1 started."""
    trace: dict = field(default_factory=dict)
    """``t``, ``x``, ``z`` (m), ``vx`` (m/s, world), ``tilt`` (rad), ``kp_mean``: the true base motion and the
    mean commanded stiffness at ``TRACE_RATE_HZ``."""


class SimRobotServer:
    """``robot``'s MuJoCo plant on Unitree's low-level DDS topics (module docstring)."""

    def __init__(
        self,
        robot: Robot,
        domain: int = 1,
        network_interface: str | None = "lo",
        multicast: bool = True,
        rate_hz: float = 500.0,
        link: LinkModel | None = None,
        seed: int = 0,
        signal_outage: float = 0.3,
        realtime_priority: int = 0,
    ) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate_hz must be positive, got {rate_hz}")
        self.priority = RealTimePriority(realtime_priority)
        self.robot = robot
        self.plant = MujocoMotorPlant(robot)
        self.period = 1.0 / rate_hz
        self.substeps = max(1, round(self.period / self.plant.timestep))
        self.link = link or LinkModel()
        self.side = UnitreeDdsRobotSide(robot, domain, network_interface, multicast)
        self.random = np.random.default_rng(seed)
        self.summary = SimRobotSummary()
        self._stop = False
        self.signal_outage = float(signal_outage)
        self._outage_requested = False
        self._outages: list[tuple[float, float]] = []
        """Outages started by SIGUSR1: (start, end) s of simulated time."""
        self._command = JointCommand.zeros(robot.nu)
        self._decoded = JointCommand.zeros(robot.nu)
        self._sensed = RobotState.zeros(robot.nu, robot.n_feet)
        self._outbox: deque[tuple[float, bytes]] = deque()
        self._inbox: deque[tuple[float, bytes]] = deque()
        self._sent_at: dict[int, float] = {}
        self._round_trips: list[float] = []

    def stop(self, *_: object) -> None:
        """End the run at the next tick (a signal handler)."""
        self._stop = True

    def cut_link(self, *_: object) -> None:
        """Start an outage of ``signal_outage`` s at the next tick (the SIGUSR1 handler)."""
        self._outage_requested = True

    def _delay(self) -> float:
        link = self.link
        return link.latency + (self.random.uniform(0.0, link.jitter) if link.jitter > 0 else 0.0)

    def _receive(self, now: float) -> None:
        summary, link = self.summary, self.link
        for data in self.side.take_commands():
            if link.loss and self.random.random() < link.loss:
                summary.commands_dropped += 1
                continue
            self._inbox.append((now + self._delay(), data))
        while self._inbox and self._inbox[0][0] <= now:
            _, data = self._inbox.popleft()
            try:
                crc_ok, echoed = self.side.decode_command(data, self._decoded)
            except WireFormatError:
                summary.malformed += 1
                continue
            if not crc_ok:
                summary.crc_errors += 1
                continue
            summary.commands_received += 1
            self._command.copy_from(self._decoded)
            sent = self._sent_at.pop(echoed, None)
            if sent is not None:
                self._round_trips.append(now - sent)

    def _publish(self, now: float) -> None:
        plant, summary, link = self.plant, self.summary, self.link
        tick = round(plant.time * 1e3)
        if self._outage_requested:
            self._outage_requested = False
            self._outages.append((plant.time, plant.time + self.signal_outage))
        cut = any(start <= plant.time < end for start, end in self._outages)
        if cut or link.in_outage(plant.time) or (link.loss and self.random.random() < link.loss):
            summary.states_dropped += 1
        else:
            plant.sense(self._sensed)
            data = self.side.encode_state(self._sensed.readings, self._sensed.foot_forces, tick)
            self._outbox.append((now + self._delay(), data))
            self._sent_at[tick] = now
            if len(self._sent_at) > 1000:
                self._sent_at.pop(next(iter(self._sent_at)))
        while self._outbox and self._outbox[0][0] <= now:
            self.side.send_state(self._outbox.popleft()[1])
            summary.states_published += 1

    def run(
        self,
        duration: float | None = None,
        out: Path | None = None,
        say=print,
        viewer: LiveViewer | None = None,
    ) -> SimRobotSummary:
        """Serve until ``duration`` s of simulated time (None: until stopped); the summary to ``out``.
        ``viewer``: MuJoCo's viewer on the plant (started here, in the normal scheduling class; closing its
        window ends the run)."""
        plant, summary = self.plant, self.summary
        for signal_number in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signal_number, self.stop)
        signal.signal(signal.SIGUSR1, self.cut_link)
        plant.lie_down()
        trace: dict[str, list[float]] = {name: [] for name in ("t", "x", "z", "vx", "tilt", "kp_mean")}
        clock = WallClock(spin=0.0)
        if viewer is not None:
            viewer.start(plant.plant)
        self.priority.acquire()
        summary.scheduling = self.priority.description
        self.side.open()
        say(f"sim-robot: {self.robot.name} lying, publishing rt/lowstate on {self.side.where()}")
        start = next_tick = clock.now()
        next_trace = 0.0
        try:
            while not self._stop and (duration is None or plant.time < duration):
                clock.sleep_until(next_tick)
                now = clock.now()
                if now - next_tick > 0.5 * self.period:
                    summary.late_ticks += 1
                next_tick = max(next_tick + self.period, now - self.period)
                self._receive(now)
                for _ in range(self.substeps):
                    plant.step_command(self._command)
                self._publish(now)
                if viewer is not None and not viewer.update(plant.time, plant.plant):
                    say(f"sim-robot: {viewer.stop_reason}")
                    self._stop = True
                if plant.time >= next_trace:
                    next_trace += 1.0 / TRACE_RATE_HZ
                    position, velocity = plant.base_position(), plant.base_velocity()
                    for name, value in (
                        ("t", plant.time),
                        ("x", position[0]),
                        ("z", position[2]),
                        ("vx", velocity[0]),
                        ("tilt", plant.tilt()),
                        ("kp_mean", float(np.mean(self._command.kp))),
                    ):
                        trace[name].append(round(float(value), 4))
        finally:
            self.priority.release()
            if viewer is not None:
                viewer.close()
                summary.viewer_frames = viewer.frames
            self.side.close()
            summary.duration = plant.time
            summary.wall_time = clock.now() - start
            if self._round_trips:
                trips = np.asarray(self._round_trips) * 1e3
                summary.round_trip_ms_p50 = float(np.median(trips))
                summary.round_trip_ms_p99 = float(np.percentile(trips, 99))
            summary.trace = trace
            summary.outages = self._outages
            if out is not None:
                Path(out).write_text(json.dumps(asdict(summary)))
            say(
                f"sim-robot: {summary.duration:.1f} s simulated in {summary.wall_time:.1f} s; "
                f"{summary.states_published} states published, {summary.commands_received} commands applied, "
                f"round trip median {summary.round_trip_ms_p50} ms"
            )
        return summary
