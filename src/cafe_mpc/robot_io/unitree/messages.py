"""Unitree's low-level messages (``unitree_go`` IDL: ``LowCmd_``, ``LowState_`` and their parts), their wire
encoding and their checksum, without DDS.

The message definitions are Unitree's public IDL (unitree_sdk2, unitree_sdk2_python:
``unitree_go/msg/dds_``); ``STRUCTS`` writes them down once, and everything else is derived from it:

* the **C layout** (``c_dtype``): the struct as the robot's firmware holds it, little-endian, every member
  aligned to its size, nested structs to their largest member and padded to it (numpy's ``align=True`` is
  that rule). ``LowCmd_`` is 812 bytes, ``LowState_`` 1180. Unitree's checksum covers it;
* the **wire layout** (``MessageCodec``): the CDR encoding DDS sends (a 4-byte encapsulation header, then
  every primitive aligned to its size relative to the payload's start, no padding after nested structs).
  For these types (no member wider than 4 bytes) XCDR1 and XCDR2 lay the payload out the same way;
* the **checksum** (``unitree_crc32``): CRC-32 with polynomial 0x04C11DB7, initial value 0xFFFFFFFF, no
  reflection and no final XOR (CRC-32/MPEG-2), over the C layout taken as little-endian 32-bit words, each
  fed most significant bit first, every word but the last (the ``crc`` member itself).

``MessageCodec`` keeps one message in its C layout as a 0-d numpy structured array (``message``: fields by
name, e.g. ``message["motor_cmd"]["q"]``), and turns it into wire bytes and back with one precomputed byte
permutation: a few microseconds, where the DDS binding's own Python serialiser takes about 0.7 ms per
``LowCmd_`` (a third of a 500 Hz tick).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

TOPIC_LOW_STATE = "rt/lowstate"
TOPIC_LOW_COMMAND = "rt/lowcmd"
HEAD = (0xFE, 0xEF)
"""``head`` of a low-level message."""
LEVEL_LOW = 0xFF
"""``level_flag`` of low-level control."""
MOTOR_MODE_SERVO = 0x01
"""``mode`` of a motor under command (Unitree: PMSM servo mode)."""
POSITION_STOP = 2.146e9
VELOCITY_STOP = 16000.0
"""``q`` and ``dq`` Unitree's SDK sends to a motor that must not track a position or a rate."""
MOTOR_SLOTS = 20
"""Motor slots of a ``unitree_go`` message (12 used by a quadruped)."""
FEET = 4


@dataclass(frozen=True)
class Member:
    """One member of an IDL struct: a primitive (``u1``, ``i1``, ``u2``, ``i2``, ``u4``, ``i4``, ``f4``)
    or a struct, alone or as a fixed-length array."""

    name: str
    kind: str | Struct
    length: int | None = None


@dataclass(frozen=True)
class Struct:
    """An IDL struct: its type name (``module.msg.dds_.Name_``) and members in declaration order."""

    typename: str
    members: tuple[Member, ...]

    @property
    def name(self) -> str:
        return self.typename.rsplit(".", 1)[-1]


def _struct(name: str, *members: tuple) -> Struct:
    return Struct(f"unitree_go.msg.dds_.{name}", tuple(Member(*member) for member in members))


MOTOR_CMD = _struct(
    "MotorCmd_",
    ("mode", "u1"),
    ("q", "f4"),
    ("dq", "f4"),
    ("tau", "f4"),
    ("kp", "f4"),
    ("kd", "f4"),
    ("reserve", "u4", 3),
)
BMS_CMD = _struct("BmsCmd_", ("off", "u1"), ("reserve", "u1", 3))
LOW_CMD = _struct(
    "LowCmd_",
    ("head", "u1", 2),
    ("level_flag", "u1"),
    ("frame_reserve", "u1"),
    ("sn", "u4", 2),
    ("version", "u4", 2),
    ("bandwidth", "u2"),
    ("motor_cmd", MOTOR_CMD, MOTOR_SLOTS),
    ("bms_cmd", BMS_CMD),
    ("wireless_remote", "u1", 40),
    ("led", "u1", 12),
    ("fan", "u1", 2),
    ("gpio", "u1"),
    ("reserve", "u4"),
    ("crc", "u4"),
)
IMU_STATE = _struct(
    "IMUState_",
    ("quaternion", "f4", 4),
    ("gyroscope", "f4", 3),
    ("accelerometer", "f4", 3),
    ("rpy", "f4", 3),
    ("temperature", "u1"),
)
MOTOR_STATE = _struct(
    "MotorState_",
    ("mode", "u1"),
    ("q", "f4"),
    ("dq", "f4"),
    ("ddq", "f4"),
    ("tau_est", "f4"),
    ("q_raw", "f4"),
    ("dq_raw", "f4"),
    ("ddq_raw", "f4"),
    ("temperature", "u1"),
    ("lost", "u4"),
    ("reserve", "u4", 2),
)
BMS_STATE = _struct(
    "BmsState_",
    ("version_high", "u1"),
    ("version_low", "u1"),
    ("status", "u1"),
    ("soc", "u1"),
    ("current", "i4"),
    ("cycle", "u2"),
    ("bq_ntc", "u1", 2),
    ("mcu_ntc", "u1", 2),
    ("cell_vol", "u2", 15),
)
LOW_STATE = _struct(
    "LowState_",
    ("head", "u1", 2),
    ("level_flag", "u1"),
    ("frame_reserve", "u1"),
    ("sn", "u4", 2),
    ("version", "u4", 2),
    ("bandwidth", "u2"),
    ("imu_state", IMU_STATE),
    ("motor_state", MOTOR_STATE, MOTOR_SLOTS),
    ("bms_state", BMS_STATE),
    ("foot_force", "i2", FEET),
    ("foot_force_est", "i2", FEET),
    ("tick", "u4"),
    ("wireless_remote", "u1", 40),
    ("bit_flag", "u1"),
    ("adc_reel", "f4"),
    ("temperature_ntc1", "u1"),
    ("temperature_ntc2", "u1"),
    ("power_v", "f4"),
    ("power_a", "f4"),
    ("fan_frequency", "u2", 4),
    ("reserve", "u4"),
    ("crc", "u4"),
)
STRUCTS = (MOTOR_CMD, BMS_CMD, LOW_CMD, IMU_STATE, MOTOR_STATE, BMS_STATE, LOW_STATE)
"""Every struct, parts before the messages that hold them."""


def c_dtype(struct: Struct) -> np.dtype:
    """The struct's C layout as a numpy structured dtype (little-endian, C alignment)."""
    fields = []
    for member in struct.members:
        base = c_dtype(member.kind) if isinstance(member.kind, Struct) else np.dtype("<" + member.kind)
        fields.append((member.name, base) if member.length is None else (member.name, base, (member.length,)))
    return np.dtype(fields, align=True)


def _primitives(dtype: np.dtype, base: int = 0):
    """``(offset, size)`` of every primitive element of ``dtype`` in declaration order (C layout)."""
    for name in dtype.names:
        sub, offset = dtype.fields[name][:2]
        if sub.subdtype is not None:
            element, shape = sub.subdtype
            for index in range(int(np.prod(shape))):
                yield from _element(element, base + offset + index * element.itemsize)
        else:
            yield from _element(sub, base + offset)


def _element(dtype: np.dtype, offset: int):
    if dtype.names:
        yield from _primitives(dtype, offset)
    else:
        yield offset, dtype.itemsize


def wire_layout(dtype: np.dtype) -> tuple[np.ndarray, np.ndarray, int]:
    """``(c_bytes, wire_bytes, size)``: byte ``c_bytes[i]`` of the C layout is byte ``wire_bytes[i]`` of the
    CDR payload; ``size``: the payload's length (every primitive aligned to its size from the payload's
    start, no padding between or after structs)."""
    c_index, wire_index = [], []
    position = 0
    for offset, size in _primitives(dtype):
        position = -(-position // size) * size
        c_index.extend(range(offset, offset + size))
        wire_index.extend(range(position, position + size))
        position += size
    return np.array(c_index, dtype=np.intp), np.array(wire_index, dtype=np.intp), position


_REVERSED_BITS = bytes(int(f"{value:08b}"[::-1], 2) for value in range(256))


def _reverse32(value: int) -> int:
    return int(f"{value:032b}"[::-1], 2)


def unitree_crc32(c_bytes: np.ndarray | bytes) -> int:
    """Unitree's checksum of a message in its C layout (module docstring): CRC-32/MPEG-2 over the
    little-endian 32-bit words of ``c_bytes`` but the last, each word most significant bit first. Computed
    with ``zlib``'s reflected CRC-32 on the bit-reversed bytes (the same register, mirrored)."""
    words = np.frombuffer(bytes(c_bytes), dtype="<u4")[:-1]
    stream = words.astype(">u4").tobytes().translate(_REVERSED_BITS)
    return _reverse32(zlib.crc32(stream) ^ 0xFFFFFFFF)


class WireFormatError(ValueError):
    """Bytes that are not a message of the expected type (wrong length or encoding)."""


ENCODING_XCDR1_LE = 0x01
ENCODING_XCDR2_LE = 0x07
"""Encapsulation identifiers (second header byte) of a little-endian final struct, XCDR1 and XCDR2."""


class MessageCodec:
    """One message of ``struct`` in its C layout (``message``), to and from its CDR wire bytes.

    ``message`` is a 0-d structured array over ``c_bytes``: write fields by name, then ``encode()``; or
    ``decode(data)`` and read them. ``seal()`` sets the ``crc`` member; ``crc_ok()`` checks it.
    """

    def __init__(self, struct: Struct) -> None:
        self.struct = struct
        self.dtype = c_dtype(struct)
        self.c_bytes = np.zeros(self.dtype.itemsize, dtype=np.uint8)
        self.message = self.c_bytes.view(self.dtype).reshape(())
        self._c_index, wire_index, self.payload_size = wire_layout(self.dtype)
        self._wire_index = wire_index + 4
        padded = -(-self.payload_size // 4) * 4
        self.wire = np.zeros(4 + padded, dtype=np.uint8)
        self.wire[1] = ENCODING_XCDR1_LE
        self._gather = np.zeros(len(self._c_index), dtype=np.uint8)
        self._padding = np.setdiff1d(np.arange(self.dtype.itemsize), self._c_index)
        """Padding bytes of the C layout: zero, as in the robot's structs (the checksum covers them)."""

    def offset_of(self, name: str) -> int:
        """Byte offset in the wire bytes (header included) of top-level primitive member ``name``."""
        offset = self.dtype.fields[name][1]
        return int(self._wire_index[np.searchsorted(self._c_index, offset)])

    def seal(self) -> None:
        """Set ``crc`` to the checksum of the message as it is now (padding zeroed first)."""
        self.c_bytes[self._padding] = 0
        self.message["crc"] = unitree_crc32(self.c_bytes)

    def crc_ok(self) -> bool:
        return int(self.message["crc"]) == unitree_crc32(self.c_bytes)

    def encode(self) -> bytes:
        """The wire bytes (XCDR1 header, little-endian) of ``message``."""
        np.take(self.c_bytes, self._c_index, out=self._gather)
        self.wire[self._wire_index] = self._gather
        return self.wire.tobytes()

    def decode(self, data: bytes | bytearray | memoryview) -> None:
        """``message`` from wire bytes; ``WireFormatError`` unless they hold a little-endian message of this
        type."""
        wire = np.frombuffer(data, dtype=np.uint8)
        if len(wire) < 4 + self.payload_size:
            raise WireFormatError(
                f"{self.struct.name}: {len(wire)} bytes, expected {4 + self.payload_size} or more"
            )
        if wire[0] != 0 or wire[1] not in (ENCODING_XCDR1_LE, ENCODING_XCDR2_LE):
            raise WireFormatError(
                f"{self.struct.name}: encapsulation {wire[0]:#04x}{wire[1]:02x} is not little-endian CDR"
            )
        np.take(wire, self._wire_index, out=self._gather)
        self.c_bytes[self._c_index] = self._gather
