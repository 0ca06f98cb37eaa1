"""A raw log's block sums and the table's deterministic part fitted out of them: the one pass
over the record and the one fit that the Allan analysis (:mod:`hse_opt.align.noise`) and the
quality checks (:mod:`hse_opt.align.quality`, its step test :mod:`hse_opt.align.steps`) share.

Steps
-----
1. Blocks. The increments of each gyro and accelerometer channel (rows 1..n-1 of the log:
   the first row's interval has no encoder angle at its start) are summed over blocks of
   ``B`` samples, ``B`` the whole number of samples nearest to :data:`BLOCK_PERIOD` (64 ms:
   32 samples at 500 Hz, 6 at 100 Hz).
2. The deterministic part, fitted out per channel. The table turns at a constant rate about
   z_b, so in the sensor frame a gyro channel holds the table turn projected on its axis and
   the Earth rate modulated at the table rate; an accelerometer channel holds gravity and the
   tilt's horizontal gravity modulated the same way. Per block ``(t_s, t_e]`` with encoder
   angles ``alpha_s, alpha_e``, ``d alpha = alpha_e - alpha_s``, ``alpha_m`` their mean and
   ``dt = t_e - t_s``, each channel's block sum is fitted (least squares, all six channels in
   one solve) by four regressors: ``dt`` (bias, the constant part of the turn and of
   gravity), ``cos(alpha_m) sinc(d alpha / 2) dt`` and ``sin(alpha_m) sinc(d alpha / 2) dt``
   (the exact integrals of a vector fixed in b0 seen from the turning table, for an angle
   linear within the block: Earth rate, horizontal gravity, their leak through any
   misalignment) and ``d alpha - Omega dt`` (the encoder's turn beyond the mean rate: the
   table's jitter and rate ripple, which the gyros sense as real motion). No calibration and
   no attitude are needed: each coefficient is what the channel shows. The fit is made once
   per log (:attr:`BlockSums.residual`): the quality checks' gyro step test
   (:mod:`hse_opt.align.steps`) works on the same residual.

With ``checks`` (:func:`block_sums`), the same pass also takes what the checks read of the
record while each array is in the cache: the gyros' weighted sums over the same blocks (check
3b) and the encoder's steps' extremes, statistics and weighted sums (checks 1 and 3b).

Where the package's compiled part is built (:mod:`hse_opt.align._compiled`) the pass and the fit
run there (each array read once); else by numpy, the same figures to rounding.

Units: SI (rad, m/s, s).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from hse_opt.align import _compiled
from hse_opt.align._angles import rotate
from hse_opt.align._blas import block_dot, one_thread
from hse_opt.align._quanta import EncoderSteps
from hse_opt.align._stats import cholesky_inverse

__all__ = ["BlockSums", "block_sums", "Residual", "deterministic_residual", "CHANNELS", "BLOCK_PERIOD",
           "MIN_BLOCKS"]

#: the six channels, in this order in every (6, ...) array
CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
#: the block the deterministic part is fitted on, s
BLOCK_PERIOD = 0.064
#: fewest blocks a log must have (an Allan curve of at least 10 cluster times)
MIN_BLOCKS = 32


def _columns_compiled(x, nb, block, out=None, weighted=None):
    """:func:`_block_sums` of ``x`` (n, 3) by the compiled pass (:mod:`hse_opt.align._kernels`)
    where it is built and the columns are contiguous float64 rows, else None; ``weighted``
    (3, nb): also their weighted sums (:func:`_weighted_block_sums`), in the same read."""
    rows = _compiled.rows(x)
    if rows is None:
        return None
    out = np.empty((3, nb)) if out is None else out
    for j in range(3):
        _compiled.kernels.block_sums(rows[j], block, nb, out[j], None if weighted is None else weighted[j])
    return out


def _block_sums(x, stop, nb, block, out=None):
    """Sums of rows 1..stop-1 of ``x`` (n, 3) over blocks of ``block`` rows, shape (3, nb)
    (summed in the array's own memory order: a column-major array as a view of its columns,
    by the compiled pass (:func:`_columns_compiled`) or else by a matrix-vector product on one
    BLAS thread (:mod:`hse_opt.align._blas`), a row-major one by ``reduceat``, 4 times faster
    there than a reshaped sum over the middle axis; the quality checks use it too); written
    into ``out`` (3, nb) when given (its rows contiguous)."""
    x = np.asarray(x)
    done = _columns_compiled(x, nb, block, out)
    if done is not None:
        return done
    if x.T.flags.c_contiguous:
        return block_dot(x.T[:, 1:stop].reshape(3, nb, block), np.ones(block), out=out)
    s = np.add.reduceat(x[1:stop], np.arange(0, nb * block, block), axis=0).T
    if out is None:
        return s
    out[...] = s
    return out


def _weighted_block_sums(x, nb, block):
    """The weighted sums of rows 1 .. nb block of ``x`` (n, 3) over blocks of ``block`` rows
    (row ``i`` of a block weighted ``block + 1 - i``), shape (3, nb), by a matrix-vector
    product on one BLAS thread (:mod:`hse_opt.align._blas`) or by the compiled pass
    (:func:`_columns_compiled`); a row-major ``x`` is copied to columns first. Check 3b's gyro
    sums (:func:`hse_opt.align.steps.weighted_sums`)."""
    g = np.asarray(x).T                              # (3, n): rows (a view for a column-major log)
    if g.strides[1] != g.itemsize:
        g = np.ascontiguousarray(g)                  # (a row-major log: the blocks as contiguous rows)
    weighted = np.empty((3, nb))
    if _columns_compiled(g.T, nb, block, weighted=weighted) is not None:
        return weighted
    return block_dot(g[:, 1:nb * block + 1].reshape(3, nb, block), np.arange(block, 0, -1, dtype=float))


def _encoder_weighted(enc, nb, block):
    """The encoder's weighted sums over blocks of ``block`` steps (:func:`_weighted_step_sums`)
    of the encoder ``enc`` (n,), rad, shape (nb,): by the compiled pass where it is built."""
    enc = np.asarray(enc)
    if _compiled.takes(enc):
        weighted = np.empty(nb)
        _compiled.kernels.encoder_steps(enc, block, nb, weighted)
        return weighted
    return _weighted_step_sums(enc[1:nb * block + 1] - enc[:nb * block], nb, block)


def _weighted_step_sums(steps, nb, block):
    """The encoder's weighted sums over blocks of ``block`` steps: ``sum (enc[start + i] -
    enc[start])``, i = 1 .. block, shape (nb,), rad, from its steps ``steps`` (the first
    ``nb block`` of them at least), rad: steps ``b block .. (b + 1) block - 1`` (into samples
    ``1 + b block .. (b + 1) block``) weighted ``block .. 1`` by a matrix-vector product on
    one BLAS thread; the rounding of the steps, not of the angles (a by-parts sum of the
    angles rounds at their size, up to thousands of rad)."""
    return block_dot(steps[:nb * block].reshape(nb, block), np.arange(block, 0, -1, dtype=float))


def _blocking(log, block_period):
    """``(block, nb)``: samples per block (the whole number nearest ``block_period``, s, at the
    log's mean sample period) and whole blocks over rows 1..n-1.

    Raises
    ------
    ValueError
        The log has fewer than :data:`MIN_BLOCKS` blocks.
    """
    t = np.asarray(log.t, dtype=float)
    n = t.shape[0]
    block = max(1, int(round(block_period * (n - 1) / (t[-1] - t[0]))))
    nb = (n - 1) // block
    if nb < MIN_BLOCKS:
        raise ValueError(f"the log has {n} samples, {nb} blocks of {block} for the Allan analysis; allowed: at "
                         f"least {MIN_BLOCKS * block + 1} samples")
    return block, nb


@dataclass(frozen=True, eq=False)
class BlockSums:
    """A raw log's six channels summed over blocks (module docstring, step 1): one pass over
    the samples that the Allan analysis (:func:`hse_opt.align.noise.noise_from_log`) and the quality checks
    (:func:`hse_opt.align.quality.assess`, whose windows are whole numbers of blocks at the
    default sample rates) share; with ``checks``, also what the checks read of the record
    (:func:`block_sums`: the record's passes in one place).

    Attributes
    ----------
    log : RawLog
        The log summed: the sums serve this object only (a repaired copy is summed anew).
    block : int
        Samples per block.
    sums : numpy.ndarray, shape (6, nb)
        Block ``b``'s sums of rows ``1 + b block .. (b + 1) block`` of the gyros (rad) and
        the accelerometers (m/s), in :data:`CHANNELS` order.
    weighted : numpy.ndarray, shape (3, nb), or None
        The gyros' weighted sums over the same blocks (row ``i`` of a block weighted
        ``block + 1 - i``), rad: check 3b's (:func:`hse_opt.align.steps.weighted_sums`).
    weighted_encoder : numpy.ndarray, shape (nb,), or None
        The encoder's, ``sum (enc[start + i] - enc[start])``, i = 1 .. block, from its steps,
        rad: check 3b's too.
    encoder_steps : hse_opt.align._quanta.EncoderSteps, or None
        What checks 1 and 3 read of the encoder's steps (their extremes and statistics; the
        steps themselves are not kept), taken from the same steps.
    """

    log: object
    block: int
    sums: np.ndarray
    weighted: np.ndarray = None
    weighted_encoder: np.ndarray = None
    encoder_steps: EncoderSteps = None

    def of(self, log, block):
        """The sums when they are ``log``'s over blocks of ``block`` samples, else None."""
        return self.sums if self.log is log and self.block == block else None

    @functools.cached_property
    def residual(self):
        """The deterministic part fitted out of these sums (:func:`deterministic_residual`),
        fitted once for the quality checks' step test and the Allan analysis."""
        return _fit_residual(self.log, self.block, self.sums)


def block_sums(log, *, block_period=BLOCK_PERIOD, checks=True):
    """The six channels of ``log`` summed over the Allan analysis' blocks, once for both
    :func:`hse_opt.align.noise.noise_from_log` and :func:`hse_opt.align.quality.assess` (their ``sums``).

    Parameters
    ----------
    log : RawLog
    block_period : float
        Target block length, s (rounded to whole samples).
    checks : bool
        Also take what the quality checks read of the record: check 3b's weighted sums of
        the gyros (right after their plain sums) and of the encoder (:attr:`BlockSums.weighted`,
        :attr:`BlockSums.weighted_encoder`; the bytes :func:`hse_opt.align.steps.weighted_sums`
        gives) and, from the same pass over the encoder's steps, what checks 1 and 3 read of
        them (:attr:`BlockSums.encoder_steps`). Nothing of a record's size is kept (a 2.4-MB
        array of the encoder's steps kept here through the alignment made ``align`` 0.07 ms
        slower, 2026-11-26). False for the Allan analysis alone.

    Returns
    -------
    BlockSums

    Raises
    ------
    ValueError
        The log has fewer than :data:`MIN_BLOCKS` blocks.
    """
    block, nb = _blocking(log, block_period)
    compiled = _compiled_checks_pass(log, block, nb) if checks else None
    if compiled is not None:
        return compiled
    stop = nb * block + 1
    sums = np.empty((6, nb))
    _block_sums(log.gyro, stop, nb, block, out=sums[:3])
    if not checks:
        _block_sums(log.accel, stop, nb, block, out=sums[3:])
        return BlockSums(log=log, block=block, sums=sums)
    weighted = _weighted_block_sums(log.gyro, nb, block)         # (while the gyros are in the cache)
    _block_sums(log.accel, stop, nb, block, out=sums[3:])
    enc = log.encoder
    steps = enc[1:] - enc[:-1]
    return BlockSums(log=log, block=block, sums=sums, weighted=weighted,
                     weighted_encoder=_weighted_step_sums(steps, nb, block), encoder_steps=EncoderSteps.of(enc, steps))


def _compiled_checks_pass(log, block, nb):
    """:func:`block_sums` with ``checks`` by the compiled pass (:mod:`hse_opt.align._kernels`:
    one read of each array), or None where it is not built or the log's arrays are not
    contiguous float64 rows (a row-major log)."""
    enc = np.asarray(log.encoder)
    if not _compiled.takes(enc) or enc.shape[0] < 2:
        return None
    sums, weighted = np.empty((6, nb)), np.empty((3, nb))
    if _columns_compiled(log.gyro, nb, block, sums[:3], weighted) is None or \
            _columns_compiled(log.accel, nb, block, sums[3:]) is None:
        return None
    weighted_encoder = np.empty(nb)
    largest, smallest = _compiled.kernels.encoder_steps(enc, block, nb, weighted_encoder)
    return BlockSums(log=log, block=block, sums=sums, weighted=weighted, weighted_encoder=weighted_encoder,
                     encoder_steps=EncoderSteps.of(enc, extremes=(largest, smallest)))

#: largest angle the series of :func:`_cos_sin_small` takes, rad (error |d|^7 / 5040 < 3e-9)
_SERIES_MAX = 0.2
#: entries of the short phase table of :func:`_cos_sin`
_TABLE = 64


def _cos_sin_small(d, top=None, sinc=False):
    """``(cos d, sin d)`` by their series when every ``|d| <= _SERIES_MAX``, else numpy's: to
    ``d^2`` and ``d^3`` when ``top``, the largest ``|d|`` (taken here if None), is at most 1e-3
    (errors below 5e-14: the encoder's deviation from a steady turn), to ``d^4`` and ``d^5`` up to
    0.03 (below 2e-12: half a block's turn), else to ``d^6`` and ``d^5`` (below 3e-9).
    ``sinc``: also ``sin(d) / d`` (1 at 0), the sine's series before its factor ``d`` (its error
    the sine's over ``top``)."""
    top = float(np.abs(d).max(initial=0.0)) if top is None else top
    if not top <= _SERIES_MAX:      # (False for NaN too)
        c, s = np.cos(d), np.sin(d)
        return (c, s, np.divide(s, d, out=np.ones_like(d), where=d != 0.0)) if sinc else (c, s)
    q = d * d
    if top <= 1e-3:
        c = q * -0.5
        s = q * (-1.0 / 6.0)
    elif top <= 0.03:
        c = q * (1.0 / 24.0)
        c -= 0.5
        c *= q
        s = q * (1.0 / 120.0)
        s -= 1.0 / 6.0
        s *= q
    else:
        c = 1.0 - q * (0.5 - q * (1.0 / 24.0 - q / 720.0))
        s = 1.0 - q * (1.0 / 6.0 - q / 120.0)
        return (c, s * d, s) if sinc else (c, s * d)
    c += 1.0
    s += 1.0
    if sinc:
        return c, s * d, s
    s *= d
    return c, s


def _cos_sin(a):
    """``(cos a, sin a)`` of angles (n,) that grow nearly linearly with their index (the
    encoder at the block edges): the linear phase from two short tables of ``exp(i phase)``
    (``_TABLE`` steps and every ``_TABLE``-th step; one complex outer product), the deviation
    from it by series and the angle-addition formulas; numpy's cos and sin where the
    deviation exceeds ``_SERIES_MAX`` (a stall, a table at rest). A tenth of numpy's cost."""
    n = a.shape[0]
    step = (a[-1] - a[0]) / max(n - 1, 1)
    d = a - (a[0] + step * np.arange(n))
    top = float(np.abs(d).max())
    if not top <= _SERIES_MAX:
        return np.cos(a), np.sin(a)
    low = np.exp(1j * step * np.arange(_TABLE))
    high = np.exp(1j * (a[0] + _TABLE * step * np.arange(-(-n // _TABLE))))
    phase = np.multiply.outer(high, low).ravel()[:n]
    cd, sd = _cos_sin_small(d, top)
    c, s = rotate(phase.real, phase.imag, cd, sd, np.empty((2, n)), np.empty(n))
    return c, s


def _regressors(ce, se, da, dt, rate):
    """The four regressors (module docstring, step 2) of spans with ``(cos, sin)`` of their
    start angle ``ce``, ``se``, encoder turn ``da`` (rad) and length ``dt`` (s), shape
    (4, spans): the cos/sin terms at the midpoint angle (angle addition with ``da / 2``)
    times ``sinc(da / 2) dt``."""
    X = np.empty((4,) + da.shape)
    h = 0.5 * da
    ch, sh, w = _cos_sin_small(h, sinc=True)
    rotate(ce, se, ch, sh, X[1:3], X[3])
    w *= dt
    X[1:3] *= w
    X[0] = dt
    np.multiply(dt, -rate, out=X[3])
    X[3] += da
    return X


@dataclass(frozen=True, eq=False)
class Residual:
    """The deterministic part fitted out (module docstring, step 2).

    Attributes
    ----------
    blocks : numpy.ndarray, shape (6, nb)
        Block sums less the fitted part: rad (gyros), m/s (accelerometers).
    tau0 : float
        Mean block length, s.
    block : int
        Samples per block.
    coefficients : numpy.ndarray, shape (4, 6)
        Each channel's coefficients of the regressors ``dt``, ``cos``, ``sin``, ``d alpha -
        Omega dt`` (rad or m/s per s, per s, per s, per rad).
    rate : float
        Omega, the encoder's mean rate, rad/s.
    edge_cos, edge_sin : numpy.ndarray, shape (nb + 1,)
        cos and sin of the encoder angle at the block edges (samples 0, B, 2B, ...).
    regressors : numpy.ndarray, shape (4, nb)
        The four regressors of each block (``dt`` s, the cos and sin terms s, ``d alpha -
        Omega dt`` rad), in the order of ``coefficients``.
    """

    blocks: np.ndarray
    tau0: float
    block: int
    coefficients: np.ndarray
    rate: float
    edge_cos: np.ndarray
    edge_sin: np.ndarray
    regressors: np.ndarray


def deterministic_residual(log, *, block_period=BLOCK_PERIOD, sums=None):
    """Block sums of the six channels with the table's deterministic part fitted out
    (module docstring, steps 1-2).

    Parameters
    ----------
    log : RawLog
        Any object with ``t`` (n,) s, ``gyro`` (n, 3) rad, ``accel`` (n, 3) m/s and
        ``encoder`` (n,) rad (unwrapped).
    block_period : float
        Target block length, s (rounded to whole samples).
    sums : BlockSums, optional
        The log's block sums when already taken (:func:`block_sums`; used when they are this
        log's over these blocks: their residual is fitted once, for both the quality checks'
        step test and the Allan analysis).

    Returns
    -------
    Residual

    Raises
    ------
    ValueError
        The log has fewer than :data:`MIN_BLOCKS` blocks.
    """
    block, _ = _blocking(log, block_period)
    if sums is None or sums.of(log, block) is None:
        sums = block_sums(log, block_period=block_period, checks=False)
    return sums.residual


def _fit_residual(log, block, y):
    """:func:`deterministic_residual` of ``log``'s block sums ``y`` (6, nb) over ``block`` samples."""
    t, enc = np.asarray(log.t, dtype=float), np.asarray(log.encoder, dtype=float)
    nb = y.shape[1]
    compiled = _fit_compiled(t, enc, block, y)
    if compiled is not None:
        return compiled
    stop = nb * block + 1
    # the block edges gathered once (each strided read of the record touches a cache line an edge)
    a, te = enc[:stop:block].copy(), t[:stop:block].copy()
    rate = float((a[-1] - a[0]) / (te[-1] - te[0]))
    ce, se = _cos_sin(a)
    X = _regressors(ce[:-1], se[:-1], np.diff(a), np.diff(te), rate)        # (4, nb)
    with one_thread():       # (the same bytes whatever the threads: hse_opt.align._blas)
        G, H = X @ X.T, X @ y.T
        coef = _normal_solve(G, H)
        residual = y - coef.T @ X
    return Residual(blocks=residual, tau0=float((te[-1] - te[0]) / nb), block=block,
                    coefficients=coef, rate=rate, edge_cos=ce, edge_sin=se, regressors=X)


def _fit_compiled(t, enc, block, y):
    """:func:`_fit_residual` by the compiled kernels (:mod:`hse_opt.align._compiled`: the block
    edges' cos and sin, the regressors and the normal equations in one pass, the residual in
    another; the same steps) where they are built and the arrays are contiguous float64, else
    None."""
    if not _compiled.takes(t, enc, y):
        return None
    kernels = _compiled.kernels
    nb = y.shape[1]
    ce, se, X, G, H = np.empty(nb + 1), np.empty(nb + 1), np.empty((4, nb)), np.empty((4, 4)), np.empty((4, 6))
    rate = kernels.fit(enc, t, block, nb, y, ce, se, X, G, H)
    coef = np.ascontiguousarray(_normal_solve(G, H))
    residual = np.empty_like(y)
    kernels.residual(y, coef, X, residual)
    return Residual(blocks=residual, tau0=float((t[nb * block] - t[0]) / nb), block=block, coefficients=coef,
                    rate=rate, edge_cos=ce, edge_sin=se, regressors=X)


def _normal_solve(G, H):
    """The least-squares coefficients (k, c) from the normal equations ``G coef = H`` (G (k, k)
    symmetric positive semi-definite, H (k, c)), the columns scaled to unit norm: a term whose
    column is zero or that the others determine (an eigenvalue of the scaled matrix below
    1e-12 of the largest: the table's jitter with a perfect encoder, the sinusoid of a table
    at rest) is left out by the eigen-decomposition's pseudo-inverse. Where the scaled
    matrix's determinant (the product of its eigenvalues) exceeds ``1e-12 k^k``, which
    ``trace = k`` makes the bound of every eigenvalue above 1e-12 of the largest, its inverse is
    the pseudo-inverse and comes from a Cholesky factorisation in Python floats
    (:func:`hse_opt.align._stats.cholesky_inverse`): no LAPACK call, whose first after the
    alignment has run costs tens of microseconds."""
    k = G.shape[0]
    norm = np.sqrt(np.diagonal(G)).copy()
    norm[norm == 0] = 1.0
    Gs = G / np.outer(norm, norm)
    Hs = H / norm[:, None]
    factor = cholesky_inverse(Gs)
    if factor is None or not factor[1] > 1e-12 * k ** k:
        ev, V = np.linalg.eigh(Gs)
        keep = ev > 1e-12 * ev[-1]
        return ((V[:, keep] / ev[keep]) @ (V[:, keep].T @ Hs)) / norm[:, None]
    Li = factor[0]
    return (Li.T @ (Li @ Hs)) / norm[:, None]
