"""Python's garbage collector kept out of MPC updates.

A collection is triggered by allocations wherever they happen; one that falls inside an update adds its
pause to that update (a full collection over the few hundred thousand objects of an MPC, its knot data
and the simulator took 100-150 ms on the CI-class machine: BENCHMARKS.md). So:

* ``paused``: every update phase (cold solve, preparation, feedback) runs with the collector disabled;
  the allocations it made are collected afterwards, between updates;
* ``freeze_live_objects``: after the cold solve and the warm-up, everything alive is collected once and
  moved to the permanent generation (``gc.freeze``): the models, data and workspaces that live as long as
  the MPC are then never traversed again, so the collections between updates stay short. A later cold
  solve (a new MPC in the same process) first unfreezes (``gc.unfreeze``), so the objects of an MPC that
  is gone become collectable again.
"""

from __future__ import annotations

import functools
import gc
from collections.abc import Callable
from typing import ParamSpec, TypeVar

P = ParamSpec("P")
R = TypeVar("R")


def paused(method: Callable[P, R]) -> Callable[P, R]:
    """Run ``method`` with the garbage collector disabled (restored afterwards, also on errors)."""

    @functools.wraps(method)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        enabled = gc.isenabled()
        gc.disable()
        try:
            return method(*args, **kwargs)
        finally:
            if enabled:
                gc.enable()

    return wrapper


def thaw() -> None:
    """Make the frozen objects collectable again (before a cold solve)."""
    gc.unfreeze()


def freeze_live_objects() -> None:
    """Collect everything, then move the survivors to the permanent generation (``gc.freeze``)."""
    gc.collect()
    gc.freeze()
