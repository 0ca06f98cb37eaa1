"""The report's figures: matplotlib's object API in one style (no pyplot, no global state beyond
a temporary ``rc_context``), embedded as SVG."""
from __future__ import annotations

import io

from .page import Figure

_RC = {
    "figure.dpi": 100, "savefig.dpi": 100, "font.size": 9, "axes.titlesize": 10,
    "axes.labelsize": 9, "legend.fontsize": 8, "axes.grid": True, "grid.alpha": 0.3,
    "axes.spines.top": False, "axes.spines.right": False,
    "svg.fonttype": "path",          # text as paths: no font needed to view the page
    "svg.hashsalt": "hse_opt",       # deterministic ids: the same data give the same file
}
_COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2",
           "#17becf", "#7f7f7f", "#bcbd22")
#: at most this many lines (azimuth groups, rates) in one panel; beyond it points are coloured
#: by value instead
_MAX_LINES = 6


def _new_figure(width, height):
    from matplotlib.figure import Figure as MplFigure
    return MplFigure(figsize=(width, height), layout="constrained")


def _svg(fig):
    import matplotlib
    buf = io.BytesIO()
    with matplotlib.rc_context(_RC):
        fig.savefig(buf, format="svg", metadata={"Date": None})
    return buf.getvalue()


def _embed(fig, caption, alt):
    """The figure for the page; None (a plot with nothing to show) gives no block."""
    return None if fig is None else Figure(_svg(fig), caption, alt)


def _plotting(fn):
    """Run a plot function inside the report's matplotlib style."""
    def wrapper(*args, **kw):
        import matplotlib
        with matplotlib.rc_context(_RC):
            return fn(*args, **kw)
    wrapper.__name__, wrapper.__doc__ = fn.__name__, fn.__doc__
    return wrapper
