"""The ``task`` block of an acrobatic run's ``metrics.json`` (paper Sec. VII-C; ``report.task_metrics``).

The composed reference itself (stand, stored trajectory, gait segments) and its weight set are the
assembly's (``assembly.references``, ``planners.cafe.setup``).
"""

from __future__ import annotations

from cafe_mpc.planners.resolved import ResolvedRun
from cafe_mpc.reference.base import Reference
from cafe_mpc_lab.report.task_metrics import task_from_reference, task_metrics
from cafe_mpc_lab.sim.bar import bar_of
from cafe_mpc_lab.sim.loop import SimulationLog


def task_block(run: ResolvedRun, log: SimulationLog, reference: Reference | None) -> dict | None:
    """The ``task`` block of ``metrics.json`` for a run whose reference holds a stored trajectory with a
    flight phase (``report.task_metrics``), with the torque limits the run's controller was built with;
    ``None`` otherwise. The roll's friction-cone score uses ``task_metrics``' default contact model (the
    nominal floor's friction, ``config.DEFAULT_FRICTION``, and the reference robot's Baumgarte rate and
    tolerance), not the run's (``mpc.friction``, scaled), which the ``wbc`` block's score uses."""
    task = task_from_reference(reference)
    if task is None:
        return None
    return task_metrics(
        run.robot,
        log,
        task,
        run.control_period,
        requested=log.extra.get("torque_requested"),
        planned_stance=log.extra.get("planned_stance"),
        limits=run.torque_limits,
        bar=bar_of(run.config.scene),
    )
