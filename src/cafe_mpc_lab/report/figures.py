"""Matplotlib figures without pyplot: no global backend or figure registry is touched.

Each figure gets its own Agg canvas (``matplotlib.figure.Figure`` + ``FigureCanvasAgg``), so importing the
package never calls ``matplotlib.use`` and an interactive session keeps its backend.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure


def new_figure(figsize: tuple[float, float]) -> Figure:
    """An empty figure with its own Agg canvas."""
    figure = Figure(figsize=figsize)
    FigureCanvasAgg(figure)
    return figure


def subplots(
    nrows: int = 1, ncols: int = 1, *, figsize: tuple[float, float], **kwargs: Any
) -> tuple[Figure, Any]:
    """Like ``pyplot.subplots`` (same ``sharex``/``squeeze`` keywords) on a ``new_figure``."""
    figure = new_figure(figsize)
    return figure, figure.subplots(nrows, ncols, **kwargs)


def save_figure(figure: Figure, path: Path, dpi: int = 110) -> Path:
    """Lay out and write ``figure`` as a PNG."""
    figure.tight_layout()
    figure.savefig(path, dpi=dpi)
    return path
