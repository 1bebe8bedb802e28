"""Video of a logged run: the logged configurations replayed in MuJoCo (``robots.rendering``), in the
plant's scene (terrain, bar), with the plan in effect at every frame drawn over it
(``robots.plan_overlay``: planned base path, footholds, swing-foot paths, GRF arrows)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cafe_mpc.robots.plan_overlay import PlanOverlay, draw_plan
from cafe_mpc.robots.rendering import RenderUnavailable, render_configurations
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.sim.loop import SimulationLog

__all__ = ["RenderUnavailable", "render_run"]


def render_run(
    robot: Robot,
    log: SimulationLog,
    path: Path,
    fps: int = 30,
    plans: Sequence | None = None,
    mjcf: str | None = None,
) -> Path:
    """Replay the logged base/joint states in MuJoCo and write a video; returns the file written.

    ``plans``: the plans the controller followed (``experiments.controllers.RecordedPlan``: ``t`` first used,
    ``times``, ``configurations``, ``contacts``, ``forces``), drawn at every frame (the newest one used by
    then); ``mjcf``: the plant's scene (``sim.scene.Scene.mjcf``: terrain, bar; default the robot alone)."""
    if log.ticks == 0:
        raise RenderUnavailable("nothing to render: the log is empty")
    frame_times = np.arange(0.0, log.time[-1] + 1e-9, 1.0 / fps)
    indices = np.searchsorted(log.time, frame_times).clip(0, log.ticks - 1)
    decorate = None
    if plans:
        starts = np.array([plan.t for plan in plans])
        overlays: dict[int, PlanOverlay] = {}

        def decorate(frame: int, scene) -> None:
            t = float(frame_times[frame])
            index = int(np.searchsorted(starts, t + 1e-9, side="right")) - 1
            if index < 0:
                return
            if index not in overlays:
                plan = plans[index]
                overlays.clear()  # frames move forward: only the current plan is needed
                overlays[index] = PlanOverlay.of(
                    robot, plan.times, plan.configurations, plan.contacts, plan.forces
                )
            draw_plan(scene, overlays[index], t)

    return render_configurations(robot, log.q[indices], path, fps, mjcf=mjcf, decorate=decorate)
