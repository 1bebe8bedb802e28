"""Tiny compiled helpers shared by every layer (numba)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def same_point(a: np.ndarray, b: np.ndarray) -> bool:
    """Element-wise equality of two vectors of the same length (a cheap ``np.array_equal`` for hot paths)."""
    for i in range(a.shape[0]):  # noqa: SIM110 - an explicit loop compiles to a tight, early-exit loop
        if a[i] != b[i]:
            return False
    return True


@njit(cache=True, nogil=True)
def all_finite(values: np.ndarray) -> bool:
    """Whether every entry of the vector ``values`` is finite (``np.isfinite(values).all()`` without its
    temporary array of flags)."""
    for i in range(values.shape[0]):  # noqa: SIM110 - an explicit loop compiles to a tight, early-exit loop
        if not np.isfinite(values[i]):
            return False
    return True


@njit(cache=True, nogil=True)
def stack_columns(left: np.ndarray, right: np.ndarray, out: np.ndarray) -> None:
    """``out = [left | right]`` (same number of rows)."""
    n_left = left.shape[1]
    for i in range(out.shape[0]):
        for j in range(n_left):
            out[i, j] = left[i, j]
        for j in range(right.shape[1]):
            out[i, n_left + j] = right[i, j]


@njit(cache=True, nogil=True)
def stack_columns_left_multiplied(
    jacobian: np.ndarray, rows: int, left: np.ndarray, right: np.ndarray, out: np.ndarray
) -> None:
    """``out = J [left | right]`` where ``J`` is the identity except its leading ``rows x rows`` block
    (``jacobian``): the tangent map of a state difference whose non-Euclidean part comes first."""
    stack_columns(left, right, out)
    n_left = left.shape[1]
    columns = out.shape[1]
    row = np.empty(rows)
    for j in range(columns):
        for i in range(rows):
            total = 0.0
            for p in range(rows):
                total += jacobian[i, p] * (left[p, j] if j < n_left else right[p, j - n_left])
            row[i] = total
        for i in range(rows):
            out[i, j] = row[i]
