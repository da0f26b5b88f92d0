"""Figures without pyplot: a matplotlib Figure on the Agg canvas (no global state, no display) and
an atomic PNG writer without a date or software stamp, so the same results give the same bytes.

It sits below every package that draws (pedcal.report, pedcal.detect, pedcal.track).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from pedcal.io.atomic import atomic_path

PNG_METADATA = {"Software": None}
DPI = 100


def new_figure(width_in: float, height_in: float) -> Figure:
    fig = Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_png(fig: Figure, path: Path) -> None:
    """Write ``fig`` atomically as a PNG without metadata that changes from run to run."""
    with matplotlib.rc_context({"svg.hashsalt": "pedcal", "path.simplify": True}), atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI, metadata=PNG_METADATA)
