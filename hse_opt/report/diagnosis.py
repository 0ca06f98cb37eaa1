"""The report of a diagnosis: the ranking of candidate effects, residual structure against each
factor, and the section with verdict, ambiguities, influential runs and outliers."""
from __future__ import annotations

import html

import numpy as np

from ..factors import campaign_factors
from .cells import _fmt, _jsonable, _missing_figure, _notes, _p_text, _table
from .fit_plots import plot_residuals
from .page import Section
from .style import _COLORS, _embed, _new_figure, _plotting


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
    factor_rows = [[html.escape(t.name), html.escape(t.description), _p_text(t.p_value) + html.escape(t.adjustment),
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
        + "".join(f"<br>{html.escape(line)}" for line in d.cannot_rule_out())
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
