"""The IEEE Std 952-1997 Annex C fit of an Allan curve (:mod:`hse_opt.align.noise`'s
module docstring, step 4): the Allan variance model ``sigma^2(tau) = sum_k A_k tau^k``, k =
-2..1, every ``A_k >= 0``, fitted by least squares weighted by each estimate's own variance
(iterated with the fitted model in the weights), refitted with the model's own error where it
misses its points by far more than their scatter.

The non-negative least squares is solved exactly: the best feasible solution of the 15 sets
of active terms, all rows (channels; the fit and its refit) in one batched solve; from the
second pass each row first tries the previous pass's set and keeps it where it is optimal (the
Karush-Kuhn-Tucker conditions, which one set only meets, the normal matrix being positive
definite), so the 15 sets are solved only for the rows whose set changed.

Units: those of the Allan deviation given (SI in the project: rad/s, m/s^2); ``tau`` s.
"""
from __future__ import annotations

import itertools

import numpy as np

from hse_opt.align.processor import _vecdot

__all__ = ["fit_allan", "MODEL_ERROR", "MISFIT"]

#: relative 1-sigma of the four-term model itself, added in quadrature to each Allan
#: variance's own in the fit's weights (:mod:`hse_opt.align.noise`, step 4)
MODEL_ERROR = 0.1
#: a fit whose weighted residuals exceed this many times their degrees of freedom is refitted
#: with :data:`MODEL_ERROR` in its weights
MISFIT = 10.0
#: the powers of tau of the model's four terms
_POWERS = np.arange(-2, 2)
#: every non-empty set of active terms, (15, 4) bool
_SUBSETS = np.array([s for s in itertools.product((False, True), repeat=4) if any(s)])
#: the entries of each set's normal matrix, (15, 4, 4) bool, and the identity that fills the rest
_SUBSETS_BOTH = _SUBSETS[:, :, None] & _SUBSETS[:, None, :]
_EYE4 = np.eye(4)
_DIAG4 = np.arange(4)
#: the ridge added to the fit's scaled normal matrix
_RIDGE = 1e-13 * _EYE4
for _a in (_POWERS, _SUBSETS, _SUBSETS_BOTH, _EYE4, _DIAG4, _RIDGE):
    _a.flags.writeable = False


def fit_allan(tau, adev, clusters, *, iterations=3):
    """The IEEE 952 Annex C fit (the module docstring).

    Parameters
    ----------
    tau : array_like, shape (k,)
        s.
    adev : array_like, shape (c, k)
        Allan deviation per channel.
    clusters : array_like, shape (k,)
        Independent clusters behind each point.

    Returns
    -------
    coefficients, coefficients_std : numpy.ndarray, shape (c, 4)
        ``A_k``, k = -2..1, >= 0, and their 1-sigma (NaN where held at zero).
    """
    tau = np.asarray(tau, dtype=float)
    avar = np.atleast_2d(np.asarray(adev, dtype=float)) ** 2
    c = avar.shape[0]
    rel = np.sqrt(2.0 / np.maximum(np.asarray(clusters, dtype=float) - 1.0, 1.0))
    # the fit and its refit with the model's own error (taken where the fit misses its points
    # by far more than their scatter) in one batched pass: rows c.. are the refit's
    rels = np.empty((2, c, tau.size))
    rels[0] = rel
    rels[1] = np.sqrt(rel ** 2 + MODEL_ERROR ** 2)
    coef, std, chi2 = _weighted_fit(tau, np.concatenate([avar, avar]), rels.reshape(2 * c, -1), iterations)
    pick = np.where(chi2[:c] > MISFIT, np.arange(c, 2 * c), np.arange(c))
    return coef[pick], std[pick]


def _weighted_fit(tau, avar, rel, iterations):
    """The non-negative weighted least squares of :func:`fit_allan` with relative 1-sigma
    ``rel`` (c, k) of each variance; returns ``(coef, std, chi2)``, ``chi2`` (c,) the weighted
    residual sum of squares per degree of freedom.

    Each pass forms the weighted normal equations of all rows in one product (the variances
    as a fifth column: ``[A b]' [A b]``), the columns scaled to unit norm. The non-negative
    solution is the best feasible one of the 15 sets of active terms; after the first pass
    the previous pass's set is tried alone and kept where it is optimal (its terms >= 0 and
    no held term would lower the residuals: the Karush-Kuhn-Tucker conditions, met by one
    set only, the normal matrix being positive definite), all 15 solved where it is not."""
    T = tau[:, None] ** _POWERS[None, :]                     # (k, 4)
    c, k = avar.shape
    Tb = np.empty((c, k, 5))
    Tb[:, :, :4] = T
    Tb[:, :, 4] = avar
    model, best = avar, None
    for _ in range(iterations):
        s = np.maximum(model, 1e-300)
        s *= rel                                              # (c, k) 1-sigma of each variance
        Ab = Tb / s[:, :, None]
        Gb = np.matmul(Ab.transpose(0, 2, 1), Ab)             # (c, 5, 5)
        scale = np.sqrt(Gb[:, _DIAG4, _DIAG4])
        scale[scale == 0] = 1.0
        G = Gb[:, :4, :4] / (scale[:, :, None] * scale[:, None, :])
        G += _RIDGE
        h = Gb[:, :4, 4] / scale
        best, x = _nonnegative(G, h, best)
        coef = x / scale
        model = coef @ T.T
    cov = np.linalg.inv(np.where(_SUBSETS_BOTH[best], G, _EYE4))
    std = np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0.0)) / scale
    std[~(_SUBSETS[best] & np.isfinite(x).all(axis=1, keepdims=True))] = np.nan
    w = np.maximum(model, 1e-300)
    w *= rel
    chi2 = _vecdot(avar - model, (avar - model) / w ** 2, None) / max(tau.size - 4, 1)
    return coef, std, chi2


def _nonnegative(G, h, prev=None):
    """``min x' G x - 2 h' x`` over ``x >= 0`` per row (G (c, 4, 4) positive definite, h (c,
    4)): ``(best, x)``, ``best`` the index of the set of active terms in :data:`_SUBSETS`, x
    zero outside it (all zero where no set is feasible: NaN input). ``prev``: each row's set
    to try first, kept where the KKT conditions hold; the other rows try all 15."""
    if prev is None:
        return _best_set(G, h)
    S = _SUBSETS[prev]
    x = np.linalg.solve(np.where(_SUBSETS_BOTH[prev], G, _EYE4), np.where(S, h, 0.0)[..., None])[..., 0]
    # KKT: the active terms >= 0, no held term's gain h - G x above 0
    kkt = np.where(S, x, np.matmul(G, x[..., None])[..., 0] - h)
    ok = kkt.min(axis=1) >= 0.0
    if not ok.all():
        redo = ~ok
        prev = prev.copy()
        prev[redo], x[redo] = _best_set(G[redo], h[redo])
    return prev, x


def _best_set(G, h):
    """:func:`_nonnegative` by trying every set of active terms: the best feasible one."""
    Gm = np.where(_SUBSETS_BOTH[None], G[:, None], _EYE4)    # (c, 15, 4, 4)
    hm = np.where(_SUBSETS[None], h[:, None], 0.0)           # (c, 15, 4)
    x = np.linalg.solve(Gm, hm[..., None])[..., 0]
    # the weighted residual sum of squares less b'b: -h_S' G_SS^-1 h_S at each set's solution
    cost = -_vecdot(x, hm, None)
    cost[~(x.min(axis=2) >= 0.0)] = np.inf                  # (NaN too)
    best = cost.argmin(axis=1)
    rows = np.arange(G.shape[0])
    xs = x[rows, best]
    xs[~np.isfinite(cost[rows, best])] = 0.0
    return best, xs
