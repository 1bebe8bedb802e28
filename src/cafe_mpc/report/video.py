"""Video of a logged run: the logged configurations replayed in MuJoCo (``robots.rendering``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cafe_mpc.robots.rendering import RenderUnavailable, render_configurations
from cafe_mpc.robots.robot import Robot
from cafe_mpc.sim.loop import SimulationLog

__all__ = ["RenderUnavailable", "render_run"]


def render_run(robot: Robot, log: SimulationLog, path: Path, fps: int = 30) -> Path:
    """Replay the logged base/joint states in MuJoCo and write a video; returns the file written."""
    if log.ticks == 0:
        raise RenderUnavailable("nothing to render: the log is empty")
    frame_times = np.arange(0.0, log.time[-1] + 1e-9, 1.0 / fps)
    indices = np.searchsorted(log.time, frame_times).clip(0, log.ticks - 1)
    return render_configurations(robot, log.q[indices], path, fps)
