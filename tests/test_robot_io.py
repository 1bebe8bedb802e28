"""The robot interface (``robot_io``): Unitree's low-level messages and their checksum, the DDS binding's view
of them, the motor mapping of a robot file's ``hardware`` section, the command limits and the start-up
checks, and one message each way over DDS on the loopback interface."""

from __future__ import annotations

import dataclasses
import sys
import time

import numpy as np
import pytest

from cafe_mpc.deploy.limits import CommandLimiter
from cafe_mpc.deploy.settings import DeploySettings
from cafe_mpc.deploy.startup import StartupRefused, check_joints, check_link, check_upright
from cafe_mpc.robot_io.interface import JointCommand, LinkMonitor, RobotState
from cafe_mpc.robot_io.mapping import MotorMapping
from cafe_mpc.robot_io.unitree.messages import (
    LOW_CMD,
    LOW_STATE,
    MessageCodec,
    WireFormatError,
    unitree_crc32,
)
from cafe_mpc.robots.hardware import HardwareError, read_hardware
from cafe_mpc.robots.robot import Robot, load_robot


@pytest.fixture(scope="module")
def go2() -> Robot:
    return load_robot("go2")


def crc32_mpeg2_bitwise(words: np.ndarray) -> int:
    """CRC-32/MPEG-2 (polynomial 0x04C11DB7, register 0xFFFFFFFF, no reflection, no final XOR) fed 32-bit
    words most significant bit first, one bit at a time: Unitree's ``crc32_core`` written out."""
    register = 0xFFFFFFFF
    for word in (int(w) for w in words):
        for bit in range(31, -1, -1):
            top = (register >> 31) & 1
            register = (register << 1) & 0xFFFFFFFF
            if top ^ ((word >> bit) & 1):
                register ^= 0x04C11DB7
    return register


def test_message_layouts_match_unitree_sizes():
    """The C layouts Unitree's checksum covers: LowCmd_ 812 bytes, LowState_ 1180 (unitree_sdk2's structs)."""
    assert MessageCodec(LOW_CMD).dtype.itemsize == 812
    assert MessageCodec(LOW_STATE).dtype.itemsize == 1180
    command = MessageCodec(LOW_CMD).dtype
    assert command.fields["motor_cmd"][1] == 24  # after head, flags, sn, version, bandwidth and 2 pad bytes
    assert command.fields["crc"][1] == 808


@pytest.mark.parametrize("struct", [LOW_CMD, LOW_STATE], ids=lambda s: s.name)
def test_checksum_is_crc32_mpeg2_over_the_words_but_the_last(struct):
    codec = MessageCodec(struct)
    codec.c_bytes[:] = np.random.default_rng(3).integers(0, 256, codec.c_bytes.size)
    words = np.frombuffer(codec.c_bytes.tobytes(), dtype="<u4")[:-1]
    assert unitree_crc32(codec.c_bytes) == crc32_mpeg2_bitwise(words)
    codec.seal()
    assert codec.crc_ok()
    codec.message["motor_state" if struct is LOW_STATE else "motor_cmd"]["q"][3] += 0.01
    assert not codec.crc_ok()


def test_wire_bytes_are_what_the_dds_binding_serialises():
    """Our encoding of a message is the Cyclone DDS binding's own serialisation of the IDL type (so a robot's
    readers and writers, built on the same IDL, read ours), and back."""
    pytest.importorskip("cyclonedds")
    from cafe_mpc.robot_io.unitree.dds import idl_types

    types = idl_types(pre_encoded=False)
    for struct in (LOW_CMD, LOW_STATE):
        codec = MessageCodec(struct)
        rng = np.random.default_rng(7)
        codec.c_bytes[:] = rng.integers(0, 256, codec.c_bytes.size)
        for name in codec.dtype.names:  # finite floats everywhere (NaN payloads compare unequal)
            if codec.dtype[name].kind == "f":
                codec.message[name] = 1.5
        for part in ("motor_cmd", "motor_state", "imu_state"):
            if part in codec.dtype.names:
                for name in codec.dtype[part].base.names:
                    if codec.dtype[part].base[name].base.kind == "f":
                        codec.message[part][name] = rng.normal(size=codec.message[part][name].shape)
        codec.seal()
        wire = codec.encode()
        sample = types[struct.name].deserialize(wire)
        assert sample.serialize() == wire
        assert sample.crc == int(codec.message["crc"])
        other = MessageCodec(struct)
        other.decode(sample.serialize())
        assert other.crc_ok() and other.c_bytes.tobytes() == codec.c_bytes.tobytes()
    with pytest.raises(WireFormatError, match="bytes"):
        MessageCodec(LOW_CMD).decode(b"\x00\x01\x00\x00" + bytes(10))


def test_go2_motor_mapping_round_trips(go2):
    """Unitree's motor order (FR, FL, RR, RL) against the robot's joint order, with signs and offsets."""
    spec = go2.hardware
    assert spec.interface == "unitree-dds" and spec.n_motors == 12
    assert [spec.motor_joints[slot] for slot in spec.motor_of_joint] == list(go2.joint_names)
    flipped = dataclasses.replace(
        spec, joint_signs=np.tile([-1.0, 1.0, 1.0], 4), joint_offsets=np.tile([0.0, 0.1, -0.2], 4)
    )
    mapping = MotorMapping(dataclasses.replace(go2, hardware=flipped))
    q = np.random.default_rng(1).normal(size=12)
    motors = np.zeros(20)
    mapping.motor_positions_into(q, motors)
    back = np.zeros(12)
    mapping.joint_positions_into(motors, back)
    np.testing.assert_allclose(back, q)
    fr_hip = go2.joint_names.index("FR_hip_joint")
    assert motors[0] == pytest.approx(-q[fr_hip])  # motor slot 0 is FR's hip, sign -1


def test_hardware_section_errors_name_the_key(go2):
    lower, upper = go2.position_lower, go2.position_upper
    good = {"interface": "unitree-dds", "motors": list(go2.joint_names), "lying_pose": [0.0, 1.0, -2.0]}
    good |= {"stance_kp": 60.0, "stance_kd": 5.0}
    assert read_hardware(good, go2.joint_names, lower, upper) is not None
    for change, key in [
        ({"motors": list(go2.joint_names)[:-1]}, "hardware.motors"),
        ({"joint_signs": [1, 2, 1]}, "hardware.joint_signs"),
        ({"lying_pose": [0.0, 9.0, -2.0]}, "hardware.lying_pose"),
        ({"stance_kp": -1}, "hardware.stance_kp"),
        ({"wheels": 4}, "unknown keys"),
    ]:
        with pytest.raises(HardwareError, match=key):
            read_hardware(good | change, go2.joint_names, lower, upper)


def test_limiter_holds_every_command_to_the_limits(go2):
    settings = DeploySettings()
    limiter = CommandLimiter(go2, settings, period=0.002)
    q = np.array(go2.q_standing[7:])
    command = JointCommand.zeros(12).set(q=q + 10.0, dq=1e3, kp=1e3, kd=1e3, tau=1e3)
    limiter.apply(command, q, np.zeros(12))
    assert np.all(command.q <= go2.position_upper) and np.all(command.kp == settings.max_kp)
    assert np.all(command.kd == settings.max_kd) and np.all(command.dq <= go2.velocity_limits)
    assert np.all(np.abs(command.tau) <= go2.torque_limits)
    first_tau = command.tau.copy()
    second = JointCommand.zeros(12).set(q=q, kp=0.0, tau=-first_tau)
    limiter.apply(second, q, np.zeros(12))
    step = settings.max_torque_rate * 0.002
    np.testing.assert_allclose(second.tau, first_tau - step)  # the torque moves at most its rate per tick
    outward = JointCommand.zeros(12).set(q=q, tau=5.0)
    limiter.reset()
    limiter.apply(outward, go2.position_upper + 0.1, np.zeros(12))  # every joint beyond its upper limit
    assert np.all(outward.tau == 0.0)
    assert limiter.clamps["position"] >= 2 and limiter.clamps["rate"] == 1


def test_startup_checks_refuse_with_one_line(go2):
    state = RobotState.zeros(12, 4)
    state.readings.joint_positions[:] = go2.hardware.lying_pose
    check_joints(state, go2, 0.05)
    check_upright(state, 0.5)
    state.readings.joint_positions[2] = go2.position_upper[2] + 0.2
    with pytest.raises(StartupRefused, match=f"joint outside its range: {go2.joint_names[2]}"):
        check_joints(state, go2, 0.05)
    state.readings.orientation[:] = (1.0, 0.0, 0.0, 0.0)  # rolled by pi: upside down
    with pytest.raises(StartupRefused, match="upside down"):
        check_upright(state, 0.5)
    monitor = LinkMonitor(window=0.5)
    for k in range(100):  # 200 Hz for half a second, every other counter value missing
        monitor.arrived(0.005 * k, counter=2 * k)
    monitor.arrived(0.5, counter=203)  # two states lost
    health = monitor.health(0.5)
    assert health.lost == 1 and health.rate_hz == pytest.approx(200.0, abs=4.0)
    with pytest.raises(StartupRefused, match="below the 400 Hz"):
        check_link(health, 400.0, "lo")


@pytest.mark.realtime
def test_states_and_commands_cross_dds_on_loopback(go2):
    """One end publishes states as a robot does, the other reads them and answers with commands: values,
    checksums and the echoed tick arrive intact; a link that stops shows in the state's age."""
    pytest.importorskip("cyclonedds")
    from cafe_mpc.robot_io.unitree.robot import UnitreeDdsRobot, UnitreeDdsRobotSide

    domain = 37  # away from the robots' 0 and the simulators' 1
    robot_side = UnitreeDdsRobotSide(go2, domain, "lo")
    controller_side = UnitreeDdsRobot(go2, domain, "lo")
    readings = RobotState.zeros(12, 4).readings
    readings.joint_positions[:] = np.linspace(-0.5, 0.5, 12)
    readings.orientation[:] = (0.0, 0.0, np.sin(0.1), np.cos(0.1))
    sent = JointCommand.zeros(12).set(q=np.linspace(0.1, 1.2, 12), kp=20.0, kd=1.0, tau=np.arange(12.0))
    received = JointCommand.zeros(12)
    commands: list[bytes] = []
    with controller_side:
        robot_side.open()
        try:
            deadline = time.perf_counter() + 10.0
            state = None
            tick = 0
            while time.perf_counter() < deadline and not commands:
                tick += 1
                robot_side.send_state(robot_side.encode_state(readings, np.array([10, 20, 30, 40]), tick))
                state = controller_side.read()
                if state is not None:
                    controller_side.write(sent)
                commands += robot_side.take_commands()
                time.sleep(0.002)
            assert state is not None and commands, "nothing crossed the loopback within 10 s"
            np.testing.assert_allclose(state.readings.joint_positions, readings.joint_positions, atol=1e-6)
            np.testing.assert_allclose(state.readings.orientation, readings.orientation, atol=1e-6)
            np.testing.assert_array_equal(state.foot_forces, [10, 20, 30, 40])
            crc_ok, echoed = robot_side.decode_command(commands[-1], received)
            assert crc_ok and 0 < echoed <= tick
            for name in ("q", "kp", "kd", "tau"):
                np.testing.assert_allclose(getattr(received, name), getattr(sent, name), atol=1e-5)
            assert controller_side.health().crc_errors == 0
            time.sleep(0.1)
            assert controller_side.health().age > 0.09  # no new state: the newest one ages
        finally:
            robot_side.close()


def test_interface_errors_are_one_line(go2, robot, monkeypatch):
    """A robot file without a hardware section, and a missing DDS binding: one line saying what to do."""
    from cafe_mpc.robot_io import RobotInterfaceError, make_interface

    with pytest.raises(ValueError, match="has no hardware section"):
        make_interface("unitree-dds", robot)
    with pytest.raises(ValueError, match="unknown robot interface 'lcm'"):
        make_interface("lcm", go2)
    monkeypatch.setitem(sys.modules, "cyclonedds", None)  # as if the extra were not installed
    with pytest.raises(RobotInterfaceError, match=r"pip install 'cafe-mpc\[robot\]'"):
        make_interface("unitree-dds", go2, domain=38, network_interface="lo").open()
