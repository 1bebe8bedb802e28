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
