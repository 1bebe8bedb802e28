"""What every plan has: knot intervals over time, and the lookups of the knot that holds a time.

``interval_at(times, t)``: the interval ``[times[k], times[k + 1])`` that contains ``t`` (the knot a low
level follows at ``t``, zero-order hold); ``nearest_knot(times, t)``: the knot closest in time.
"""

from __future__ import annotations

import numpy as np


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
