"""Steps in a gyro's angle below the window test: the raw-log quality check 3b
(:func:`hse_opt.align.quality.assess` calls :func:`find_steps`; its module docstring has the
other checks, their thresholds and the false-alarm design).

Why
---
A sample's error ``d`` in one gyro stays in its angle: the heading moves by up to 20 ``d`` on a
10-minute log (the filter takes it as a rate error ``d / T``; how much depends on the gyro, the
time and the table angle there), so ``d`` = 0.2 arcsec moves it by half its 1-sigma (8 arcsec
for the paper-like system at 10 deg/s), a quarter of the window test's threshold (check 3:
0.66-0.8 arcsec). A window sum cannot see that: it carries a whole pulse and a share of an
encoder count of quantization. But a counter carries its remainder, so its error in the
*cumulative* angle is bounded and, once the table's jitter dithers it, white: averaged over
``K`` samples it falls as ``1 / sqrt(K)``, while the angle random walk grows as ``sqrt(K dt)``.

The statistic
-------------
For each gyro the cumulative residual ``e``: each increment less the table's deterministic part,
the Allan analysis' fit (:func:`hse_opt.align.blocks.deterministic_residual`: a constant rate,
the Earth's rate and gravity's leak turning with the table), except that the encoder's steps
beyond the mean rate (the table's jitter, real motion that the gyros sense too) are taken off
in the ratio ``beta_j`` of each gyro's mean rate to the encoder's (:func:`shares`), not in the
fit's jitter coefficient, which a smooth table leaves undetermined: a step of the encoder
alone then shows in all three gyros in that ratio. At each sample ``p``, ``D(p)`` is the mean
of ``e`` over the ``K`` samples after ``p`` less that over the ``K`` before: a step ``d`` at
``p0`` shows as ``d (1 - |p - p0| / K)``; a constant, a sinusoid of the table angle (what the
encoder's once-a-turn error leaves in the ratio ``beta_j``) and a quadratic drift in time are
fitted out of ``D`` by least squares. ``K`` is :data:`GRID` (4) blocks of the Allan
analysis (:func:`block_period`: 4 x 64 ms = 0.256 s at 500 Hz for ``step_span_s`` = 0.25 s;
another span gets blocks of its own), and ``D`` is evaluated at every block edge from each
block's plain sum of the residual (the Allan analysis' own) and its weighted sum (increment
``i`` of a block of ``h`` weighted ``h + 1 - i``: :func:`weighted_sums`, less the fitted part's,
:func:`weighted_regressors`) by moving sums over ``GRID`` blocks, so a step's peak is seen at
7/8 of it at least; the step's exact sample comes from the per-sample statistic around the peak.
What 3b adds to the Allan analysis' sums and fit on a 10-minute 500 Hz log is the gyros' and
the encoder's weighted sums (one pass over each; ``hse-opt align`` takes them with the block
sums, :func:`hse_opt.align.blocks.block_sums`), moving sums and the slow part's fit over
9,375 block edges (the table angle's cos and sin there are the fit's), and the robust
1-sigma from every ``K``-th of them.

Its 1-sigma ``s`` (1.4826 x the median of ``|D|``, which its fit centres on 0) is 0.0071 arcsec
on the paper-like 10-minute log at 10 deg/s. Predicted: the white quantization of the pulses and the encoder's
share, ``sqrt(q^2 + (beta qe)^2) / sqrt(12)`` = 0.042 arcsec a sample, and the angle random
walk N = 0.012 deg/h/sqrt(Hz) give ``var = 2 sigma_w^2 dt / tau + 2 N^2 tau / 3``, least at
``tau`` = 0.27 s: 0.0072 arcsec. The threshold is ``max(z s + quant, floor)``: ``z`` the
Bonferroni level of the checks' false-alarm figure over six tests a span and three gyros
(6.3 for 10 minutes: 0.044 arcsec); ``quant`` = 0 when the quantization is dithered (the
table's jitter at least one encoder count and its share ``|beta_j|`` of it at least one pulse:
Widrow's condition for a white quantization error), else the window test's ``2 (q + |beta_j|
qe)``, whose bounded error a resonance can hold still and then move by a count (a jitter-free
or coarse-pulse system gains nothing over the window test).

What is found
-------------
A step in one gyro (a sample's error; a lost or extra pulse of 0.1 arcsec too), or steps in
all three at one sample in the ratio of their ``beta_j`` (``ptp`` of ``-d_j / beta_j`` within
30 % of the largest): the encoder's, a jump below checks 1 and 3 (1 arcsec moves the heading
by less than that). Measured (``tests/test_align_quality.py``): at two times and in three
gyros the ``d`` that moves the 10-minute heading by half its sigma (about 0.2 arcsec) is found
at its sample (within 2) and, taken off, leaves the heading within a tenth of a sigma; 0.06
arcsec (a third above the threshold) is found wherever it falls in a block, 0.05 at 5 of 9 places
(as before this check shared the Allan analysis' blocks). False alarms
(``studies/quality_false_alarms.py``): 0 in 3,600 clean logs of six systems, 20 s to 10
minutes (``--full``), and 0 in 240 at its CI size.
"""
from __future__ import annotations

import functools

import numpy as np

from hse_opt import units
from hse_opt.align import _compiled
from hse_opt.align._blas import block_dot, one_thread
from hse_opt.align._stats import MAD as _MAD, row_median as _row_median, solve_normal as _solve_normal
from hse_opt.align.blocks import BLOCK_PERIOD, _encoder_weighted, _weighted_block_sums

__all__ = ["block_period", "weighted_sums", "weighted_regressors", "shares", "check_steps", "find_steps",
           "step_statistic", "GRID"]

#: blocks a span ``K``: the statistic is evaluated every ``K / GRID`` samples
GRID = 4


def block_period(span):
    """The block the statistic is evaluated on, s: the Allan analysis' (:data:`BLOCK_PERIOD`)
    when ``GRID`` of them make the span ``span`` (s) to the nearest block, so that both share
    one fit of the deterministic part; else ``span / GRID``."""
    return BLOCK_PERIOD if round(span / BLOCK_PERIOD) == GRID else span / GRID


def weighted_sums(enc, gyro, h, nb, sums=None):
    """The gyros' and the encoder's weighted sums over blocks of ``h`` increments (increments
    ``1 + b h .. (b + 1) h``; increment ``i`` of a block weighted ``h + 1 - i``), as
    matrix-vector products on one BLAS thread (:mod:`hse_opt.align._blas`), or from ``sums``.

    Parameters
    ----------
    enc : numpy.ndarray, shape (n,)
        The encoder angle, rad (unwrapped).
    gyro : numpy.ndarray, shape (n, 3)
        Gyro increments, rad.
    h, nb : int
        Increments a block, blocks.
    sums : hse_opt.align.blocks.BlockSums, optional
        The log's block sums with the checks' passes (:func:`hse_opt.align.blocks.block_sums`):
        their weighted sums are taken where they are of these very arrays (a repaired copy is
        summed here) over these blocks; the same bytes as summed here.

    Returns
    -------
    W : numpy.ndarray, shape (3, nb)
        Each gyro's, rad.
    E : numpy.ndarray, shape (nb,)
        The encoder's, rad: ``sum (enc[start + i] - enc[start])``, i = 1 .. h, summed from its
        steps ``enc[k] - enc[k - 1]``.
    """
    W = E = None
    if sums is not None and sums.weighted is not None and sums.block == h and sums.weighted.shape[1] == nb:
        if sums.log.gyro is gyro:
            W = sums.weighted
        if sums.log.encoder is enc:
            E = sums.weighted_encoder
    if W is None:
        W = _weighted_block_sums(gyro, nb, h)
    if E is None:
        E = _encoder_weighted(enc, nb, h)
    return W, E


def weighted_regressors(residual, E):
    """The deterministic part's regressors (:class:`hse_opt.align.blocks.Residual`) summed with
    the weights of :func:`weighted_sums`, the first three rows divided by ``(h + 1) / 2`` (the
    factor left to the coefficients: four passes fewer), shape (4, nb).

    Within a block of ``h`` samples the angle is taken as linear (as the regressors are): with
    ``delta`` its turn a sample and ``u_i = i - (h + 1) / 2``, the weighted sum of the
    per-sample cos/sin terms is the block's term times ``(h + 1) / 2 - j B / A``, ``A = sum
    cos(u delta)``, ``B = sum u sin(u delta)``; ``B / A = cot(delta / 2) / 2 - h cot(h delta /
    2) / 2 = delta (h^2 - 1) / 12 (1 + delta^2 (h^2 + 1) / 60)`` to ``O(delta^5 h^4)``. The
    time's weighted sum is ``(h + 1) / 2`` times the block's (its coefficient less the jitter
    term's share of it is the bias alone); the encoder's is ``E``, less the mean rate's."""
    X = residual.regressors
    h = residual.block
    half = 0.5 * (h + 1)
    # c / half, c = B / A: with d = (X[3] + rate X[0]) k1, k1 = (h^2 - 1) / (12 h half),
    # c / half = d (1 + d^2 k2 / k1^2), k2 = (h^2 + 1) / (60 h^2)
    k1 = (h * h - 1) / (12.0 * h * half)
    Xw = np.empty_like(X)
    d = np.multiply(X[0], residual.rate * k1)
    np.multiply(X[3], k1, out=Xw[0])
    d += Xw[0]
    c = np.multiply(d, d)
    c *= ((h * h + 1) / (60.0 * h * h)) / (k1 * k1) if h > 1 else 0.0     # (h = 1: d = 0, c = 0)
    c += 1.0
    c *= d
    Xw[0] = X[0]
    np.multiply(c, X[2], out=Xw[1])
    Xw[1] += X[1]
    np.multiply(c, X[1], out=Xw[2])
    np.subtract(X[2], Xw[2], out=Xw[2])
    np.multiply(X[0], half, out=Xw[3])               # (in this order: E less a term of its size)
    Xw[3] *= -residual.rate
    Xw[3] += E
    return Xw


def step_statistic(t, enc, gyro, residual, beta, sums=None):
    """``D`` on its grid, the slow part fitted out (module docstring).

    Parameters
    ----------
    t : numpy.ndarray, shape (n,)
        s.
    enc : numpy.ndarray, shape (n,)
        The encoder angle, rad (unwrapped).
    gyro : numpy.ndarray, shape (n, 3)
        Gyro increments, rad.
    residual : hse_opt.align.blocks.Residual
        The deterministic part fitted out of these samples' block sums (its block ``h``; the
        span ``K = GRID h``).
    beta : numpy.ndarray, shape (3,)
        Each gyro's share of the encoder's turn (:func:`shares`): the encoder's steps are
        taken off the gyros in this ratio (a step of the encoder alone then shows in all
        three in it), not in the fit's jitter coefficients, which a smooth table leaves
        undetermined.
    sums : hse_opt.align.blocks.BlockSums, optional
        The log's block sums, for :func:`weighted_sums`.

    Returns
    -------
    D : numpy.ndarray, shape (3, g)
        rad, at the increments ``p = K, K + h, ...``.
    p : numpy.ndarray of int, shape (g,)
    local : callable
        ``local(j, a, b)``: gyro ``j``'s per-increment statistic at the splits ``a .. b - 1``
        (their exact step), the slow part's rate taken off.
    """
    h = residual.block
    nb = residual.blocks.shape[1]
    K = GRID * h
    coef = residual.coefficients[:, :3].copy()       # (4, 3)
    W, E = weighted_sums(enc, gyro, h, nb, sums)
    D = _statistic_compiled(residual, beta, W, E)
    if D is None:
        D = _statistic(residual, beta, coef, W, E)
    coef[3] = beta
    p = h * np.arange(GRID, nb + 1 - GRID)
    # the slow part: a constant, a sinusoid of the table angle (the encoder's own once-a-turn
    # error, in the ratio beta) and a quadratic drift, fitted by least squares (the columns
    # O(1), nearly orthogonal; the table angle's cos and sin are the fit's, at the block edges)
    # (fitted on every GRID-th edge, a K apart: D's values closer than that are nearly the same)
    A = _slow_regressors(residual.edge_cos[GRID:nb + 1 - GRID], residual.edge_sin[GRID:nb + 1 - GRID])
    M = np.empty((8, -(-A.shape[1] // GRID)))            # the fit's edges: its regressors and D
    M[:5] = A[:, ::GRID]
    M[5:] = D[:, ::GRID]
    with one_thread():
        P = M @ M[:5].T                                  # (8, 5): the normal matrix and right sides
        model = _solve_normal(P[:5], P[5:].T).T @ A
    g = np.asarray(gyro).T
    dt = residual.tau0 / h                           # the mean sample period (weighted_regressors)

    def local(j, a, b):
        lo, hi = a - K, b + K                        # increments lo + 1 .. hi
        da = np.diff(enc[lo:hi + 1])
        mid = enc[lo:hi] + 0.5 * da
        det = coef[0, j] * dt + beta[j] * (da - residual.rate * dt) \
            + (coef[1, j] * np.cos(mid) + coef[2, j] * np.sin(mid)) * dt
        i = np.clip(np.searchsorted(p, np.arange(lo, hi)), 0, p.size - 1)
        x = g[j, lo + 1:hi + 1] - det - model[j, i] / K      # the slow part's rate: D ~ K x rate a sample
        cs = np.concatenate(([0.0], np.cumsum(np.cumsum(x))))
        q = np.arange(K, K + b - a)
        return (cs[q + K] - 2.0 * cs[q] + cs[q - K]) / K

    D -= model
    return D, p, local


def _statistic(residual, beta, coef, W, E):
    """:func:`step_statistic`'s ``D`` (3, nb - 7) before its slow part is fitted out, by numpy
    (``coef``: the coefficients' gyro columns (4, 3))."""
    h = residual.block
    nb = residual.blocks.shape[1]
    X = residual.regressors
    r = residual.blocks[:3] + np.multiply.outer(coef[3] - beta, X[3])       # the jitter in the ratio beta
    C = coef.T.copy()                                # (3, 4): the halved rows' coefficients
    C[:, 3] = beta
    C[:, :3] *= 0.5 * (h + 1)
    with one_thread():
        rw = W - C @ weighted_regressors(residual, E)
    # block b's sum of e is rw_b + h e(end of block b - 1), e(end of b) = r_0 + .. + r_b; over the
    # GRID blocks after edge b less the GRID before, the e(end) terms leave h times the sum of r
    # over a triangle of 2 GRID - 1 blocks: one moving sum over GRID blocks of rw's change over
    # GRID blocks plus h times r's moving sum (no sum over the record to cancel)
    y = _moving(r, GRID)[:, :nb - GRID]
    y *= h
    y += rw[:, GRID:]
    y -= rw[:, :-GRID]
    D = _moving(y, GRID)
    D /= GRID * h
    return D


def _statistic_compiled(residual, beta, W, E):
    """:func:`_statistic` by the compiled kernel (:mod:`hse_opt.align._compiled`: the same steps
    in one pass a gyro) where it is built and the arrays are contiguous float64, else None."""
    nb = residual.blocks.shape[1]
    arrays = (residual.blocks, residual.coefficients, residual.regressors, W, E)
    if GRID != 4 or nb < 8 or not _compiled.takes(*arrays):
        return None
    D = np.empty((3, nb - 2 * GRID + 1))
    _compiled.kernels.step_statistic(residual.blocks[:3], residual.coefficients, np.ascontiguousarray(beta, dtype=float),
                           residual.regressors, W, E, residual.block, residual.rate, D)
    return D


def _moving(x, k):
    """Sums of ``k`` (a power of two) consecutive columns of ``x`` (m, n), shape (m, n - k + 1),
    by doubling."""
    w = 1
    while w < k:
        x = x[:, :-w] + x[:, w:]
        w *= 2
    return x


def _slow_regressors(c, s):
    """The rows (5, g) of the statistic's slow part: 1, ``cos`` and ``sin`` of the table angle,
    ``u`` and ``u^2`` (``u`` from -1 to 1 over the grid)."""
    A = np.empty((5, c.size))
    A[0] = 1.0
    A[1], A[2] = c, s
    A[3:] = _drift(c.size)
    return A


@functools.lru_cache(maxsize=8)
def _drift(g):
    """The rows ``u`` (``numpy.linspace(-1, 1, g)``) and ``u^2`` of :func:`_slow_regressors`,
    (2, g), read-only (one per log length)."""
    U = np.empty((2, g))
    U[0] = np.linspace(-1.0, 1.0, g)
    np.multiply(U[0], U[0], out=U[1])
    U.flags.writeable = False
    return U


def shares(residual):
    """Each gyro's share of the encoder's turn, shape (3,): its mean rate over the encoder's
    (the fit's constant-rate coefficient over ``Omega``; the sum of its increments over the
    encoder's turn)."""
    return residual.coefficients[0, :3] / residual.rate


def find_steps(t, enc, gyro, residual, beta, level, quant, floor, sums=None):
    """The steps of the three gyros (module docstring).

    Parameters
    ----------
    t, enc, gyro, residual, beta, sums
        As :func:`step_statistic`.
    level : float
        The Bonferroni multiplier of the statistic's robust 1-sigma.
    quant : numpy.ndarray, shape (3,)
        Added to each gyro's threshold (0 where the quantization is dithered), rad.
    floor : float
        The smallest threshold, rad.

    Returns
    -------
    steps : list of tuple
        ``("gyro", row, j, d)``: gyro ``j``'s increment at the log's ``row`` is off by ``d``
        (rad); ``("encoder", row, None, delta)``: the encoder steps by ``delta`` more than the
        gyros at ``row``; in order of ``row``.
    thr : numpy.ndarray, shape (3,)
        Each gyro's threshold, rad.
    """
    D, p, local = step_statistic(t, enc, gyro, residual, beta, sums)
    # the robust 1-sigma: 1.4826 x the median of |D| (its fit holds a constant: D is centred on
    # 0), at every K (values a K apart are nearly independent)
    # (D is this call's own: its magnitude taken in place, all that is looked at here)
    D = np.abs(D, out=D)
    sigma = _MAD * _row_median(np.array(D[:, ::GRID]))
    thr = np.maximum(level * sigma + quant, floor)
    bad = D > thr[:, None]
    if not bad.any():
        return [], thr
    h, N = residual.block, t.size - 1
    K = GRID * h
    found = []                                      # (increment, channel, d)
    for j in range(3):
        idx = np.flatnonzero(bad[j])
        if not idx.size:
            continue
        for run in np.split(idx, np.flatnonzero(np.diff(idx) > 2 * GRID) + 1):
            g0 = int(run[0]) + int(np.argmax(D[j, run[0]:run[-1] + 1]))
            a, b = max(K, int(p[g0]) - h), min(N - K, int(p[g0]) + h + 1)
            d = local(j, a, b)
            i = int(np.argmax(np.abs(d)))
            found.append((a + i, j, float(d[i])))
    found.sort()
    out, done = [], set()
    for p0, j, d in found:
        if (p0, j) in done:
            continue
        near = [(p2, j2, d2) for p2, j2, d2 in found if abs(p2 - p0) <= h]
        if {j2 for _, j2, _ in near} == {0, 1, 2}:
            delta = np.array([-d2 / beta[j2] for _, j2, d2 in near])
            if np.ptp(delta) <= 0.3 * np.abs(delta).max():
                done.update((p2, j2) for p2, j2, _ in near)
                out.append(("encoder", p0 + 1, None, float(np.mean(delta))))
                continue
        done.add((p0, j))
        out.append(("gyro", p0 + 1, j, d))
    return out, thr


def check_steps(t, enc, gyro, residual, *, jitter, q, qe, level, floor, bound, most, spikes=(), sums=None):
    """Check 3b of :func:`hse_opt.align.quality.assess`: find the steps, repair or refuse.

    Parameters
    ----------
    t, enc, gyro, residual
        As :func:`step_statistic` (the residual's blocks of :func:`block_period`, at least
        :data:`hse_opt.align.blocks.MIN_BLOCKS` of them).
    jitter : float
        The table's jitter in angle, rad (1/sqrt(2) of the encoder steps' robust 1-sigma).
    q : numpy.ndarray, shape (3,)
        Each gyro's pulse, rad; ``qe``: the encoder's count, rad (0: unquantized).
    level : callable
        ``level(m)``: the Bonferroni multiplier for ``m`` spans of the log.
    floor : float
        The smallest threshold, rad.
    bound : float
        Quanta a window sum's quantization is bounded by (where not dithered).
    most : int
        Steps repaired in one gyro; more refuse the log.
    spikes : collection of (int, int)
        ``(row, channel)`` of the spikes check 3 repaired: a step within a span of one is
        what that repair left (the neighbours' noise), taken off without a finding of its own.
    sums : hse_opt.align.blocks.BlockSums, optional
        The log's block sums, for :func:`weighted_sums`.

    Returns
    -------
    gyro : numpy.ndarray
        A repaired copy, or the input.
    findings : list of tuple
        ``(check, sample, time, action, detail)`` (:class:`hse_opt.align.findings.Finding`'s
        fields).
    """
    N = t.size - 1
    K = GRID * residual.block
    beta = shares(residual)
    # the pulses and the encoder's counts are white only when the table's jitter dithers them
    # (a noise of at least one quantum: Widrow); else their bounded error is added
    dithered = (jitter >= qe) & (np.abs(beta) * jitter >= q)
    quant = np.where(dithered, 0.0, bound * (q + np.abs(beta) * qe))
    steps, thr = find_steps(t, enc, gyro, residual, beta, level(N / K), quant, floor, sums)
    if not steps:
        return gyro, []
    gyro, out, count = gyro.copy(), [], [0, 0, 0]
    for kind, k, j, d in steps:
        if kind == "encoder":
            out.append(("encoder", k, float(t[k]), "noted",
                        f"the encoder steps by {d / units.ARCSEC:+.4g} arcsec more than the gyros turned and stays "
                        "off (below checks 1 and 3: it moves the heading by less than that)"))
            continue
        name = ("gyro_x", "gyro_y", "gyro_z")[j]
        count[j] += 1
        if count[j] > most:
            out.append(("channel", k, float(t[k]), "refused",
                        f"{name}: more than {most} steps in its angle, each beyond {thr[j] / units.ARCSEC:.4g} "
                        f"arcsec (lost or extra pulses); allowed: at most {most}, each repaired"))
            return gyro, out
        gyro[k, j] -= d
        if not any(c == j and abs(r - k) <= K for r, c in spikes):
            out.append(("channel", k, float(t[k]), "repaired",
                        f"{name} angle steps by {d / units.ARCSEC:+.4g} arcsec here and stays off (one sample's "
                        f"error below the window test; allowed within {thr[j] / units.ARCSEC:.4g} arcsec): taken "
                        "off the sample"))
    return gyro, out
