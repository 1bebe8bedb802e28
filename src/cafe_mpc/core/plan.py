"""What every plan is, whatever planner made it, and how a plan type's arrays are laid out for a transport.

``KnotPlan``: ``n`` knot intervals ``[times[k], times[k] + dt[k])`` with the stance flags and ground reaction
forces planned over each, the plan's start and end, and the interval that holds a time (``knot_at``:
zero-order hold, the knot a low level follows at ``t``). It is what the MPC loops (the plan in effect, the
horizon run out), the PD fallback, the state estimator's planned stance, the run's records and the plan's
drawing read. A planner's own plan type adds what its low
level needs (``planners.cafe.plan.Plan``: states, torques, gains, Q-function pieces;
``planners.template.plan.TemplatePlan``: SRB states, ground reaction forces, reference feet).

``PlanFormat``: a plan type's array fields, their shapes for a plan of ``n`` knots and its constructor, so
that a transport (``control.ipc``: the shared-memory plan channel) moves any plan type without knowing its
fields.

``interval_at(times, t)`` and ``nearest_knot(times, t)``: the lookups plans and their users share.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Generic, Protocol, TypeVar

import numpy as np

PlanT = TypeVar("PlanT", bound="KnotPlan")
"""A plan type (``KnotPlan`` and what its planner adds)."""


class KnotPlan(Protocol):
    """What every plan has (module docstring)."""

    times: np.ndarray
    """(n,) start time of each knot interval."""
    dt: np.ndarray
    """(n,) duration of each knot interval."""
    contacts: np.ndarray
    """(n, n_feet) bool: the stance flags planned over each interval (leg order)."""
    forces: np.ndarray
    """(n, n_feet, 3): the planned world-frame ground reaction forces over each interval."""

    @property
    def start_time(self) -> float: ...

    @property
    def end_time(self) -> float: ...

    def knot_at(self, t: float) -> int:
        """Index of the interval that contains ``t`` (clamped to the plan)."""
        ...

    def knot_configurations(self, nq: int) -> np.ndarray | None:
        """The robot's configurations ``(n + 1, nq)`` at the knot times when the plan has them (what a drawing
        of the plan shows: ``robots.plan_overlay``), else None."""
        ...


@dataclass(frozen=True)
class PlanFormat(Generic[PlanT]):
    """How plans of one type travel as arrays (module docstring).

    ``make(**arrays)``: the plan from its fields; ``shapes(n)``: each field's shape for a plan of ``n`` knots
    (first axis: rows, which grow with ``n``); ``capacity``: the most knots a plan of the run may have;
    ``dtypes``: the fields that are not float arrays, and their types. Picklable when ``make`` and ``shapes``
    are (a class and a ``functools.partial`` of a module-level function are), so that another process can
    read the plans."""

    make: Callable[..., PlanT]
    shapes: Callable[[int], dict[str, tuple[int, ...]]]
    capacity: int
    dtypes: Mapping[str, type] = field(default_factory=dict)


def nearest_knot(times: np.ndarray, t: float) -> int:
    """Index of the entry of the sorted ``times`` closest to ``t`` (clamped to the first and last)."""
    index = int(np.searchsorted(times, t))
    if index <= 0:
        return 0
    if index >= len(times):
        return len(times) - 1
    return index if times[index] - t < t - times[index - 1] else index - 1


def interval_at(times: np.ndarray, t: float) -> int:
    """Index ``k`` of the interval ``[times[k], times[k + 1])`` that contains ``t`` (clamped to the first and
    last); a time within 1 ns of a knot time belongs to the interval that starts there."""
    index = int(np.searchsorted(times, t + 1e-9, side="right")) - 1
    return min(max(index, 0), len(times) - 1)
