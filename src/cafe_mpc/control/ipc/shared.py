"""Named shared-memory blocks of float64 values, for the channels between the MPC process and the loop.

A block is created zero-filled by one process and attached to by name in another. Its name starts with
``shared_block_prefix()``: the creating process's pid, so that its blocks are told from other programs'
(a test checks that none outlive a run). The creator unlinks it (``close(unlink=True)``); the others only
close their view.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from multiprocessing import shared_memory

import numpy as np


def shared_block_prefix(pid: int | None = None) -> str:
    """Prefix of the shared-memory blocks a process creates (``/dev/shm/<prefix>...`` on Linux)."""
    return f"cafe_mpc_{os.getpid() if pid is None else pid}_"


class SharedArray:
    """``size`` float64 values in a shared-memory block: a new zero-filled block, or the block ``name``."""

    def __init__(self, size: int, name: str | None = None) -> None:
        nbytes = 8 * size
        if name is not None:
            self.memory = shared_memory.SharedMemory(name=name, create=False, size=nbytes)
        else:
            self.memory = shared_memory.SharedMemory(
                name=shared_block_prefix() + secrets.token_hex(6), create=True, size=nbytes
            )
            self.memory.buf[:nbytes] = bytes(nbytes)
        self.array = np.ndarray((size,), dtype=np.float64, buffer=self.memory.buf)

    @property
    def name(self) -> str:
        return self.memory.name

    def close(self, unlink: bool) -> None:
        """Drop this view (every array over the block must be gone first); ``unlink``: free the block."""
        self.array = None  # type: ignore[assignment]
        with contextlib.suppress(Exception):
            self.memory.close()
        if unlink:
            with contextlib.suppress(FileNotFoundError):
                self.memory.unlink()
