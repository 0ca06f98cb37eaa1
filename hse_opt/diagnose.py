"""Model against measurements: where the model fails, which effect is missing, add it.

``diagnose(runs, model)`` fits ``model`` to ``runs`` and returns a frozen :class:`Diagnosis`:

Comparison
    per run: residual (measured - model), standardised residual (residual / sigma), externally
    studentised residual, leverage and Cook's distance; the runs the fit hinges on and the
    outliers.
Goodness of fit
    the chi-square test of the standardised residuals when the runs carry their own sigmas
    (``heading_std_arcsec``), and the pure-error lack-of-fit F test when settings (rate,
    azimuth, duration, latitude, tilt) are replicated.
Where it fails
    residual structure against every factor: bias rate, rotation sense, azimuth harmonics,
    rate x azimuth, the tilt of the rotation axis (C23, when pitch/roll are known), time since
    power-on (or run order standing in for it), run order, duration, latitude and every
    covariate column; one test per factor, ranked.
Which effect is missing
    every catalogue effect not in the model (and ``covariate:<column>`` for every covariate
    column), ranked: score (Lagrange-multiplier) test at the fit (no refit), Delta-BIC and
    residual RMS after refitting. Candidates that these runs cannot test (no heading signature,
    or confounded with the model) are named with the reason; candidates that explain the data
    equally well are reported as ambiguous, with the runs that would tell them apart (a
    T-optimal discrimination design by :mod:`hse_opt.design`, :func:`discriminating_runs`).
Structure in words
    a sparse (forward-stepwise) regression of the residuals over a library of factor
    functions, each selected term as a sentence a user can act on, with the catalogue effects
    whose signature it matches.
Verdict
    ``adequate`` when no test of the family (chi-square, lack of fit, factors, candidates)
    rejects at the family-wise level ``alpha`` (Bonferroni: a test rejects when
    ``p < alpha / m``, ``m`` the number of tests); else ``missing-effect``.

:meth:`Diagnosis.add` refits with one more effect and diagnoses again; :func:`compare` puts
two diagnoses side by side (RMS, chi-square, lack-of-fit p, BIC, parameters); :func:`refine`
adds the best significant candidate until the verdict is adequate.

Statistics
----------
The tests on structure are F tests of nested weighted linear models built at the fit: the
weighted residual ``r = (y - h(p)) / sigma`` and the weighted, column-scaled Jacobian ``A`` of
the free parameters. For ``q`` more columns ``Z`` (a factor's functions, or a candidate
effect's Jacobian columns at the fit with its own parameters at their nominal values, weighted
the same way), ``P`` projects on the part of ``Z`` orthogonal to ``A`` and the score statistic
``S = r' P r`` is the fall of the weighted residual sum of squares ``RSS`` that refitting the
linearised extended model would give (the Lagrange-multiplier statistic). It is referred to
``F = (S / q) / ((RSS - S) / (n - k - q)) ~ F(q, n - k - q)``, exact for Gaussian noise and
models linear in their parameters, and independent of the sigmas' absolute scale (only their
ratios weight the runs). The lack-of-fit test is the same test with one indicator column per
replicate group. Nonlinear parameters of a candidate (the warm-up time constant) are held at
their nominal values for the score test; the refit estimates them (profiled when the fit's
Gauss-Newton start cannot see them).
"""
from __future__ import annotations

import dataclasses
import math
import sys
import types
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, stats

from . import units
from .data import Plan, Runs
from .fit import FitResult, fit, replicate_groups
from .information import (MAX_CONDITION, UnidentifiableError, check_identifiable, heading_sigma,
                          weighted_jacobian)
from .model import CATALOGUE, as_model, effect as make_effect

__all__ = ["ALPHA", "Candidate", "Comparison", "Diagnosis", "Term", "Test", "compare", "diagnose",
           "diagnostic_plan", "discriminating_runs", "model_runs", "refine"]

#: default family-wise significance level of the verdict
ALPHA = 0.05
#: a projected direction (unit columns) shorter than this is in the span of the model
_TOL = 1.0 / MAX_CONDITION
#: a parameter that, at the edge of its bounds, moves no run's heading by this many sigma has
#: no heading signature in these runs
_BLIND = 1e-3
#: time constants (s) of the warm-up-like functions in the factor library
_TAUS = (600.0, 3600.0)
#: at most this many terms in the sparse regression
_MAX_TERMS = 6
#: a structure term is "explained by" a candidate when this fraction of it lies in the
#: candidate's signature
_EXPLAINED = 0.7


# -- results -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Test:
    """One hypothesis test.

    Attributes
    ----------
    name : str
        The factor or test (``azimuth``, ``chi-square``, ``lack of fit``, ...).
    description : str
        What was tested, in words.
    statistic : float or None
        F (or chi-square) statistic; None when the runs cannot test it.
    dof : tuple of int
        Degrees of freedom (numerator, denominator) or (dof,) for chi-square.
    p_value, log_p : float or None
        The p-value and its logarithm (for ranking far into the tail); None when not computable
        (``note`` says why).
    best : str
        For a factor, the single function of it that explains most of the residual.
    note : str
    """

    name: str
    description: str
    statistic: float | None
    dof: tuple
    p_value: float | None
    log_p: float | None = None
    best: str = ""
    note: str = ""

    @property
    def tested(self):
        return self.p_value is not None

    def to_dict(self):
        return {"name": self.name, "description": self.description,
                "statistic": _num(self.statistic), "dof": list(self.dof),
                "p_value": _num(self.p_value), "best": self.best, "note": self.note}


@dataclass(frozen=True, eq=False)
class Candidate:
    """A catalogue effect not in the model, tested against the residuals.

    Attributes
    ----------
    effect, description : str
    parameters : tuple of str
        Its parameters in the extended model (tilt-coupled ones as free C23 coefficients when
        the tilt is unknown).
    held : tuple of str
        Parameters without a heading signature in these runs, held at their nominal value
        (named, never silently).
    testable : bool
    reason : str
        Why it is not testable (confounded with which parameters), else "".
    statistic : float or None
        Score-test F statistic; ``dof`` its degrees of freedom; ``p_value``, ``log_p``.
    delta_bic : float or None
        BIC after refitting minus BIC before (negative: the effect pays for its parameters).
    rms_after : float or None
        Residual RMS after refitting, rad.
    chi2_red_after : float or None
    fit : FitResult or None
        The refit.
    significant : bool
        Its score test rejects at the family-wise level.
    ambiguous_with : tuple of str
        Candidates that explain the data equally well (see :class:`Diagnosis`).
    """

    effect: str
    description: str
    parameters: tuple
    held: tuple
    testable: bool
    reason: str
    statistic: float | None = None
    dof: tuple = ()
    p_value: float | None = None
    log_p: float | None = None
    delta_bic: float | None = None
    rms_after: float | None = None
    chi2_red_after: float | None = None
    fit: FitResult | None = None
    significant: bool = False
    ambiguous_with: tuple = ()

    @property
    def rms_after_arcsec(self):
        return None if self.rms_after is None else self.rms_after / units.ARCSEC

    def to_dict(self):
        return {"effect": self.effect, "p_value": _num(self.p_value),
                "delta_bic": _num(self.delta_bic), "rms_after_arcsec": _num(self.rms_after_arcsec),
                "statistic": _num(self.statistic), "dof": list(self.dof),
                "chi2_red_after": _num(self.chi2_red_after), "significant": self.significant,
                "testable": self.testable, "reason": self.reason, "parameters": list(self.parameters),
                "held": list(self.held), "ambiguous_with": list(self.ambiguous_with),
                "description": self.description}


@dataclass(frozen=True)
class Term:
    """One term of the sparse regression of the residuals over factor functions.

    Attributes
    ----------
    function : str
        ``sin(2 x azimuth)``, ``exp(-t/600 s)``, ...
    factor : str
    coefficient, std : float
        Residual per unit of the function, arcsec per ``unit``.
    unit : str
        Unit of the function (``deg/s``, ``1``, ...).
    p_value : float
        When the term entered (Bonferroni over the remaining library).
    explained_by : tuple of str
        Catalogue candidates whose signature holds most of this term.
    text : str
        The term in words.
    """

    function: str
    factor: str
    coefficient: float
    std: float
    unit: str
    p_value: float
    explained_by: tuple
    text: str

    def to_dict(self):
        return {"function": self.function, "factor": self.factor, "coefficient_arcsec": self.coefficient,
                "std_arcsec": self.std, "unit": self.unit, "p_value": _num(self.p_value),
                "explained_by": list(self.explained_by), "text": self.text}


@dataclass(frozen=True, eq=False)
class Diagnosis:
    """A model compared with measurements (module docstring).

    Attributes
    ----------
    fit : FitResult
        The fit of the model being diagnosed.
    runs : hse_opt.data.Runs
    alpha : float
        Family-wise significance level of the verdict.
    fix : tuple of (str, float)
        Parameters held at a value (display units), as given (plus profiled ones).
    candidate_names : tuple of str
        The effects tested as candidates.
    covariates : tuple of str
        The covariate columns used as factors and candidates.
    studentized, leverage, cooks : numpy.ndarray, shape (n,)
        Externally studentised residuals, hat-matrix diagonal and Cook's distance per run.
    outliers : tuple of int
        Run ids whose studentised residual rejects at ``alpha`` (Bonferroni over the runs).
    influential : tuple of int
        Run ids the fit hinges on (Cook's distance above the median of F(k, n-k), or leverage
        above 0.5), most influential first.
    chi2_test, lack_of_fit : Test or None
    factors : tuple of Test
        Residual structure against each factor, most significant first.
    candidates : tuple of Candidate
        Best first: testable ones by Delta-BIC (score p when not refitted), then untestable.
    structure : tuple of Term
    ambiguous : tuple of str
        Significant candidates that these runs cannot tell apart (the best first), or ().
    proposals : tuple of dict
        Runs that would tell the ambiguous candidates apart, best first.
    verdict : str
        ``adequate`` or ``missing-effect``.
    n_tests : int
        Size of the test family behind the verdict.
    notes : tuple of str
    """

    fit: FitResult
    runs: Runs
    alpha: float
    fix: tuple
    candidate_names: tuple
    covariates: tuple
    studentized: np.ndarray
    leverage: np.ndarray
    cooks: np.ndarray
    outliers: tuple
    influential: tuple
    chi2_test: Test | None
    lack_of_fit: Test | None
    factors: tuple
    candidates: tuple
    structure: tuple
    ambiguous: tuple
    proposals: tuple
    verdict: str
    n_tests: int
    notes: tuple = field(default_factory=tuple)

    # -- views -------------------------------------------------------------------------------
    @property
    def effects(self):
        return tuple(self.fit.model.effect_names)

    @property
    def n_runs(self):
        return self.fit.n_runs

    @property
    def residuals(self):
        """measured - model, rad, shape (n,)."""
        return self.fit.residuals

    @property
    def standardized(self):
        return self.fit.standardized

    @property
    def rms_arcsec(self):
        return self.fit.rms_arcsec

    @property
    def chi2_red(self):
        return self.fit.chi2_red

    @property
    def lack_of_fit_p(self):
        return None if self.lack_of_fit is None else self.lack_of_fit.p_value

    @property
    def best(self):
        """The best significant candidate, or None."""
        return next((c for c in self.candidates if c.significant), None)

    def candidate(self, name):
        for c in self.candidates:
            if c.effect == name:
                return c
        raise ValueError(f"{name!r} is not a candidate of this diagnosis; candidates: "
                         f"{', '.join(c.effect for c in self.candidates) or 'none'}")

    # -- add an effect -----------------------------------------------------------------------
    def add(self, effect):
        """Diagnose again with ``effect`` (a catalogue name, ``covariate:<col>`` or an Effect)
        added to the model; reuses this diagnosis's refit when it has one."""
        name = make_effect(effect).name
        if name in self.effects:
            raise ValueError(f"effect {name!r} is already in the model ({', '.join(self.effects)})")
        prior = next((c.fit for c in self.candidates if c.effect == name and c.fit is not None), None)
        return diagnose(self.runs, prior if prior is not None else self.fit.model + effect, fix=dict(self.fix),
                        tilt_known=self.fit.tilt_known, alpha=self.alpha, covariates=self.covariates,
                        candidates=[c for c in self.candidate_names if c != name])

    # -- output ------------------------------------------------------------------------------
    def to_dict(self):
        """The JSON form (DESIGN.md contract, plus more keys)."""
        return {
            "effects": list(self.effects),
            "n_runs": self.n_runs,
            "rms_arcsec": self.rms_arcsec,
            "chi2_red": float(self.chi2_red),
            "lack_of_fit_p": self.lack_of_fit_p,
            "verdict": self.verdict,
            "candidates": [c.to_dict() for c in self.candidates],
            "ambiguous": list(self.ambiguous),
            "alpha": self.alpha,
            "n_tests": self.n_tests,
            "chi2_p": None if self.chi2_test is None else self.chi2_test.p_value,
            "weighting": self.fit.weighting,
            "factors": [t.to_dict() for t in self.factors],
            "structure": [t.to_dict() for t in self.structure],
            "proposals": list(self.proposals),
            "outliers": [int(r) for r in self.outliers],
            "influential": [int(r) for r in self.influential],
            "fit": self.fit.to_dict(),
            "notes": list(self.notes),
        }

    def plot_data(self):
        """The numbers a report plots (JSON-serialisable; edge units): per run the factors,
        residual, standardised residual, leverage and Cook's distance; the factor tests; the
        candidate ranking; the structure terms."""
        per_run = {"run": [int(r) for r in self.fit.run],
                   "residual_arcsec": (self.residuals / units.ARCSEC).tolist(),
                   "standardized": self.standardized.tolist(),
                   "studentized": [_num(v) for v in self.studentized],
                   "leverage": self.leverage.tolist(), "cooks": [_num(v) for v in self.cooks]}
        factors = {f.label: f.values.tolist()
                   for f in _factor_columns(self.runs, self.covariates, self.fit.tilt_known)}
        return {"per_run": per_run, "factors": factors, "factor_tests": [t.to_dict() for t in self.factors],
                "candidates": [c.to_dict() for c in self.candidates],
                "structure": [t.to_dict() for t in self.structure],
                "outliers": [int(r) for r in self.outliers],
                "influential": [int(r) for r in self.influential]}

    def summary(self):
        """The diagnosis as lines of text (the CLI prints them)."""
        f = self.fit
        out = [f"Diagnosis of {'+'.join(self.effects)} on {self.n_runs} runs ({self.runs.source})",
               f"  residual RMS {self.rms_arcsec:.3g} arcsec, chi2_red {f.chi2_red:.3g} "
               f"(weighting: {f.weighting})"]
        for t in (self.chi2_test, self.lack_of_fit):
            if t is not None:
                out.append(f"  {t.name}: {_test_text(t)}")
        if self.lack_of_fit is None:
            out.append("  lack of fit: not computable (no replicated settings)")
        out.append(f"  verdict: {self.verdict} ({self.n_tests} tests, family-wise alpha "
                   f"{self.alpha:g}, Bonferroni)")
        out.append("Where it fails (residual against each factor, most significant first):")
        for t in self.factors:
            line = f"  {t.name:<22} {_test_text(t)}" if t.tested else f"  {t.name:<22} not tested: {t.note}"
            out.append(line + (f"; best: {t.best}" if t.tested and t.best else ""))
        out.append("Which effect is missing (best first):")
        out.append(f"  {'effect':<26}{'p (score)':>11}{'dBIC':>10}{'RMS after':>11}")
        for c in self.candidates:
            if c.testable:
                mark = " *" if c.significant else ""
                out.append(f"  {c.effect:<26}{_p(c.p_value):>11}{_f(c.delta_bic):>10}"
                           f"{_f(c.rms_after_arcsec):>11}{mark}")
            else:
                out.append(f"  {c.effect:<26} not testable: {c.reason}")
            if c.testable and c.reason:
                out.append(f"  {'':<26} {c.reason}")
            if c.held:
                out.append(f"  {'':<26} held at nominal (no heading signature here): {', '.join(c.held)}")
        out.append("  (* significant at the family-wise level; RMS in arcsec)")
        if self.structure:
            out.append("Structure in the residuals, in words (sparse regression over factor functions):")
            out.extend(f"  - {t.text}" for t in self.structure)
        if self.ambiguous:
            out.append(f"Ambiguous: {', '.join(self.ambiguous)} explain these data equally well.")
            for r in self.proposals:
                out.append(f"  run that would tell {r['a']} from {r['b']}: {_run_text(r)}")
        if self.influential:
            out.append("Runs the fit hinges on: " + ", ".join(
                f"{r} (Cook {_f(_num(self.cooks[i]))}, leverage {self.leverage[i]:.2f})"
                for r, i in ((r, self._index(r)) for r in self.influential)))
        if self.outliers:
            out.append("Outliers: " + ", ".join(
                f"{r} ({self.studentized[self._index(r)]:+.2f} studentised)" for r in self.outliers))
        out.extend(f"Note: {n}" for n in self.notes)
        return out

    def _index(self, run_id):
        return int(np.flatnonzero(self.fit.run == run_id)[0])


@dataclass(frozen=True, eq=False)
class Comparison:
    """Two diagnoses of the same runs side by side (before and after adding effects).

    Attributes
    ----------
    before, after : Diagnosis
    added : tuple of str
        Effects in ``after`` but not in ``before``.
    statistics : tuple of (str, value_before, value_after)
        Residual RMS (arcsec), chi2, chi2_red, chi-square p, lack-of-fit p, BIC, verdict.
    parameters : tuple of (name, unit, value_before, std_before, value_after, std_after)
        Every parameter of either model (None where a model lacks it), display units.
    """

    before: Diagnosis
    after: Diagnosis
    added: tuple
    statistics: tuple
    parameters: tuple

    def to_dict(self):
        return {"added": list(self.added),
                "statistics": {k: {"before": b if isinstance(b, str) else _num(b),
                                   "after": a if isinstance(a, str) else _num(a)}
                               for k, b, a in self.statistics},
                "parameters": {n: {"unit": u, "before": _num(vb), "std_before": _num(sb),
                                   "after": _num(va), "std_after": _num(sa)}
                               for n, u, vb, sb, va, sa in self.parameters},
                "before": self.before.to_dict(), "after": self.after.to_dict()}

    def summary(self):
        out = [f"Adding {', '.join(self.added) or 'nothing'}: before -> after"]
        for k, b, a in self.statistics:
            out.append(f"  {k:<22}{_cell(b):>14}{_cell(a):>14}")
        out.append(f"  {'parameter':<22}{'before':>24}{'after':>24}")
        for n, u, vb, sb, va, sa in self.parameters:
            out.append(f"  {n:<22}{_pm(vb, sb):>24}{_pm(va, sa):>24}  {u}")
        return out


# -- the diagnosis -------------------------------------------------------------------------------
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
        Bad arguments (unknown effect, covariate column not in the runs, alpha outside (0, 1)).
    """
    if not (0.0 < alpha < 1.0):
        raise ValueError(f"alpha = {alpha!r}; allowed: a significance level in (0, 1)")
    covariates = _covariates(runs, covariates)
    fix = dict(fix or {})
    if isinstance(model, FitResult):
        f0 = model
        if f0.run.shape != runs.run.shape or np.any(f0.run != runs.run):
            raise ValueError("the FitResult given as model was not fitted to these runs (run ids differ)")
    else:
        f0 = _fit(runs, as_model(model), fix, tilt_known)
    fix.update(_fixed_of(f0))
    null = _Null(f0, runs)
    notes = list(dict.fromkeys(f0.notes))

    # comparison: influence and outliers
    lev, cooks, stud = null.influence()
    outliers, influential = _flagged(f0.run, lev, cooks, stud, null.k, alpha)
    if np.any(lev > 1 - 1e-9):
        notes.append("runs " + ", ".join(str(int(r)) for r in f0.run[lev > 1 - 1e-9])
                     + " alone determine a parameter (leverage 1): their residuals are 0 by construction")

    # goodness of fit
    chi2_test = None
    if f0.weighting == "heading_std":
        chi2_test = Test("chi-square", "standardised residuals against the runs' own sigmas",
                         float(f0.chi2), (int(f0.dof),), float(stats.chi2.sf(f0.chi2, f0.dof)),
                         float(stats.chi2.logsf(f0.chi2, f0.dof)))
    lof = _lack_of_fit(null, runs)

    # where it fails
    factor_tests, library = _factor_tests(null, runs, covariates, f0.tilt_known)
    if runs.t_start is None:
        notes.append("time since power-on unknown: cumulative run durations (run order) stand in")

    # which effect is missing
    names = _candidate_names(f0, covariates, candidates)
    cands, bases = _candidates(null, f0, runs, names, fix, refit)

    tested = [t for t in (chi2_test, lof) if t is not None and t.tested]
    tested += [t for t in factor_tests if t.tested]
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
    cands = _rank(cands)
    ambiguous, cands = _ambiguity(null, cands, bases, alpha)
    proposals = ()
    if len(ambiguous) > 1:
        by = {c.effect: c for c in cands}
        proposals = tuple(dict(r, a=ambiguous[0], b=b) for b in ambiguous[1:]
                          if by[ambiguous[0]].fit is not None and by[b].fit is not None
                          for r in _propose(runs, by[ambiguous[0]].fit, by[b].fit, k=2))
    structure = _structure(null, library, bases, alpha)
    factor_tests = tuple(sorted(factor_tests, key=lambda t: (not t.tested, t.log_p if t.tested else 0.0)))
    return Diagnosis(
        fit=f0, runs=runs, alpha=alpha, fix=tuple(sorted(fix.items())), candidate_names=tuple(names),
        covariates=tuple(covariates), studentized=stud, leverage=lev, cooks=cooks, outliers=outliers,
        influential=influential, chi2_test=chi2_test, lack_of_fit=lof, factors=factor_tests,
        candidates=tuple(cands), structure=tuple(structure), ambiguous=tuple(ambiguous),
        proposals=proposals, verdict="missing-effect" if rejected else "adequate", n_tests=m,
        notes=tuple(notes))


def compare(before, after):
    """Two diagnoses of the same runs side by side -> :class:`Comparison`."""
    if before.runs is not after.runs and (before.fit.run.shape != after.fit.run.shape
                                          or np.any(before.fit.run != after.fit.run)):
        raise ValueError("compare() needs two diagnoses of the same runs (run ids differ)")
    added = tuple(e for e in after.effects if e not in before.effects)
    rows = []
    for label, get in (("residual RMS (arcsec)", lambda d: d.rms_arcsec),
                       ("chi2", lambda d: float(d.fit.chi2)), ("dof", lambda d: int(d.fit.dof)),
                       ("chi2_red", lambda d: float(d.fit.chi2_red)),
                       ("chi-square p", lambda d: None if d.chi2_test is None else d.chi2_test.p_value),
                       ("lack-of-fit p", lambda d: d.lack_of_fit_p),
                       ("BIC", lambda d: float(d.fit.bic)), ("verdict", lambda d: d.verdict)):
        rows.append((label, get(before), get(after)))
    names = list(before.fit.names) + [n for n in after.fit.names if n not in before.fit.names]
    params = []
    for name in names:
        cells = []
        unit = ""
        for d in (before, after):
            if name in d.fit.names:
                i = d.fit.names.index(name)
                unit = d.fit.units[i]
                cells += [float(d.fit.values[i]), float(d.fit.std[i])]
            else:
                cells += [None, None]
        params.append((name, unit, *cells))
    return Comparison(before, after, added, tuple(rows), tuple(params))


def refine(runs, model=None, *, max_steps=4, **kw):
    """Diagnose, add the best significant candidate, repeat until the verdict is adequate (or no
    significant candidate is left, or ``max_steps`` effects were added).

    Returns
    -------
    tuple of Diagnosis
        The first diagnosis, then one per added effect; ``compare(steps[0], steps[-1])`` shows
        the error fall.
    """
    steps = [diagnose(runs, model, **kw)]
    while steps[-1].verdict != "adequate" and len(steps) <= max_steps and steps[-1].best is not None:
        steps.append(steps[-1].add(steps[-1].best.effect))
    return tuple(steps)


def _flagged(run, lev, cooks, stud, k, alpha):
    """Outliers (externally studentised residual rejecting at ``alpha``, Bonferroni over the
    runs) and the runs the fit hinges on (Cook's distance above the median of F(k, n - k), or
    leverage above 0.5), as run ids, most extreme first."""
    n = run.size
    with np.errstate(invalid="ignore"):
        p = n * 2.0 * stats.t.sf(np.abs(stud), n - k - 1) if n - k - 1 > 0 else np.full(n, np.nan)
    cut = stats.f.ppf(0.5, k, n - k) if n > k else np.inf
    cooks = np.nan_to_num(cooks, nan=np.inf)  # leverage 1: the fit rests on the run entirely
    outliers = tuple(int(run[i]) for i in np.argsort(-np.nan_to_num(np.abs(stud))) if p[i] < alpha)
    influential = tuple(int(run[i]) for i in np.argsort(-cooks) if cooks[i] > cut or lev[i] > 0.5)
    return outliers, influential


# -- fitting -------------------------------------------------------------------------------------
def _fixed_of(f):
    """Linear parameters a FitResult held fixed, display units (fixed nonlinear ones were
    profiled, or given in ``fix``: refits profile them again)."""
    nonlinear = f.measurement.nonlinear
    return {n: float(v) for n, v, free in zip(f.names, f.values, f.free) if not free and n not in nonlinear}


def _fit(runs, model, fix, tilt_known, start=None):
    """:func:`hse_opt.fit.fit` from ``start`` (display units; names outside the model are
    ignored). Free nonlinear parameters (the warm-up time constant) are first profiled - a grid
    and Brent search over the parameter, the model's other parameters solved linearly at each
    value - because a Gauss-Newton start cannot see them where their heading signature
    vanishes; the fit then starts from the profile optimum with every parameter free. When the
    data cannot estimate a nonlinear parameter jointly with the rest (or the iteration leaves
    its bounds), it is held at its profile optimum: the FitResult's dof, AIC and BIC count it as
    fitted and a note says so."""
    tk = runs.pitch is not None if tilt_known is None else bool(tilt_known)
    mm = model.measurement(tk)
    start = {k: v for k, v in (start or {}).items() if k in mm.names and k not in fix}
    nonlinear = [q for q in mm.nonlinear if q not in fix]
    if not nonlinear:
        return fit(runs, model, fix=fix, tilt_known=tk, start=start)
    for name in nonlinear:
        q = mm.params[mm.parameter_index(name)]
        objective = _profile_objective(runs, mm, fix, start, name)
        grid = np.linspace(math.log(q.lower), math.log(q.upper), 13)
        values = [objective(u)[0] for u in grid]
        i = int(np.argmin(values))
        res = optimize.minimize_scalar(lambda u: objective(u)[0], method="bounded",
                                       bounds=(grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]),
                                       options={"xatol": 1e-3})
        start = objective(res.x if res.fun <= values[i] else grid[i])[1]
    held = {n: start[n] for n in nonlinear}
    f_held = fit(runs, model, fix={**fix, **held}, tilt_known=tk, start=start)
    f = None
    # a profile optimum at a bound is set by the bound, not the data: no joint fit from there
    # (IPOPT would spend its iterations on a direction the data do not see)
    if all(_inside(mm, n, start[n], margin=1e-3) for n in nonlinear):
        try:
            f = fit(runs, model, fix=fix, tilt_known=tk, start=start)
        except (UnidentifiableError, RuntimeError, np.linalg.LinAlgError, ValueError):
            # the held fit validated the inputs: failing here means the data cannot estimate
            # the nonlinear parameters jointly with the rest (or the iteration diverged)
            pass
    if f is not None and all(_inside(mm, n, f.value(n)[0], margin=1e-3) for n in nonlinear) \
            and f.chi2 <= f_held.chi2 * (1 + 1e-9):
        return f
    dof = f_held.dof - len(held)
    if dof < 1:
        raise ValueError(f"{runs.source}: {f_held.n_runs} runs cannot fit the model's free parameters and "
                         f"{', '.join(held)}; need more runs")
    text = ", ".join(f"{n} = {v:.4g} {mm.params[mm.parameter_index(n)].unit}"
                     + (" (at its bound)" if not _inside(mm, n, v, margin=1e-3) else "")
                     for n, v in held.items())
    return dataclasses.replace(
        f_held, dof=dof, chi2_red=f_held.chi2 / dof, aic=f_held.aic + 2 * len(held),
        bic=f_held.bic + len(held) * math.log(f_held.n_runs),
        notes=f_held.notes + (f"{text} from a profile search (these runs cannot estimate it jointly "
                              f"with the rest): counted as fitted in dof and BIC, its uncertainty not in "
                              f"the covariance",))


def _inside(mm, name, value, margin=0.0):
    """Whether ``value`` lies inside the bounds of ``name`` (by ``margin``, relative)."""
    q = mm.params[mm.parameter_index(name)]
    if q.lower > 0:  # a scale parameter: relative margin
        return q.lower * (1 + margin) <= value <= q.upper * (1 - margin)
    span = q.upper - q.lower
    return q.lower + margin * span <= value <= q.upper - margin * span


def _profile_objective(runs, mm, fix, start, name):
    """``u -> (weighted RSS, parameters)`` with ``name`` at ``exp(u)`` (display unit) and the
    other free parameters solved by one linearised step from ``start``: exact for models linear
    in them."""
    X = mm.inputs_from_runs(runs)
    y = np.asarray(runs.heading_err, float)
    w = 1.0 / (np.asarray(runs.heading_std, float) if runs.heading_std is not None else np.ones(y.size))
    free = np.array([q not in fix and q != name for q in mm.names])

    def objective(u):
        values = {**start, **fix, name: math.exp(u)}
        p = mm.vector(values)
        r = (y - mm.predict(p, X)) * w
        A = mm.jacobian(p, X)[:, free] * mm.scale[free] * w[:, None]
        step, *_ = np.linalg.lstsq(A, r, rcond=None)
        p_disp = p / mm.scale
        p_disp[free] += step
        return float(np.sum((r - A @ step) ** 2)), dict(zip(mm.names, p_disp.tolist()))

    return objective


# -- linear algebra at the fit -------------------------------------------------------------------
class _Null:
    """The fit as a weighted linear model: residual, orthonormal basis of the model's columns,
    and projections / F tests of extra columns."""

    def __init__(self, f, runs):
        self.f = f
        self.sigma = np.asarray(f.sigma, float)
        self.r = np.asarray(f.residuals, float) / self.sigma
        mm = f.measurement
        free = np.asarray(f.free, bool)
        self.A = weighted_jacobian(mm.jacobian(f.p, mm.inputs_from_runs(runs))[:, free], self.sigma,
                                   mm.scale[free])
        d = np.linalg.norm(self.A, axis=0)
        self.Q, _ = np.linalg.qr(self.A / np.where(d > 0, d, 1.0))
        self.n = self.r.size
        # profiled parameters count as fitted (FitResult.dof already holds that)
        self.k = self.n - int(f.dof)
        self.rss = float(self.r @ self.r)

    def basis(self, Z, extra=None):
        """Orthonormal basis (n, q') of the part of span(Z) orthogonal to the model (and to
        ``extra``); Z (n, q) already weighted."""
        Z = np.asarray(Z, float)
        if Z.ndim == 1:
            Z = Z[:, None]
        d = np.linalg.norm(Z, axis=0)
        Z = Z[:, d > 0] / d[d > 0]
        blocks = [self.Q] + ([extra] if extra is not None and extra.shape[1] else [])
        for _ in range(2):  # twice is enough (Kahan-Parlett)
            for B in blocks:
                Z = Z - B @ (B.T @ Z)
        if Z.shape[1] == 0:
            return np.zeros((self.n, 0))
        U, s, _ = np.linalg.svd(Z, full_matrices=False)
        return U[:, s > _TOL]

    def score(self, U, r=None, rss=None, k_extra=0):
        """``(F, (q, dof), p, log p)`` of the columns U (orthonormal, orthogonal to the model):
        the score / nested-model F test. ``r``/``rss`` default to the fit's."""
        r = self.r if r is None else r
        rss = self.rss if rss is None else rss
        q = U.shape[1]
        dof = self.n - self.k - k_extra - q
        if q < 1 or dof < 1:
            return None, (q, dof), None, None
        s = float(np.sum((U.T @ r) ** 2))
        s = min(max(s, 0.0), rss)
        F = (s / q) / ((rss - s) / dof) if rss > s else np.inf
        return F, (q, dof), float(stats.f.sf(F, q, dof)), _f_logsf(F, q, dof)

    def influence(self):
        """Leverage, Cook's distance and externally studentised residuals per run."""
        h = np.clip(np.sum(self.Q ** 2, axis=1), 0.0, 1.0)
        n, k = self.n, self.Q.shape[1]
        e = self.r
        s2 = self.rss / (n - k) if n > k else np.nan
        with np.errstate(divide="ignore", invalid="ignore"):
            one_h = 1.0 - h
            cooks = e ** 2 * h / (k * s2 * one_h ** 2)
            s2_i = ((n - k) * s2 - e ** 2 / one_h) / (n - k - 1) if n - k - 1 > 0 else np.full(n, np.nan)
            stud = e / np.sqrt(s2_i * one_h)
        bad = one_h < 1e-9
        cooks[bad], stud[bad] = np.nan, np.nan
        return h, cooks, stud


def _f_logsf(F, q, dof):
    """log of the F(q, dof) upper tail, finite far into the tail."""
    if not np.isfinite(F):
        return -np.inf
    v = float(stats.f.logsf(F, q, dof))
    if np.isfinite(v):
        return v
    x = dof / (dof + q * F)  # sf = I_x(dof/2, q/2); log of its leading term
    a, b = dof / 2.0, q / 2.0
    return float(a * math.log(x) + b * math.log1p(-x) - math.log(a)
                 - (math.lgamma(a) + math.lgamma(b) - math.lgamma(a + b)))


# -- factors and their functions -----------------------------------------------------------------
@dataclass(frozen=True)
class _Column:
    """One factor as a column (for plots) and the library of its functions."""

    factor: str
    label: str
    values: np.ndarray
    functions: tuple   # (name, values (n,), unit, text template)


def _factor_columns(runs, covariates=None, tilt_known=True):
    """Every factor that varies over the runs, with its library of functions."""
    n = len(runs)
    rate = np.asarray(runs.rate, float)
    rate_dps = rate / units.DEG_PER_S
    psi = np.asarray(runs.azimuth, float)
    dur = np.asarray(runs.duration, float)
    t0 = (np.asarray(runs.t_start, float) if runs.t_start is not None
          else np.concatenate([[0.0], np.cumsum(dur[:-1])]))
    sense = np.sign(rate)
    cols = []
    if np.ptp(rate_dps) > 1e-9:
        fns = [("rate", rate_dps, "deg/s", "residual changes linearly with the signed bias rate "
                "(it reverses with the rotation sense): {c} arcsec per deg/s"),
               ("|rate|", np.abs(rate_dps), "deg/s", "residual grows with |bias rate|, the same for "
                "both senses: {c} arcsec per deg/s"),
               ("rate x |rate|", rate_dps * np.abs(rate_dps), "(deg/s)^2", "residual grows with "
                "rate x |rate| (a scale-factor nonlinearity signature): {c} arcsec per (deg/s)^2")]
        cols.append(_Column("bias rate", "bias rate [deg/s]", rate_dps, tuple(fns)))
    if np.any(sense > 0) and np.any(sense < 0):
        cols.append(_Column("rotation sense", "rotation sense", sense, (
            ("sense", sense, "1", "residual changes sign with the rotation sense: +-{c} arcsec"),
            ("sense x cos(azimuth)", sense * np.cos(psi), "1", "residual follows sense x cos(azimuth): "
             "amplitude {c} arcsec"),
            ("sense x sin(azimuth)", sense * np.sin(psi), "1", "residual follows sense x sin(azimuth): "
             "amplitude {c} arcsec"))))
    az_deg = np.mod(psi / units.DEG, 360.0)
    n_az = np.unique(np.round(az_deg, 3)).size
    if n_az >= 2:
        fns = []
        for h in range(1, max(1, min(3, n_az // 2)) + 1):  # resolvable harmonics only
            for name, fn in (("cos", np.cos), ("sin", np.sin)):
                fns.append((f"{name}({h} x azimuth)" if h > 1 else f"{name}(azimuth)", fn(h * psi), "1",
                            f"residual follows {name}({h} x azimuth): amplitude {{c}} arcsec"
                            if h > 1 else f"residual follows {name}(azimuth): amplitude {{c}} arcsec"))
        cols.append(_Column("azimuth", "stand azimuth [deg]", az_deg, tuple(fns)))
        if np.ptp(rate_dps) > 1e-9:
            cols.append(_Column("rate x azimuth", "rate x azimuth", rate_dps, (
                ("rate x cos(azimuth)", rate_dps * np.cos(psi), "deg/s", "residual follows rate x "
                 "cos(azimuth), a heading-sensitive error through a tilt: {c} arcsec per deg/s"),
                ("rate x sin(azimuth)", rate_dps * np.sin(psi), "deg/s", "residual follows rate x "
                 "sin(azimuth), a heading-sensitive error through a tilt: {c} arcsec per deg/s"))))
    if tilt_known and runs.pitch is not None:
        c23 = (np.asarray(runs.pitch) * np.sin(psi) - np.asarray(runs.roll) * np.cos(psi)) / units.MRAD
        if np.ptp(c23) > 1e-6:
            cols.append(_Column("tilt (C23)", "C23 [mrad]", c23, (
                ("C23", c23, "mrad", "residual follows the east tilt C23 of the rotation axis: {c} "
                 "arcsec per mrad (an error along the axis, e.g. an axis gyro bias)"),
                ("rate x C23", rate_dps * c23, "deg/s mrad", "residual follows rate x C23: {c} arcsec "
                 "per deg/s per mrad (a heading-sensitive error, lambda2-like)"),
                ("rate x |rate| x C23", rate_dps * np.abs(rate_dps) * c23, "(deg/s)^2 mrad",
                 "residual follows rate x |rate| x C23: {c} arcsec per (deg/s)^2 per mrad "
                 "(a scale-factor nonlinearity through the tilt)"))))
    time_name = "time since power-on" if runs.t_start is not None else "run order (time unknown)"
    if np.ptp(t0) > 0:
        fns = []
        for tau in _TAUS:
            fns.append((f"exp(-t/{tau:g} s)", tau / dur * (np.exp(-t0 / tau) - np.exp(-(t0 + dur) / tau)),
                        "1", f"residual decays with {time_name} (time constant about {tau:g} s): {{c}} "
                        "arcsec at power-on"))
        fns.append(("t", (t0 + dur / 2) / units.HOUR, "h",
                    f"residual drifts linearly with {time_name}: {{c}} arcsec per hour"))
        cols.append(_Column(time_name, f"{time_name} [h]", t0 / units.HOUR, tuple(fns)))
    if runs.t_start is not None and n > 2:
        order = np.arange(n, dtype=float)
        cols.append(_Column("run order", "run order", order, (
            ("run order", order, "run", "residual drifts with run order: {c} arcsec per run"),
            ("(run order)^2", (order - order.mean()) ** 2, "run^2", "residual bends with run order: "
             "{c} arcsec per run^2"))))
    if np.ptp(dur) > 1e-9:
        cols.append(_Column("duration", "alignment length [s]", dur, (
            ("1/sqrt(duration)", 1.0 / np.sqrt(dur), "s^-1/2", "residual follows 1/sqrt(alignment "
             "length): {c} arcsec sqrt(s)"),
            ("duration", dur / units.MINUTE, "min", "residual changes with alignment length: {c} "
             "arcsec per minute"))))
    lat = np.asarray(runs.latitude, float)
    if np.ptp(lat) > 1e-9:
        cols.append(_Column("latitude", "latitude [deg]", lat / units.DEG, (
            ("1/cos(latitude)", 1.0 / np.cos(lat), "1", "residual follows 1/cos(latitude) (a "
             "horizontal-rate error read as heading): {c} arcsec"),
            ("tan(latitude)", np.tan(lat), "1", "residual follows tan(latitude): {c} arcsec"))))
    for name in (runs.covariates if covariates is None else covariates):
        v = np.asarray(runs.covariates[name], float)
        if np.ptp(v) > 0:
            c = v - v.mean()
            cols.append(_Column(f"covariate {name}", name, v, (
                (name, c, f"{name} unit", f"residual follows {name} linearly: {{c}} arcsec per unit "
                 "(add covariate:" + name + ")"),
                (f"{name}^2", c ** 2 - np.mean(c ** 2), f"({name} unit)^2", f"residual bends with "
                 f"{name}: {{c}} arcsec per unit^2 (a nonlinear dependence on {name})"))))
    return cols


def _factor_tests(null, runs, covariates, tilt_known):
    """One F test per factor, and the whole function library (for the sparse regression)."""
    cols = _factor_columns(runs, covariates, tilt_known)
    tests, library = [], []
    for col in cols:
        Z = np.column_stack([fv for _, fv, _, _ in col.functions]) / null.sigma[:, None]
        U = null.basis(Z)
        F, dof, p, logp = null.score(U)
        best, best_s = "", -1.0
        for (name, fv, unit, text) in col.functions:
            u = null.basis(fv / null.sigma)
            library.append((col.factor, name, fv, unit, text, u))
            s = float(np.sum((u.T @ null.r) ** 2)) if u.shape[1] else 0.0
            if s > best_s:
                best, best_s = name, s
        desc = "residual against " + ", ".join(name for name, *_ in col.functions)
        if p is None:
            note = ("every function of it is in the model's span" if U.shape[1] == 0
                    else "too few runs for the test")
            tests.append(Test(col.factor, desc, None, dof, None, None, "", note))
        else:
            tests.append(Test(col.factor, desc, F, dof, p, logp, best))
    for factor, why in _untested_factors(runs, tilt_known, cols):
        tests.append(Test(factor, "", None, (), None, None, "", why))
    return tests, library


def _untested_factors(runs, tilt_known, cols):
    present = {c.factor for c in cols}
    out = []
    if "bias rate" not in present:
        out.append(("bias rate", f"every run is at {runs.rate[0] / units.DEG_PER_S:.4g} deg/s"))
    if "rotation sense" not in present:
        out.append(("rotation sense", "every run turns the same sense"))
    if "azimuth" not in present:
        out.append(("azimuth", "every run is at one azimuth"))
    if "tilt (C23)" not in present:
        out.append(("tilt (C23)", "no pitch_arcsec/roll_arcsec: tilt-coupled terms are free azimuth "
                    "sinusoids in the model" if runs.pitch is None or not tilt_known
                    else "C23 does not vary over the runs"))
    if not any(c.factor.startswith(("time", "run order (")) for c in cols):
        out.append(("time since power-on", "every run starts at the same time since power-on"))
    if "duration" not in present:
        out.append(("duration", f"every run lasts {runs.duration[0]:.4g} s"))
    return out


def _lack_of_fit(null, runs):
    """Pure-error lack-of-fit F test: the model against one mean per replicate group."""
    labels, g = replicate_groups(runs, null.f.measurement)
    if g == null.n:
        return None
    D = np.zeros((null.n, g))
    D[np.arange(null.n), labels] = 1.0
    U = null.basis(D / null.sigma[:, None])
    F, dof, p, logp = null.score(U)
    if p is None:
        return Test("lack of fit", f"{g} replicate groups", None, dof, None, None, "",
                    "not enough replicate groups beyond the model's parameters")
    return Test("lack of fit", f"model against {g} replicate-group means (pure error from "
                f"{dof[1]} degrees of freedom)", F, dof, p, logp)


# -- candidates ----------------------------------------------------------------------------------
def _covariates(runs, covariates):
    if covariates is None:
        return list(runs.covariates)
    covariates = [c.strip() for c in covariates.split(",")] if isinstance(covariates, str) else list(covariates)
    missing = [c for c in covariates if c not in runs.covariates]
    if missing:
        raise ValueError(f"{runs.source}: covariate column(s) {missing} not in the runs; allowed: "
                         f"{', '.join(runs.covariates) or 'none (the file has no covariate columns)'}")
    return covariates


def _candidate_names(f0, covariates, candidates):
    have = set(f0.model.effect_names)
    if candidates is None:
        names = [e for e in CATALOGUE if e not in have]
        names += [f"covariate:{c}" for c in covariates if f"covariate:{c}" not in have]
        return names
    names = [c.strip() for c in candidates.split(",")] if isinstance(candidates, str) else list(candidates)
    for name in names:
        make_effect(name)  # raises with the allowed names
        if name in have:
            raise ValueError(f"candidate {name!r} is already in the model ({', '.join(sorted(have))})")
    return names


def _candidates(null, f0, runs, names, fix, refit):
    out, bases = [], {}
    for name in names:
        cand, U = _candidate(null, f0, runs, name, fix, refit)
        out.append(cand)
        if U is not None:
            bases[name] = U
    return out, bases


def _candidate(null, f0, runs, name, fix, refit):
    eff = make_effect(name)
    model1 = f0.model + eff
    mm1 = model1.measurement(f0.tilt_known)
    X1 = mm1.inputs_from_runs(runs)
    known = {n: float(v) for n, v in zip(f0.names, f0.values)}
    p1 = mm1.vector({n: v for n, v in known.items() if n in mm1.names})
    new = [i for i, n in enumerate(mm1.names) if n not in known]
    params = tuple(mm1.names[i] for i in new)
    description = eff.description
    tested = [i for i in new if mm1.names[i] not in mm1.nonlinear and mm1.names[i] not in fix]
    J = mm1.jacobian(p1, X1)
    # blind parameters: at the edge of their bounds they move no heading by _BLIND sigma
    reach = np.array([np.max(np.abs(J[:, i])) * max(abs(mm1.params[i].lower), abs(mm1.params[i].upper))
                      * mm1.scale[i] / np.min(null.sigma) for i in tested])
    held = tuple(mm1.names[i] for i, r in zip(tested, reach) if r < _BLIND)
    tested = [i for i, r in zip(tested, reach) if r >= _BLIND]
    if not tested:
        return Candidate(name, description, params, held, False,
                         "no heading signature in these runs" + _signature_hint(params)), None
    # identifiable jointly with the model? (the same check the fit makes)
    free0 = [mm1.names.index(n) for n, fr in zip(f0.names, f0.free) if fr]
    cols = free0 + tested
    A1 = weighted_jacobian(J[:, cols], null.sigma, mm1.scale[cols])
    try:
        check_identifiable(A1.T @ A1, [mm1.names[i] for i in cols])
    except UnidentifiableError as err:
        other = [n for n in err.names if n not in params]
        mine = [n for n in err.names if n in params]
        if other:
            why = f"{', '.join(mine) or params[0]} cannot be told apart from {', '.join(other)} by these runs"
        else:
            why = f"{', '.join(err.names)} cannot be told apart from each other by these runs"
        return Candidate(name, description, params, held, False, why), None
    U = null.basis(A1[:, len(free0):])
    F, dof, p, logp = null.score(U)
    cand = Candidate(name, description, params, held, True, "", F, dof, p, logp)
    if refit and p is not None:
        fix1 = dict(fix)
        fix1.update({n: mm1.params[mm1.parameter_index(n)].nominal for n in held})
        try:
            f1 = _fit(runs, model1, fix1, f0.tilt_known, start=known)
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as err:
            # the null fit validated the runs: this is the candidate not fitting these runs
            cand = dataclasses.replace(cand, reason=f"refit failed: {err}")
        else:
            cand = dataclasses.replace(cand, delta_bic=float(f1.bic - f0.bic), rms_after=float(
                np.sqrt(np.mean(f1.residuals ** 2))), chi2_red_after=float(f1.chi2_red), fit=f1)
            nonlinear = [i for i in new if mm1.names[i] in mm1.nonlinear]
            if nonlinear:  # its signature at the fitted nonlinear values, for the comparisons
                p_nl = p1.copy()
                p_nl[nonlinear] = f1.p[nonlinear]
                J = mm1.jacobian(p_nl, X1)
                U = null.basis(weighted_jacobian(J[:, tested], null.sigma, mm1.scale[tested]))
    return cand, U


def _signature_hint(params):
    if any("*tilt_" in p for p in params):
        return " (it acts through the tilt, which these runs do not carry)"
    return ""


def _rank(cands):
    """Testable candidates by Delta-BIC (score log p where there is no refit, and as tie-break),
    then the untestable ones."""
    def key(c):
        if not c.testable or c.p_value is None:
            return (2, 0.0, 0.0, c.effect)
        if c.delta_bic is None:
            return (1, c.log_p, 0.0, c.effect)
        return (0, c.delta_bic, c.log_p, c.effect)
    return sorted(cands, key=key)


def _ambiguity(null, cands, bases, alpha):
    """The best significant candidate and every significant candidate that makes it redundant
    (its score test given the other does not reject at ``alpha``): these runs cannot tell them
    apart."""
    sig = [c for c in cands if c.significant and c.effect in bases]
    if not sig:
        return [], cands
    best = sig[0]
    Ub = bases[best.effect]
    same = []
    for c in sig[1:]:
        Uc = bases[c.effect]
        # the best given c: its part orthogonal to the model and to c
        U_b_given_c = null.basis(Ub, extra=Uc)
        r_c = null.r - Uc @ (Uc.T @ null.r)
        rss_c = float(r_c @ r_c)
        _, _, p, _ = null.score(U_b_given_c, r=r_c, rss=rss_c, k_extra=Uc.shape[1])
        if p is None or p >= alpha:
            same.append(c.effect)
    if not same:
        return [], cands
    group = [best.effect] + same
    cands = [dataclasses.replace(c, ambiguous_with=tuple(g for g in group if g != c.effect))
             if c.effect in group else c for c in cands]
    return group, cands


# -- sparse regression ---------------------------------------------------------------------------
def _structure(null, library, bases, alpha):
    """Forward-stepwise selection over the function library: at each step the function with the
    largest score statistic enters when it rejects at ``alpha`` Bonferroni-corrected over the
    functions left; then every selected term is refitted jointly with the model."""
    chosen, B = [], np.zeros((null.n, 0))
    r, rss = null.r.copy(), null.rss
    remaining = [t for t in library if t[5].shape[1]]
    while remaining and len(chosen) < _MAX_TERMS:
        scored = []
        for t in remaining:
            u = null.basis(t[2] / null.sigma, extra=B)
            if u.shape[1]:
                scored.append((float(np.sum((u.T @ r) ** 2)), t, u))
        if not scored:
            break
        s, t, u = max(scored, key=lambda x: x[0])
        _, _, p, _ = null.score(u, r=r, rss=rss, k_extra=B.shape[1])
        if p is None or p * len(scored) >= alpha:
            break
        chosen.append((t, p * len(scored)))
        B = np.column_stack([B, u])
        r = r - u @ (u.T @ r)
        rss = float(r @ r)
        remaining = [x for x in remaining if x is not t]
    if not chosen:
        return []
    # joint weighted LS of the residual on model + chosen functions (coefficients, sigmas)
    T = np.column_stack([t[2] for t, _ in chosen]) / null.sigma[:, None]
    M = np.column_stack([null.A, T])
    coef, *_ = np.linalg.lstsq(M, null.r, rcond=None)
    res = null.r - M @ coef
    dof = null.n - M.shape[1]
    s2 = float(res @ res) / dof if dof > 0 else np.nan
    cov = np.linalg.pinv(M.T @ M) * s2
    k0 = null.A.shape[1]
    terms = []
    for j, ((factor, name, fv, unit, text, u), p) in enumerate(chosen):
        c = coef[k0 + j] / units.ARCSEC  # sigma-weighted residuals: rad per unit
        sd = math.sqrt(max(cov[k0 + j, k0 + j], 0.0)) / units.ARCSEC
        explained = []
        for eff, U in bases.items():
            frac = float(np.sum((U.T @ u[:, 0]) ** 2))
            if frac >= _EXPLAINED:
                explained.append((frac, eff))
        explained = tuple(e for _, e in sorted(explained, reverse=True))
        words = text.format(c=f"{c:.3g} +- {sd:.2g}")
        words += (f"; matches {', '.join(explained)}" if explained
                  else "; no catalogue effect has this signature (a covariate or an effect of your own?)")
        terms.append(Term(name, factor, float(c), float(sd), unit, float(p), explained, words))
    return terms


# -- runs that tell two candidates apart ---------------------------------------------------------
def discriminating_runs(runs, fit_a, fit_b, k=3):
    """The runs that would best tell two fitted models apart: a T-optimal discrimination
    design (:class:`hse_opt.design.LackOfFit`, :func:`hse_opt.design.approximate_design`)
    over candidate runs (both senses at the smallest and largest |rate|, azimuths every
    45 deg, a cold start, mid and late times since power-on, the observed tilts and the
    extremes of each covariate), added to the runs already made: the runs, in proportions,
    on which model ``b`` -- refitted to everything -- would fit data from model ``a`` worst.

    Parameters
    ----------
    runs : hse_opt.data.Runs
        The runs both models were fitted to.
    fit_a, fit_b : FitResult
    k : int
        At most this many runs (the design's support, largest share first).

    Returns
    -------
    list of dict
        ``rate_dps, azimuth_deg, t_start_s, duration_s`` (``pitch_arcsec, roll_arcsec`` when the
        tilt is known; covariates by name), ``pred_a_arcsec``, ``pred_b_arcsec``, ``share``
        (the design's fraction of new runs there) and ``separation`` (the difference of the
        predictions in sigmas of run noise and both fits' prediction uncertainty).
    """
    from .design import LackOfFit, approximate_design

    grid = _candidate_grid(runs, fit_a, fit_b)
    sigma_run = float(np.median(fit_a.sigma))

    def rows(r):  # [J_b, h_a - h_b] / sigma over the runs r, and the variance of h_a - h_b
        preds, var = [], np.zeros(len(r))
        for f in (fit_a, fit_b):
            mm = f.measurement
            X = mm.inputs_from_runs(r)
            preds.append(mm.predict(f.p, X))
            G = mm.jacobian(f.p, X) * mm.scale  # per display unit
            var += np.einsum("ij,jk,ik->i", G, f.covariance, G)
        mm = fit_b.measurement
        Jb = (mm.jacobian(fit_b.p, mm.inputs_from_runs(r)) * mm.scale)[:, np.asarray(fit_b.free, bool)]
        return np.column_stack([Jb, preds[0] - preds[1]]) / sigma_run, preds, var

    A, preds, var = rows(grid)
    A0 = rows(runs)[0]
    design = approximate_design(A, LackOfFit(), prior=A0.T @ A0)
    sep = np.abs(preds[0] - preds[1]) / np.sqrt(sigma_run ** 2 + var)
    support = design.support[np.argsort(-design.runs[design.support], kind="stable")]
    out = []
    for i in support[:k]:
        row = {"rate_dps": float(grid.rate[i] / units.DEG_PER_S),
               "azimuth_deg": float(np.mod(grid.azimuth[i] / units.DEG, 360.0)),
               "t_start_s": float(grid.t_start[i]), "duration_s": float(grid.duration[i])}
        if grid.pitch is not None:
            row["pitch_arcsec"] = float(grid.pitch[i] / units.ARCSEC)
            row["roll_arcsec"] = float(grid.roll[i] / units.ARCSEC)
        row.update({c: float(v[i]) for c, v in grid.covariates.items()})
        row.update(pred_a_arcsec=float(preds[0][i] / units.ARCSEC),
                   pred_b_arcsec=float(preds[1][i] / units.ARCSEC),
                   share=float(design.runs[i] / design.runs.sum()), separation=float(sep[i]))
        out.append(row)
    return out


_propose = discriminating_runs


def _candidate_grid(runs, *fits):
    r = np.abs(np.asarray(runs.rate, float))
    rates = np.unique(np.concatenate([[r.min(), r.max()], [-r.min(), -r.max()]]))
    az = np.deg2rad(np.arange(0.0, 360.0, 45.0))
    dur = float(np.max(runs.duration))
    t_obs = (np.asarray(runs.t_start, float) if runs.t_start is not None
             else np.concatenate([[0.0], np.cumsum(np.asarray(runs.duration)[:-1])]))
    times = np.unique([0.0, float(np.median(t_obs)), float(np.max(t_obs))])
    tilts = [(None, None)]
    if runs.pitch is not None:
        q = np.round(np.column_stack([runs.pitch, runs.roll]) / (60 * units.ARCSEC))
        _, first = np.unique(q, axis=0, return_index=True)
        tilts = [(float(runs.pitch[i]), float(runs.roll[i])) for i in sorted(first)[:4]]
    used = []
    for f in fits:
        used += [c for c in f.model.covariates if c not in used]
    cov_levels = [[]]
    for c in used[:2]:
        v = np.asarray(runs.covariates[c], float)
        cov_levels = [lv + [(c, x)] for lv in cov_levels for x in (v.min(), v.max())]
    rows = []
    for rate in rates:
        for a in az:
            for t in times:
                for tilt in tilts:
                    for lv in cov_levels:
                        rows.append((rate, a, t, tilt, dict(lv)))
    m = len(rows)
    cov = {c: np.array([row[4].get(c, float(np.mean(runs.covariates[c]))) for row in rows]) for c in used}
    pitch = None if runs.pitch is None else np.array([row[3][0] for row in rows])
    roll = None if runs.pitch is None else np.array([row[3][1] for row in rows])
    return Runs(run=np.arange(m), rate=np.array([row[0] for row in rows]), azimuth=np.array([row[1] for row in rows]),
                heading_err=np.zeros(m), latitude=np.full(m, float(np.mean(runs.latitude))),
                duration=np.full(m, dur), t_start=np.array([row[2] for row in rows]), pitch=pitch, roll=roll,
                covariates=cov, source="candidate runs")


# -- plans and model data for diagnosis studies ---------------------------------------------------
def diagnostic_plan(sessions=4, runs_per_session=16, rates_dps=(20.0, 40.0, 60.0), n_azimuths=8,
                    duration=300.0, tilt_arcsec=1800.0):
    """A plan in which the catalogue effects have distinct signatures.

    ``sessions`` cold starts (time since power-on restarts at 0: the warm-up is seen several
    times, at different settings), each of ``runs_per_session`` back-to-back runs; both senses
    at every ``rates_dps`` (so rate-odd, rate-even and rate x |rate| terms separate); azimuths
    every ``360 / n_azimuths`` deg, each session shifted (azimuth harmonics, and C23 turning
    with the azimuth); a deliberate base tilt per session from a tilt fixture (none, +x, +y,
    -x-y, of ``tilt_arcsec``: C23 takes several amplitudes, which separates effects acting
    through the tilt from the offset and from each other).

    Returns
    -------
    hse_opt.data.Plan
        ``sessions * runs_per_session`` runs.
    """
    if sessions < 1 or runs_per_session < 1 or n_azimuths < 1 or duration <= 0 or not rates_dps:
        raise ValueError("diagnostic_plan needs sessions, runs_per_session, n_azimuths >= 1, duration > 0 "
                         "and at least one rate")
    m = len(rates_dps)
    # every |rate| in both senses, consecutive runs changing rate and sense
    order = [rates_dps[i % m] * (-1.0) ** (i + (i // m if m % 2 == 0 else 0)) for i in range(2 * m)]
    # azimuth step coprime with n_azimuths: every azimuth, neighbours far apart
    step = next(k for k in (3, 5, 7, 1) if math.gcd(k, n_azimuths) == 1)
    tilts = [(0.0, 0.0), (tilt_arcsec, 0.0), (0.0, tilt_arcsec), (-tilt_arcsec, -tilt_arcsec)]
    rows = {k: [] for k in ("rate", "azimuth", "t_start", "tilt_x", "tilt_y")}
    for s in range(sessions):
        for j in range(runs_per_session):
            rows["rate"].append(order[(j + 2 * s) % len(order)] * units.DEG_PER_S)
            rows["azimuth"].append(2 * np.pi / n_azimuths * ((step * j + s) % n_azimuths))
            rows["t_start"].append(j * duration)
            tx, ty = tilts[s % len(tilts)]
            rows["tilt_x"].append(tx * units.ARCSEC)
            rows["tilt_y"].append(ty * units.ARCSEC)
    n = sessions * runs_per_session
    return Plan(run=np.arange(n), duration=np.full(n, float(duration)), source="diagnostic plan",
                **{k: np.array(v) for k, v in rows.items()})


def model_runs(plan, values, rng, *, model=None, latitude=28.07 * units.DEG, base_tilt=(0.0, 0.0),
               sigma=None, covariates=None):
    """Runs generated by the measurement model itself plus seeded Gaussian noise.

    Parameters
    ----------
    plan : hse_opt.data.Plan
    values : mapping name -> value (display unit)
        The true parameters (the rest at nominal).
    rng : numpy.random.Generator
    model : Model, str or sequence of str, optional
        The true model (default: the effects the ``values`` belong to, plus ``hse``).
    latitude : float
        rad.
    base_tilt : (float, float)
        Pitch and roll of the turntable base without the plan's tilt, rad (the stand's own).
    sigma : float or array_like, optional
        Heading noise, rad (default :func:`hse_opt.information.heading_sigma` of each run);
        written to ``heading_std``.
    covariates : mapping name -> array_like, optional
        Covariate columns (file units), shape (n,).

    Returns
    -------
    hse_opt.data.Runs
        With pitch/roll (plan tilt + ``base_tilt``), ``t_start`` and ``heading_std``.
    """
    n = len(plan)
    tx = np.zeros(n) if plan.tilt_x is None else np.asarray(plan.tilt_x)
    ty = np.zeros(n) if plan.tilt_y is None else np.asarray(plan.tilt_y)
    lat = np.full(n, float(latitude))
    sig = heading_sigma(plan.duration, lat) if sigma is None else np.broadcast_to(np.asarray(sigma, float), (n,))
    runs = Runs(run=plan.run, rate=plan.rate, azimuth=plan.azimuth, heading_err=np.zeros(n), latitude=lat,
                duration=plan.duration, t_start=plan.t_start, pitch=ty + base_tilt[0], roll=tx + base_tilt[1],
                heading_std=np.array(sig), covariates=dict(covariates or {}), source="measurement model")
    if model is None:
        owners = {p.name: name for name in CATALOGUE for p in CATALOGUE[name].params}
        owners.update({f"k_{c}": f"covariate:{c}" for c in runs.covariates})
        unknown = sorted(set(values) - set(owners))
        if unknown:
            raise ValueError(f"parameters {unknown} belong to no catalogue effect; pass model=")
        model = ["hse"] + sorted({owners[v] for v in values} - {"hse"})
    mm = as_model(model).measurement(True)
    h = mm.predict(mm.vector(values), mm.inputs_from_runs(runs))
    return runs.replace(heading_err=h + rng.normal(0.0, 1.0, n) * sig)


# -- formatting ----------------------------------------------------------------------------------
def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _p(p):
    return "-" if p is None else f"{p:.2g}"


def _f(x):
    return "-" if x is None else f"{x:.3g}"


def _cell(x):
    if x is None:
        return "-"
    if isinstance(x, str):
        return x
    return f"{x:.4g}"


def _pm(v, s):
    return "-" if v is None else f"{v:.4g} +- {s:.2g}"


def _test_text(t):
    if not t.tested:
        return f"not computable ({t.note})"
    if len(t.dof) == 1:
        return f"chi2({t.dof[0]}) = {t.statistic:.4g}, p = {t.p_value:.3g}"
    return f"F({t.dof[0]}, {t.dof[1]}) = {t.statistic:.4g}, p = {t.p_value:.3g}"


def _run_text(r):
    parts = [f"{r['rate_dps']:+.4g} deg/s", f"azimuth {r['azimuth_deg']:.4g} deg",
             f"t_start {r['t_start_s']:.4g} s"]
    if "pitch_arcsec" in r:
        parts.append(f"pitch {r['pitch_arcsec']:.4g} / roll {r['roll_arcsec']:.4g} arcsec")
    extra = [k for k in r if k not in ("rate_dps", "azimuth_deg", "t_start_s", "duration_s", "pitch_arcsec",
                                       "roll_arcsec", "pred_a_arcsec", "pred_b_arcsec", "separation", "a", "b")]
    parts += [f"{c} {r[c]:.4g}" for c in extra]
    return (", ".join(parts) + f": predicted {r['pred_a_arcsec']:.3g} vs {r['pred_b_arcsec']:.3g} arcsec "
            f"({r['separation']:.2g} sigma apart)")


class _CallableModule(types.ModuleType):
    """``hse_opt.diagnose(runs, ...)`` calls :func:`diagnose`: the package exports this module
    under the function's name."""

    def __call__(self, *args, **kwargs):
        return diagnose(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
