"""CAFE-MPC as a run config builds it (``planners.registry``: ``planner: cafe``).

The planner (``RecedingHorizonMpc``) over the run's CAFE problem (``planners.cafe.setup``) with the ``mpc``
section's receding-horizon settings; its plans' format for the MPC process's plan channel. Its low level is
the one the config's ``wbc`` names (``low_level.registry``: Riccati (33) or the VWBC (34) on its ``Plan``).
"""

from __future__ import annotations

from cafe_mpc.core.plan import PlanFormat
from cafe_mpc.planners.base import PlannerSlice
from cafe_mpc.planners.cafe.plan import Plan, plan_format
from cafe_mpc.planners.cafe.planner import RecedingHorizonMpc
from cafe_mpc.planners.cafe.setup import build_problem
from cafe_mpc.planners.resolved import ResolvedRun
from cafe_mpc.reference.base import Reference

SWITCH_KNOTS = 16
"""Knots a plan may have beyond the whole-body grid's: one per contact switch inside the horizon."""


def build_planner(run: ResolvedRun, reference: Reference) -> RecedingHorizonMpc:
    """The CAFE-MPC planner of a run: the CAFE problem with its model schedule (Sec. IV-D) tracking
    ``reference``, receding-horizon settings from the ``mpc`` section."""
    return RecedingHorizonMpc(run.controller_robot, reference, build_problem(run), run.config.mpc)


def build_plan_format(run: ResolvedRun) -> PlanFormat[Plan]:
    """How the run's plans travel as arrays: at most the whole-body grid's knots plus the splits at contact
    switches."""
    robot = run.controller_robot
    capacity = run.schedule.whole_body_knots + SWITCH_KNOTS
    return plan_format(capacity, robot.nq + robot.nv, robot.nu, 2 * robot.nv, robot.n_feet)


SLICE = PlannerSlice(Plan, build_planner, build_plan_format)
"""CAFE-MPC's entry in ``planners.registry.PLANNERS``."""
