"""Unitree's messages on Cyclone DDS: the IDL types for the binding, a participant on one network interface,
and the publishers and subscribers of pre-encoded messages.

The Cyclone DDS Python binding (``cyclonedds``, the ``robot`` extra: ``pip install 'cafe-mpc[robot]'``) is
imported here, on first use; without it ``require_cyclonedds`` raises one ``RobotInterfaceError`` saying
how to install it.

``idl_types()`` builds the binding's types from ``messages.STRUCTS`` (final structs with sequential member
ids, the type names of Unitree's IDL), so that DDS matches them with Unitree's own readers and writers. The
two messages (``LowCmd_``, ``LowState_``) travel pre-encoded: their instances carry the CDR bytes
``messages.MessageCodec`` made (``serialize`` returns them), and taking a sample returns its bytes
(``deserialize`` keeps them), so the binding's Python serialiser (0.7 ms a message) never runs. Anything the
binding itself serialises for these types (``type.__idl__``) gives the same bytes (tests/test_robot_io.py).

Network: ``participant(domain, network_interface, multicast)`` joins DDS domain ``domain`` on one interface
(as Unitree's SDK does: its robots use domain 0 on the robot's Ethernet, unitree_mujoco domain 1 on ``lo``).
Without multicast (``multicast=False``) discovery goes by unicast to 127.0.0.1 with participant indices:
for a loopback interface that does not carry multicast (some containers); both ends must then use it.
"""

from __future__ import annotations

import functools
from typing import Any

from cafe_mpc.robot_io.interface import RobotInterfaceError
from cafe_mpc.robot_io.unitree.messages import LOW_CMD, LOW_STATE, STRUCTS, Struct

INSTALL_HINT = "pip install 'cafe-mpc[robot]' (the pinned Cyclone DDS binding, cyclonedds==11.0.1)"
HISTORY_DEPTH = 16
"""Samples a subscriber keeps between two takes (a 500 Hz stream read at 500 Hz with jitter needs a few)."""
_PRIMITIVES = {"u1": "uint8", "i1": "int8", "u2": "uint16", "i2": "int16", "u4": "uint32", "i4": "int32"}


def require_cyclonedds():
    """The ``cyclonedds`` module; ``RobotInterfaceError`` (one line) when the extra is not installed."""
    try:
        import cyclonedds
        import cyclonedds.domain
    except ImportError as error:
        raise RobotInterfaceError(f"the unitree-dds interface needs Cyclone DDS: {INSTALL_HINT}") from error
    return cyclonedds


class Received:
    """A sample as taken from a subscriber: its CDR bytes (``data``) and the binding's ``sample_info``."""

    __slots__ = ("data", "sample_info")

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.sample_info = None


def _serialize_pre_encoded(self, buffer=None, endianness=None, use_version_2: bool | None = None) -> bytes:
    """``serialize`` of a message instance: the wire bytes it carries (``_payload``)."""
    if use_version_2:  # the same payload; only the encapsulation identifier differs
        return self._payload[:1] + b"\x07" + self._payload[2:]
    return self._payload


def _deserialize_pre_encoded(cls, data: bytes, has_header: bool = True, use_version_2=None) -> Received:
    """``deserialize`` of a message type: the sample's wire bytes, kept for ``messages.MessageCodec``."""
    return Received(bytes(data))


def _deserialize_key_pre_encoded(cls, data: bytes, has_header: bool = True, use_version_2=None) -> None:
    """The key of an invalid sample (a writer gone): a keyless topic has nothing to read."""
    return None


@functools.cache
def idl_types(pre_encoded: bool = True) -> dict[str, Any]:
    """The binding's IDL types of ``messages.STRUCTS`` by struct name (``LowCmd_``, ...). ``pre_encoded``:
    the two messages carry their own wire bytes (module docstring); False: plain dataclasses the binding
    serialises itself (for tests)."""
    require_cyclonedds()
    import cyclonedds.idl as idl
    import cyclonedds.idl.annotations as annotate
    import cyclonedds.idl.types as types

    built: dict[str, Any] = {}

    def member_type(member):
        if isinstance(member.kind, Struct):
            base = built[member.kind.name]
        elif member.kind == "f4":
            base = types.float32
        else:
            base = getattr(types, _PRIMITIVES[member.kind])
        return base if member.length is None else types.array[base, member.length]

    for struct in STRUCTS:
        fields = {member.name: member_type(member) for member in struct.members}
        encoded = pre_encoded and struct in (LOW_CMD, LOW_STATE)
        cls = idl.make_idl_struct(struct.name, struct.typename, fields, dataclassify=not encoded)
        annotate.final(cls)
        annotate.autoid("sequential")(cls)
        if encoded:  # methods, not a base class: a base would be an IDL base struct to DDS
            cls._payload = b""
            cls.serialize = _serialize_pre_encoded
            cls.deserialize = classmethod(_deserialize_pre_encoded)
            cls.deserialize_key = classmethod(_deserialize_key_pre_encoded)
        built[struct.name] = cls
    return built


def loopback_config(network_interface: str, multicast: bool) -> str:
    """Cyclone DDS's XML configuration for one network interface (module docstring)."""
    discovery = ""
    general = ""
    if not multicast:
        general = "<AllowMulticast>false</AllowMulticast>"
        discovery = (
            "<Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>20"
            '</MaxAutoParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers></Discovery>'
        )
    return (
        '<CycloneDDS><Domain Id="any"><General><Interfaces>'
        f'<NetworkInterface name="{network_interface}" priority="default" multicast="default"/>'
        f"</Interfaces>{general}</General>{discovery}</Domain></CycloneDDS>"
    )


_DOMAINS: dict[int, tuple[str | None, Any, Any]] = {}
"""Domain id -> (configuration, Domain, DomainParticipant): one participant per domain and process."""


def participant(domain: int, network_interface: str | None = None, multicast: bool = True):
    """This process's participant in DDS domain ``domain`` on ``network_interface`` (None: Cyclone's
    default, or ``CYCLONEDDS_URI``). A second call for the same domain returns the same participant; with
    another interface it raises ``RobotInterfaceError``."""
    require_cyclonedds()
    from cyclonedds.domain import Domain, DomainParticipant

    config = None if network_interface is None else loopback_config(network_interface, multicast)
    if domain in _DOMAINS:
        known, _, existing = _DOMAINS[domain]
        if known != config:
            raise RobotInterfaceError(
                f"DDS domain {domain} is already joined here with another configuration"
            )
        return existing
    try:
        handle = Domain(domain, config) if config is not None else None
        joined = DomainParticipant(domain)
    except Exception as error:  # the binding raises DDSException for a bad interface or configuration
        where = f" on network interface {network_interface!r}" if network_interface else ""
        raise RobotInterfaceError(f"cannot join DDS domain {domain}{where}: {error}") from error
    _DOMAINS[domain] = (config, handle, joined)
    return joined


class Publisher:
    """Writes pre-encoded messages of ``struct`` on ``topic`` (the binding's default QoS: reliable, keep
    the last, as Unitree's SDK)."""

    def __init__(self, joined, topic: str, struct: Struct) -> None:
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic

        cls = idl_types()[struct.name]
        self.topic = Topic(joined, topic, cls)
        self.writer = DataWriter(joined, self.topic)
        self.sample = cls()

    def write(self, data: bytes) -> None:
        self.sample._payload = data
        self.writer.write(self.sample)

    def matched(self) -> int:
        """Subscribers matched so far."""
        return len(self.writer.get_matched_subscriptions())

    def close(self) -> None:
        self.writer = None
        self.topic = None


class Subscriber:
    """Takes the messages of ``struct`` on ``topic`` as their wire bytes (best effort, the last
    ``HISTORY_DEPTH``)."""

    def __init__(self, joined, topic: str, struct: Struct) -> None:
        from cyclonedds.qos import Policy, Qos
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        cls = idl_types()[struct.name]
        self.topic = Topic(joined, topic, cls)
        qos = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(HISTORY_DEPTH))
        self.reader = DataReader(joined, self.topic, qos=qos)

    def take(self) -> list[Received]:
        """Every sample received since the last take, oldest first (invalid samples left out)."""
        samples = self.reader.take(N=HISTORY_DEPTH)
        return [sample for sample in samples if isinstance(sample, Received)]

    def close(self) -> None:
        self.reader = None
        self.topic = None
