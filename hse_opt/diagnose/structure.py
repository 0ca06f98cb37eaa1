"""Structure in words: a sparse (forward-stepwise) regression of the residuals over the library
of factor functions, each selected term as a sentence a user can act on, with the catalogue
effects whose signature it matches."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import units
from ._format import num

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
                "std_arcsec": self.std, "unit": self.unit, "p_value": num(self.p_value),
                "explained_by": list(self.explained_by), "text": self.text}



def sparse_structure(null, library, bases, alpha):
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
