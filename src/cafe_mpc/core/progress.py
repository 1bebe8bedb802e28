"""Start-up that talks: one line per stage of a run (loading the robot, compiling kernels on the first run,
the first solve, the warm-up, running, writing plots).

Every layer reports its own stage with ``stage(message)`` on the ``cafe_mpc.stage`` logger at INFO level. A
library user sees nothing (no handler); the command line prints them on stderr (``cafe-mpc run``, unless
``--quiet``) and a run folder's ``run.log`` records them with the run's other messages.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

STAGE_LOGGER = "cafe_mpc.stage"

_stage_logger = logging.getLogger(STAGE_LOGGER)


def stage(message: str) -> None:
    """Report the stage a run has reached (one line)."""
    _stage_logger.info(message)


def kernels_cached() -> bool:
    """Whether numba has cached this package's compiled kernels (``*.nbi`` index files in its
    ``__pycache__`` folders or in ``NUMBA_CACHE_DIR``): if not, the first run compiles them."""
    roots = [Path(__file__).resolve().parent.parent]
    if os.environ.get("NUMBA_CACHE_DIR"):
        roots.append(Path(os.environ["NUMBA_CACHE_DIR"]))
    return any(next(root.rglob("*.nbi"), None) is not None for root in roots if root.is_dir())
