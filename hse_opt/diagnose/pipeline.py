"""The diagnosis itself: :func:`diagnose` (fit, influence, goodness of fit, factors,
candidates, ambiguity, structure, verdict) and :func:`refine` (add the best candidate until
adequate)."""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy import stats

from ..aliasing import alias_budget
from ..fit import FitResult, fit_profiled
from ..fit.checks import zero_scatter
from ..model import as_model
from .candidates import (AMBIGUOUS_DELTA_BIC, ambiguity, candidate_names, covariate_columns, rank,
                         test_candidates)
from .discrimination import discriminating_runs
from .factors import factor_tests
from .resolution import resolving_plan
from .result import Diagnosis
from .statistics import ALPHA, Null, Test, flag_runs, lack_of_fit
from .structure import run_order_tests, sparse_structure


def diagnose(runs, model=None, *, fix=None, tilt_known=None, alpha=ALPHA, candidates=None,
             covariates=None, refit=True):
    """Compare ``model`` with the measured ``runs``: residuals, influence, goodness of fit,
    residual structure against every factor, the ranking of missing effects, the verdict.

    Parameters
    ----------
    runs : hse_opt.data.Runs
    model : Model, str, sequence of str or FitResult, optional
        The model to diagnose (default the paper's ``hse``); a FitResult of these runs is used
        as the fit.
    fix : mapping name -> value (display unit), optional
        Parameters held at a value (passed to :func:`hse_opt.fit.fit`).
    tilt_known : bool, optional
        Use the runs' pitch/roll (default: when the runs have them).
    alpha : float
        Family-wise significance level of the verdict, in (0, 1).
    candidates : sequence of str, optional
        Effects to test (default: every catalogue effect not in the model, and
        ``covariate:<column>`` for each covariate column).
    covariates : sequence of str, optional
        Covariate columns to use as factors and candidates (default: every covariate column).
    refit : bool
        Refit every testable candidate (Delta-BIC, RMS after); False gives the score tests only.

    Returns
    -------
    Diagnosis

    Raises
    ------
    UnidentifiableError
        The model itself cannot be fitted to these runs (named parameters).
    ValueError
        Bad arguments (unknown effect, covariate column not in the runs, alpha outside (0, 1)),
        or heading errors without noise (the model reproduces them to rounding: every test
        would compare rounding errors). Copies of one measurement (rows written twice:
        :meth:`hse_opt.data.Runs.copies`) are no error: the tests count each measurement
        once, and a note says so.
    """
    if not (0.0 < alpha < 1.0):
        raise ValueError(f"alpha = {alpha!r}; allowed: a significance level in (0, 1)")
    covariates = covariate_columns(runs, covariates)
    fix = dict(fix or {})
    if isinstance(model, FitResult):
        f0 = model
        if f0.run.shape != runs.run.shape or np.any(f0.run != runs.run):
            raise ValueError("the FitResult given as model was not fitted to these runs (run ids differ)")
    else:
        f0 = fit_profiled(runs, as_model(model), fix=fix, tilt_known=tilt_known)
    fix.update(fixed_of(f0))
    zero = zero_scatter(f0)
    if zero:
        raise ValueError(f"{runs.source}: {zero}: {'+'.join(f0.model.effect_names)} reproduces them to "
                         "rounding, and every test of the diagnosis would compare rounding errors; allowed: "
                         "measured heading errors (hse-opt fit reports the fit itself)")
    null = Null(f0, runs)
    notes = list(dict.fromkeys(f0.notes))
    if null.n_eff < null.n:
        notes.append(f"copies (rows written twice, not runs measured again): the tests count each of the "
                     f"{null.n_eff} measurements once, not the {null.n} rows")

    # comparison: influence and outliers
    lev, cooks, stud = null.influence()
    outliers, influential = flag_runs(f0.run, lev, cooks, stud, null.k, alpha, null.n_eff)
    if np.any(lev > 1 - 1e-9):
        notes.append("runs " + ", ".join(str(int(r)) for r in f0.run[lev > 1 - 1e-9])
                     + " alone determine a parameter (leverage 1): their residuals are 0 by construction")

    # goodness of fit
    chi2_test = None
    if f0.weighting == "heading_std":
        chi2_test = Test("chi-square", "standardised residuals against the runs' own sigmas",
                         float(f0.chi2), (int(f0.dof),), float(stats.chi2.sf(f0.chi2, f0.dof)),
                         float(stats.chi2.logsf(f0.chi2, f0.dof)))
    lof = lack_of_fit(null, runs)

    # where it fails
    factor_results, library = factor_tests(null, runs, covariates, f0.tilt_known)
    factor_results += run_order_tests(null, f0.run)
    if runs.t_start is None:
        notes.append("time since power-on unknown: cumulative run durations (run order) stand in")

    # which effect is missing
    names = candidate_names(f0, covariates, candidates)
    cands, bases = test_candidates(null, f0, runs, names, fix, refit)

    tested = [t for t in (chi2_test, lof) if t is not None and t.tested]
    tested += [t for t in factor_results if t.tested]
    m = len(tested) + sum(c.p_value is not None for c in cands)
    level = alpha / max(m, 1)
    cands = [dataclasses.replace(c, significant=c.testable and c.p_value is not None and c.p_value < level)
             for c in cands]
    rejected = any(t.p_value < level for t in tested) or any(c.significant for c in cands)
    if m == 0:
        notes.append("no test is possible with these runs (too few, or nothing varies): the verdict "
                     "'adequate' only means that nothing could be checked")
    elif chi2_test is not None and chi2_test.p_value < level and not any(c.significant for c in cands) \
            and not any(t.p_value < level for t in tested if t is not chi2_test):
        notes.append(f"the scatter exceeds the runs' own sigmas (chi2_red {f0.chi2_red:.3g}) but no factor "
                     "or catalogue effect explains it: the sigmas may be optimistic, or the missing effect "
                     "follows nothing recorded with the runs")
    cands = rank(cands)
    ambiguous, cands = ambiguity(null, cands, bases, alpha, level)
    proposals = ()
    if len(ambiguous) > 1:
        by = {c.effect: c for c in cands}
        proposals = tuple(dict(r, a=ambiguous[0], b=b) for b in ambiguous[1:]
                          if by[ambiguous[0]].fit is not None and by[b].fit is not None
                          for r in discriminating_runs(runs, by[ambiguous[0]].fit, by[b].fit, k=2))
    structure = sparse_structure(null, library, bases, alpha, level=level, run=f0.run)
    verdict = "missing-effect" if rejected else "adequate"
    # what these runs cannot rule out: every catalogue effect not in the model, at the edge of its
    # plausible range, under this diagnosis's own test and level (hse_opt.aliasing)
    budget = alias_budget(f0, runs, level=level, alpha=alpha)
    f0 = f0.with_budget(budget)
    resolving = ()
    if verdict == "adequate":
        verdict, more, resolving = _inconclusive(f0, runs, budget, cands, alpha, level, chi2_test)
        notes += more
    if rejected and structure and _unexplained(structure[0], cands, bases, null):
        verdict = "unexplained structure"
        notes.append(f"unexplained structure: the strongest structure in the residuals ({structure[0].function}) "
                     "follows no catalogue effect and explains more than any candidate. Model it with a covariate "
                     "column (0/1 for a step) and the effect covariate:<column>, or declare an Effect of your "
                     "own (README: effects outside the catalogue)")
    factor_results = tuple(sorted(factor_results, key=lambda t: (not t.tested, t.log_p if t.tested else 0.0)))
    return Diagnosis(
        fit=f0, runs=runs, alpha=alpha, fix=tuple(sorted(fix.items())), candidate_names=tuple(names),
        covariates=tuple(covariates), studentized=stud, leverage=lev, cooks=cooks, outliers=outliers,
        influential=influential, chi2_test=chi2_test, lack_of_fit=lof, factors=factor_results,
        candidates=tuple(cands), structure=tuple(structure), ambiguous=tuple(ambiguous),
        proposals=proposals, verdict=verdict, n_tests=m,
        notes=tuple(notes), likelihood=null.scale.text, budget=budget, resolving=resolving,
        rediagnose=diagnose)



def _inconclusive(f0, runs, budget, cands, alpha, level, chi2_test):
    """``('inconclusive', notes, resolving runs)`` when the model fits but these runs cannot rule
    out what would move it: a systematic risk (an effect the test would miss that moves a
    fitted parameter by more than its sigma), or a candidate the BIC strongly favours (Delta-BIC
    below -:data:`~.candidates.AMBIGUOUS_DELTA_BIC`) whose test does not reject at the
    family-wise level; else ``('adequate', notes, ())``. The notes also say why a chi-square
    test that rejects alone at ``alpha`` leaves the verdict adequate (it is one test of the
    family)."""
    notes, resolving, plans = [], [], []
    if chi2_test is not None and level <= chi2_test.p_value < alpha:
        notes.append(f"the chi-square test alone rejects at {alpha:g} (p = {chi2_test.p_value:.3g}; hse-opt fit "
                     f"prints this p), but not at the family-wise level {level:.3g} = {alpha:g} / {round(alpha / level)} "
                     "tests (Bonferroni) the verdict uses: the scatter is somewhat above the runs' own sigmas")
    strong = [c for c in cands if c.testable and not c.significant and c.delta_bic is not None
              and c.delta_bic <= -AMBIGUOUS_DELTA_BIC]
    for c in strong:
        notes.append(f"inconclusive: {c.effect} lowers the BIC by {-c.delta_bic:.3g} (strong evidence for it) but its "
                     f"score test (p = {c.p_value:.3g}) does not reject at the family-wise level {level:.3g}: "
                     "more runs would decide; fit with it to see what it changes")
    free = np.asarray(f0.free, bool)
    at_risk = [i for i in np.flatnonzero(free) if f0.systematic[i] > 0]
    effects = []
    for i in at_risk:
        effects += [e for e in f0.systematic_by[i] if e not in effects]
    for e in effects:
        risk = budget.effect(e)
        hit = [f"{f0.names[i]} by up to {f0.systematic_by[i][e]:.3g} {f0.units[i]} (its sigma {f0.std[i]:.3g})"
               for i in at_risk if e in f0.systematic_by[i]]
        plan = resolving_plan(f0, runs, [e], level=level)
        if plan.resolved:
            resolving += [dict(r, effect=e) for r in plan.runs]
            plans.append(plan)
        notes.append(f"inconclusive: {e}, {risk.threshold_text()}, could move {', '.join(hit)}; "
                     f"{_plan_text(plan, runs)}")
    if len(effects) > 1 and len(plans) == len(effects):
        # greedy for all at once, and each effect's own plan completed: the shorter
        both = [resolving_plan(f0, runs, effects, level=level), resolving_plan(f0, runs, effects, level=level,
                                                                               start=plans)]
        plan = min(both, key=lambda p: (not p.resolved, p.n_runs))
        notes.append(f"inconclusive: all of {', '.join(effects)} together: {_plan_text(plan, runs)}")
    return ("inconclusive" if effects or strong else "adequate"), notes, tuple(resolving)


def _plan_text(plan, runs):
    """What it takes to resolve a risk, in words (:class:`.resolution.ResolvingPlan`)."""
    return plan.text(field=runs.surveyed is not None and not np.all(runs.surveyed))


def _unexplained(term, cands, bases, null):
    """Whether the strongest structure term is one no catalogue effect explains and it explains
    more of the residual than the best significant candidate's signature does."""
    if not term.significant or term.explained_by:
        return False
    best = max((float(np.sum((bases[c.effect].T @ null.r) ** 2)) for c in cands
                if c.significant and c.effect in bases), default=0.0)
    return term.score > best


def refine(runs, model=None, *, max_steps=4, **kw):
    """Diagnose, add the best significant candidate, repeat until the verdict is adequate (or no
    significant candidate is left, or ``max_steps`` effects were added). It stops without
    adding when the verdict is ``unexplained structure`` or the best candidates are ambiguous
    (the last diagnosis says which, and proposes the runs that tell them apart): it never picks
    one of an ambiguous pair. Nor does it add a candidate whose refit failed (its parameters
    cannot be told apart from the model's by these runs: the diagnosis says which): the model
    it would make is not identifiable, and the last diagnosis stands.

    Returns
    -------
    tuple of Diagnosis
        The first diagnosis, then one per added effect; ``compare(steps[0], steps[-1])`` shows
        the error fall.
    """
    steps = [diagnose(runs, model, **kw)]
    while steps[-1].verdict == "missing-effect" and len(steps) <= max_steps and steps[-1].best is not None \
            and steps[-1].best.fit is not None and len(steps[-1].ambiguous) < 2:
        steps.append(steps[-1].add(steps[-1].best.effect))
    return tuple(steps)


def fixed_of(f):
    """Linear parameters a FitResult held fixed, display units (fixed nonlinear ones were
    profiled, or given in ``fix``: refits profile them again)."""
    nonlinear = f.measurement.nonlinear
    return {n: float(v) for n, v, free in zip(f.names, f.values, f.free) if not free and n not in nonlinear}
