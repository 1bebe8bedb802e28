"""Relaxed barrier (ReB) penalty for inequality constraints ``g >= 0`` (paper Sec. III-B-2, ref. [94]).

    B(g) = -ln g                                              if g >  delta
    B(g) = 0.5 * (((g - 2 delta) / delta)^2 - 1) - ln delta   if g <= delta

``B`` is C1 and convex with a quadratic extension below ``delta``, so an infeasible point has a finite
penalty and a useful gradient (the barrier never returns ``inf`` or ``NaN``). A constraint contributes
``eps * B(g)`` (times the knot's time step when it is a running constraint).
"""

from __future__ import annotations

import numpy as np


class RelaxedBarrier:
    """Vectorised relaxed barrier with per-constraint ``delta`` and weight ``eps``."""

    def __init__(self, delta: float | np.ndarray, eps: float | np.ndarray) -> None:
        delta_arr = np.atleast_1d(np.asarray(delta, dtype=float))
        eps_arr = np.atleast_1d(np.asarray(eps, dtype=float))
        if np.any(delta_arr <= 0) or not np.all(np.isfinite(delta_arr)):
            raise ValueError(f"relaxed barrier delta must be positive and finite, got {delta}")
        if np.any(eps_arr < 0) or not np.all(np.isfinite(eps_arr)):
            raise ValueError(f"relaxed barrier eps must be non-negative and finite, got {eps}")
        self.delta = delta_arr
        self.eps = eps_arr
        self._log_delta = np.log(delta_arr)

    def value(self, g: np.ndarray) -> float:
        """``sum_i eps_i * B(g_i)``."""
        g = np.asarray(g, dtype=float)
        inside = g > self.delta
        safe_g = np.where(inside, g, 1.0)
        z = (g - 2.0 * self.delta) / self.delta
        b = np.where(inside, -np.log(safe_g), 0.5 * (z * z - 1.0) - self._log_delta)
        return float(np.sum(self.eps * b))

    def derivatives(self, g: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """Value, gradient ``eps * B'(g)`` and diagonal Hessian ``eps * B''(g)`` (element-wise)."""
        g = np.asarray(g, dtype=float)
        inside = g > self.delta
        safe_g = np.where(inside, g, 1.0)
        z = (g - 2.0 * self.delta) / self.delta
        b = np.where(inside, -np.log(safe_g), 0.5 * (z * z - 1.0) - self._log_delta)
        db = np.where(inside, -1.0 / safe_g, z / self.delta)
        ddb = np.where(inside, 1.0 / (safe_g * safe_g), 1.0 / (self.delta * self.delta))
        return float(np.sum(self.eps * b)), self.eps * db, self.eps * ddb


def constraint_violation(g: np.ndarray) -> float:
    """Largest violation ``max(0, -g_i)`` of ``g >= 0`` (0 when all hold)."""
    if g.size == 0:
        return 0.0
    return float(max(0.0, -float(np.min(g))))
