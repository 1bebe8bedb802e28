"""The command range each gait was measured to track (``reference/data/tested_ranges.yaml``), and the
warning a command outside it gets.

The schema accepts any command the robot's legs allow (|vx| <= 3 m/s, ``validate_command``); what a gait
tracks is less. The file is written by the sweep ``python -m cafe_mpc_lab.experiments.command_ranges --write``
(fixed latency, Mini Cheetah): per gait the forward speeds that worked (``vx``: low and high, m/s, at yaw rate
0) and the largest yaw rate that worked at 0.5 m/s (``yaw_rate_max``, rad/s), with the date and the command.
A command outside is still run, with a warning (``outside_tested_range``): it may work, it was not tested.
"""

from __future__ import annotations

import functools
from pathlib import Path

import yaml

from cafe_mpc.config import VelocityCommand

TESTED_RANGES_FILE = Path(__file__).parent / "data" / "tested_ranges.yaml"
TESTED_ROBOT = "mini_cheetah"
"""The robot the sweep ran on; other robots' ranges are not measured (no warning for them)."""


@functools.lru_cache(maxsize=1)
def tested_ranges() -> dict:
    """The measured ranges by gait name (snake case); empty when the file is missing."""
    if not TESTED_RANGES_FILE.is_file():
        return {}
    with open(TESTED_RANGES_FILE) as handle:
        data = yaml.safe_load(handle) or {}
    return dict(data.get("gaits") or {})


def outside_tested_range(gait: str, command: VelocityCommand, robot: str = TESTED_ROBOT) -> str | None:
    """Why ``command`` is outside the range ``gait`` was tested in (one line), or None when it is inside or
    nothing was measured for this gait and robot."""
    if robot != TESTED_ROBOT:
        return None
    tested = tested_ranges().get(gait.replace("-", "_"))
    if not tested:
        return None
    span = tested.get("vx")
    if span is None:
        return f"gait {gait}: no tested forward speed worked (docs/usage.md, 'Tested command ranges')"
    low, high = span
    if not low - 1e-9 <= command.vx <= high + 1e-9:
        return (
            f"gait {gait}: vx = {command.vx:g} m/s is outside the tested range {low:g} to {high:g} m/s "
            "(docs/usage.md, 'Tested command ranges')"
        )
    yaw_max = tested.get("yaw_rate_max")
    if yaw_max is not None and abs(command.yaw_rate) > yaw_max + 1e-9:
        return (
            f"gait {gait}: |yaw_rate| = {abs(command.yaw_rate):g} rad/s is above the tested "
            f"{yaw_max:g} rad/s (docs/usage.md, 'Tested command ranges')"
        )
    return None
