"""Knot times of a receding-horizon problem on the absolute time grid, and interpolation by time.

An MPC update may start at any time ``t0`` (the time of its measurement: a multiple of the control period,
not of the knot spacing). If the knots sat at ``t0 + k dt``, every update would discretise the contact
schedule differently: a touchdown at 0.300 s would fall inside a knot interval when ``t0`` = 0.026 s and be
moved to the next knot, 4 ms late, and the warm start would map knots 6 ms apart onto each other. Measured:
the bound preset fell with fixed latencies of 25 and 35 ms and MPC periods of 15 and 25 ms (update starts
off the 10 ms grid) and stood when the same runs started their updates on the grid (BENCHMARKS.md).

So the knots of the whole-body plan sit on the absolute grid ``k dt``: the first interval runs from ``t0``
to the first grid time after it (a fractional first knot), and an interval that a contact switch falls
inside is split at the switch, so that every touchdown and lift-off happens at the reference's absolute
time whatever ``t0`` is (``grid_times``). Knot durations are rounded to ``TIME_QUANTUM`` so that the
dynamics objects of the few distinct durations can be made once and kept.

``PiecewiseTrajectory`` evaluates a previous solution at new knot times: states interpolated linearly in
the tangent space between the two knots around ``t``, controls held over their interval (zero-order hold,
as the discretised dynamics apply them). The warm start of every update uses it.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Sequence

import numpy as np

TIME_QUANTUM = 1e-3
"""Resolution of knot times and durations (s): switch times closer than half of it to a grid time are that
grid time, and each knot's duration is a whole number of quanta (one dynamics object per duration)."""


def quanta(duration: float) -> int:
    """``duration`` as a whole number of ``TIME_QUANTUM`` (at least 1)."""
    return max(round(duration / TIME_QUANTUM), 1)


def grid_times(
    t0: float,
    count: int,
    dt: float,
    switches: Sequence[float] = (),
    first_min: float = 0.0,
) -> np.ndarray:
    """Knot times from ``t0`` over ``count`` grid intervals of the absolute grid ``k dt``.

    The first knot runs from ``t0`` to the first grid time later than ``t0 + first_min`` (and later than
    ``t0`` by at least half a quantum); ``count - 1`` full intervals follow, so the horizon ends on the
    grid. ``switches`` strictly inside the horizon that are not grid times (within half a quantum) split
    their interval. Returns the ``count + 1 + (number of splits)`` increasing times.
    """
    if count < 1:
        raise ValueError(f"a horizon needs at least one knot, got {count}")
    if not dt > 0:
        raise ValueError(f"knot spacing must be positive, got {dt}")
    tolerance = 0.5 * TIME_QUANTUM
    first = math.floor((t0 + max(first_min, tolerance)) / dt + 1e-9) + 1
    grid = (first + np.arange(count)) * dt
    end = float(grid[-1])
    inside = [
        float(s)
        for s in switches
        if t0 + tolerance < s < end - tolerance and abs(s / dt - round(s / dt)) * dt > tolerance
    ]
    if not inside:
        times = np.empty(count + 1)
        times[0] = t0
        times[1:] = grid
        return times
    merged = sorted({*grid.tolist(), *inside})
    cleaned = [t0]
    for t in merged:
        if t - cleaned[-1] > tolerance:
            cleaned.append(t)
        elif t in grid:  # a switch within tolerance of a grid time: the grid time wins
            cleaned[-1] = t
    return np.asarray(cleaned)


class PiecewiseTrajectory:
    """A solved trajectory as a function of time (for warm starts by time, see the module docstring).

    ``times`` (n + 1) are the knot times, ``xs`` (n + 1, nx) the states, ``us`` (n, nu) the controls of the
    intervals. ``difference(x0, x1)`` and ``integrate(x, dx)`` are the state manifold's.
    """

    def __init__(
        self,
        times: np.ndarray,
        xs: np.ndarray,
        us: np.ndarray,
        difference: Callable[[np.ndarray, np.ndarray], np.ndarray],
        integrate: Callable[[np.ndarray, np.ndarray], np.ndarray],
    ) -> None:
        self.times: list[float] = np.asarray(times, dtype=float).tolist()
        self.start = self.times[0]
        self.end = self.times[-1]
        self.xs = xs
        self.us = us
        self._difference = difference
        self._integrate = integrate

    def covers(self, t: float) -> bool:
        tolerance = 0.5 * TIME_QUANTUM
        return self.times[0] - tolerance <= t <= self.times[-1] + tolerance

    def state_at(self, t: float) -> np.ndarray:
        """The state at ``t`` (a new array; ``state_into``)."""
        out = np.empty(self.xs.shape[1])
        self.state_into(t, out)
        return out

    def state_into(self, t: float, out: np.ndarray) -> None:
        """Write the state at ``t`` into ``out``: a knot's own state within half a quantum of its time, else
        the linear interpolation in the tangent space between the knots around ``t``; clamped to the ends."""
        times = self.times
        tolerance = 0.5 * TIME_QUANTUM
        index = bisect.bisect_left(times, t - tolerance)
        if index >= len(times):
            out[:] = self.xs[-1]
        elif abs(times[index] - t) <= tolerance or index == 0:
            out[:] = self.xs[index]
        else:
            t_a, t_b = times[index - 1], times[index]
            alpha = (t - t_a) / (t_b - t_a)
            x_a = self.xs[index - 1]
            out[:] = self._integrate(x_a, alpha * self._difference(x_a, self.xs[index]))

    def control_at(self, t: float) -> np.ndarray | None:
        """The control of the interval that contains ``t`` (``None`` outside the trajectory)."""
        times = self.times
        tolerance = 0.5 * TIME_QUANTUM
        if not times[0] - tolerance <= t < times[-1] - tolerance:
            return None
        index = bisect.bisect_right(times, t + tolerance) - 1
        return self.us[min(max(index, 0), len(self.us) - 1)]
