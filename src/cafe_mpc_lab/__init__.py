"""The lab around the ``cafe_mpc`` library: the MuJoCo and gym-quadruped plants (``sim``), the paper's
experiments and their execution on Dask (``experiments``), metrics, plots and reports (``report``), benchmark
problems (``bench``) and the ``cafe-mpc`` command (``cli``).

The library (``cafe_mpc``) imports nothing from here; everything here may import the library.
"""

from __future__ import annotations

LOGGERS = ("cafe_mpc", "cafe_mpc_lab")
"""The packages whose log records a run writes to its run.log."""
