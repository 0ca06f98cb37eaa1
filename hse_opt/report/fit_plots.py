"""Plots of a fit: the calibration line (the paper's Fig. 2, also per position in the field), heading
error against azimuth before and after compensation (Fig. 3), residuals against every factor."""
from __future__ import annotations

import numpy as np

from .. import units
from .curves import _arcsec, _curve, _grid_runs, _only, _slope_others, slope_parts
from .rules import _MAX_SETUPS, _groups, _tilt_of_azimuth, factors, tilt_setups
from .style import _COLORS, _MAX_LINES, _new_figure, _plotting


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
    from ..fit.correction import compensation

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
    from ..fit.field import position_lines

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
