"""The IEEE Std 952-1997 Annex C fit of an Allan curve (:mod:`hse_opt.align.noise`'s
module docstring, step 4): the Allan variance model ``sigma^2(tau) = sum_k A_k tau^k``, k =
-2..1, every ``A_k >= 0``, fitted by least squares weighted by each estimate's own variance
(iterated with the fitted model in the weights), refitted with the model's own error where it
misses its points by far more than their scatter.

The non-negative least squares is solved exactly, all fits (channels; the fit and its refit)
at once, by the Schur complements of the bordered normal matrix ``[G h]`` on every set of
terms: eliminating the terms of a set ``T`` one by one (Gaussian elimination in the terms'
order, the normal matrix being positive definite) leaves, for each term ``i`` outside it,

- ``g_T(i) = (h - G x_T)_i``, the gain that term ``i`` would bring to the solution ``x_T``
  on ``T`` alone, and
- ``d_T(i) > 0``, the Schur complement of ``G_TT`` at ``(i, i)``.

Adding ``i`` to ``T`` gives ``x_i = g_T(i) / d_T(i)`` (block elimination), and ``1 / d_T(i)``
is the ``(i, i)`` entry of the inverse normal matrix on ``T + i``: the covariance of the
chosen set's terms. A set ``S`` is the non-negative solution when it meets the
Karush-Kuhn-Tucker conditions, ``g_{S-i}(i) >= 0`` for its terms (``x_i >= 0``) and ``g_S(j)
<= 0`` for the others (no held term would lower the residuals); one set meets them, the
normal matrix being positive definite. All 16 sets (the empty one too) are checked from one
table of Schur complement entries per fit, built in three vectorised steps (the sets of one,
two and three terms): a few dozen numpy operations a pass, whatever the sets.

Units: those of the Allan deviation given (SI in the project: rad/s, m/s^2); ``tau`` s.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

__all__ = ["fit_allan", "MODEL_ERROR", "MISFIT"]

#: relative 1-sigma of the four-term model itself, added in quadrature to each Allan
#: variance's own in the fit's weights (:mod:`hse_opt.align.noise`, step 4)
MODEL_ERROR = 0.1
#: a fit whose weighted residuals exceed this many times their degrees of freedom is refitted
#: with :data:`MODEL_ERROR` in its weights
MISFIT = 10.0
#: the powers of tau of the model's four terms
_POWERS = np.arange(-2, 2)
#: the ridge added to the diagonal of the fit's normal matrix scaled to a unit diagonal
_RIDGE = 1e-13
#: every set of active terms, (16, 4) bool: set ``s`` holds term ``i`` where bit ``i`` of ``s``
#: is set (set 0 is empty, set 15 holds all four)
_SETS = (np.arange(16)[:, None] >> np.arange(4)) & 1 == 1
_DIAGONAL = np.arange(4)
#: Allan deviations whose largest lies outside are scaled by a power of two towards 1
_RANGE = (1e-30, 1e30)


def _schur_tables():
    """The layout of :func:`_nonnegative`'s table (the module docstring) and its index tables.

    The table holds one fit per column. Rows 0-23: ``[G h -h]`` (``(i, j)`` at ``6 i + j``;
    ``j = 4``: ``h``, ``j = 5``: ``-h``); then for each set ``T`` of one, two and three terms
    the Schur complement entries ``(i, j)``, ``i <= j``, ``(i, h)`` and ``(i, -h)`` for ``i,
    j`` outside ``T``; then three constants: 0, 1 and NaN.

    Returns
    -------
    steps : tuple of (numpy.ndarray, slice)
        For the sets of one, two and three terms: the rows ``(4, m)`` of each new entry's
        parent entries ``(i, j)``, ``(i, l)``, ``(l, j)`` and ``(l, l)`` on ``T - l`` (``l``
        the last term of ``T``), and the ``m`` rows the new entries go to.
    width : int
        Rows of the table.
    kkt : numpy.ndarray, shape (4, 16)
        Per term and set ``S``: the row of ``g_{S-i}(i)`` (a term of ``S``) or of
        ``-g_S(i)``; ``S`` is the solution where all four are ``>= 0``.
    solve : numpy.ndarray, shape (16, 8)
        Per set: the rows of ``x``'s numerators ``g_{S-i}(i)`` and denominators
        ``d_{S-i}(i)`` (0 and 1 for a term outside the set).
    variance : numpy.ndarray, shape (16, 4)
        Per set: the rows of ``d_{S-i}(i)`` (NaN outside the set).
    """
    row = {}

    def at(t, i, j):                                  # (i, j) of set t's complement, j = 4, 5: +-h
        return row[t, min(i, j), max(i, j)] if j < 4 else row[t, i, j]

    for i in range(4):
        for j in range(6):
            row[0, i, j] = 6 * i + j
    width, steps = 24, []
    for size in (1, 2, 3):
        parents = []
        for t in range(16):
            if bin(t).count("1") != size:
                continue
            last = t.bit_length() - 1
            p = t & ~(1 << last)
            rest = [i for i in range(4) if not t >> i & 1]
            for i in rest:
                for j in [j for j in rest if j >= i] + [4, 5]:
                    parents.append((at(p, i, j), at(p, i, last), at(p, last, j), at(p, last, last)))
                    row[t, i, j] = width + len(parents) - 1
        steps.append((np.array(parents).T.copy(), slice(width, width + len(parents))))
        width += len(parents)
    zero, one, nan = width, width + 1, width + 2
    kkt = np.empty((4, 16), dtype=np.intp)
    solve, variance = np.empty((16, 2, 4), dtype=np.intp), np.empty((16, 4), dtype=np.intp)
    for s in range(16):
        for i in range(4):
            if s >> i & 1:
                t = s & ~(1 << i)
                kkt[i, s] = at(t, i, 4)
                solve[s, :, i] = at(t, i, 4), at(t, i, i)
                variance[s, i] = at(t, i, i)
            else:
                kkt[i, s] = at(s, i, 5)
                solve[s, :, i] = zero, one
                variance[s, i] = nan
    return tuple(steps), width + 3, kkt, solve.reshape(16, 8), variance


_STEPS, _WIDTH, _KKT, _SOLVE, _VARIANCE = _schur_tables()
for _a in (_POWERS, _SETS, _KKT, _SOLVE, _VARIANCE, *(s[0] for s in _STEPS)):
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
        ``A_k``, k = -2..1, >= 0, and their 1-sigma (NaN where held at zero). A channel
        with NaN in its Allan deviation gets NaN terms; one of zeros, or with an infinite
        point, zero terms without 1-sigma. Any unit: the deviations are scaled by a power of
        two when their largest lies outside :data:`_RANGE` (a channel more than 1e30 below
        the largest may then get zero terms).
    """
    adev = np.atleast_2d(np.asarray(adev, dtype=float))
    c, k = adev.shape
    design = _design(np.asarray(tau, dtype=float).tobytes(), np.asarray(clusters, dtype=float).tobytes(), c)
    # the deviations scaled by a power of two where the largest is far from 1 (exactly: the
    # fit scales with them), so that the normal equations' products stay within range
    top = float(adev.max())
    scale = 0
    if not _RANGE[0] < top < _RANGE[1] and 0.0 < top < math.inf:
        scale = math.frexp(top)[1]
        adev = adev * math.ldexp(1.0, -scale)
    # the fit and its refit with the model's own error (taken where the fit misses its points
    # by far more than their scatter) side by side: columns c.. are the refit's
    avar = np.empty((k, 2 * c))
    np.square(adev.T, out=avar[:, :c])
    avar[:, c:] = avar[:, :c]
    coef, std, chi2 = _weighted_fit(design, avar, iterations)
    refit = (chi2[:c] > MISFIT * max(k - 4, 1))[:, None]
    coef = np.where(refit, coef[c:], coef[:c])
    std = np.where(refit, std[c:], std[:c])
    if scale:
        for a in (coef, std, coef, std):
            a *= math.ldexp(1.0, scale)
    if top != top:
        # NaN in a channel's Allan deviation: NaN terms (a channel of zeros or with an infinite
        # point has no solution but 0, with no 1-sigma)
        lost = np.isnan(adev).any(axis=1)
        coef[lost] = np.nan
        std[lost] = np.nan
    return coef, std


@dataclass(frozen=True)
class _Design:
    """What the fits of ``c`` channels on one set of cluster times need besides their Allan
    variances (:func:`_design`); read-only arrays.

    Attributes
    ----------
    T : numpy.ndarray, shape (k, 4)
        ``tau^k``, k = -2..1.
    basis : numpy.ndarray, shape (24, 2 k)
        ``[G h -h]`` ((4, 6) flat) ``= basis @ [w; w avar]`` for weights ``w`` (k, fits):
        each point's ``T_i T_j`` (the diagonal's times ``1 +`` :data:`_RIDGE`), ``T_i`` and
        ``-T_i``.
    inv_rel2 : numpy.ndarray, shape (k, 2 c)
        ``1 / rel^2``, ``rel = sqrt(2 / (K - 1))`` each variance's relative 1-sigma (``K``
        its independent clusters); columns c.. the refit's, :data:`MODEL_ERROR` added in
        quadrature.
    """

    T: np.ndarray
    basis: np.ndarray
    inv_rel2: np.ndarray


@functools.lru_cache(maxsize=64)
def _design(tau, clusters, c):
    """The :class:`_Design` of ``c`` channels on cluster times ``tau`` (s) with ``clusters``
    independent clusters (both float64 bytes): the same for every log of one length."""
    tau, clusters = np.frombuffer(tau), np.frombuffer(clusters)
    k = tau.size
    T = tau[:, None] ** _POWERS[None, :]
    basis = np.zeros((4, 6, 2 * k))
    basis[:, :4, :k] = T.T[:, None, :] * T.T[None, :, :]
    basis[_DIAGONAL, _DIAGONAL, :k] *= 1.0 + _RIDGE
    basis[:, 4, k:] = T.T
    basis[:, 5, k:] = -T.T
    half_dof = 0.5 * np.maximum(clusters - 1.0, 1.0)
    inv_rel2 = np.empty((k, 2 * c))
    inv_rel2[:, :c] = half_dof[:, None]
    inv_rel2[:, c:] = (1.0 / (1.0 / half_dof + MODEL_ERROR ** 2))[:, None]
    design = _Design(T=T, basis=basis.reshape(24, 2 * k), inv_rel2=inv_rel2)
    for a in (design.T, design.basis, design.inv_rel2):
        a.flags.writeable = False
    return design


def _weighted_fit(design, avar, iterations):
    """The non-negative weighted least squares of :func:`fit_allan`, a fit per column.

    Parameters
    ----------
    design : _Design
    avar : numpy.ndarray, shape (k, c)
        Allan variances, a column per fit (``c`` twice the design's: the fit and its refit).
    iterations : int
        Passes, each weighted by the previous pass's model (the first by ``avar``).

    Returns
    -------
    coef, std : numpy.ndarray, shape (c, 4)
        The terms and their 1-sigma (NaN outside the solution's set).
    chi2 : numpy.ndarray, shape (c,)
        The weighted residual sum of squares.

    Each pass forms the weighted normal equations ``[G h -h]`` of all fits in one product
    (:attr:`_Design.basis`, the weights ``w = 1 / (model rel)^2`` and ``w avar``), which
    :func:`_nonnegative` solves."""
    k, c = avar.shape
    T, inv_rel2 = design.T, design.inv_rel2
    weights = np.empty((2 * k, c))
    w, wa = weights[:k], weights[k:]
    table = _table(c)
    model = avar
    for it in range(iterations):
        np.square(model, out=w)
        np.divide(inv_rel2, w, out=w)                         # 1 / (model rel)^2
        np.multiply(w, avar, out=wa)
        np.matmul(design.basis, weights, out=table[:24])
        x, var, _ = _nonnegative(table, with_variance=it + 1 == iterations)
        model = T @ x.T
    np.square(model, out=w)
    np.divide(inv_rel2, w, out=w)
    r = avar - model
    r *= r
    r *= w
    return x, np.sqrt(var), r.sum(axis=0)


@functools.lru_cache(maxsize=16)
def _template(c):
    """For ``c`` fits: :func:`_table`'s empty table (its constants set), ``arange(c)``, and
    per set, fit and term the flat indices into the table of ``x``'s numerator and
    denominator (16, c, 8) and of ``d_{S-i}(i)`` (16, c, 4); read-only."""
    table = np.empty((_WIDTH, c))
    table[-3:] = np.array([0.0, 1.0, np.nan])[:, None]
    fits = np.arange(c)
    solve = np.ascontiguousarray(_SOLVE[:, None, :] * c + fits[None, :, None])
    variance = np.ascontiguousarray(_VARIANCE[:, None, :] * c + fits[None, :, None])
    for a in (table, fits, solve, variance):
        a.flags.writeable = False
    return table, fits, solve, variance


def _table(c):
    """A table of :func:`_nonnegative` for ``c`` fits, shape (:data:`_WIDTH`, c): each fit's
    ``[G h -h]``, (4, 6) flat, goes to its first 24 rows."""
    return _template(c)[0].copy()


def _nonnegative(table, with_variance=False):
    """``min x' G x - 2 h' x`` over ``x >= 0`` per fit (G positive definite): the solution
    set by the Karush-Kuhn-Tucker conditions from the Schur complements of ``[G h]`` on every
    set of terms (the module docstring).

    Parameters
    ----------
    table : numpy.ndarray, shape (:data:`_WIDTH`, c)
        From :func:`_table`, each fit's ``[G h -h]`` ((4, 6) flat) in its first 24 rows; the
        Schur complements are written to the rest.
    with_variance : bool
        Also the diagonal of ``G_SS^-1`` on the solution's set ``S``.

    Returns
    -------
    x : numpy.ndarray, shape (c, 4)
        Zero outside the solution's set. A fit with NaN in its table gets the first set
        whose conditions are NaN (the empty one, x = 0, where all are).
    variance : numpy.ndarray, shape (c, 4) or None
        ``(G_SS^-1)_ii``, NaN outside ``S``.
    best : numpy.ndarray, shape (c,)
        The solution's set, an index of :data:`_SETS`.
    """
    c = table.shape[1]
    for parents, out in _STEPS:
        p = np.take(table, parents, axis=0)                   # (4, m, c)
        np.subtract(p[0], p[1] * p[2] / p[3], out=table[out])
    margin = np.minimum.reduce(np.take(table, _KKT, axis=0), axis=0)   # (16, c): >= 0 at S
    best = margin.argmax(axis=0)
    _, fits, solve, variance = _template(c)
    num_den = np.take(table, solve[best, fits])               # (c, 8)
    x = num_den[:, :4] / num_den[:, 4:]
    var = 1.0 / np.take(table, variance[best, fits]) if with_variance else None
    return x, var, best
