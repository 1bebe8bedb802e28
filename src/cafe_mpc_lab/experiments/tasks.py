"""The ``task`` block of an acrobatic run's ``metrics.json`` (paper Sec. VII-C; ``report.task_metrics``).

The composed reference itself (stand, stored trajectory, gait segments) and its weight set are the
assembly's (``assembly.references``, ``planners.cafe.setup``).
"""

from __future__ import annotations

from cafe_mpc.assembly.context import torque_limits_of
from cafe_mpc.config import RunConfig
from cafe_mpc.reference.base import Reference
from cafe_mpc.robots.robot import Robot
from cafe_mpc_lab.report.task_metrics import task_from_reference, task_metrics
from cafe_mpc_lab.sim.bar import bar_of
from cafe_mpc_lab.sim.loop import SimulationLog


def task_block(
    config: RunConfig, robot: Robot, log: SimulationLog, reference: Reference | None
) -> dict | None:
    """The ``task`` block of ``metrics.json`` for a run whose reference holds a stored trajectory with a
    flight phase (``report.task_metrics``); ``None`` otherwise."""
    task = task_from_reference(reference)
    if task is None:
        return None
    return task_metrics(
        robot,
        log,
        task,
        1.0 / config.simulation.control_rate_hz,
        requested=log.extra.get("torque_requested"),
        planned_stance=log.extra.get("planned_stance"),
        limits=torque_limits_of(config, robot),
        bar=bar_of(config.scene),
    )
