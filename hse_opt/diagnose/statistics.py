"""The fit as a weighted linear model, and the tests made at it.

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
replicate group. Influence (leverage, Cook's distance, externally studentised residuals) is
that of the same weighted linear model. Rows that are copies of one measurement
(:meth:`hse_opt.data.Runs.copies`) share its weight in the fit; ``n`` in the degrees of freedom
counts the measurements, not the rows, and each copy carries its measurement's influence.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from ..fit import replicate_groups
from ..fit.weights import multiplicity
from ..information import MAX_CONDITION, weighted_jacobian
from ..units import ARCSEC
from ._format import num

#: default family-wise significance level of the verdict
ALPHA = 0.05
#: a projected direction (unit columns) shorter than this is in the span of the model
_TOL = 1.0 / MAX_CONDITION


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
    adjusted_over : int
        0 when ``p_value`` is the statistic's own p-value; else the number ``m`` of tests it is
        Bonferroni-adjusted over (a max-type test: ``p_value = min(1, m * raw p)``).
    adjusted_what : str
        What those ``m`` tests are (``positions in run order``).
    raw_p : float or None
        The best column's own p-value before the adjustment (None when not adjusted).
    """

    name: str
    description: str
    statistic: float | None
    dof: tuple
    p_value: float | None
    log_p: float | None = None
    best: str = ""
    note: str = ""
    adjusted_over: int = 0
    adjusted_what: str = ""
    raw_p: float | None = None

    @property
    def tested(self):
        return self.p_value is not None

    @property
    def adjustment(self):
        """`` (adjusted for 21 positions in run order)`` when ``p_value`` is adjusted, else ""."""
        return f" (adjusted for {self.adjusted_over} {self.adjusted_what})" if self.adjusted_over else ""

    def to_dict(self):
        out = {"name": self.name, "description": self.description,
               "statistic": num(self.statistic), "dof": list(self.dof),
               "p_value": num(self.p_value), "best": self.best, "note": self.note}
        if self.adjusted_over:
            out["p_adjustment"] = {"method": "bonferroni", "tests": int(self.adjusted_over),
                                   "over": self.adjusted_what, "raw_p_value": num(self.raw_p)}
        return out



class Null:
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
        # a position without a heading reference has its own unknown constant (the fit
        # eliminates it): it is part of the model's span, so every test below is a test of
        # the differences within such positions
        group, self.positions = runs.reference_groups()
        self.level_runs = runs
        if self.positions and runs.pitch is not None:
            # one placement, one tilt: the leveling's run-to-run noise is no signature
            pitch, roll = np.array(runs.pitch), np.array(runs.roll)
            for k in range(len(self.positions)):
                pitch[group == k], roll[group == k] = pitch[group == k].mean(), roll[group == k].mean()
            self.level_runs = runs.replace(pitch=pitch, roll=roll)
        self.G = (group[:, None] == np.arange(len(self.positions))[None, :]) / self.sigma[:, None]
        M = np.column_stack([self.A, self.G])
        d = np.linalg.norm(M, axis=0)
        self.Q, _ = np.linalg.qr(M / np.where(d > 0, d, 1.0))
        self.n = self.r.size
        self.rss = float(self.r @ self.r)
        # copies of one measurement (Runs.copies: rows written twice) share its weight in the
        # fit (hse_opt.fit.run_sigma), so the weighted sums of squares are those of one row per
        # measurement and the degrees of freedom count the measurements (an F test of a
        # function that fits them exactly is then not F = inf but not possible)
        labels, m = runs.copies()
        self.copies = labels if m < self.n else None
        self.n_eff = m
        # profiled parameters count as fitted (FitResult.dof already holds that)
        self.k = self.n_eff - int(f.dof)
        self.scale = LikelihoodScale.of(f)

    def within_share(self, Z):
        """Per column of Z (n, q; weighted): the share of its norm left after removing each
        unsurveyed position's mean -- 1 without such positions, 0 for a column constant
        within every position (a constant per position is not a missing effect). Signatures
        to test this way come from :attr:`level_runs` (each position's pitch and roll at their
        means: the same placement)."""
        Z = np.asarray(Z, float)
        if not self.positions:
            return np.ones(Z.shape[1])
        Gq, _ = np.linalg.qr(self.G)
        W = Z - Gq @ (Gq.T @ Z)
        d = np.linalg.norm(Z, axis=0)
        return np.linalg.norm(W, axis=0) / np.where(d > 0, d, 1.0)

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
        dof = self.n_eff - self.k - k_extra - q
        if q < 1 or dof < 1:
            return None, (q, dof), None, None
        s = float(np.sum((U.T @ r) ** 2))
        s = min(max(s, 0.0), rss)
        F = (s / q) / ((rss - s) / dof) if rss > s else np.inf
        return F, (q, dof), float(stats.f.sf(F, q, dof)), f_logsf(F, q, dof)

    def influence(self):
        """Leverage, Cook's distance and externally studentised residuals per run. Copies of
        one measurement are one run of their summed weight: their setting's leverage (the sum
        of theirs), residual and statistics, given to each copy."""
        h = np.clip(np.sum(self.Q ** 2, axis=1), 0.0, 1.0)
        n, k = self.n, self.Q.shape[1]
        e = self.r
        if self.copies is not None:
            lab, n = self.copies, self.n_eff
            c = np.bincount(lab, minlength=n)
            h = np.clip(np.bincount(lab, h, n), 0.0, 1.0)[lab]
            e = e * np.sqrt(c[lab])                 # the setting's weighted residual
        s2 = self.rss / (n - k) if n > k else np.nan
        with np.errstate(divide="ignore", invalid="ignore"):
            one_h = 1.0 - h
            cooks = e ** 2 * h / (k * s2 * one_h ** 2)
            s2_i = ((n - k) * s2 - e ** 2 / one_h) / (n - k - 1) if n - k - 1 > 0 else np.full(e.size, np.nan)
            stud = e / np.sqrt(s2_i * one_h)
        bad = one_h < 1e-9
        cooks[bad], stud[bad] = np.nan, np.nan
        return h, cooks, stud


def f_logsf(F, q, dof):
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



def flag_runs(run, lev, cooks, stud, k, alpha, n=None):
    """Outliers (externally studentised residual rejecting at ``alpha``, Bonferroni over the
    ``n`` independent runs, default every run) and the runs the fit hinges on (Cook's distance
    above the median of F(k, n - k), or leverage above 0.5), as run ids, most extreme first."""
    n = run.size if n is None else n
    with np.errstate(invalid="ignore"):
        p = n * 2.0 * stats.t.sf(np.abs(stud), n - k - 1) if n - k - 1 > 0 else np.full(run.size, np.nan)
    cut = stats.f.ppf(0.5, k, n - k) if n > k else np.inf
    cooks = np.nan_to_num(cooks, nan=np.inf)  # leverage 1: the fit rests on the run entirely
    outliers = tuple(int(run[i]) for i in np.argsort(-np.nan_to_num(np.abs(stud)), kind="stable")
                     if p[i] < alpha)
    influential = tuple(int(run[i]) for i in np.argsort(-cooks, kind="stable")
                         if cooks[i] > cut or lev[i] > 0.5)
    return outliers, influential



def lack_of_fit(null, runs):
    """Pure-error lack-of-fit F test: the model against one mean per replicate group, by the
    fit's own rule (:func:`hse_opt.fit.weights.lack_of_fit_test`: the pure error is the scatter
    within the groups, ``measurements - groups`` degrees of freedom, whatever the model's
    columns do within a group -- measured tilts and rates vary a little)."""
    from ..fit.weights import lack_of_fit_test
    labels, g = replicate_groups(runs, null.f.measurement)
    if g == null.n:
        return None
    test = lack_of_fit_test(null.f.residuals, null.sigma, labels, g, null.n_eff, null.k)
    dof = (g - null.k, null.n_eff - g)
    if test is None and (null.n_eff < null.n or dof[0] >= 1):    # copies, or no scatter within groups
        return Test("lack of fit", f"{g} replicate groups", None, dof, None, None, "",
                    "the replicates are identical (copies: zero pure error): no lack-of-fit test; "
                    "check that the repeated runs were really measured again")
    if test is None:
        return Test("lack of fit", f"{g} replicate groups", None, dof, None, None, "",
                    "not enough replicate groups beyond the model's parameters")
    dof = test.dof
    return Test("lack of fit", f"model against {g} replicate-group means (pure error from "
                f"{dof[1]} degrees of freedom)", test.statistic, dof, test.p_value,
                f_logsf(test.statistic, *dof))


@dataclass(frozen=True)
class LikelihoodScale:
    """The one likelihood on which every candidate's refit is compared with the base model: the
    base model's noise model.

    ``fixed``: the base fit's sigmas (the runs' own ``heading_std``, or the pure-error sigma of
    the base model's replicate groups) are held for every refit -- a candidate that changes the
    replicate grouping (a warm-up, a covariate) cannot change the scale; ``-2 log L = chi2``.
    ``profiled``: no sigma is known (residual weighting): one common unknown sigma, profiled per
    model; ``-2 log L = n ln(RSS / n)``. ``BIC = -2 log L + k ln n``, ``k = n - dof``.
    """

    kind: str
    sigma: np.ndarray
    weighting: str

    @classmethod
    def of(cls, f):
        kind = "profiled" if f.weighting == "residual" else "fixed"
        return cls(kind, np.asarray(f.sigma, float), f.weighting)

    def refit_runs(self, runs):
        """The runs as a candidate is refitted: with the base sigmas as their own when fixed
        (each copy's share of its measurement's weight taken out again: the refit shares it)."""
        if self.kind != "fixed":
            return runs
        return runs.replace(heading_std=self.sigma / np.sqrt(multiplicity(runs)[0]))

    def bic(self, residuals, dof):
        r = np.asarray(residuals, float)
        n = r.size
        ll = float(np.sum((r / self.sigma) ** 2)) if self.kind == "fixed" else n * math.log(np.sum(r ** 2) / n)
        return ll + (n - dof) * math.log(n)

    def chi2_red(self, residuals, dof):
        r = np.asarray(residuals, float)
        return float(np.sum((r / self.sigma) ** 2)) / dof if self.kind == "fixed" else 1.0

    @property
    def text(self):
        if self.kind == "profiled":
            return ("one unknown sigma profiled per model (no heading_std_arcsec, no replicates): "
                    "Delta-BIC = n ln(RSS_after / RSS_before) + Delta k ln n")
        what = ("the runs' own sigmas (heading_std_arcsec)" if self.weighting == "heading_std" else
                f"the base model's {self.weighting} sigma {float(np.median(self.sigma)) / ARCSEC:.3g} arcsec, "
                "held for every refit")
        return f"{what}: Delta-BIC = Delta chi2 + Delta k ln n"
