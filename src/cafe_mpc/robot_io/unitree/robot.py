"""A Unitree robot's low level over DDS: ``UnitreeDdsRobot`` (the controller's end) and
``UnitreeDdsRobotSide`` (the robot's end, for a simulated robot on the wire).

The controller subscribes to ``rt/lowstate`` and publishes ``rt/lowcmd`` (``messages``), as Unitree's
``unitree_sdk2`` low-level examples do: a Go2 on its Ethernet (DDS domain 0), or unitree_mujoco and
``cafe-mpc sim-robot`` on ``lo`` (domain 1). Joints map to motor slots by the robot file's ``hardware``
section (``robot_io.mapping``).

What a ``LowState_`` becomes (``RobotState``): the IMU quaternion (``w, x, y, z`` on the wire; ``x, y, z,
w`` in ``SensorReadings``), gyroscope and accelerometer (base frame); each joint's ``q``, ``dq`` and
``tau_est``; ``foot_force``; ``tick`` (the robot's millisecond counter: the robot's time, and the counter
whose gaps count lost states). Its ``crc`` is checked and mismatches are counted, not dropped (unitree_mujoco
leaves it zero).

What a ``JointCommand`` becomes: ``head`` ``FE EF``, ``level_flag`` ``0xFF``; each joint's motor slot in servo
mode with ``q``, ``dq``, ``kp``, ``kd``, ``tau``; unused slots with the SDK's stop values and zero gains;
``reserve`` carries the ``tick`` of the newest state the controller had (the robot ignores it; a simulated
robot measures the round trip with it); ``crc`` last. A robot drops commands whose checksum is wrong.
"""

from __future__ import annotations

import numpy as np

from cafe_mpc.core.sensors import SensorReadings
from cafe_mpc.robot_io.interface import (
    Clock,
    JointCommand,
    LinkHealth,
    LinkMonitor,
    RobotInterface,
    RobotInterfaceError,
    RobotState,
    WallClock,
)
from cafe_mpc.robot_io.mapping import MotorMapping
from cafe_mpc.robot_io.unitree import dds
from cafe_mpc.robot_io.unitree.messages import (
    HEAD,
    LEVEL_LOW,
    LOW_CMD,
    LOW_STATE,
    MOTOR_MODE_SERVO,
    MOTOR_SLOTS,
    POSITION_STOP,
    TOPIC_LOW_COMMAND,
    TOPIC_LOW_STATE,
    VELOCITY_STOP,
    MessageCodec,
    WireFormatError,
)
from cafe_mpc.robots.robot import Robot

TICK_SECONDS = 1e-3
"""``LowState_.tick`` counts milliseconds."""


class _Link:
    """The DDS ends both sides share: the participant, one subscriber and one publisher."""

    def __init__(self, domain: int, network_interface: str | None, multicast: bool) -> None:
        self.domain = int(domain)
        self.network_interface = network_interface
        self.multicast = multicast
        self.subscriber: dds.Subscriber | None = None
        self.publisher: dds.Publisher | None = None

    def open(self, listen: str, listen_struct, speak: str, speak_struct) -> None:
        if self.subscriber is not None:
            return
        joined = dds.participant(self.domain, self.network_interface, self.multicast)
        try:
            self.subscriber = dds.Subscriber(joined, listen, listen_struct)
            self.publisher = dds.Publisher(joined, speak, speak_struct)
        except Exception as error:  # the binding's DDSException
            raise RobotInterfaceError(f"cannot open the DDS topics {listen}, {speak}: {error}") from error

    def close(self) -> None:
        for end in (self.subscriber, self.publisher):
            if end is not None:
                end.close()
        self.subscriber = self.publisher = None

    def where(self) -> str:
        interface = self.network_interface or "Cyclone DDS's default interface"
        return f"DDS domain {self.domain} on {interface}"


class UnitreeDdsRobot(RobotInterface):
    """The controller's end of Unitree's low-level topics (module docstring).

    ``domain``: DDS domain (a Go2: 0; unitree_mujoco and ``cafe-mpc sim-robot``: 1); ``network_interface``:
    the interface the robot is on (``lo``, ``eth0``, ...; None: Cyclone DDS's default or ``CYCLONEDDS_URI``);
    ``multicast``: False for unicast discovery on a loopback without multicast (``dds``).
    """

    def __init__(
        self,
        robot: Robot,
        domain: int = 0,
        network_interface: str | None = None,
        multicast: bool = True,
        clock: Clock | None = None,
    ) -> None:
        self.mapping = MotorMapping(robot)
        self.n_joints = robot.nu
        self.clock = clock or WallClock()
        self.monitor = LinkMonitor()
        self.link = _Link(domain, network_interface, multicast)
        self._states = MessageCodec(LOW_STATE)
        self._commands = MessageCodec(LOW_CMD)
        self._tick_at = self._states.offset_of("tick")
        self._state = RobotState.zeros(robot.nu, robot.n_feet)
        self._have_state = False
        self._newest_tick = 0
        self._motor = np.zeros(MOTOR_SLOTS)
        self._sent = 0
        self._prepare_command()

    def _prepare_command(self) -> None:
        message = self._commands.message
        message["head"] = HEAD
        message["level_flag"] = LEVEL_LOW
        motors = message["motor_cmd"]
        motors["mode"] = 0
        motors["q"] = POSITION_STOP
        motors["dq"] = VELOCITY_STOP
        motors["mode"][self.mapping.slots] = MOTOR_MODE_SERVO

    @property
    def commands_sent(self) -> int:
        return self._sent

    def where(self) -> str:
        """The domain and network interface, for messages."""
        return self.link.where()

    def open(self) -> None:
        self.link.open(TOPIC_LOW_STATE, LOW_STATE, TOPIC_LOW_COMMAND, LOW_CMD)

    def close(self) -> None:
        self.link.close()

    def _poll(self) -> None:
        """Take every state that arrived; decode the newest."""
        subscriber = self.link.subscriber
        if subscriber is None:
            raise RobotInterfaceError("the robot interface is not open")
        samples = subscriber.take()
        if not samples:
            return
        now = self.clock.now()
        newest = None
        at = self._tick_at
        for sample in samples:
            data = sample.data
            if len(data) < at + 4:
                self.monitor.rejected += 1
                continue
            self.monitor.arrived(now, int.from_bytes(data[at : at + 4], "little"))
            newest = data
        if newest is None:
            return
        try:
            self._states.decode(newest)
        except WireFormatError:
            self.monitor.rejected += 1
            return
        if not self._states.crc_ok():
            self.monitor.crc_errors += 1
        self._fill_state(now)

    def _fill_state(self, now: float) -> None:
        message = self._states.message
        state = self._state
        readings: SensorReadings = state.readings
        imu = message["imu_state"]
        quaternion = imu["quaternion"]  # w, x, y, z
        readings.orientation[:3] = quaternion[1:]
        readings.orientation[3] = quaternion[0]
        readings.gyro[:] = imu["gyroscope"]
        readings.accelerometer[:] = imu["accelerometer"]
        motors = message["motor_state"]
        mapping = self.mapping
        np.copyto(self._motor, motors["q"])
        mapping.joint_positions_into(self._motor, readings.joint_positions)
        np.copyto(self._motor, motors["dq"])
        mapping.joint_rates_into(self._motor, readings.joint_velocities)
        np.copyto(self._motor, motors["tau_est"])
        mapping.joint_rates_into(self._motor, readings.joint_torques)
        readings.time = now
        state.foot_forces[:] = message["foot_force"][: len(state.foot_forces)]
        self._newest_tick = int(message["tick"])
        state.robot_time = self._newest_tick * TICK_SECONDS
        state.received = now
        state.sequence = self.monitor.received
        self._have_state = True

    def read(self) -> RobotState | None:
        self._poll()
        return self._state if self._have_state else None

    def health(self) -> LinkHealth:
        self._poll()
        return self.monitor.health(self.clock.now())

    def write(self, command: JointCommand) -> None:
        publisher = self.link.publisher
        if publisher is None:
            raise RobotInterfaceError("the robot interface is not open")
        codec = self._commands
        motors = codec.message["motor_cmd"]
        mapping, motor = self.mapping, self._motor
        motor[:] = 0.0
        mapping.motor_positions_into(command.q, motor)
        motors["q"][mapping.slots] = motor[mapping.slots]
        mapping.motor_rates_into(command.dq, motor)
        motors["dq"][mapping.slots] = motor[mapping.slots]
        mapping.motor_rates_into(command.tau, motor)
        motors["tau"][mapping.slots] = motor[mapping.slots]
        mapping.motor_gains_into(command.kp, motor)
        motors["kp"][mapping.slots] = motor[mapping.slots]
        mapping.motor_gains_into(command.kd, motor)
        motors["kd"][mapping.slots] = motor[mapping.slots]
        codec.message["reserve"] = self._newest_tick & 0xFFFFFFFF
        codec.seal()
        publisher.write(codec.encode())
        self._sent += 1


class UnitreeDdsRobotSide:
    """The robot's end of Unitree's low-level topics, for a robot simulated on the wire (``cafe-mpc
    sim-robot``): it encodes states and decodes commands; when they are sent and applied is the caller's
    (``cafe_mpc_lab.sim.robot_server`` delays and drops them to model a link)."""

    def __init__(
        self, robot: Robot, domain: int = 1, network_interface: str | None = None, multicast: bool = True
    ) -> None:
        self.mapping = MotorMapping(robot)
        self.link = _Link(domain, network_interface, multicast)
        self._states = MessageCodec(LOW_STATE)
        self._commands = MessageCodec(LOW_CMD)
        self._motor = np.zeros(MOTOR_SLOTS)
        message = self._states.message
        message["head"] = HEAD
        message["level_flag"] = LEVEL_LOW
        message["motor_state"]["mode"][self.mapping.slots] = MOTOR_MODE_SERVO

    def open(self) -> None:
        self.link.open(TOPIC_LOW_COMMAND, LOW_CMD, TOPIC_LOW_STATE, LOW_STATE)

    def close(self) -> None:
        self.link.close()

    def where(self) -> str:
        return self.link.where()

    def encode_state(self, readings: SensorReadings, foot_forces: np.ndarray, tick: int) -> bytes:
        """The wire bytes of a ``LowState_`` with ``readings`` (robot joint order; torques NaN -> 0),
        ``foot_forces`` (leg order, rounded to integers) and ``tick`` (ms)."""
        message = self._states.message
        imu = message["imu_state"]
        orientation = readings.orientation
        imu["quaternion"][0] = orientation[3]
        imu["quaternion"][1:] = orientation[:3]
        imu["rpy"] = _roll_pitch_yaw(orientation)
        imu["gyroscope"] = readings.gyro
        imu["accelerometer"] = readings.accelerometer
        motors = message["motor_state"]
        mapping, motor, slots = self.mapping, self._motor, self.mapping.slots
        mapping.motor_positions_into(readings.joint_positions, motor)
        motors["q"][slots] = motor[slots]
        mapping.motor_rates_into(readings.joint_velocities, motor)
        motors["dq"][slots] = motor[slots]
        mapping.motor_rates_into(np.nan_to_num(readings.joint_torques), motor)
        motors["tau_est"][slots] = motor[slots]
        forces = np.clip(np.round(foot_forces), -32768, 32767)
        message["foot_force"][: len(forces)] = forces
        message["tick"] = int(tick) & 0xFFFFFFFF
        self._states.seal()
        return self._states.encode()

    def send_state(self, data: bytes) -> None:
        self.link.publisher.write(data)

    def take_commands(self) -> list[bytes]:
        """The wire bytes of every command that arrived since the last call, oldest first."""
        return [sample.data for sample in self.link.subscriber.take()]

    def decode_command(self, data: bytes, out: JointCommand) -> tuple[bool, int]:
        """``out`` from a command's wire bytes (robot joint order); returns ``(crc_ok, echoed_tick)``.
        ``WireFormatError`` for bytes that are no ``LowCmd_``."""
        codec = self._commands
        codec.decode(data)
        motors = codec.message["motor_cmd"]
        mapping, motor = self.mapping, self._motor
        np.copyto(motor, motors["q"])
        mapping.joint_positions_into(motor, out.q)
        np.copyto(motor, motors["dq"])
        mapping.joint_rates_into(motor, out.dq)
        np.copyto(motor, motors["tau"])
        mapping.joint_rates_into(motor, out.tau)
        out.kp[:] = motors["kp"][mapping.slots]
        out.kd[:] = motors["kd"][mapping.slots]
        return codec.crc_ok(), int(codec.message["reserve"])


def _roll_pitch_yaw(quaternion_xyzw: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw (rad, ZYX) of a unit quaternion ``(x, y, z, w)`` (``LowState_.imu_state.rpy``)."""
    x, y, z, w = (float(value) for value in quaternion_xyzw)
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw
