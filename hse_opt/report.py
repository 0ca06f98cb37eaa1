"""Plots and the self-contained HTML report of a fit, a diagnosis and a design.

A report is a list of :class:`Section` objects rendered into one HTML file that needs
nothing else to be viewed: no scripts, no web fonts, no network. Every plot is a matplotlib
figure saved as SVG and embedded as a ``data:`` URI in an ``<img>``, so it stays sharp at
any zoom, its internal ids cannot clash with another plot's, and the page opens offline.

Plots use matplotlib's object API (:class:`matplotlib.figure.Figure`, no ``pyplot`` and no
global state beyond a temporary ``rc_context``), so the library works on headless
machines and in worker processes. Each ``plot_*`` function returns the Figure, for
notebooks; each ``*_section`` function returns a :class:`Section`.

Units at the edge: heading errors and residuals in arcsec, rates in deg/s, azimuths in deg,
times in h, parameters in their display units (``Param.unit``).

Sections
--------
:func:`fit_section`
    parameter table (value, sigma, unit), fit statistics, the calibration line of heading
    error against bias rate (the paper's Fig. 2), heading error against azimuth with the
    model before and after compensation (Fig. 3), residuals against every factor.
:func:`comparison_section`
    the before/after of adding an effect: statistics and parameters side by side,
    residuals before and after against every factor.
:func:`diagnosis_section`
    verdict and goodness of fit, the ranking of candidate effects, residual structure
    against each factor and in words, ambiguities, influential runs and outliers.
:func:`design_section`, :func:`evaluation_section`
    a plan's runs over time (rate, azimuth, tilt) and its predicted sigmas against the
    paper's plan.
:func:`write_report`
    renders sections into ``DIR/report.html``, written whole (temporary file + rename).

The page also carries every section's numbers as an inert JSON block
(``<script type="application/json" id="hse-opt-data">``) and marks table rows with
``data-key`` attributes, so that tests and scripts can read back what it shows.
"""
from __future__ import annotations

import base64
import html
import io
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import __version__, units
from .data import Runs, write_text_atomic
from .factors import campaign_factors

__all__ = ["Section", "Figure", "REPORT_NAME", "SETUP_TOL",
           "fit_section", "comparison_section", "diagnosis_section", "design_section",
           "evaluation_section", "plan_section", "text_section", "render_html", "write_report",
           "plot_calibration_line", "plot_azimuth", "plot_residuals", "plot_before_after",
           "plot_candidates", "plot_factor_tests", "plot_plan", "plot_sigmas", "factors",
           "tilt_setups"]

#: file name of the report inside the report directory
REPORT_NAME = "report.html"

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


# -- building blocks -------------------------------------------------------------------------
@dataclass(frozen=True)
class Figure:
    """One embedded plot: an SVG document with its caption.

    Attributes
    ----------
    svg : bytes
        The SVG document.
    caption : str
        Plain text shown under the plot.
    alt : str
        Text alternative of the image.
    """

    svg: bytes
    caption: str
    alt: str

    def html(self):
        uri = "data:image/svg+xml;base64," + base64.b64encode(self.svg).decode("ascii")
        return (f'<figure><img class="plot" src="{uri}" alt="{html.escape(self.alt)}">'
                f"<figcaption>{html.escape(self.caption)}</figcaption></figure>")


@dataclass(frozen=True)
class Section:
    """One section of a report.

    Attributes
    ----------
    title : str
    blocks : tuple
        Parts in order: :class:`Figure` objects and HTML fragments (str, already escaped).
    data : dict
        The section's numbers (JSON-serialisable), embedded in the page for machines.
    """

    title: str
    blocks: tuple
    data: dict = field(default_factory=dict)

    @property
    def figures(self):
        return tuple(b for b in self.blocks if isinstance(b, Figure))

    def html(self, anchor):
        body = "\n".join(b.html() if isinstance(b, Figure) else b for b in self.blocks)
        return f'<section id="{anchor}"><h2>{html.escape(self.title)}</h2>\n{body}\n</section>'


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


def _fmt(x, digits=4):
    """A number for a table cell."""
    if x is None:
        return "&ndash;"
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    x = float(x)
    if not np.isfinite(x):
        return html.escape(str(x))
    return f"{x:.{digits}g}"


def _table(header, rows, keys=None, cls=""):
    """An HTML table; ``keys`` (per row, optional) become ``data-key`` attributes of the
    rows so machines can read the numbers back."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = []
    for i, row in enumerate(rows):
        key = f' data-key="{html.escape(keys[i])}"' if keys is not None else ""
        body.append(f"<tr{key}>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>")
    return (f'<table class="{cls}"><thead><tr>{head}</tr></thead><tbody>'
            + "".join(body) + "</tbody></table>")


def _paragraph(text):
    return f"<p>{html.escape(text)}</p>"


def _notes(notes):
    if not notes:
        return ""
    return ('<ul class="notes">' + "".join(f"<li>{html.escape(n)}</li>" for n in notes)
            + "</ul>")


# -- factors and model evaluation -----------------------------------------------------------
def factors(runs, derived=(), resolution=None):
    """The factors a residual is plotted against, as ``(key, label, values)``, values in the
    edge units of the label: those that vary beyond their resolution, never a column derived
    from the heading error (:func:`hse_opt.factors.campaign_factors` has the rules).

    Parameters
    ----------
    runs : hse_opt.data.Runs
    derived : sequence of str
        Covariate columns derived from the heading error (besides those named ``heading...``).
    resolution : mapping, optional
        Resolutions overriding :data:`hse_opt.factors.RESOLUTION`.

    Returns
    -------
    list of (str, str, numpy.ndarray of shape (n,))
    """
    return [(f.key, f.label, f.values) for f in campaign_factors(runs, derived, resolution).varying]


def _arcsec(x):
    return np.asarray(x, dtype=float) / units.ARCSEC


def _grid_runs(runs, mask, n, **columns):
    """``n`` made-up runs like ``runs[mask]``: every column at its median over the mask
    except those given (SI arrays of shape (n,)); for drawing the model as a curve."""
    def med(x):
        return None if x is None else np.full(n, np.median(np.asarray(x)[mask]))
    cols = {name: med(getattr(runs, name)) for name in
            ("rate", "azimuth", "latitude", "duration", "t_start", "pitch", "roll")}
    cols.update(columns)
    if runs.pitch is None:
        cols["pitch"] = cols["roll"] = None
    return Runs(run=np.arange(1, n + 1), heading_err=np.zeros(n), source="model curve",
                covariates={k: med(v) for k, v in runs.covariates.items()}, **cols)


def _curve(fit, runs, mask, **columns):
    """The fitted model's heading error (rad) and the part compensation removes (rad) on
    made-up runs (:func:`_grid_runs`)."""
    from .compensation import compensation
    n = len(next(iter(columns.values())))
    grid = _grid_runs(runs, mask, n, **columns)
    h = fit.measurement.predict(fit.p, fit.measurement.inputs_from_runs(grid))
    return h, compensation(grid, fit)[0]


def _only(fit, effects):
    """The fit's SI parameter vector with the parameters of every effect outside ``effects``
    at their nominal (no-error) values (tilt coefficients ``name*tilt_...`` follow ``name``)."""
    mm = fit.measurement
    owner = {q.name: e.name for e in fit.model.effects for q in e.params}
    keep = np.array([owner.get(nm.split("*", 1)[0]) in effects for nm in mm.names])
    return np.where(keep, fit.p, mm.nominal)


def slope_parts(fit, runs):
    """The calibration line's slope at each stand azimuth of the runs and each effect's part.

    The slope is that of the fitted model between the smallest and largest bias rate, the
    other inputs at their medians over the runs at that azimuth; an effect's part is the
    slope of the model with only that effect's parameters as fitted (the others at their
    nominal values). For the paper's model the ``hse`` part is -K_HSE (our sign, Eq. 16).

    Returns
    -------
    dict or None
        ``azimuth_deg`` (m,), ``slope`` (m,) and ``parts`` (effect -> (m,)), arcsec per
        deg/s; None when the runs share one bias rate.
    """
    r1, r2 = float(np.min(runs.rate)), float(np.max(runs.rate))
    if np.unique(np.round(runs.rate / units.DEG_PER_S, 6)).size < 2:
        return None
    mm = fit.measurement
    labels, centres = _groups(np.mod(runs.azimuth, 2 * np.pi), 1 * units.DEG)
    grids = [_grid_runs(runs, labels == g, 2, rate=np.array([r1, r2]), azimuth=np.full(2, c))
             for g, c in enumerate(centres)]
    X = np.concatenate([mm.inputs_from_runs(gr) for gr in grids], axis=1)

    def slope(p):
        h = mm.predict(p, X).reshape(-1, 2)
        return (h[:, 1] - h[:, 0]) / units.ARCSEC / ((r2 - r1) / units.DEG_PER_S)
    return {"azimuth_deg": centres / units.DEG, "slope": slope(fit.p),
            "parts": {e: slope(_only(fit, {e})) for e in fit.model.effect_names}}


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def _slope_others(parts):
    """Effects beyond hse whose part of the slope exceeds 5 % of it (RMS over azimuths)."""
    return {e: v for e, v in parts["parts"].items() if e != "hse" and _rms(v) > 0.05 * _rms(parts["slope"])}


def slope_caption(parts):
    """The calibration line's caption: what its slope holds (:func:`slope_parts`)."""
    base = ("Heading error against bias rate at each stand azimuth (points: measured, 1-sigma bars; "
            "lines: the fitted model). The paper's Fig. 2: ")
    others = _slope_others(parts)
    if not others:
        return base + ("the slope is -K_HSE = -lambda2 C23 / (3 w_ie cos L) (our sign), so it changes "
                       "with azimuth as the tilt term C23 does.")
    shares = ", ".join(f"{e} {_rms(v):.3g}" for e, v in {"hse": parts["parts"]["hse"], **others}.items())
    return base + (f"here the slope is not K_HSE alone: effects beyond hse contribute to it. Of its "
                   f"RMS over the stand azimuths, {_rms(parts['slope']):.3g} arcsec per deg/s, the "
                   f"effects alone give: {shares} arcsec per deg/s. Dashed: the hse part alone, "
                   "-K_HSE = -lambda2 C23 / (3 w_ie cos L) (our sign).")


def _groups(values, tol):
    """Group labels of ``values`` (neighbours closer than ``tol`` share one), numbered in
    increasing order, and the group means."""
    order = np.argsort(values)
    v = np.asarray(values)[order]
    sorted_labels = np.cumsum(np.r_[True, np.diff(v) > tol]) - 1
    labels = np.empty_like(sorted_labels)
    labels[order] = sorted_labels
    return labels, np.bincount(sorted_labels, v) / np.bincount(sorted_labels)


#: runs whose leveled tilts (pitch, roll) differ by less than this belong to one tilt setup
#: (a fixture setting or the stand's own tilt): stand tilts that turn with azimuth stay
#: well inside it, deliberate fixture tilts (>= 0.1 deg) well outside
SETUP_TOL = 300 * units.ARCSEC


def tilt_setups(runs):
    """Runs grouped by tilt setup (fixture setting), as ``[(mask, label)]``.

    Runs without pitch/roll form one setup. Otherwise runs join the first setup whose mean
    pitch and roll are both within :data:`SETUP_TOL` of theirs.
    """
    n = len(runs)
    if runs.pitch is None:
        return [(np.ones(n, bool), "tilt not recorded")]
    tilt = np.column_stack([runs.pitch, runs.roll])
    labels = np.full(n, -1)
    centres = []
    for i in range(n):
        for k, c in enumerate(centres):
            if np.all(np.abs(tilt[i] - c) < SETUP_TOL):
                labels[i] = k
                break
        else:
            centres.append(tilt[i])
            labels[i] = len(centres) - 1
        centres[labels[i]] = tilt[labels == labels[i]].mean(axis=0)
    out = []
    for k in range(len(centres)):
        m = labels == k
        p, r = tilt[m].mean(axis=0) / units.ARCSEC
        out.append((m, f"pitch {p:.0f}, roll {r:.0f} arcsec"))
    return out


def _tilt_of_azimuth(runs, mask):
    """pitch/roll (rad) as functions of the stand azimuth within one tilt setup: a first
    harmonic fitted to the runs' own leveling (a stand tilt fixed in n turns with azimuth,
    one fixed in b0 does not), or the mean when fewer than three azimuths were visited."""
    if runs.pitch is None:
        return lambda az: (np.zeros_like(az), np.zeros_like(az))
    az, pitch, roll = runs.azimuth[mask], runs.pitch[mask], runs.roll[mask]
    _, centres = _groups(np.mod(az, 2 * np.pi), 1 * units.DEG)
    if centres.size >= 3:
        A = np.column_stack([np.ones_like(az), np.cos(az), np.sin(az)])
        cp = np.linalg.lstsq(A, pitch, rcond=None)[0]
        cr = np.linalg.lstsq(A, roll, rcond=None)[0]

        def tilt(a):
            B = np.column_stack([np.ones_like(a), np.cos(a), np.sin(a)])
            return B @ cp, B @ cr
        return tilt
    mp, mr = float(np.mean(pitch)), float(np.mean(roll))
    return lambda a: (np.full_like(a, mp), np.full_like(a, mr))


#: at most this many tilt setups get panels of their own
_MAX_SETUPS = 3


# -- plots of a fit --------------------------------------------------------------------------
@_plotting
def plot_calibration_line(fit, runs, hse_only=False):
    """Heading error against bias rate, per stand azimuth and tilt setup, with the fitted
    model (the paper's Fig. 2). One panel per tilt setup (:func:`tilt_setups`). When effects
    beyond ``hse`` are in the model, the ``hse`` part of the model is drawn dashed.

    Parameters
    ----------
    fit : hse_opt.fit.FitResult
    runs : hse_opt.data.Runs
        The runs the fit used.
    hse_only : bool
        Draw the ``hse`` part alone: points are the measurements less the fitted model's
        other effects, lines the model's ``hse`` part (slope -K_HSE).

    Returns
    -------
    matplotlib.figure.Figure or None
        None when the runs share one bias rate (no line to draw).
    """
    rate_dps = runs.rate / units.DEG_PER_S
    if np.unique(np.round(rate_dps, 6)).size < 2:
        return None
    y, s = _arcsec(runs.heading_err), _arcsec(fit.sigma)
    mm = fit.measurement
    p_hse = _only(fit, {"hse"})
    dashed = not hse_only and bool(_slope_others(slope_parts(fit, runs)))
    if hse_only:  # the measurements less the fitted model's other effects
        X = mm.inputs_from_runs(runs)
        y = y - _arcsec(mm.predict(fit.p, X) - mm.predict(p_hse, X))
    setups = tilt_setups(runs)
    if len(setups) > _MAX_SETUPS:
        setups = [(np.ones(len(runs), bool), f"{len(setups)} tilt setups")]
    labels, centres = _groups(np.mod(runs.azimuth, 2 * np.pi), 1 * units.DEG)
    fig = _new_figure(7.5, 3.4 if len(setups) == 1 else 3.0)
    axes = fig.subplots(1, len(setups), sharey=True, squeeze=False)[0]
    lo, hi = rate_dps.min(), rate_dps.max()
    pad = 0.05 * max(hi - lo, 1.0)
    grid = np.linspace(lo - pad, hi + pad, 61)
    line_axes = []
    for ax, (setup, title) in zip(axes, setups):
        present = [g for g in range(centres.size) if np.any(setup & (labels == g))]
        if len(present) <= _MAX_LINES:
            line_axes.append(ax)
            for g in present:
                col = _COLORS[g % len(_COLORS)]
                m = setup & (labels == g)
                ax.errorbar(rate_dps[m], y[m], yerr=s[m], fmt="o", ms=4, color=col, capsize=2,
                            label=f"{centres[g] / units.DEG:.0f} deg")
                X = mm.inputs_from_runs(_grid_runs(runs, m, grid.size, rate=grid * units.DEG_PER_S,
                                                   azimuth=np.full(grid.size, centres[g])))
                ax.plot(grid, _arcsec(mm.predict(p_hse if hse_only else fit.p, X)), "-", color=col, lw=1.2)
                if dashed:
                    ax.plot(grid, _arcsec(mm.predict(p_hse, X)), "--", color=col, lw=1.0)
        else:
            sc = ax.scatter(rate_dps[setup], y[setup], s=16, cmap="twilight", vmin=0, vmax=360,
                            c=np.mod(runs.azimuth[setup] / units.DEG, 360), label="measured")
            ax.plot(rate_dps[setup], y[setup] - _arcsec(fit.residuals[setup]), "k+", ms=6,
                    label="model")
            fig.colorbar(sc, ax=ax, label="stand azimuth [deg]")
            ax.legend(loc="best", frameon=False)
        ax.set_title(title)
        ax.set_xlabel("bias rate Omega [deg/s]")
    if line_axes:  # one legend of the azimuths, outside the panels: it hides no data
        legend = {}
        for ax in line_axes:
            legend.update({nm: hd for hd, nm in zip(*ax.get_legend_handles_labels()) if nm not in legend})
        fig.legend(list(legend.values()), list(legend), loc="outside right upper", frameon=False,
                   title="stand azimuth")
    axes[0].set_ylabel("heading error [arcsec]")
    fig.suptitle("Calibration line, the hse part alone: heading error less the other effects"
                 if hse_only else "Calibration line: heading error against bias rate")
    return fig


@_plotting
def plot_azimuth(fit, runs):
    """Heading error against stand azimuth before and after compensation with the fitted
    model (the paper's Fig. 3); one row per tilt setup (:func:`tilt_setups`).

    "After" subtracts what compensation with the fit removes
    (:func:`hse_opt.compensation.compensation`: every error of the system, as the paper's Eq. 14
    removes the heading-sensitive error); the stand's own errors (the offset of its zero
    mark, errors of its azimuth reading, covariate offsets) remain.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from .compensation import compensation

    az = np.mod(runs.azimuth / units.DEG, 360.0)
    y, s = _arcsec(runs.heading_err), _arcsec(fit.sigma)
    after = y - _arcsec(compensation(runs, fit)[0])
    rates, rate_centres = _groups(runs.rate, 0.05 * units.DEG_PER_S)
    many = rate_centres.size > _MAX_LINES
    grid = np.linspace(0.0, 360.0, 181) * units.DEG
    setups = tilt_setups(runs)
    if len(setups) > _MAX_SETUPS:
        setups = [(np.ones(len(runs), bool), f"{len(setups)} tilt setups")]
    fig = _new_figure(7.5, 1.0 + 2.6 * len(setups))
    axes = fig.subplots(len(setups), 2, sharey="row", squeeze=False)
    for (ax1, ax2), (setup, title) in zip(axes, setups):
        pitch, roll = _tilt_of_azimuth(runs, setup)(grid)
        for g, r in enumerate(rate_centres):
            m = setup & (rates == g)
            if not m.any():
                continue
            col = _COLORS[g % len(_COLORS)]
            lab = None if many else f"{r / units.DEG_PER_S:+.0f} deg/s"
            ax1.errorbar(az[m], y[m], yerr=s[m], fmt="o", ms=4, color=col, capsize=2, label=lab)
            ax2.errorbar(az[m], after[m], yerr=s[m], fmt="o", ms=4, color=col, capsize=2)
            if many:
                continue
            tilt = {"pitch": pitch, "roll": roll} if runs.pitch is not None else {}
            h, comp = _curve(fit, runs, m, rate=np.full(grid.size, r), azimuth=grid, **tilt)
            ax1.plot(grid / units.DEG, _arcsec(h), "-", color=col, lw=1.2)
            ax2.plot(grid / units.DEG, _arcsec(h - comp), "-", color=col, lw=1.2)
        ax1.set_title(f"before: peak-to-peak {np.ptp(y[setup]):.1f} arcsec", fontsize=9)
        ax2.set_title(f"after: peak-to-peak {np.ptp(after[setup]):.1f} arcsec", fontsize=9)
        ax1.set_ylabel(f"{title}\nheading error [arcsec]" if len(setups) > 1
                       else "heading error [arcsec]")
        if not many:
            ax1.legend(loc="best", frameon=False)
    for ax in axes.ravel():
        ax.set_xticks(np.arange(0, 361, 90))
    for ax in axes[-1]:
        ax.set_xlabel("stand azimuth [deg]")
    fig.suptitle("Heading error against azimuth, before and after compensation")
    return fig


def _residual_grid(fig, runs, series, ncols=3, derived=()):
    """Residuals (arcsec, 1-sigma bars) against every factor: one row of panels per entry of
    ``series`` = ``[(title, residual, sigma, colour)]``, factors wrapped ``ncols`` to a row,
    the rows of one factor chunk next to each other so before/after read top to bottom."""
    facs = factors(runs, derived)
    chunks = [facs[i:i + ncols] for i in range(0, len(facs), ncols)] or [[]]
    axes = fig.subplots(len(chunks) * len(series), ncols, squeeze=False, sharey=True)
    lim = max(float(np.max(np.abs(r) + s)) for _, r, s, _ in series) * 1.08
    for c, chunk in enumerate(chunks):
        for k, (title, r, s, col) in enumerate(series):
            row = axes[c * len(series) + k]
            for ax, (_, label, v) in zip(row, chunk):
                ax.errorbar(v, r, yerr=s, fmt="o", ms=3, color=col, capsize=0, lw=0.6)
                ax.axhline(0, color="k", lw=0.8)
                ax.set_ylim(-lim, lim)
                if k == len(series) - 1:
                    ax.set_xlabel(label)
            for ax in row[len(chunk):]:
                ax.set_visible(False)
            row[0].set_ylabel(f"{title}\nresidual [arcsec]" if title else "residual [arcsec]")
    return facs


@_plotting
def plot_residuals(fit, runs, derived=()):
    """Residuals (measured - model, arcsec, with the 1-sigma used in the fit) against every
    factor that varies over the runs (:func:`factors`; ``derived`` as there).

    Returns
    -------
    matplotlib.figure.Figure or None
        None when no factor varies beyond its resolution.
    """
    rows = -(-len(factors(runs, derived)) // 3)
    if not rows:
        return None
    fig = _new_figure(7.5, 2.1 * max(1, rows))
    _residual_grid(fig, runs, [("", _arcsec(fit.residuals), _arcsec(fit.sigma), _COLORS[0])],
                   derived=derived)
    fig.suptitle(f"Residuals against every factor (RMS {fit.rms_arcsec:.2f} arcsec)")
    return fig


@_plotting
def plot_before_after(before, after, runs, derived=()):
    """Residuals of two fits of the same runs against every factor: a row of panels for
    ``before`` above a row for ``after``, on the same scale.

    Parameters
    ----------
    before, after : hse_opt.fit.FitResult

    Returns
    -------
    matplotlib.figure.Figure
    """
    rows = -(-len(factors(runs, derived)) // 3)
    if not rows:
        return None
    fig = _new_figure(7.5, 1.9 * 2 * max(1, rows))
    _residual_grid(fig, runs, [(f"{_effects_label(f)}", _arcsec(f.residuals), _arcsec(f.sigma), col)
                               for f, col in ((before, "#7f7f7f"), (after, _COLORS[1]))], derived=derived)
    fig.suptitle(f"Residuals before (RMS {before.rms_arcsec:.2f} arcsec) and after "
                 f"(RMS {after.rms_arcsec:.2f} arcsec)")
    return fig


def _effects_label(fit):
    return " + ".join(fit.model.effect_names)


# -- plots of a diagnosis --------------------------------------------------------------------
def _minus_log10_p(test):
    """-log10 p of a test or candidate (from its log p when p underflows), or None."""
    log_p = getattr(test, "log_p", None)
    if log_p is not None and np.isfinite(log_p):
        return -log_p / np.log(10.0)
    p = getattr(test, "p_value", None)
    return None if p is None else -np.log10(max(p, 1e-300))


@_plotting
def plot_candidates(diagnosis):
    """The ranking of candidate effects: score-test significance (-log10 p, with the
    family-wise threshold) and Delta-BIC after refitting, best first.

    Parameters
    ----------
    diagnosis : hse_opt.diagnose.Diagnosis

    Returns
    -------
    matplotlib.figure.Figure
    """
    cands = [c for c in diagnosis.candidates if c.testable]
    names = [c.effect for c in cands][::-1]
    lp = np.array([_minus_log10_p(c) or 0.0 for c in cands])[::-1]
    dbic = np.array([np.nan if c.delta_bic is None else c.delta_bic for c in cands])[::-1]
    colours = [_COLORS[1] if c.significant else "#7f7f7f" for c in cands][::-1]
    fig = _new_figure(7.5, 1.2 + 0.32 * max(len(cands), 1))
    ax1, ax2 = fig.subplots(1, 2, sharey=True)
    y = np.arange(len(cands))
    ax1.barh(y, lp, color=colours)
    ax1.axvline(-np.log10(diagnosis.alpha / max(diagnosis.n_tests, 1)), color="k", ls="--", lw=0.8,
                label=f"family-wise {diagnosis.alpha:g}")
    ax1.set_xlabel("score test: -log10 p")
    ax1.legend(loc="lower right", frameon=False)
    ax2.barh(y, np.nan_to_num(dbic), color=colours)
    ax2.axvline(0, color="k", lw=0.8)
    ax2.set_xlabel("Delta-BIC after refitting (negative: better)")
    ax1.set_yticks(y, names)
    fig.suptitle("Which effect is missing: candidates ranked (red: significant)")
    return fig


@_plotting
def plot_factor_tests(diagnosis):
    """Residual structure against each factor: -log10 p of each factor's test, with the
    family-wise threshold.

    Returns
    -------
    matplotlib.figure.Figure
    """
    tests = [t for t in diagnosis.factors if t.p_value is not None]
    names = [t.name for t in tests][::-1]
    lp = np.array([_minus_log10_p(t) for t in tests])[::-1]
    thr = -np.log10(diagnosis.alpha / max(diagnosis.n_tests, 1))
    fig = _new_figure(7.5, 1.2 + 0.3 * max(len(tests), 1))
    ax = fig.add_subplot()
    y = np.arange(len(tests))
    ax.barh(y, lp, color=[_COLORS[1] if v > thr else "#7f7f7f" for v in lp])
    ax.axvline(thr, color="k", ls="--", lw=0.8, label=f"family-wise {diagnosis.alpha:g}")
    ax.set_yticks(y, names)
    ax.set_xlabel("-log10 p of the residual's dependence on the factor")
    ax.legend(loc="lower right", frameon=False)
    ax.set_title("Where the model fails: residual structure against each factor")
    return fig


# -- plots of a plan -------------------------------------------------------------------------
@_plotting
def plot_plan(plan, title="The plan's runs over time"):
    """A plan's runs over time: bias rate, stand azimuth and (when any) deliberate tilt of
    each alignment, as bars from its start to its end.

    Parameters
    ----------
    plan : hse_opt.data.Plan or hse_opt.data.Runs
        Needs ``t_start`` (time since power-on).

    Returns
    -------
    matplotlib.figure.Figure
    """
    t0 = np.asarray(plan.t_start if plan.t_start is not None
                    else np.concatenate([[0.0], np.cumsum(plan.duration[:-1])]), float)
    t1 = t0 + np.asarray(plan.duration, float)
    panels = [("bias rate [deg/s]", plan.rate / units.DEG_PER_S),
              ("stand azimuth [deg]", np.mod(plan.azimuth / units.DEG, 360.0))]
    tilt_x, tilt_y = getattr(plan, "tilt_x", None), getattr(plan, "tilt_y", None)
    if tilt_x is not None and (np.any(tilt_x != 0) or np.any(tilt_y != 0)):
        panels.append(("deliberate tilt [arcsec]", None))
    fig = _new_figure(7.5, 1.5 + 1.3 * len(panels))
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (label, v) in zip(axes, panels):
        if v is None:
            # pitch thin on top of roll: both show where they are equal
            ax.hlines(tilt_x / units.ARCSEC, t0 / units.HOUR, t1 / units.HOUR, color=_COLORS[0],
                      lw=6, label="x (roll)")
            ax.hlines(tilt_y / units.ARCSEC, t0 / units.HOUR, t1 / units.HOUR, color=_COLORS[1],
                      lw=2, label="y (pitch)")
            fig.legend(*ax.get_legend_handles_labels(), loc="outside right lower", frameon=False)
        else:
            ax.hlines(v, t0 / units.HOUR, t1 / units.HOUR, color=_COLORS[0], lw=4)
        ax.set_ylabel(label)
    axes[1].set_yticks(np.arange(0, 361, 90))
    axes[-1].set_xlabel("time since power-on [h]")
    fig.suptitle(f"{title}: {len(t0)} alignments, {t1.max() / units.HOUR:.1f} h")
    return fig


@_plotting
def plot_sigmas(evaluation, baseline=None, labels=("optimised plan", "paper's plan")):
    """Predicted 1-sigma of each parameter for a plan, against a baseline plan's.

    Parameters
    ----------
    evaluation, baseline : hse_opt.design.Evaluation
        ``names``, ``units``, ``std`` (display units); ``baseline`` optional.
    labels : tuple of 2 str

    Returns
    -------
    matplotlib.figure.Figure
    """
    names = list(evaluation.names)
    k = len(names)
    fig = _new_figure(7.5, 1.3 + 0.42 * k)
    ax = fig.add_subplot()
    y = np.arange(k)[::-1]
    h = 0.38 if baseline is not None else 0.6
    ax.barh(y + (h / 2 if baseline is not None else 0), evaluation.std, height=h,
            color=_COLORS[0], label=labels[0])
    if baseline is not None:
        base = np.array([baseline.std[list(baseline.names).index(n)] if n in baseline.names else np.nan
                         for n in names])
        ax.barh(y - h / 2, base, height=h, color="#7f7f7f", label=labels[1])
        for yi, a, b in zip(y, evaluation.std, base):
            if np.isfinite(b) and a > 0:
                ax.annotate(f"{b / a:.3g}x smaller" if a < b else f"{a / b:.3g}x larger", (max(a, b), yi),
                            xytext=(4, -3), textcoords="offset points", fontsize=8)
        ax.margins(x=0.25)  # room for the labels
    ax.set_xscale("log")
    ax.set_yticks(y, [f"{n} [{u}]" for n, u in zip(names, evaluation.units)])
    ax.set_xlabel("predicted 1-sigma (display unit of each parameter)")
    ax.legend(loc="best", frameon=False)
    ax.set_title("Predicted uncertainty of each parameter")
    return fig


# -- sections --------------------------------------------------------------------------------
def _fit_statistics(fit):
    """(label, key, formatted value) rows of a fit's statistics."""
    return [
        ("runs", "n_runs", _fmt(fit.n_runs)),
        ("RMS of residuals [arcsec]", "rms_arcsec", _fmt(fit.rms_arcsec)),
        ("chi-square", "chi2", _fmt(fit.chi2)),
        ("degrees of freedom", "dof", _fmt(fit.dof)),
        ("reduced chi-square", "chi2_red", _fmt(fit.chi2_red)),
        ("AIC", "aic", _fmt(fit.aic)),
        ("BIC", "bic", _fmt(fit.bic)),
        ("condition number", "condition", _fmt(fit.condition, 3)),
        ("weights", "weighting", html.escape(fit.weighting)),
        ("solver", "method", html.escape(f"{fit.method} ({fit.status})")),
    ]


def _parameter_table(rows):
    """The parameter table from :func:`hse_opt.fit.summary.report_data` rows."""
    cells = [[f"<code>{html.escape(r['name'])}</code>", _fmt(r["value"], 5),
              _fmt(r["std"], 3) if r["state"] != "fixed" else "&ndash;", html.escape(r["unit"]),
              html.escape(r["state"]), html.escape(r["description"])]
             for r in rows]
    return _table(["parameter", "value", "1-sigma", "unit", "state", "meaning"], cells,
                  keys=[f"param:{r['name']}" for r in rows], cls="params")


def _correlation_table(fit):
    free = np.flatnonzero(fit.free)
    if free.size < 2 or free.size > 12:
        return ""
    names = [fit.names[i] for i in free]
    C = fit.correlation[np.ix_(free, free)]
    rows = [[f"<code>{html.escape(n)}</code>"]
            + [f'<span class="{"hi" if i != j and abs(C[i, j]) > 0.9 else ""}">{C[i, j]:+.3f}</span>'
               for j in range(len(names))] for i, n in enumerate(names)]
    return ("<details><summary>Correlation of the estimates</summary>"
            + _table(["parameter"] + names, rows, cls="corr") + "</details>")


def _missing_figure(what, why):
    return f'<p class="notes">No {html.escape(what)}: {html.escape(why)}</p>'


def _one_rate_text(runs):
    rates = np.unique(np.round(runs.rate / units.DEG_PER_S, 6))
    return (f"every run is at {', '.join(f'{r:g}' for r in rates)} deg/s; a line through the heading "
            "error against bias rate needs two or more bias rates")


def fit_section(fit, runs, title=None, derived=()):
    """The report section of a calibration fit.

    Parameters
    ----------
    fit : hse_opt.fit.FitResult
    runs : hse_opt.data.Runs
        The runs the fit used.
    title : str, optional
    derived : sequence of str
        Covariate columns derived from the heading error, never plotted as factors (besides
        those named ``heading...``; :mod:`hse_opt.factors`).

    Returns
    -------
    Section
    """
    from .fit.summary import report_data

    title = title or f"Calibration fit: {_effects_label(fit)}"
    data = report_data(fit, runs)            # also checks that these are the fit's runs
    stats = _fit_statistics(fit)
    facs = campaign_factors(runs, derived)
    parts = slope_parts(fit, runs)
    data["factors"] = _factor_data(facs)
    if parts is not None:
        data["slope_arcsec_per_dps"] = _jsonable(parts)
    field = runs.surveyed is not None     # positions without a reference: the paper's own Fig. 2
    line = plot_field_line(fit, runs) if field else plot_calibration_line(fit, runs)
    residuals = plot_residuals(fit, runs, derived)
    blocks = [
        _paragraph(f"Weighted least squares of the model ({_effects_label(fit)}) to "
                   f"{fit.n_runs} alignments."),
        '<div class="cols">' + _parameter_table(data["parameters"])
        + _table(["statistic", "value"], [[lab, v] for lab, _, v in stats],
                 keys=[k for _, k, _ in stats], cls="stats") + "</div>",
        _correlation_table(fit),
        _notes(list(fit.notes) + [f"bound binds: {b}" for b in fit.binding] + facs.notes()),
        _embed(line, FIELD_LINE_CAPTION if field else slope_caption(parts), "heading error against bias rate")
        if line is not None
        else _missing_figure("calibration line (the paper's Fig. 2)", _one_rate_text(runs)),
        None if field else _embed(plot_azimuth(fit, runs),
               "Heading error against stand azimuth before (left) and after (right) compensation "
               "with the fit (the paper's Fig. 3), one row per tilt setup. Lines: the model at "
               "each rate with the other inputs at their medians; after compensation only the "
               "stand's own errors remain (the offset of its zero mark, errors of its azimuth "
               "reading).",
               "heading error against azimuth before and after compensation"),
        _embed(residuals,
               "Residuals (measured minus model) against every factor that varies over the runs "
               "beyond its resolution; structure here is an effect the model lacks.",
               "residuals against every factor") if residuals is not None
        else _missing_figure("residual plot", "no factor varies beyond its resolution"),
    ]
    return Section(title, tuple(b for b in blocks if b), data)


def _factor_data(facs):
    return {"varying": [f.key for f in facs.varying],
            "constant": [{"key": f.key, "label": f.label, "min": float(np.min(f.values)),
                          "max": float(np.max(f.values)), "resolution": f.resolution}
                         for f in facs.constant],
            "derived": list(facs.derived)}


def _cell(x):
    if isinstance(x, str):
        return html.escape(x)
    if isinstance(x, float) and 0 < abs(x) < 1e-3:
        return _p_text(x)
    return _fmt(x)


def comparison_section(before, after=None, runs=None, title=None, derived=()):
    """The before/after of adding an effect: statistics and parameters side by side, and
    the residuals against every factor before and after.

    Parameters
    ----------
    before : hse_opt.fit.FitResult or hse_opt.diagnose.Comparison
        The fit without the effect, or a whole comparison of two diagnoses
        (:func:`hse_opt.diagnose.compare`: its lack-of-fit tests and verdicts are shown too).
    after : hse_opt.fit.FitResult, optional
        The fit with it (same runs); not with a Comparison.
    runs : hse_opt.data.Runs, optional
        The runs both fits used; not with a Comparison.
    title : str, optional

    Returns
    -------
    Section
    """
    comparison = before if hasattr(before, "statistics") else None
    if comparison is not None:
        before, after, runs = comparison.before.fit, comparison.after.fit, comparison.after.runs
    elif after is None or runs is None:
        raise ValueError("comparison_section needs before, after and runs (FitResults), or a "
                         "hse_opt.diagnose.Comparison")
    added = [e for e in after.model.effect_names if e not in before.model.effect_names]
    title = title or f"Adding {', '.join(added) or 'nothing'}: before and after"
    header = ["statistic", _effects_label(before), _effects_label(after)]
    if comparison is not None:
        stats = [[html.escape(k), _cell(b), _cell(a)] for k, b, a in comparison.statistics]
        keys = [k for k, _, _ in comparison.statistics]
        params = [[f"<code>{html.escape(n)}</code> [{html.escape(u)}]",
                   "&ndash;" if vb is None else f"{_fmt(vb, 5)} &plusmn; {_fmt(sb, 3)}",
                   "&ndash;" if va is None else f"{_fmt(va, 5)} &plusmn; {_fmt(sa, 3)}"]
                  for n, u, vb, sb, va, sa in comparison.parameters]
        data = _jsonable(comparison.to_dict())
    else:
        sb, sa = _fit_statistics(before), _fit_statistics(after)
        stats = [[lab, vb, va] for (lab, _, vb), (_, _, va) in zip(sb, sa)]
        keys = [k for _, k, _ in sb]
        params = []
        for n in dict.fromkeys(before.names + after.names):
            cells = [f"<code>{html.escape(n)}</code>"]
            for f in (before, after):
                cells.append(f"{_fmt(f.values[f.names.index(n)], 5)} &plusmn; "
                             f"{_fmt(f.std[f.names.index(n)], 3)} {html.escape(f.units[f.names.index(n)])}"
                             if n in f.names else "&ndash;")
            params.append(cells)
        data = {"before": before.to_dict(), "after": after.to_dict()}
    blocks = [
        '<div class="cols">' + _table(header, stats, keys=keys, cls="stats")
        + _table(["parameter"] + header[1:], params, cls="params") + "</div>",
        _embed(plot_before_after(before, after, runs, derived),
               f"Residuals against every factor before (grey rows) and after (red rows) adding "
               f"{', '.join(added) or 'nothing'}, on one scale.", "residuals before and after")
        or _missing_figure("residual plot", "no factor varies beyond its resolution"),
    ]
    return Section(title, tuple(blocks), data)


def _p_text(p):
    return "&ndash;" if p is None else (f"{p:.2g}" if p >= 1e-300 else "&lt;1e-300")


def diagnosis_section(diagnosis, title=None, residuals=True, derived=()):
    """The report section of a diagnosis: verdict and goodness of fit, the ranking of
    candidate effects, residual structure against each factor and in words, ambiguities
    with the runs that would resolve them, influential runs and outliers.

    Parameters
    ----------
    diagnosis : hse_opt.diagnose.Diagnosis
    title : str, optional
    residuals : bool
        Also plot the residuals against every factor (False when the page already shows
        them in the fit's section).
    derived : sequence of str
        Covariate columns derived from the heading error (as :func:`fit_section`).

    Returns
    -------
    Section
    """
    d = diagnosis
    title = title or f"Diagnosis of {' + '.join(d.effects)}"
    chi2_p = None if d.chi2_test is None else d.chi2_test.p_value
    stats = [("verdict", "verdict", html.escape(d.verdict)),
             ("runs", "n_runs", _fmt(d.n_runs)),
             ("RMS of residuals [arcsec]", "rms_arcsec", _fmt(d.rms_arcsec)),
             ("reduced chi-square", "chi2_red", _fmt(d.chi2_red)),
             ("chi-square test p", "chi2_p", _p_text(chi2_p)),
             ("lack-of-fit test p", "lack_of_fit_p", _p_text(d.lack_of_fit_p)),
             ("tests in the family (Bonferroni)", "n_tests", _fmt(d.n_tests))]
    cand_rows = []
    for c in d.candidates:
        if c.testable:
            cand_rows.append([f"<code>{html.escape(c.effect)}</code>", html.escape(c.description),
                              _p_text(c.p_value), _fmt(c.delta_bic, 4), _fmt(c.rms_after_arcsec, 4),
                              "yes" if c.significant else "no"])
        else:
            cand_rows.append([f"<code>{html.escape(c.effect)}</code>", html.escape(c.description),
                              f'<span class="notes">not testable: {html.escape(c.reason)}</span>', "", "", ""])
    factor_rows = [[html.escape(t.name), html.escape(t.description), _p_text(t.p_value),
                    html.escape(t.best or t.note)] for t in d.factors]
    words = [t.text for t in d.structure]
    if d.ambiguous:
        words.append(f"Ambiguous: {', '.join(d.ambiguous)} explain these data equally well.")
        words += [f"{n}: " + ("; ".join(d.candidate(n).plausibility)
                              or "every fitted magnitude within its physical range") for n in d.ambiguous]
        words += [f"a run that would tell {r.get('a')} from {r.get('b')}: "
                  + ", ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}"
                              for k, v in r.items() if k not in ("a", "b"))
                  for r in d.proposals]
    if d.influential:
        words.append("Runs the fit hinges on: " + ", ".join(str(r) for r in d.influential) + ".")
    if d.outliers:
        words.append("Outliers: " + ", ".join(str(r) for r in d.outliers) + ".")
    testable = any(c.testable for c in d.candidates)
    blocks = [
        f'<p class="summary{"" if d.verdict == "adequate" else " warn"}">Verdict: '
        f'<b>{html.escape(d.verdict)}</b>'
        + (f"; best candidate <code>{html.escape(d.best.effect)}</code>" if d.best is not None else "")
        + "</p>",
        _table(["statistic", "value"], [[lab, v] for lab, _, v in stats],
               keys=[k for _, k, _ in stats], cls="stats"),
        _embed(plot_candidates(d), "Candidate effects not in the model, best first: the score "
               "(Lagrange-multiplier) test needs no refit; Delta-BIC refits with the effect. The "
               "dashed line is the family-wise significance level (Bonferroni).",
               "ranking of candidate effects") if testable else "",
        _table(["candidate", "what it is", "p (score)", "Delta-BIC", "RMS after [arcsec]",
                "significant"], cand_rows, keys=[f"candidate:{c.effect}" for c in d.candidates],
               cls="cands"),
        _embed(plot_factor_tests(d), "Each factor's test of the residual's dependence on it.",
               "residual structure against each factor") if any(t.p_value is not None for t in d.factors) else "",
        "<details><summary>Tests against each factor</summary>"
        + _table(["factor", "test", "p", "best function / note"], factor_rows) + "</details>",
        ("<h3>In words</h3>" + _notes(words)) if words else "",
        (_embed(plot_residuals(d.fit, d.runs, derived), "Residuals against every factor that varies "
                "beyond its resolution.", "residuals against every factor")
         or _missing_figure("residual plot", "no factor varies beyond its resolution")) if residuals else "",
        _notes(list(d.notes) + campaign_factors(d.runs, derived).notes()
               + ([f"Delta-BIC on one likelihood scale: {d.likelihood}"] if d.likelihood else [])),
    ]
    return Section(title, tuple(b for b in blocks if b), {"diagnosis": _jsonable(d.to_dict())})


def _jsonable(obj):
    """``obj`` with numpy scalars and arrays made JSON-serialisable."""
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def _evaluation_blocks(ev, plan, baseline, baseline_note, label):
    """Plan over time, predicted sigmas (plot and table) against a baseline plan's."""
    rows, keys = [], []
    for i, (n, u, sd) in enumerate(zip(ev.names, ev.units, ev.std)):
        b = None
        if baseline is not None and n in baseline.names:
            b = float(baseline.std[list(baseline.names).index(n)])
        rows.append([f"<code>{html.escape(n)}</code>", html.escape(u), _fmt(sd, 3), _fmt(b, 3),
                     _fmt(sd / b, 3) if b else "&ndash;", _fmt(ev.drift_bias[i], 3)])
        keys.append(f"sigma:{n}")
    return [
        _embed(plot_plan(plan, label), f"Each bar is one alignment of {label.lower()}, from its "
               "start to its end.", "the plan's runs over time"),
        _embed(plot_sigmas(ev, baseline, (label.lower(), "paper's plan")),
               "Predicted 1-sigma of each parameter (log scale)"
               + (" against the paper's plan in the same model; the labels: how many times smaller."
                  if baseline is not None else "."), "predicted sigmas"),
        _table(["parameter", "unit", "predicted sigma", "paper's plan", "ratio",
                "bias per arcsec/h of drift"], rows, keys=keys, cls="sigmas"),
        _paragraph(baseline_note) if baseline_note else "",
    ]


def design_section(result, baseline=None, title=None, baseline_note=None):
    """The report section of an optimised plan: its runs over time, its predicted sigmas
    against a baseline plan's (the paper's), efficiency and times.

    Parameters
    ----------
    result : hse_opt.design.DesignResult
    baseline : hse_opt.design.Evaluation, optional
        The baseline plan evaluated for the same model.
    title : str, optional
    baseline_note : str, optional
        Said instead of the comparison when there is no baseline (e.g. the paper's plan
        cannot identify the model).

    Returns
    -------
    Section
    """
    ev = result.evaluation
    title = title or f"Optimised plan for {' + '.join(ev.effects)} ({result.criterion})"
    stats = [("criterion", "criterion", html.escape(result.criterion)),
             ("alignments", "n_runs", _fmt(result.n_runs)),
             ("total time [h]", "total_time_h", _fmt(result.total_time / units.HOUR)),
             ("setup time [h]", "setup_time_h", _fmt(result.setup_time / units.HOUR)),
             ("efficiency (rounded + refined vs approximate optimum)", "efficiency",
              _fmt(result.efficiency)),
             ("efficiency against the whole budget", "budget_efficiency",
              _fmt(result.budget_efficiency)),
             ("refinement", "refinement", html.escape(result.refinement))]
    blocks = [_table(["statistic", "value"], [[lab, v] for lab, _, v in stats],
                     keys=[k for _, k, _ in stats], cls="stats")]
    blocks += _evaluation_blocks(ev, result.plan, baseline, baseline_note, "The optimised plan")
    blocks.append(_notes(list(result.notes)))
    data = {"design": _jsonable(result.to_dict()),
            "baseline": None if baseline is None else _jsonable(baseline.to_dict())}
    return Section(title, tuple(b for b in blocks if b), data)


def evaluation_section(evaluation, plan, baseline=None, title=None, baseline_note=None):
    """The report section of an existing plan's evaluation (``hse-opt design --evaluate``):
    its runs over time and predicted sigmas against a baseline plan's.

    Parameters
    ----------
    evaluation : hse_opt.design.Evaluation
    plan : hse_opt.data.Plan
    baseline : hse_opt.design.Evaluation, optional
    title, baseline_note : str, optional

    Returns
    -------
    Section
    """
    ev = evaluation
    title = title or f"The plan evaluated for {' + '.join(ev.effects)}"
    stats = [("alignments", "n_runs", _fmt(ev.n_runs)),
             ("total time [h]", "total_time_h", _fmt(ev.total_time / units.HOUR)),
             ("criterion", "criterion", html.escape(f"{ev.criterion} = {ev.criterion_value:.6g}")),
             ("condition number", "condition", _fmt(ev.condition, 3))]
    blocks = [_table(["statistic", "value"], [[lab, v] for lab, _, v in stats],
                     keys=[k for _, k, _ in stats], cls="stats")]
    blocks += _evaluation_blocks(ev, plan, baseline, baseline_note, "The plan")
    data = {"evaluation": _jsonable(ev.to_dict()),
            "baseline": None if baseline is None else _jsonable(baseline.to_dict())}
    return Section(title, tuple(b for b in blocks if b), data)


def text_section(title, lines):
    """A section of plain text lines (a list)."""
    return Section(title, (_notes(list(lines)),))


def plan_section(plan, title="The test plan", text=None):
    """A plan's runs over time (:func:`plot_plan`) with an optional paragraph.

    Returns
    -------
    Section
    """
    blocks = ([_paragraph(text)] if text else []) + [
        _embed(plot_plan(plan), "Each bar is one alignment, from its start to its end, against the "
               "time since power-on.", "the plan's runs over time")]
    return Section(title, tuple(blocks), {"n_runs": len(plan)})


# -- the page --------------------------------------------------------------------------------
_CSS = """
body{font-family:-apple-system,"Segoe UI",Roboto,"Helvetica Neue",Arial,sans-serif;margin:0;
color:#1b1b1b;background:#fff;line-height:1.45}
main{max-width:60rem;margin:0 auto;padding:1rem 1.5rem 3rem}
h1{font-size:1.6rem;margin:.5rem 0}h2{font-size:1.25rem;border-bottom:1px solid #ddd;
padding-bottom:.2rem;margin-top:2.2rem}
table{border-collapse:collapse;margin:.6rem 0;font-size:.88rem}
th,td{border-bottom:1px solid #e3e3e3;padding:.2rem .6rem;text-align:left;vertical-align:top}
th{background:#f4f6f8}td{font-variant-numeric:tabular-nums}
.cols{display:flex;flex-wrap:wrap;gap:1.5rem;align-items:flex-start}
figure{margin:1rem 0}img.plot{max-width:100%;height:auto;display:block}
figcaption{font-size:.85rem;color:#444;margin-top:.3rem}
.summary{background:#f4f8f4;border-left:4px solid #2ca02c;padding:.6rem 1rem}
.summary.warn{background:#fdf5f4;border-left-color:#d62728}
.notes{font-size:.85rem;color:#555}.hi{color:#d62728;font-weight:600}
nav ol{margin:.3rem 0;padding-left:1.3rem}code{font-size:.9em}
footer{font-size:.8rem;color:#777;margin-top:3rem}
"""


def render_html(sections, title="hse_opt report", summary=None):
    """The report page as one HTML string.

    Parameters
    ----------
    sections : sequence of Section
    title : str
    summary : sequence of str, optional
        Lines shown at the top, before the sections.

    Returns
    -------
    str
    """
    anchors = [f"s{i + 1}" for i in range(len(sections))]
    toc = "".join(f'<li><a href="#{a}">{html.escape(s.title)}</a></li>'
                  for a, s in zip(anchors, sections))
    top = ""
    if summary:
        top = '<div class="summary">' + "".join(f"<p>{html.escape(line)}</p>" for line in summary) + "</div>"
    data = {s.title: s.data for s in sections}
    # a JSON data block is inert (never executed); "</" cannot end it early once escaped
    payload = json.dumps(data, allow_nan=False, default=float).replace("</", "<\\/")
    body = "\n".join(s.html(a) for a, s in zip(anchors, sections))
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{html.escape(title)}</title><style>{_CSS}</style></head>\n<body><main>"
            f"<h1>{html.escape(title)}</h1>{top}<nav><ol>{toc}</ol></nav>\n{body}\n"
            f'<footer>hse_opt {html.escape(__version__)}. Heading errors are estimated minus '
            f'true (the paper\'s delta-psi has the opposite sign).</footer></main>\n'
            f'<script type="application/json" id="hse-opt-data">{payload}</script>'
            f"</body></html>\n")


def write_report(directory, sections, title="hse_opt report", summary=None):
    """Render ``sections`` into ``directory/report.html`` (the directory is created when
    missing; the file is written whole or not at all).

    Returns
    -------
    pathlib.Path
        The report file.
    """
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise ValueError(f"report directory {str(directory)!r} is a file; allowed: a directory "
                         "(created when missing)")
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / REPORT_NAME
    write_text_atomic(path, render_html(sections, title, summary))
    return path


#: the caption of :func:`plot_field_line`
FIELD_LINE_CAPTION = (
    "The paper's Fig. 2, per position: each alignment's heading error against the bias rate, "
    "normalised to the position's line at 0 deg/s (the unknown heading of a position without a "
    "reference drops out there), with the fitted line and its 1-sigma band. The slope is "
    "-K_HSE; it differs between positions through their C23 = -gamma cos psi + theta sin psi "
    "(their own leveling and heading), while lambda2 is one. A position seen at one rate has "
    "no line. The heading-error-against-azimuth figure needs surveyed azimuths and is not drawn.")


@_plotting
def plot_field_line(fit, runs):
    """The paper's Fig. 2 for a field campaign: heading against bias rate at each position,
    normalised to the position's line at 0 deg/s, with the fitted line and its 1-sigma band
    (:func:`hse_opt.field.position_lines`; the slope is -K_HSE, which differs between
    positions through their C23).

    Returns
    -------
    matplotlib.figure.Figure or None
        None when no position has two bias rates (no line to draw).
    """
    from .field import position_lines

    lines = [ln for ln in position_lines(fit, runs) if np.unique(np.round(ln.rate, 9)).size >= 2]
    if not lines:
        return None
    fig = _new_figure(7.5, 3.4)
    ax = fig.subplots()
    for g, ln in enumerate(lines):
        col = _COLORS[g % len(_COLORS)]
        rate_dps = ln.rate / units.DEG_PER_S
        lo, hi = min(rate_dps.min(), 0.0), max(rate_dps.max(), 0.0)
        grid = np.linspace(lo, hi, 41)
        mid, band = ln.line(grid * units.DEG_PER_S)
        label = (f"{ln.label}{' (surveyed)' if ln.surveyed else ''}: K_HSE "
                 f"{ln.k_hse_arcsec_per_radps:.1f} +- {ln.k_hse_std_arcsec_per_radps:.1f} arcsec/(rad/s)")
        ax.fill_between(grid, _arcsec(mid - band), _arcsec(mid + band), color=col, alpha=0.15, lw=0)
        ax.plot(grid, _arcsec(mid), "-", color=col, lw=1.2)
        ax.errorbar(rate_dps, _arcsec(ln.heading), yerr=_arcsec(ln.sigma), fmt="o", ms=4, color=col,
                    capsize=2, label=label)
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.set_xlabel("bias rate Omega [deg/s]")
    ax.set_ylabel("heading, normalised to 0 deg/s [arcsec]")
    fig.legend(loc="outside right upper", frameon=False, title="position")
    fig.suptitle("Calibration line per position (the paper's Fig. 2)")
    return fig
