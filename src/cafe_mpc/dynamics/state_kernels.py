"""Compiled ``⊕``/``⊖`` of the state manifolds that have them, selected by the manifold's ``kernel`` code.

``StateManifold.kernel`` (``core.interfaces``) names which compiled operations equal a manifold's
``integrate``/``difference``: plain ``+``/``-`` (``STATE_EUCLIDEAN``), the free-flyer robot's
(``STATE_FREE_FLYER``, ``dynamics.kernels``) or the SRB state's (``STATE_SRB``, ``dynamics.srb_kernels``).
Compiled callers (the solver's forward roll-out) take the code as an argument and call these, so one
compiled call can do several manifold operations and the algebra between them; ``state_transport_stacked``
is the solver's per-knot ``[A | B]`` in one call.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cafe_mpc.core.interfaces import STATE_EUCLIDEAN, STATE_FREE_FLYER
from cafe_mpc.core.kernels import same_point, stack_columns
from cafe_mpc.dynamics.kernels import (
    free_flyer_difference_jacobian_product_stacked,
    free_flyer_state_difference,
    free_flyer_state_integrate,
)
from cafe_mpc.dynamics.srb_kernels import srb_difference, srb_difference_jacobian_product, srb_integrate


@njit(cache=True, nogil=True)
def state_difference(kind: int, x0: np.ndarray, x1: np.ndarray, out: np.ndarray) -> None:
    """``out = x1 ⊖ x0`` on the manifold ``kind`` (a code without compiled operations is the caller's error
    and is not checked). The free-flyer state's sizes follow from the arrays': ``ndx = 2 nv``,
    ``nx = nq + nv``."""
    if kind == STATE_EUCLIDEAN:
        for i in range(out.shape[0]):
            out[i] = x1[i] - x0[i]
    elif kind == STATE_FREE_FLYER:
        nv = out.shape[0] // 2
        free_flyer_state_difference(x0, x1, x0.shape[0] - nv, nv, out)
    else:
        srb_difference(x0, x1, out)


@njit(cache=True, nogil=True)
def state_integrate(kind: int, x: np.ndarray, dx: np.ndarray, out: np.ndarray) -> None:
    """``out = x ⊕ dx`` on the manifold ``kind`` (as ``state_difference``)."""
    if kind == STATE_EUCLIDEAN:
        for i in range(out.shape[0]):
            out[i] = x[i] + dx[i]
    elif kind == STATE_FREE_FLYER:
        nv = dx.shape[0] // 2
        free_flyer_state_integrate(x, dx, x.shape[0] - nv, nv, out)
    else:
        srb_integrate(x, dx, out)


@njit(cache=True, nogil=True)
def state_transport_stacked(
    kind: int, x_nominal: np.ndarray, y: np.ndarray, left: np.ndarray, right: np.ndarray, out: np.ndarray
) -> None:
    """``out = ∂(y ⊖ x̄)/∂y @ [left | right]`` on the manifold ``kind`` (``StateManifold``'s
    ``difference_jacobian_product_stacked``); the plain ``[left | right]`` when ``y == x̄`` (no defect: the
    Jacobian is the identity) or on ``R^n``."""
    if kind == STATE_EUCLIDEAN or same_point(x_nominal, y):
        stack_columns(left, right, out)
    elif kind == STATE_FREE_FLYER:
        free_flyer_difference_jacobian_product_stacked(x_nominal, y, left, right, out)
    else:
        n_left = left.shape[1]
        srb_difference_jacobian_product(x_nominal, y, left, out[:, :n_left])
        srb_difference_jacobian_product(x_nominal, y, right, out[:, n_left:])
