"""Central finite differences on state manifolds (the tests' counterpart of Crocoddyl's ``NumDiff`` models).

A function of ``(x, u)`` is evaluated at ``x ⊕ (±h e_i)`` for every tangent direction ``e_i`` of ``x`` and at
``u ± h e_j`` for every control direction; its outputs are kept per evaluation, so that every Jacobian of
one model (dynamics, cost, residuals, constraint values, forces) comes from the same evaluations. An output
on a manifold is differenced in that manifold's tangent at the output of the unperturbed point
(``difference(f(x, u), f(x ⊕ h e_i, u))``), which is how the interface defines ``Fx``, ``Fu`` and ``Px``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from cafe_mpc.core.interfaces import StateManifold

STEP = 1e-6
"""Step ``h`` of the central differences: their truncation error is O(h^2) (about 1e-12 here) and their
rounding error about 1e-16 |f| / h (1e-10 |f|), both far below the tolerances of the checks."""


@dataclass(frozen=True)
class Probe:
    """The outputs of a function at ``x ⊕ (±h e_i)`` (``i`` over the tangent of ``x``, then ``u ± h e_j``).

    ``plus[i]``/``minus[i]`` are tuples of outputs (copies); ``base`` the outputs at ``(x, u)``.
    """

    base: tuple
    plus: list[tuple]
    minus: list[tuple]
    ndx: int
    step: float

    def jacobian(self, output: int, manifold: StateManifold | None = None) -> np.ndarray:
        """The central-difference Jacobian of output ``output`` over ``[tangent of x | u]``: a vector output
        differenced as it is, a point of ``manifold`` in the tangent at the unperturbed output."""
        base = self.base[output]

        def delta(value: np.ndarray) -> np.ndarray:
            if manifold is None:
                return np.atleast_1d(np.asarray(value, dtype=float))
            return manifold.difference(base, value)

        columns = [
            (delta(plus[output]) - delta(minus[output])) / (2.0 * self.step)
            for plus, minus in zip(self.plus, self.minus, strict=True)
        ]
        size = delta(base).size if manifold is None else manifold.ndx
        return np.column_stack(columns) if columns else np.zeros((size, 0))

    def split(self, jacobian: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(d/dx, d/du)`` blocks of a Jacobian over ``[tangent of x | u]``."""
        return jacobian[:, : self.ndx], jacobian[:, self.ndx :]


def probe(
    evaluate: Callable[[np.ndarray, np.ndarray], Sequence],
    state: StateManifold,
    x: np.ndarray,
    u: np.ndarray,
    step: float = STEP,
) -> Probe:
    """Evaluate ``evaluate(x, u)`` (a sequence of outputs, copied here) at ``(x, u)`` and at every perturbed
    point of the central differences."""

    def outputs(x_: np.ndarray, u_: np.ndarray) -> tuple:
        return tuple(np.array(value, dtype=float, copy=True) for value in evaluate(x_, u_))

    base = outputs(x, u)
    plus, minus = [], []
    for direction in np.eye(state.ndx) * step:
        plus.append(outputs(state.integrate(x, direction), u))
        minus.append(outputs(state.integrate(x, -direction), u))
    for direction in np.eye(len(u)) * step:
        plus.append(outputs(x, u + direction))
        minus.append(outputs(x, u - direction))
    return Probe(base, plus, minus, state.ndx, step)


def relative_error(analytic: np.ndarray, numeric: np.ndarray) -> float:
    """``max |analytic - numeric|`` over ``max(1, max |numeric|)``: the error of a derivative relative to the
    size of the derivative (absolute for derivatives of order one or smaller)."""
    analytic, numeric = np.asarray(analytic, dtype=float), np.asarray(numeric, dtype=float)
    if analytic.shape != numeric.shape:
        raise AssertionError(f"shapes differ: analytic {analytic.shape}, finite differences {numeric.shape}")
    if numeric.size == 0:
        return 0.0
    return float(np.max(np.abs(analytic - numeric)) / max(1.0, float(np.max(np.abs(numeric)))))
