"""Arrays lent out and reused once nothing refers to them, so that a loop allocates no output arrays.

An output handed to a caller (a plan, a solver result) may be kept by the caller for as long as it likes:
its arrays must never change. The arrays are therefore lent again only when nothing but their lender
refers to any of them (CPython's reference counts: an array, a view of one, or an object holding either,
alive anywhere keeps it busy; a numpy view holds its base array). ``unreferenced`` is that test;
``ArrayLender`` lends sets of row buffers with it (``planners.cafe.plan.PlanBuffers`` lends plans' arrays).
"""

from __future__ import annotations

import sys

import numpy as np


def unreferenced(arrays: dict) -> bool:
    """Whether nothing outside the dict ``arrays`` (and its owner) refers to any of its arrays (stops at the
    first array that is referred to)."""
    return all(sys.getrefcount(array) <= _OWN_REFERENCES for array in arrays.values())


_OWN_REFERENCES = next(sys.getrefcount(array) for array in {"probe": np.empty(0)}.values())
"""What ``unreferenced`` sees for an array that only its dict holds (the count includes the generator's
variable and the call's argument; measured in the same form, not assumed, as the interpreter decides it)."""


class ArraySet:
    """One set of buffers of an ``ArrayLender``: ``rows`` hands out row views of them.

    Each key must be asked for once per loan: two views of one key's buffer would share memory."""

    __slots__ = ("_arrays",)

    def __init__(self, arrays: dict[tuple, np.ndarray]) -> None:
        self._arrays = arrays

    def rows(
        self, key: tuple, rows: int, shape: tuple[int, ...], dtype: type | np.dtype = float
    ) -> np.ndarray:
        """The first ``rows`` rows of the buffer ``key`` (rows of ``shape`` and ``dtype``, uninitialised):
        grown (replaced, at least 8 rows) when shorter; the key includes the row shape and type."""
        full_key = (*key, shape, dtype)
        buffer = self._arrays.get(full_key)
        if buffer is None or len(buffer) < rows:
            buffer = np.empty((max(rows, 8), *shape), dtype=dtype)
            self._arrays[full_key] = buffer
        return buffer[:rows]


class ArrayLender:
    """Sets of buffers lent for outputs that callers may keep: ``take`` returns a set none of whose buffers
    is referenced outside the lender (module docstring). With ``capacity`` sets busy it returns a new set
    that is not kept (a caller that keeps every output gets new arrays, as without a lender)."""

    def __init__(self, capacity: int = 4) -> None:
        self.capacity = capacity
        self._sets: list[dict[tuple, np.ndarray]] = []

    def take(self) -> ArraySet:
        """A set of buffers that nothing outside this lender refers to."""
        for arrays in self._sets:
            if unreferenced(arrays):
                return ArraySet(arrays)
        arrays: dict[tuple, np.ndarray] = {}
        if len(self._sets) < self.capacity:
            self._sets.append(arrays)
        return ArraySet(arrays)

    @property
    def kept(self) -> int:
        """How many sets are kept for reuse."""
        return len(self._sets)
