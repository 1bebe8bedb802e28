"""A real robot's low level behind one interface: its state in, joint commands out, the link's health.

* ``interface``: ``RobotInterface`` (read the newest state, write a ``JointCommand``, ``health``), the
  ``Clock`` it runs on, ``LinkMonitor``;
* ``mapping``: joints <-> motor slots, signs and zero offsets (the robot file's ``hardware`` section);
* ``motors``: the motor drivers' PD + feed-forward law;
* ``unitree``: Unitree's low-level DDS topics (``rt/lowstate``, ``rt/lowcmd``; needs the ``robot`` extra);
* ``inprocess``: a simulated plant in the same process, in simulated time (tests).

``make_interface(name, robot, ...)`` builds the interface a robot file names (``hardware.interface``).
"""

from __future__ import annotations

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
from cafe_mpc.robots.robot import Robot

INTERFACES = ("unitree-dds",)
"""Interfaces ``make_interface`` builds (a robot file's ``hardware.interface``)."""

__all__ = [
    "INTERFACES",
    "Clock",
    "JointCommand",
    "LinkHealth",
    "LinkMonitor",
    "RobotInterface",
    "RobotInterfaceError",
    "RobotState",
    "WallClock",
    "make_interface",
]


def make_interface(
    name: str,
    robot: Robot,
    domain: int = 0,
    network_interface: str | None = None,
    multicast: bool = True,
) -> RobotInterface:
    """The interface ``name`` to ``robot`` (not yet open). ``ValueError`` (one line) for an interface that
    does not exist or that the robot file does not name."""
    if name not in INTERFACES:
        raise ValueError(f"unknown robot interface {name!r}; interfaces: {', '.join(INTERFACES)}")
    if robot.hardware is None:
        raise ValueError(
            f"robot {robot.name!r} has no hardware section in its robot file: its motors are not mapped "
            "(docs/deploy.md)"
        )
    if robot.hardware.interface != name:
        raise ValueError(
            f"robot {robot.name!r} speaks {robot.hardware.interface!r} (hardware.interface), not {name!r}"
        )
    from cafe_mpc.robot_io.unitree.robot import UnitreeDdsRobot

    return UnitreeDdsRobot(robot, domain, network_interface, multicast)
