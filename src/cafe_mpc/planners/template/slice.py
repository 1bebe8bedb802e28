"""The template-MPC baseline as a run config builds it (``planners.registry``: ``planner: template``, paper
Sec. VII-C).

The planner (``TemplateMpc``): the SRB-only problem (``planners.template.problem``) of the ``template``
section (``config.TemplateSettings``), tracking the run's reference with the ``mpc`` section's
receding-horizon settings (period, latency, iterations), the run's friction and torque limits; its own low
level (stance ``J' F``, swing PD: ``planners.template.low_level``, the config's ``wbc`` is not used); its
plans' format for the MPC process's plan channel.
"""

from __future__ import annotations

from cafe_mpc.core.plan import PlanFormat
from cafe_mpc.planners.base import PlannerSlice
from cafe_mpc.planners.resolved import ResolvedRun
from cafe_mpc.planners.template.low_level import TemplateLowLevelController
from cafe_mpc.planners.template.plan import TemplatePlan, template_plan_format
from cafe_mpc.planners.template.planner import TemplateMpc
from cafe_mpc.planners.template.problem import TemplateProblemBuilder
from cafe_mpc.reference.base import Reference


def build_planner(run: ResolvedRun, reference: Reference) -> TemplateMpc:
    """The template MPC of a run: the SRB-only plan of the run's reference."""
    builder = TemplateProblemBuilder(
        run.controller_robot, run.config.template, run.contact.friction, run.torque_limits
    )
    return TemplateMpc(run.controller_robot, reference, builder, run.config.mpc)


def build_low_level(run: ResolvedRun) -> TemplateLowLevelController:
    """The template's low level: its swing gains carried to the robot, the run's torque limits."""
    return TemplateLowLevelController(
        run.controller_robot, run.config.template, run.scale, run.torque_limits.copy()
    )


def build_plan_format(run: ResolvedRun) -> PlanFormat[TemplatePlan]:
    """How the run's plans travel as arrays: the grid's intervals, each split at most once by a contact
    switch (``TemplateProblemBuilder.knot_times``)."""
    return template_plan_format(2 * run.config.template.knots, run.controller_robot.n_feet)


SLICE = PlannerSlice(TemplatePlan, build_planner, build_plan_format, low_level=build_low_level)
"""The template's entry in ``planners.registry.PLANNERS``."""
