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
For each gyro the cumulative residual ``e``: each increment less its share ``beta_j`` of the
encoder's step (the table's jitter, real motion, is in both and cancels) and less its mean.
At each sample ``p``, ``D(p)`` is the mean of ``e`` over the ``K`` samples after ``p`` less
that over the ``K`` before (``K`` samples of ``step_span_s``, 0.25 s): a step ``d`` at ``p0``
shows as ``d (1 - |p - p0| / K)``; a constant rate shows as a constant, a linear drift as a
line, the sinusoid of the table angle (the Earth's rate turning with the table) as that
sinusoid times about ``K dt``: check 3's model (a constant, a sinusoid of the table angle, a
quadratic drift) is fitted out of ``D`` by least squares. ``D`` is evaluated every
``K / 8`` samples from two weighted sums over blocks of that length (:func:`block_sums`: a
plain and a weighted sum of each gyro, the encoder's by parts from one pass), so a step's peak
is seen at 15/16 of it at least; the step's exact sample comes from the per-sample statistic
around the peak. Cost on a 10-minute 500 Hz log (instructions counted by callgrind, which load
does not change): 26 M for the whole check, half the alignment's 48 M; the block sums 13 M (the
weighted sum alone 6 M: numpy's loops, as a matrix product would wake BLAS threads), the rest
of the statistic 10 M (two cumulative sums, the table angle's cos and sin, the fit).

Its 1-sigma ``s`` (1.4826 x the median absolute deviation) is 0.0071 arcsec on the paper-like
10-minute log at 10 deg/s. Predicted: the white quantization of the pulses and the encoder's
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
at its sample (within 2) and, taken off, leaves the heading within a tenth of a sigma; 0.05
arcsec is found too. False alarms (``studies/quality_false_alarms.py``): 0 in 3,600 clean logs
of six systems, 20 s to 10 minutes (``--full``), and 0 in 240 at its CI size.
"""
from __future__ import annotations

import numpy as np

from hse_opt import units
from hse_opt.align._stats import MAD as _MAD, median as _median
from hse_opt.align.noise import _cos_sin

__all__ = ["block_sums", "check_steps", "find_steps", "step_statistic", "GRID"]

#: the statistic is evaluated every K / GRID samples
GRID = 8


def block_sums(enc, gyro, h):
    """The gyros' and the encoder's plain and weighted sums over blocks of ``h`` increments
    (increments ``1 + b h .. (b + 1) h``; increment ``i`` of a block weighted ``h - i``), one
    pass over the gyros for each and one over the encoder, by numpy's own loops: a matrix
    product over the record wakes BLAS threads that spin (15 ms instead of 0.8 on a busy
    2-core machine).

    Parameters
    ----------
    enc : numpy.ndarray, shape (n,)
        The encoder angle, rad (unwrapped).
    gyro : numpy.ndarray, shape (n, 3)
        Gyro increments, rad.
    h : int
        Increments a block.

    Returns
    -------
    R : numpy.ndarray, shape (3, nb, 2)
        Each gyro's plain and weighted block sums, rad (``nb = (n - 1) // h``).
    E : numpy.ndarray, shape (2, nb)
        The encoder's, rad: the plain sum is the block's turn ``enc[end] - enc[start]`` and
        the weighted one ``sum (enc[start + i] - enc[start])``, i = 1 .. h (summation by parts:
        the differences of a float angle within a block are exact, so both equal the sums of
        its steps).
    total : numpy.ndarray, shape (3,)
        Each gyro's sum over all increments 1 .. n - 1, rad.
    """
    g = np.asarray(gyro).T                           # (3, n): rows (a view for a column-major log)
    nb = (g.shape[1] - 1) // h
    M = nb * h
    w = np.arange(h, 0, -1, dtype=float)
    R = np.empty((3, nb, 2))
    gb = g[:, 1:M + 1].reshape(3, nb, h)
    np.einsum("cbi->cb", gb, out=R[:, :, 0])
    np.einsum("cbi,i->cb", gb, w, out=R[:, :, 1])
    rel = enc[1:M + 1].reshape(nb, h) - enc[:M:h, None]      # one pass over the encoder
    E = np.empty((2, nb))
    E[0] = rel[:, -1]
    np.einsum("bi->b", rel, out=E[1])
    total = R[:, :, 0].sum(axis=1) + g[:, M + 1:].sum(axis=1)
    return R, E, total


def step_statistic(t, enc, gyro, K, beta, sums=None):
    """``D`` on its grid, the slow part fitted out (module docstring).

    Parameters
    ----------
    t : numpy.ndarray, shape (n,)
        s.
    enc : numpy.ndarray, shape (n,)
        The encoder angle, rad (unwrapped).
    gyro : numpy.ndarray, shape (n, 3)
        Gyro increments, rad.
    K : int
        The span, samples (a multiple of :data:`GRID`).
    beta : numpy.ndarray, shape (3,)
        Each gyro's share of the encoder's turn (its sum over the log's over the encoder's).
    sums : tuple, optional
        :func:`block_sums` of ``enc, gyro`` over blocks of ``K / GRID`` (taken here if None).

    Returns
    -------
    D : numpy.ndarray, shape (3, g)
        rad, at the increments ``p = K, K + h, ...`` (``h = K / GRID``).
    p : numpy.ndarray of int, shape (g,)
    local : callable
        ``local(j, a, b)``: gyro ``j``'s per-increment statistic at the splits ``a .. b - 1``
        (their exact step), the slow part's rate taken off.
    """
    N = t.size - 1
    h = K // GRID
    nb = N // h
    M = nb * h
    g = np.asarray(gyro).T                           # (3, n): rows (a view for a column-major log)
    R, E, _ = block_sums(enc, gyro, h) if sums is None else sums
    P = R[:, :, 0] - beta[:, None] * E[0]            # each block's plain and weighted sums of e
    B = R[:, :, 1] - beta[:, None] * E[1]            # (new arrays: the caller's sums stay)
    mean = P.sum(axis=1) / M
    P -= mean[:, None] * h
    B -= mean[:, None] * (h * (h + 1) / 2.0)         # the weights h .. 1 summed
    e_end = np.cumsum(P, axis=1)                     # e at each block's end
    # block b's sum of e: h e(end of b - 1) + its own
    B[:, 1:] += h * e_end[:, :-1]
    S = np.zeros((3, nb + 1))
    np.cumsum(B, axis=1, out=S[:, 1:])
    kb = K // h
    D = (S[:, 2 * kb:] - 2.0 * S[:, kb:nb + 1 - kb] + S[:, :nb + 1 - 2 * kb]) / K
    p = h * np.arange(kb, nb + 1 - kb)
    c, s = _cos_sin(enc[p])
    u = np.linspace(-1.0, 1.0, p.size)
    A = np.stack([np.ones(p.size), c, s, u, u * u])          # (5, g): the regressors as rows
    # the normal equations (columns O(1), nearly orthogonal), by numpy's loops (block_sums)
    coef = np.linalg.solve(np.einsum("fk,gk->fg", A, A), np.einsum("fk,ck->fc", A, D))
    model = np.einsum("fc,fk->ck", coef, A)

    def local(j, a, b):
        x = g[j, a - K + 1:b + K + 1] - beta[j] * np.diff(enc[a - K:b + K + 1]) - mean[j]
        i = np.clip(np.searchsorted(p, np.arange(a - K, b + K)), 0, p.size - 1)
        x = x - model[j, i] / K                      # the slow part's rate: D ~ K x rate a sample
        cs = np.concatenate(([0.0], np.cumsum(np.cumsum(x))))
        q = np.arange(K, K + b - a)
        return (cs[q + K] - 2.0 * cs[q] + cs[q - K]) / K

    return D - model, p, local


def find_steps(t, enc, gyro, K, beta, level, quant, floor, sums=None):
    """The steps of the three gyros (module docstring).

    Parameters
    ----------
    t, enc, gyro : numpy.ndarray
        As :func:`step_statistic`.
    K : int
        The span, samples (a multiple of :data:`GRID`).
    beta : numpy.ndarray, shape (3,)
        Each gyro's share of the encoder's turn.
    level : float
        The Bonferroni multiplier of the statistic's robust 1-sigma.
    quant : numpy.ndarray, shape (3,)
        Added to each gyro's threshold (0 where the quantization is dithered), rad.
    floor : float
        The smallest threshold, rad.
    sums : tuple, optional
        As :func:`step_statistic`.

    Returns
    -------
    steps : list of tuple
        ``("gyro", row, j, d)``: gyro ``j``'s increment at the log's ``row`` is off by ``d``
        (rad); ``("encoder", row, None, delta)``: the encoder steps by ``delta`` more than the
        gyros at ``row``; in order of ``row``.
    thr : numpy.ndarray, shape (3,)
        Each gyro's threshold, rad.
    """
    D, p, local = step_statistic(t, enc, gyro, K, beta, sums)
    sub = D[:, ::4]                                  # (a quarter of the grid pins the median)
    sigma = _MAD * _median(np.abs(sub - _median(sub.T)[:, None]).T)
    thr = np.maximum(level * sigma + quant, floor)
    bad = np.abs(D) > thr[:, None]
    if not bad.any():
        return [], thr
    h, N = K // GRID, t.size - 1
    found = []                                      # (increment, channel, d)
    for j in range(3):
        idx = np.flatnonzero(bad[j])
        if not idx.size:
            continue
        for run in np.split(idx, np.flatnonzero(np.diff(idx) > 2 * GRID) + 1):
            g0 = int(run[0]) + int(np.argmax(np.abs(D[j, run[0]:run[-1] + 1])))
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


def check_steps(t, enc, gyro, *, span, jitter, q, qe, level, floor, bound, most, spikes=()):
    """Check 3b of :func:`hse_opt.align.quality.assess`: find the steps, repair or refuse.

    Parameters
    ----------
    t, enc, gyro : numpy.ndarray
        As :func:`step_statistic`.
    span : float
        The span ``K dt``, s (``Thresholds.step_span_s``).
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

    Returns
    -------
    gyro : numpy.ndarray
        A repaired copy, or the input.
    findings : list of tuple
        ``(check, sample, time, action, detail)`` (:class:`hse_opt.align.quality.Finding`'s
        fields).
    """
    N = t.size - 1
    K = GRID * max(1, int(round(span * N / float(t[-1] - t[0]) / GRID)))
    if N < 8 * K:
        return gyro, []
    sums = block_sums(enc, gyro, K // GRID)           # one pass each for the shares and the statistic
    beta = sums[2] / float(enc[-1] - enc[0])
    # the pulses and the encoder's counts are white only when the table's jitter dithers them
    # (a noise of at least one quantum: Widrow); else their bounded error is added
    dithered = (jitter >= qe) & (np.abs(beta) * jitter >= q)
    quant = np.where(dithered, 0.0, bound * (q + np.abs(beta) * qe))
    steps, thr = find_steps(t, enc, gyro, K, beta, level(N / K), quant, floor, sums)
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
