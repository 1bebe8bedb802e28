"""The template-MPC baseline as a run config builds it (``planners.registry``: ``planner: template``, paper
Sec. VII-C).

The planner (``TemplateMpc``): the SRB-only problem (``planners.template.problem``) of the ``template``
section, tracking the run's reference with the ``mpc`` section's receding-horizon settings (period,
latency, iterations); its own low level (stance ``J' F``, swing PD: ``planners.template.low_level``, the
config's ``wbc`` is not used); its plans' format for the MPC process's plan channel.
"""

from __future__ import annotations

from cafe_mpc.config import ConfigError
from cafe_mpc.core.plan import PlanFormat
from cafe_mpc.planners.base import PlannerSlice, RunContext
from cafe_mpc.planners.template.low_level import TemplateLowLevelController, TemplateLowLevelSettings
from cafe_mpc.planners.template.plan import TemplatePlan, template_plan_format
from cafe_mpc.planners.template.planner import TemplateMpc
from cafe_mpc.planners.template.problem import TemplateProblemBuilder, TemplateSettings, template_srb
from cafe_mpc.reference.base import Reference


def template_settings(run: RunContext) -> TemplateSettings:
    """The template's problem settings: the ``template`` section, the robot's SRB (``template_srb``), the
    run's torque limits and friction."""
    config = run.config
    section = config.template
    parameters, _ = template_srb(run.robot)
    try:
        return TemplateSettings(
            horizon=section.horizon,
            dt=section.dt,
            parameters=parameters,
            leg_torque_limits=section.leg_torque_limits,
            predict_latency=section.predict_latency,
            centroidal_state=section.centroidal_state,
            vertical_reference=section.vertical_reference,
            torque_limits=tuple(run.torque_limits.tolist()),
            friction_coefficient=config.mpc.friction,
        )
    except ValueError as error:
        raise ConfigError(f"template: {error}") from error


def build_planner(run: RunContext, reference: Reference) -> TemplateMpc:
    """The template MPC of a run: the SRB-only plan of the run's reference."""
    _, com_offset = template_srb(run.robot)
    builder = TemplateProblemBuilder(run.robot, template_settings(run), com_offset)
    return TemplateMpc(run.robot, reference, builder, run.config.mpc)


def build_low_level(run: RunContext) -> TemplateLowLevelController:
    """The template's low level: its swing gains scaled to the robot, the run's torque limits."""
    section, scale = run.config.template, run.scale
    try:
        settings = TemplateLowLevelSettings(
            scale.stiffness(section.swing_kp), scale.damping(section.swing_kd)
        )
    except ValueError as error:
        raise ConfigError(f"template: {error}") from error
    return TemplateLowLevelController(run.robot, settings, torque_limits=run.torque_limits.copy())


def build_plan_format(run: RunContext) -> PlanFormat[TemplatePlan]:
    """How the run's plans travel as arrays: the grid's intervals, each split at most once by a contact
    switch (``TemplateProblemBuilder.knot_times``)."""
    return template_plan_format(2 * template_settings(run).knots, run.robot.n_feet)


SLICE = PlannerSlice(TemplatePlan, build_planner, build_plan_format, low_level=build_low_level)
"""The template's entry in ``planners.registry.PLANNERS``."""
