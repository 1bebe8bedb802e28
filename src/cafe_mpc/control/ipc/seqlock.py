"""The seqlock: one writer, any readers, nobody waits.

A float64 array holds the counter in element 0 and the payload after it. The writer makes the counter odd
(``begin_write``), writes the payload in place, and makes it even again (``end_write``). A reader notes the
counter (``begin_read``: None while odd, a write is under way), copies what it needs, and keeps the copy only
if the counter has not moved meanwhile (``end_read``). Neither side blocks the other: a reader that lost the
race retries later or skips. The array may be plain memory (a channel inside one process) or shared memory
(``control.ipc.shared``) between processes.
"""

from __future__ import annotations

import numpy as np


class SeqLock:
    """The seqlock over ``array`` (module docstring): counter ``array[0]``, payload ``array[1:]``."""

    def __init__(self, array: np.ndarray) -> None:
        if array.dtype != np.float64 or array.ndim != 1 or len(array) < 2:
            raise ValueError(f"a seqlock needs a 1-d float64 array of at least 2 values, got {array.shape}")
        self.array = array
        self.payload = array[1:]

    @property
    def sequence(self) -> float:
        """The counter: even when the payload is consistent, odd while it is written."""
        return float(self.array[0])

    def begin_write(self) -> None:
        self.array[0] += 1.0  # odd: writing

    def end_write(self) -> None:
        self.array[0] += 1.0  # even: consistent

    def begin_read(self) -> float | None:
        """The counter before a read, or None while a write is under way."""
        before = float(self.array[0])
        return None if int(before) % 2 else before

    def end_read(self, before: float) -> bool:
        """Whether what was read since ``begin_read`` returned ``before`` is consistent."""
        return float(self.array[0]) == before

    def read_into(self, out: np.ndarray, newer_than: float | None = None) -> float | None:
        """Copy the first ``len(out)`` payload values into ``out`` if consistent (and, with ``newer_than``,
        written since that sequence number): the sequence number read, else None (retry later)."""
        before = self.begin_read()
        if before is None or before == newer_than:
            return None
        np.copyto(out, self.payload[: len(out)])
        return before if self.end_read(before) else None
