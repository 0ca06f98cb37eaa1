"""The results: :class:`Diagnosis` (a model compared with measurements) and
:class:`Comparison` (two diagnoses side by side, :func:`compare`)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import units
from ..data import Runs
from ..fit import FitResult, fit_profiled
from ..model import effect as make_effect
from ._format import cell, f_text, num, p_text, pm, run_text, test_text
from .factors import factor_columns
from .statistics import Test


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
        ``adequate``; ``missing-effect``; ``unexplained structure`` when the strongest
        structure in the residuals (a level shift, an outlier, a function no catalogue effect
        matches) explains more than any significant candidate; or ``inconclusive`` when no test
        rejects but these runs cannot rule out what would move the calibration: an effect the
        test would miss (power < 0.8) that moves a fitted parameter by more than its sigma
        (:mod:`hse_opt.aliasing`), or a candidate the BIC strongly favours whose test does not
        reject at the family-wise level (the notes say which, and the runs that would resolve it).
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
    #: the likelihood every candidate's refit is compared on (:class:`.statistics.LikelihoodScale`)
    likelihood: str = ""
    #: what these runs cannot rule out (:class:`hse_opt.aliasing.AliasBudget` of ``fit``)
    budget: object = None
    #: runs that would resolve the systematic risks (the runs of each effect's
    #: :func:`hse_opt.diagnose.resolving_plan` that resolves it, with ``effect`` and ``count``)
    resolving: tuple = ()
    #: how this diagnosis was made (:func:`hse_opt.diagnose.diagnose`), for :meth:`add` to make
    #: the next one: passed in by the pipeline, so this module does not import it
    rediagnose: object = field(default=None, repr=False, compare=False)

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
    def fits(self):
        """Whether no test of the family rejects the model (verdict ``adequate`` or
        ``inconclusive``: the second says what these runs cannot rule out)."""
        return self.verdict in ("adequate", "inconclusive")

    def cannot_rule_out(self):
        """One line per systematic risk of the fit (:mod:`hse_opt.aliasing`): the effect and
        the parameters it could move beyond their sigma, unseen; empty when none."""
        f = self.fit
        if f.systematic is None:
            return []
        by_effect = {}
        for i, by in enumerate(f.systematic_by):
            for e, s in by.items():
                by_effect.setdefault(e, []).append(f"{f.names[i]} by up to {s:.3g} {f.units[i]} "
                                                   f"(sigma {f.std[i]:.3g})")
        return [f"cannot rule out {e}: it would go undetected here and could move {', '.join(parts)}"
                for e, parts in by_effect.items()]

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
        if self.rediagnose is None:
            raise TypeError("this Diagnosis was built without its pipeline (rediagnose=None): "
                            "diagnose(runs, model + effect) instead")
        name = make_effect(effect).name
        if name in self.effects:
            raise ValueError(f"effect {name!r} is already in the model ({', '.join(self.effects)})")
        prior = next((c.fit for c in self.candidates if c.effect == name and c.fit is not None), None)
        model = self.fit.model + effect
        if prior is not None and prior.weighting != self.fit.weighting:
            # the refit held this model's sigmas (one likelihood scale); the extended model's own
            # diagnosis weighs the runs by its own noise model, from the refit's estimates
            prior = fit_profiled(self.runs, model, fix={k: v for k, v in self.fix if k in prior.names},
                                 tilt_known=self.fit.tilt_known, start=dict(zip(prior.names, prior.values)))
        return self.rediagnose(self.runs, prior if prior is not None else model, fix=dict(self.fix),
                        tilt_known=self.fit.tilt_known, alpha=self.alpha, covariates=self.covariates,
                        candidates=[c for c in self.candidate_names if c != name])

    # -- output ------------------------------------------------------------------------------
    def to_dict(self):
        """The JSON form (the contract of ``docs/formats.md``, plus more keys)."""
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
            "likelihood_scale": self.likelihood,
            "confounded": [g.to_dict() for g in self.fit.confounded],
            "alias_budget": None if self.budget is None else self.budget.to_dict(),
            "resolving": [dict(r) for r in self.resolving],
        }

    def plot_data(self):
        """The numbers a report plots (JSON-serialisable; edge units): per run the factors,
        residual, standardised residual, leverage and Cook's distance; the factor tests; the
        candidate ranking; the structure terms."""
        per_run = {"run": [int(r) for r in self.fit.run],
                   "residual_arcsec": (self.residuals / units.ARCSEC).tolist(),
                   "standardized": self.standardized.tolist(),
                   "studentized": [num(v) for v in self.studentized],
                   "leverage": self.leverage.tolist(), "cooks": [num(v) for v in self.cooks]}
        factors = {f.label: f.values.tolist()
                   for f in factor_columns(self.runs, self.covariates, self.fit.tilt_known)}
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
                out.append(f"  {t.name}: {test_text(t)}")
        if self.lack_of_fit is None:
            out.append("  lack of fit: not computable (no replicated settings)")
        out.append(f"  verdict: {self.verdict} ({self.n_tests} tests, family-wise alpha "
                   f"{self.alpha:g}, Bonferroni)")
        out.extend(f"  {line}" for line in self.cannot_rule_out())
        out.append("Where it fails (residual against each factor, most significant first):")
        for t in self.factors:
            line = f"  {t.name:<22} {test_text(t)}" if t.tested else f"  {t.name:<22} not tested: {t.note}"
            out.append(line + (f"; best: {t.best}" if t.tested and t.best else ""))
        out.append("Which effect is missing (best first):")
        out.append(f"  {'effect':<26}{'p (score)':>11}{'dBIC':>10}{'RMS after':>11}")
        for c in self.candidates:
            if c.testable:
                mark = " *" if c.significant else ""
                out.append(f"  {c.effect:<26}{p_text(c.p_value):>11}{f_text(c.delta_bic):>10}"
                           f"{f_text(c.rms_after_arcsec):>11}{mark}")
            else:
                out.append(f"  {c.effect:<26} not testable: {c.reason}")
            if c.testable and c.reason:
                out.append(f"  {'':<26} {c.reason}")
            if c.plausibility and (c.significant or c.ambiguous_with):
                out.append(f"  {'':<26} implausible: {'; '.join(c.plausibility)}")
            if c.moves and (c.significant or c.ambiguous_with):
                out.append(f"  {'':<26} adding it moves {'; '.join(c.moves)}: its alias, expected "
                           "if the effect is real")
            if c.held:
                out.append(f"  {'':<26} held at nominal (no heading signature here): {', '.join(c.held)}")
        out.append("  (* significant at the family-wise level; RMS in arcsec)")
        if self.likelihood:
            out.append(f"  Delta-BIC on one likelihood scale: {self.likelihood}")
        if self.structure:
            out.append("Structure in the residuals, in words (sparse regression over factor functions):")
            out.extend(f"  - {t.text}" for t in self.structure)
        if self.ambiguous:
            out.append(f"Ambiguous: {', '.join(self.ambiguous)} explain these data equally well (Delta-BIC "
                       f"within 6, or equally adequate fits); do not pick one: run the runs below.")
            for name in self.ambiguous:
                c = self.candidate(name)
                out.append(f"  {name}: " + ("; ".join(c.plausibility) if c.plausibility
                                            else "every fitted magnitude within its physical range"))
            for r in self.proposals:
                out.append(f"  run that would tell {r['a']} from {r['b']}: {run_text(r)}")
        if self.influential:
            out.append("Runs the fit hinges on: " + ", ".join(
                f"{r} (Cook {f_text(num(self.cooks[i]))}, leverage {self.leverage[i]:.2f})"
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
                "statistics": {k: {"before": b if isinstance(b, str) else num(b),
                                   "after": a if isinstance(a, str) else num(a)}
                               for k, b, a in self.statistics},
                "parameters": {n: {"unit": u, "before": num(vb), "std_before": num(sb),
                                   "after": num(va), "std_after": num(sa)}
                               for n, u, vb, sb, va, sa in self.parameters},
                "before": self.before.to_dict(), "after": self.after.to_dict()}

    def summary(self):
        out = [f"Adding {', '.join(self.added) or 'nothing'}: before -> after"]
        for k, b, a in self.statistics:
            out.append(f"  {k:<22}{cell(b):>14}{cell(a):>14}")
        out.append(f"  {'parameter':<22}{'before':>24}{'after':>24}")
        for n, u, vb, sb, va, sa in self.parameters:
            out.append(f"  {n:<22}{pm(vb, sb):>24}{pm(va, sa):>24}  {u}")
        return out



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
