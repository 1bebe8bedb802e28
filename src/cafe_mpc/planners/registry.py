"""The planners a run config's ``planner`` key names: one line per slice (``planners.base.PlannerSlice``)."""

from __future__ import annotations

from cafe_mpc.planners.base import PlannerSlice, Registry
from cafe_mpc.planners.cafe import slice as cafe
from cafe_mpc.planners.template import slice as template

PLANNERS: Registry[PlannerSlice] = Registry(
    "planner",
    "planner",
    {
        "cafe": cafe.SLICE,
        "template": template.SLICE,
    },
)
"""``planner`` -> its slice; ``PLANNERS.get(name)`` raises ``ConfigError`` naming the key for an unknown
name."""
