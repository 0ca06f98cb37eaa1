"""Structure in words: a sparse (forward-stepwise) regression of the residuals over the library
of factor functions, each selected term as a sentence a user can act on, with the catalogue
effects whose signature it matches."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from .. import units
from ._format import num
from .statistics import Test, f_logsf

#: at most this many terms in the sparse regression
_MAX_TERMS = 6
#: a structure term is "explained by" a candidate when this fraction of it lies in the
#: candidate's signature
_EXPLAINED = 0.7


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
        Its p-value in the joint fit on the verdict's noise model, Bonferroni-corrected over the
        functions searched.
    explained_by : tuple of str
        Catalogue candidates whose signature holds most of this term.
    text : str
        The term in words.
    significant : bool
        ``p_value`` below the verdict's family-wise level (else the words say so).
    """

    function: str
    factor: str
    coefficient: float
    std: float
    unit: str
    p_value: float
    explained_by: tuple
    text: str
    significant: bool = True
    #: the fall of the weighted residual sum of squares when it entered
    score: float = 0.0

    def to_dict(self):
        return {"function": self.function, "factor": self.factor, "coefficient_arcsec": self.coefficient,
                "std_arcsec": self.std, "unit": self.unit, "p_value": num(self.p_value),
                "explained_by": list(self.explained_by), "text": self.text,
                "significant": self.significant}



class _Family:
    """Many one-column functions of run order scored at once: level shifts (a step from run k
    on, k = 2..n) or single runs (an outlier). The score of column ``z`` against the residual
    ``r`` (orthogonal to the model and the chosen terms, whose orthonormal basis is ``W``) is
    ``(z'r)^2 / (|z|^2 - |W'z|^2)``; for steps ``z'x`` is a suffix sum of ``x``, for single runs
    the run's own row: O(n k) for every column together."""

    def __init__(self, kind, run, sigma):
        self.kind, self.run, self.w = kind, np.asarray(run), 1.0 / np.asarray(sigma, float)
        self.size = self.w.size - 1 if kind == "step" else self.w.size

    def _zt(self, X):  # z_k' X for every column k (rows), X (n, m) already weighted
        X = X * self.w[:, None]
        if self.kind == "step":
            return np.cumsum(X[::-1], axis=0)[::-1][1:]
        return X

    def scores(self, r, W):
        num = self._zt(r[:, None])[:, 0] ** 2
        norm2 = self._zt(self.w[:, None])[:, 0] if self.kind == "step" else self.w ** 2
        norm2 = norm2 - np.sum(self._zt(W) ** 2, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            sc = np.where(norm2 > _TOL_FAMILY * (self.w ** 2).max(), num / norm2, 0.0)
        if self.kind == "step":  # two runs at least on each side (else it is a single run)
            sc[[0, -1]] = 0.0
        return sc

    def term(self, k):
        """The library entry of column ``k``: (factor, name, values, unit, text)."""
        n = self.w.size
        if self.kind == "step":
            at = self.run[k + 1]
            fv = (np.arange(n) >= k + 1).astype(float)
            return ("level shift", f"step at run {at}", fv, "1",
                    f"level shift of {{c}} arcsec from run {at} on (a re-mount, a shock, a new "
                    f"reference?): not a catalogue effect; add a column such as shift = 0 before run "
                    f"{at} and 1 from it, and the effect covariate:shift")
        at = self.run[k]
        fv = (np.arange(n) == k).astype(float)
        return ("outlier", f"run {at}", fv, "1",
                f"run {at} lies {{c}} arcsec off the model (an outlier: check the run, or fit with "
                f"--robust)")


#: a step or single-run column whose part orthogonal to the model is this small is in its span
_TOL_FAMILY = 1e-9


def sparse_structure(null, library, bases, alpha, level=None, run=None):
    """Forward-stepwise selection over the function library (and the level shifts and single
    runs of run order): at each step the function with the largest score statistic enters
    when it rejects at ``alpha`` Bonferroni-corrected over the functions left; then every
    selected term is refitted jointly with the model. A term is significant when its joint
    p-value, on the verdict's noise model (the fit's sigmas when they are known or from pure
    error) and Bonferroni-corrected over the functions searched, is below the verdict's
    family-wise level ``level``."""
    level = alpha if level is None else level
    families = [] if run is None or null.n_eff < 4 else [_Family("step", run, null.sigma),
                                                      _Family("single", run, null.sigma)]
    n_searched = len(library) + sum(f.size for f in families)
    chosen, B = [], np.zeros((null.n, 0))
    r, rss = null.r.copy(), null.rss
    remaining = [t for t in library if t[5].shape[1]]
    W = null.Q
    while (remaining or families) and len(chosen) < _MAX_TERMS:
        scored = []
        for t in remaining:
            u = null.basis(t[2] / null.sigma, extra=B)
            if u.shape[1]:
                scored.append((float(np.sum((u.T @ r) ** 2)), t, u))
        n_left = len(scored)
        for fam in families:
            sc = fam.scores(r, W)
            n_left += int(np.sum(sc > 0))
            k = int(np.argmax(sc))
            if sc[k] > 0:
                t = fam.term(k)
                u = null.basis(t[2] / null.sigma, extra=B)
                if u.shape[1]:
                    scored.append((float(np.sum((u.T @ r) ** 2)), (*t, u), u))
        if not scored:
            break
        s, t, u = max(scored, key=lambda x: x[0])
        _, _, p, _ = null.score(u, r=r, rss=rss, k_extra=B.shape[1])
        if p is None or p * n_left >= alpha:
            break
        chosen.append((t, s))
        B = np.column_stack([B, u])
        W = np.column_stack([W, u])
        r = r - u @ (u.T @ r)
        rss = float(r @ r)
        remaining = [x for x in remaining if x is not t]
    if not chosen:
        return []
    # joint weighted LS of the residual on model + chosen functions (coefficients, sigmas) on
    # the verdict's noise model: sigma known (the weighted residuals have unit variance) unless
    # it is estimated from the residuals
    T = np.column_stack([t[2] for t, _ in chosen]) / null.sigma[:, None]
    M = np.column_stack([null.A, T])
    coef, *_ = np.linalg.lstsq(M, null.r, rcond=None)
    res = null.r - M @ coef
    dof = null.n_eff - M.shape[1]
    fixed = null.scale.kind == "fixed"
    s2 = 1.0 if fixed else (float(res @ res) / dof if dof > 0 else np.nan)
    cov = np.linalg.pinv(M.T @ M) * s2
    k0 = null.A.shape[1]
    terms = []
    for j, ((factor, name, fv, unit, text, u), score) in enumerate(chosen):
        c = coef[k0 + j] / units.ARCSEC  # sigma-weighted residuals: rad per unit
        sd = math.sqrt(max(cov[k0 + j, k0 + j], 0.0)) / units.ARCSEC
        z = abs(c) / sd if sd > 0 else np.inf
        p_joint = 2 * (stats.norm.sf(z) if fixed or dof < 1 else stats.t.sf(z, dof))
        p_fw = min(1.0, float(p_joint) * n_searched)
        significant = p_fw < level
        explained = []
        for eff, U in bases.items():
            frac = float(np.sum((U.T @ u[:, 0]) ** 2))
            if frac >= _EXPLAINED:
                explained.append((frac, eff))
        explained = tuple(e for _, e in sorted(explained, reverse=True))
        words = text.format(c=f"{c:.3g} +- {sd:.2g}")
        if factor not in ("level shift", "outlier"):
            words += (f"; matches {', '.join(explained)}" if explained
                      else "; no catalogue effect has this signature (a covariate or an effect of your own?)")
        if not significant:
            words += f" (not significant at the family-wise level: p = {p_fw:.2g})"
        terms.append(Term(name, factor, float(c), float(sd), unit, p_fw, explained, words, significant,
                          float(score)))
    return terms


def run_order_tests(null, run):
    """Two max-type tests over run order: a level shift (a step from some run on) and a single
    run off the model (the externally studentised residual's test), each the best column's F
    test Bonferroni-corrected over the columns."""
    out = []
    if null.n_eff < 4:
        return out
    for kind, name, what in (("step", "level shift", "a step in the heading error from one run on"),
                             ("single", "single run", "one run off the model (outlier)")):
        fam = _Family(kind, run, null.sigma)
        sc = fam.scores(null.r, null.Q)
        k = int(np.argmax(sc))
        dof = null.n_eff - null.k - 1
        if sc[k] <= 0 or dof < 1:
            out.append(Test(name, what, None, (1, dof), None, None, "", "too few runs for the test"))
            continue
        s_k = min(float(sc[k]), null.rss)
        F = s_k / ((null.rss - s_k) / dof) if null.rss > s_k else np.inf
        m = int(np.sum(sc > 0))
        raw = float(stats.f.sf(F, 1, dof))
        p = min(1.0, m * raw)
        logp = min(0.0, math.log(m) + f_logsf(F, 1, dof))
        out.append(Test(name, f"{what}: the best of {m} positions in run order", F, (1, dof), p, logp,
                        fam.term(k)[1], adjusted_over=m, adjusted_what="positions in run order",
                        raw_p=raw))
    return out
