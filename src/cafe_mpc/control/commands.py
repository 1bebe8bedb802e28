"""Commands at run time: a velocity command and a gait posted by the caller and taken by the MPC at its next
update (``cafe_mpc.Controller.set_command`` and ``set_gait``, keyboard teleop in ``--viewer``).

The caller and the MPC may be in different processes (``control.process``), so the channel is a small float64
array behind a seqlock (``control.ipc.seqlock``), the protocol of the MPC process's other channels: ``post``
writes in place (no allocation: it may be called from a 500 Hz loop), ``take`` returns a command once, when
the counter has moved and the copy is consistent. The payload is ``[vx, vy, yaw_rate, height, gait]``: m/s in
the heading frame, rad/s, m (NaN: the robot's standing height) and the index of the gait in ``GAIT_NAMES``
(NaN: the config's; once set, every post carries it).

The MPC side applies a taken command with ``apply_command``: the reference follows it from the update's
time on (``LocomotionReference.set_command``: ramped over ``gait.command_ramp`` from the value it has then,
as a timed command of the config would be) and switches to the gait at the gait's next cycle boundary
(``LocomotionReference.set_gait``) when it is not the one in force.

``check_command`` is the one check of a command, wherever it comes from: a config's commands
(``assembly.checks``), ``cafe_mpc.Controller.set_command``, the viewer's keyboard teleop.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from cafe_mpc.config import VelocityCommand
from cafe_mpc.control.ipc.seqlock import SeqLock
from cafe_mpc.ocp.contact_schedule import GAITS
from cafe_mpc.reference.base import Reference
from cafe_mpc.reference.locomotion import validate_command
from cafe_mpc.reference.tested_ranges import outside_tested_range
from cafe_mpc.robots.robot import Robot

logger = logging.getLogger(__name__)

COMMAND_SIZE = 5
"""Payload floats: vx, vy, yaw_rate, height (NaN: standing height), gait index (NaN: the config's)."""

GAIT_NAMES: tuple[str, ...] = tuple(sorted(GAITS))
"""The gaits a command can name, by index (``ocp.contact_schedule.GAITS``)."""


class CommandChannel:
    """A seqlock channel of one runtime command (module docstring) over ``array`` (``COMMAND_SIZE`` + 1
    float64; a plain array inline, shared memory in the MPC process's control block)."""

    def __init__(self, array: np.ndarray | None = None) -> None:
        if array is None:
            array = np.zeros(COMMAND_SIZE + 1)
        if array.shape != (COMMAND_SIZE + 1,) or array.dtype != np.float64:
            raise ValueError(f"a command channel needs {COMMAND_SIZE + 1} float64 values, got {array.shape}")
        self.lock = SeqLock(array)
        self._seen = 0.0  # a fresh channel starts at 0: a command posted before this side attached counts
        self._copy = np.zeros(COMMAND_SIZE)

    @property
    def array(self) -> np.ndarray:
        return self.lock.array

    def post(
        self, vx: float, vy: float, yaw_rate: float, height: float | None, gait: int | None = None
    ) -> None:
        """Write a command in place (the caller has validated it); ``gait``: an index of ``GAIT_NAMES``."""
        lock = self.lock
        payload = lock.payload
        lock.begin_write()
        payload[0] = vx
        payload[1] = vy
        payload[2] = yaw_rate
        payload[3] = math.nan if height is None else height
        payload[4] = math.nan if gait is None else float(gait)
        lock.end_write()

    def take(self) -> np.ndarray | None:
        """The newest command posted since the last ``take`` (a view reused by the next call), else None (also
        while one is being written: it is taken next time)."""
        sequence = self.lock.read_into(self._copy, newer_than=self._seen)
        if sequence is None:
            return None
        self._seen = sequence
        return self._copy


def apply_command(reference: Reference, t: float, values: np.ndarray) -> None:
    """Make ``reference`` follow the command ``values`` (``CommandChannel.take``) from time ``t`` on.

    A reference that cannot take commands (a stored trajectory, a composed reference) ignores it with a
    warning; ``cafe_mpc.Controller`` refuses such commands before they are posted."""
    set_command = getattr(reference, "set_command", None)
    if set_command is None:
        logger.warning("the reference %s takes no runtime commands; ignored", type(reference).__name__)
        return
    vx, vy, yaw_rate, height, gait = (float(value) for value in values)
    if not math.isnan(gait):
        switch = getattr(reference, "set_gait", None)
        if switch is None:
            logger.warning("the reference %s cannot switch gait; ignored", type(reference).__name__)
        elif reference.target_gait.name != GAIT_NAMES[int(gait)]:  # type: ignore[attr-defined]
            at = switch(t, GAIT_NAMES[int(gait)])
            logger.info("gait %s from %.3f s (requested at %.3f s)", GAIT_NAMES[int(gait)], at, t)
    command = VelocityCommand(
        start=max(t, 0.0), vx=vx, vy=vy, yaw_rate=yaw_rate, height=None if math.isnan(height) else height
    )
    set_command(t, command)


def check_command(command: VelocityCommand, robot: Robot, gait: str) -> str | None:
    """Whether ``robot`` can follow ``command`` in ``gait``: ``ValueError`` (naming the value) when it cannot
    (``reference.locomotion.validate_command``: speeds, yaw rate, height); why it may not work when the
    command lies outside the range the gait was tested in on the robot (``reference.tested_ranges``), else
    None."""
    validate_command(command, robot)
    return outside_tested_range(gait, command, robot.name)
