"""Robust statistics of the raw-log checks (private): the exact median by partition, the
Gaussian 1-sigma of a median absolute deviation and the encoder steps' centre and spread;
shared by :mod:`hse_opt.align.quality` and its step check (:mod:`hse_opt.align.steps`); the
window test's flags and its slow model's fit."""
from __future__ import annotations

import functools
import math

import numpy as np

#: robust 1-sigma of a Gaussian from its median absolute deviation
MAD = 1.4826


def median(x):
    """``np.median`` of a 1-D array, or of each column of a 2-D one (the same values: the middle
    order statistic, or the mean of the two middle ones, from a partition of contiguous rows;
    without ``np.median``'s generic path, which cost a 10-minute log's assessment a fifth of
    its time). Finite values (the loader refuses others).

    Parameters
    ----------
    x : array_like, shape (n,) or (n, k)

    Returns
    -------
    float or numpy.ndarray, shape (k,)
        In the unit of ``x``.
    """
    return row_median(np.array(np.asarray(x, dtype=float).T, order="C"))     # a copy: columns as rows


def row_median(x):
    """:func:`median` of each row of ``x``, a C-contiguous float array (n,) or (k, n) that is
    partitioned in place (a temporary's: no copy).

    One order statistic partitioned for: for an even ``n`` the lower middle one is the largest
    of the values below the upper (the same value as a partition at both; numpy partitions at
    one by its vectorised selection, at two by its scalar one: 6 times slower on fresh data,
    0.05 ms for (3, 2342))."""
    n = x.shape[-1]
    h = n // 2
    x.partition(h, axis=-1)
    if n % 2:
        return x[..., h]
    return (x[..., :h].max(axis=-1) + x[..., h]) / 2.0


def step_stats(d, taken=False):
    """(centre, robust 1-sigma) of the encoder steps ``d`` from every 29th step (the table's
    step and its jitter; a handful of glitches does not move a median); ``taken``: ``d`` is
    already that selection (:func:`every_29th_step`)."""
    sub = d if taken else d[::29] if d.size >= 2900 else d
    x = np.array(sub, dtype=float)                  # one copy, partitioned for both medians
    c = float(row_median(x))
    x -= c
    return c, MAD * float(row_median(np.abs(x, out=x)))


def every_29th_step(enc):
    """The steps of the encoder ``enc`` (n,) that :func:`step_stats` takes, without the others."""
    return enc[1::29] - enc[:-1:29] if enc.size > 2900 else np.diff(enc)


def robust_flags(v, sigmas, floor, quant=0.0, level=0.0):
    """Deviations from the median, thresholds and flags of each row of ``v``: a value is
    flagged beyond ``max(sigmas x s, level x s + quant, floor)``, ``s`` its row's robust
    1-sigma (``quant``: the bounded quantization part, added to the Gaussian part's bound at
    the Bonferroni ``level``). The raw-log checks' window test (check 3 of
    :mod:`hse_opt.align.quality`).

    Parameters
    ----------
    v : numpy.ndarray, shape (k, m)
        Each row a channel's values over the windows (in its unit).
    sigmas, level : float
    floor, quant : float or numpy.ndarray, shape (k,)
        In each row's unit.

    Returns
    -------
    dev : numpy.ndarray, shape (k, m)
    thr : numpy.ndarray, shape (k,)
    flags : numpy.ndarray of bool, shape (k, m)
    """
    dev = v - median(v.T)[:, None]
    s = MAD * row_median(np.abs(dev))
    thr = np.maximum(np.maximum(sigmas * s, level * s + quant), floor)
    return dev, thr, np.abs(dev) > thr[:, None]


def regressors(mid, cos_sin=None):
    """The slow model of a static base's windows (check 3 of :mod:`hse_opt.align.quality`):
    rows 1, cos, sin of the windows' middle table angles ``mid`` (m,), rad, then ``tau`` and
    ``tau^2``, ``tau`` from -1 to 1 (``numpy.linspace``'s values); shape (5, m).
    ``cos_sin``: their cos and sin when already known (two arrays (m,))."""
    m = mid.shape[0]
    A = np.empty((5, m))
    A[0] = 1.0
    if cos_sin is None:
        np.cos(mid, out=A[1])
        np.sin(mid, out=A[2])
    else:
        A[1], A[2] = cos_sin
    A[3:] = _tau(m)
    return A


@functools.lru_cache(maxsize=8)
def _tau(m):
    """The rows ``tau`` and ``tau^2`` of :func:`regressors` (2, m), read-only (one per log
    length)."""
    U = np.empty((2, m))
    np.multiply(np.arange(m), 2.0 / (m - 1), out=U[0])
    U[0] -= 1.0
    U[0, -1] = 1.0
    np.multiply(U[0], U[0], out=U[1])
    U.flags.writeable = False
    return U


def fit(A, Y, keep=None):
    """Least-squares coefficients, shape (5, k), of the rows of ``Y`` (k, m) on the regressors
    ``A`` (5, m) (:func:`regressors`) over the columns ``keep`` (bool (m,); all when None). The
    normal equations: the regressors are O(1) and nearly orthogonal, a 5x5 solve
    (:func:`solve_normal`)."""
    Ak, Yk = (A, Y) if keep is None else (A[:, keep], Y[:, keep])
    return solve_normal(Ak @ Ak.T, Ak @ Yk.T)


def solve_normal(N, R):
    """``N^-1 R`` for a small normal matrix ``N`` (k, k) of nearly orthogonal O(1) regressors
    (:func:`fit`; check 3b's slow part, :func:`hse_opt.align.steps.step_statistic`) and right
    sides ``R`` (k, r): ``L^-T (L^-1 R)`` with ``L^-1`` from :func:`cholesky_inverse` (no
    LAPACK call: the first of a routine after the alignment has run costs tens of
    microseconds, 0.037 ms for check 3's 5x5 ``numpy.linalg.solve`` against 0.01 here);
    ``numpy.linalg.solve`` where a pivot is not above ``1e-12`` of its diagonal entry (a
    regressor dependent on the others: as before).

    Parameters
    ----------
    N : numpy.ndarray, shape (k, k)
        Symmetric.
    R : numpy.ndarray, shape (k, r)

    Returns
    -------
    numpy.ndarray, shape (k, r)
    """
    factor = cholesky_inverse(N)
    if factor is None:
        return np.linalg.solve(N, R)
    Li = factor[0]
    return Li.T @ (Li @ R)


def cholesky_inverse(N, rtol=1e-12):
    """``L^-1`` for ``N = L L^T`` (a small symmetric matrix (k, k)) by Cholesky in Python floats
    and substitution, with ``det N`` (the product of the squared pivots); None where a squared
    pivot is not above ``rtol`` of its diagonal entry (not positive definite, or nearly so).

    Returns
    -------
    tuple of (numpy.ndarray, shape (k, k), lower triangular; float), or None
    """
    k = N.shape[0]
    a = N.tolist()                                   # L in place, below and on the diagonal
    det = 1.0
    for j in range(k):
        aj = a[j]
        d = aj[j]
        for m in range(j):
            d -= aj[m] * aj[m]
        if not d > rtol * N[j, j]:
            return None
        det *= d
        d = math.sqrt(d)
        aj[j] = d
        for i in range(j + 1, k):
            ai = a[i]
            x = ai[j]
            for m in range(j):
                x -= ai[m] * aj[m]
            ai[j] = x / d
    inv = [[0.0] * k for _ in range(k)]              # L^-1, lower triangular
    for i in range(k):
        ai, row = a[i], inv[i]
        row[i] = 1.0 / ai[i]
        for j in range(i):
            x = 0.0
            for m in range(j, i):
                x -= ai[m] * inv[m][j]
            row[j] = x / ai[i]
    return np.array(inv), det
