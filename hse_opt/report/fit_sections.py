"""The report sections of a fit and of a before/after comparison of two fits."""
from __future__ import annotations

import html

import numpy as np

from .. import units
from ..factors import campaign_factors
from .cells import _cell, _fmt, _jsonable, _missing_figure, _notes, _paragraph, _table
from .curves import slope_caption, slope_parts
from .fit_plots import (FIELD_LINE_CAPTION, _effects_label, plot_azimuth, plot_before_after,
                        plot_calibration_line, plot_field_line, plot_residuals)
from .page import Section
from .style import _embed


def _fit_statistics(fit):
    """(label, key, formatted value) rows of a fit's statistics."""
    lof = fit.lack_of_fit
    return [
        ("runs", "n_runs", _fmt(fit.n_runs)),
        ("RMS of residuals [arcsec]", "rms_arcsec", _fmt(fit.rms_arcsec)),
        ("chi-square", "chi2", _fmt(fit.chi2)),
        ("degrees of freedom", "dof", _fmt(fit.dof)),
        ("reduced chi-square", "chi2_red", _fmt(fit.chi2_red)),
    ] + ([("lack of fit against the replicates (docs/weights.md)", "lack_of_fit",
           html.escape(f"F({lof.dof[0]}, {lof.dof[1]}) = {lof.statistic:.4g}, p = {lof.p_value:.3g}"))]
         if lof is not None else []) + [
        ("AIC", "aic", _fmt(fit.aic)),
        ("BIC", "bic", _fmt(fit.bic)),
        ("condition number", "condition", _fmt(fit.condition, 3)),
        ("weights", "weighting", html.escape(fit.weighting)),
        ("solver", "method", html.escape(f"{fit.method} ({fit.status})")),
    ]


def _parameter_table(rows):
    """The parameter table from :func:`hse_opt.fit.summary.report_data` rows."""
    budget = any(r.get("systematic") is not None for r in rows)
    cells = [[f"<code>{html.escape(r['name'])}</code>", _fmt(r["value"], 5),
              _fmt(r["std"], 3) if r["state"] != "fixed" else "&ndash;"]
             + ([_fmt(r["systematic"], 3) if r.get("systematic") else "&ndash;"] if budget else [])
             + [html.escape(r["unit"]), html.escape(r["state"]), html.escape(r["description"])]
             for r in rows]
    head = ["parameter", "value", "1-sigma"] + (["systematic"] if budget else []) + ["unit", "state", "meaning"]
    return _table(head, cells, keys=[f"param:{r['name']}" for r in rows], cls="params")


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
    from ..fit.summary import report_data

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
        _notes(fit.tilt_amplitude_lines() + list(fit.notes) + [f"bound binds: {b}" for b in fit.binding]
               + facs.notes()),
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
        after_by_key = {k: v for _, k, v in sa}     # (a row one of them lacks: a dash)
        rows = list(sb) + [r for r in sa if r[1] not in {k for _, k, _ in sb}]
        before_by_key = {k: v for _, k, v in sb}
        stats = [[lab, before_by_key.get(k, "&ndash;"), after_by_key.get(k, "&ndash;")] for lab, k, _ in rows]
        keys = [k for _, k, _ in rows]
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
