"""The sensors' noise from the raw logs themselves: Allan deviation and the IEEE Std 952 terms.

Steps
-----
1. Blocks: each channel summed over blocks of ``B`` samples, ``B`` the whole number of
   samples nearest to :data:`BLOCK_PERIOD` (64 ms: 32 samples at 500 Hz, 6 at 100 Hz), and
2. the table's deterministic part fitted out of those sums (a constant rate, the Earth's rate
   and gravity turning with the table, the encoder's steps beyond the mean rate), once per log
   for the Allan analysis and the quality checks: :mod:`hse_opt.align.blocks` (its module
   docstring has both steps).

   What remains and is analysed: the sensors' own noise (white rate or specific-force noise,
   pulse quantization, flicker, random walk, drift) *plus* the encoder's own angle noise
   (its resolution, ``resolution / sqrt(12)`` rad white in angle) times the channel's share of
   the turn (0.577 for a gyro on the body diagonal) - the table turn is removed through the
   encoder, so the quantization term of a gyro is that of its pulses and of the encoder
   together (an upper bound on the pulse quantization alone; the alignment processor removes
   the turn through the same encoder). Effects with another time course stay in and show at
   long cluster times: the bias's warm-up transient and temperature drift,
   table wobble at harmonics of the turn.
3. Overlapping Allan deviation, vectorised numpy (:func:`allan_deviation`). Clusters of ``m``
   blocks on an octave grid (``m = 2^j``; :func:`allan_deviation` alone defaults to half
   octaves) up to half the record: for each the
   second difference of the cumulative sum ``theta`` of the residual,
   ``sigma^2(tau) = <(theta_{k+2m} - 2 theta_{k+m} + theta_k)^2> / (2 tau^2)``, ``tau = m
   tau0``, averaged over start points ``k = 0, step, 2 step, ..``. The lattice ``s`` is the
   largest power of two up to the shortest cluster's ``max(1, (n + 1 - 2m) // MAX_TERMS)``;
   a cluster shorter than ``s`` takes its own such stride, every other one ``step = s``: at
   most 2 x :data:`MAX_TERMS` start points (the short cluster times, where that many nearly
   independent clusters pin each value to 1.6 %), fully overlapping where ``s = 1`` (a log
   of fewer than 2 x :data:`MAX_TERMS` blocks, 4.4 minutes). Why the long clusters take the
   lattice and not their own stride (1 to ``2s - 1``; 3, 2 and 1 for the three longest of a
   10-minute log): every start point of their own stride lies within ``s - 1`` blocks of a
   lattice point (for those three, under 0.3 % of the cluster), so the lattice's start
   points carry the same information (the independent clusters, ``min(n / m, start
   points)``, unchanged on the 36 logs below), and the whole curve comes from the lattice sums
   without shifting them off the lattice (0.23 -> 0.10 ms on a 10-minute log). On 36 logs
   of six systems, against their own strides: the three longest cluster times of the
   10-minute logs moved by up to 6.2 % (their own 1-sigma there: 25 to 62 %), the fitted
   terms by at most 0.16 of their own 1-sigma (rms 0.011), nothing else. The number of
   independent clusters is taken as ``min(n / m, start points)``. For octave cluster sizes
   (those of a log) the second differences come from sums over the lattice and their
   doubling, not from a cumulative sum over the record (:func:`_octave_squares`: the same
   start points, rounding that does not grow with the record, a fraction of the cost).
   Clusters shorter than a block (1, 2, 4, 8, 16 samples at 500 Hz) come
   from the raw samples of :data:`SEGMENTS` stretches of :data:`SEGMENT_SAMPLES` samples
   spread over the log, fully overlapping within each, the fitted deterministic part taken
   off every sample. (Not in single precision, though that halves the memory traffic of the
   sums and differences, 0.20 -> 0.17 ms on a 10-minute log, and moved the deviations by at
   most 9e-7, the terms by 1.3e-5 of their 1-sigma on 36 logs of six systems: a rounding of
   6e-8 amplifies a difference of 1e-9 in the samples, as between a log and its stand CSV,
   into the filter's tuning and a heading 1.1e-6 arcsec apart.)
4. IEEE Std 952-1997 Annex C terms: the least-squares fit of the Allan variance model
   ``sigma^2(tau) = sum_k A_k tau^k``, k = -2..1, with every ``A_k >= 0``, weighted by the
   estimate's own variance (relative standard deviation ``sqrt(2 / (K - 1))`` of a
   chi-square with ``K - 1`` degrees of freedom, ``K`` the independent clusters; iterated
   three times with the fitted model in the weights, so that a low draw does not weigh
   more). Where that fit misses its points by far more than their scatter (weighted
   residuals above :data:`MISFIT` times their degrees of freedom) the model itself is off,
   and the channel is refitted with the model's own error, :data:`MODEL_ERROR` (10 %) of
   each variance, added in quadrature: the four terms idealise (a pulse counter that no
   noise dithers - an accelerometer on a static base - has a quantization error that is not
   white, and its shortest clusters sit up to 35 % below ``sqrt(3) Q / tau``; flicker bends),
   and the few shortest points, each worth tens of thousands of clusters, would otherwise
   decide the whole fit (simulated accelerometers: VRW 17 % high; refitted, 3 %). The terms
   (rate units; angle for a gyro, velocity for an accelerometer):

   ==================  =====  ===================================================
   term                slope  from the coefficient
   ==================  =====  ===================================================
   quantization Q      -1     ``sigma^2 = 3 Q^2 / tau^2``: Q = sqrt(A_-2 / 3)
   random walk N       -1/2   ``sigma^2 = N^2 / tau``: N = sqrt(A_-1) (ARW, VRW)
   bias instability B  0      ``sigma^2 = (2 ln 2 / pi) B^2``: the flicker floor,
                              approximated as flat (its exact curve bends at
                              ``tau`` near the flicker's cut-off)
   rate random walk K  +1/2   ``sigma^2 = K^2 tau / 3``: K = sqrt(3 A_1)
   ==================  =====  ===================================================

   The rate ramp (slope +1) is not fitted: on one record a random walk and a ramp look
   alike, and with both free the fit splits the long cluster times between them at random; a
   drift (the warm-up transient, temperature) therefore reads as rate random walk.

   The non-negative least squares is solved exactly (:mod:`hse_opt.align.allan_fit`): the
   set of free terms that meets the Karush-Kuhn-Tucker conditions, found among all 16 from
   the Schur complements of the normal equations on each (all channels in one table), which
   also give the free terms' 1-sigma.
5. A campaign (:func:`combine_noise`): the Allan variances of its logs at equal cluster
   times pooled with their independent clusters as weights, then fitted as one curve.

Why numpy and not allantools: allantools computes one channel at a time and every cluster
time fully overlapping (O(n) per cluster time per channel), which costs tens of ms on a
10-minute 500 Hz log's six channels where this step has a budget of a few ms next to the
alignment (``benchmarks/align.py``); it would also be a run-time dependency of the data
path for one formula. The tests use allantools as the independent reference for the curve.
The clusters shorter than a block run compiled where the package's compiled part is built
(:mod:`hse_opt.align._compiled`: the same steps, 0.27 -> 0.14 ms), else by numpy.

Units: SI inside (rad, rad/s, m/s, m/s^2, s); the RUNS.csv columns
(:data:`NOISE_COLUMNS`, :meth:`NoiseFigures.columns`) carry theirs in their names.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from hse_opt import units
from hse_opt.align import _compiled
from hse_opt.align._angles import rotate
from hse_opt.align.allan_fit import MISFIT, MODEL_ERROR, _POWERS, fit_allan
from hse_opt.align.blocks import (BLOCK_PERIOD, CHANNELS, BlockSums, Residual, _cos_sin_small, block_sums,
                                  deterministic_residual)
from hse_opt.align.processor import _vecdot

__all__ = ["NoiseFigures", "noise_from_log", "combine_noise", "allan_deviation", "fit_allan",
           "deterministic_residual", "Residual", "BlockSums", "block_sums", "CHANNELS", "TERMS", "NOISE_COLUMNS",
           "BLOCK_PERIOD", "MAX_TERMS", "MODEL_ERROR", "MISFIT"]

#: the fitted terms, in the order of the powers -2..1 of tau in the Allan variance model
TERMS = ("quantization", "random_walk", "bias_instability", "rate_random_walk")
#: at most about this many (at most twice) start points per cluster time
MAX_TERMS = 2048
#: clusters shorter than a block come from this many stretches of the raw samples ...
SEGMENTS = 8
#: ... of this many samples each (2 s at 500 Hz; 8192 samples, 3 % of a 10-minute log)
SEGMENT_SAMPLES = 1024
_FLICKER = 2.0 * math.log(2.0) / math.pi

#: RUNS.csv columns written by ``hse-opt align``: name -> description (the unit in the name)
NOISE_COLUMNS = {
    "gyro_arw_dph_rthz": "the three gyros' mean angle random walk, deg/h/sqrt(Hz) (= deg/h sqrt(s); "
                         "60 deg/h/sqrt(Hz) = 1 deg/sqrt(h)); TRUTH.toml's gyro.arw_dph_rthz",
    "gyro_bias_instability_dph": "the gyros' mean bias instability, deg/h",
    "gyro_quantization_arcsec": "the gyros' mean angle quantization (white angle noise), arcsec",
    "gyro_rrw_dph_rth": "the gyros' mean rate random walk, deg/h/sqrt(h)",
    "accel_vrw_ug_rthz": "the accelerometers' mean velocity random walk, ug/sqrt(Hz); TRUTH.toml's "
                         "accel.vrw_ug_rthz",
    "accel_bias_instability_ug": "the accelerometers' mean bias instability, ug",
    "accel_quantization_mps": "the accelerometers' mean velocity quantization (white velocity noise), m/s",
}


@dataclass(frozen=True, eq=False)
class NoiseFigures:
    """The Allan curve and the IEEE 952 terms of one log or of a campaign (SI).

    Attributes
    ----------
    tau : numpy.ndarray, shape (k,)
        Cluster times, s.
    adev : numpy.ndarray, shape (6, k)
        Overlapping Allan deviation per channel (:data:`CHANNELS`): rad/s for the gyros,
        m/s^2 for the accelerometers.
    clusters : numpy.ndarray, shape (k,)
        Independent clusters behind each point (its relative error is about
        ``1 / sqrt(2 (clusters - 1))``).
    coefficients : numpy.ndarray, shape (6, 4)
        ``A_k`` of ``sigma^2(tau) = sum_k A_k tau^k``, k = -2..1 (SI: rad^2/s^2 s^k for the
        gyros, (m/s^2)^2 s^k for the accelerometers), each >= 0.
    coefficients_std : numpy.ndarray, shape (6, 4)
        Their 1-sigma from the weighted fit; NaN for a term held at zero.
    n_logs : int
        Logs behind the figures.
    """

    tau: np.ndarray
    adev: np.ndarray
    clusters: np.ndarray
    coefficients: np.ndarray
    coefficients_std: np.ndarray
    n_logs: int = 1

    def term(self, name):
        """One term per channel, shape (6,), SI (see the module docstring's table): ``name`` in
        :data:`TERMS`. quantization rad | m/s; random_walk rad/sqrt(s) | m/s/sqrt(s);
        bias_instability rad/s | m/s^2; rate_random_walk rad/s/sqrt(s) | m/s^2/sqrt(s)."""
        factor = {"quantization": 1 / 3, "random_walk": 1.0, "bias_instability": 1 / _FLICKER,
                  "rate_random_walk": 3.0}[name]
        return np.sqrt(self.coefficients[:, TERMS.index(name)] * factor)

    @property
    def quantization(self):
        """(6,): Q, rad (gyros) and m/s (accelerometers)."""
        return self.term("quantization")

    @property
    def random_walk(self):
        """(6,): N, rad/sqrt(s) (angle random walk) and m/s/sqrt(s) (velocity random walk)."""
        return self.term("random_walk")

    @property
    def bias_instability(self):
        """(6,): B, rad/s and m/s^2."""
        return self.term("bias_instability")

    @property
    def rate_random_walk(self):
        """(6,): K, rad/s/sqrt(s) and m/s^2/sqrt(s)."""
        return self.term("rate_random_walk")

    def model_adev(self, tau=None):
        """The fitted curve ``sqrt(sum_k A_k tau^k)``, shape (6, k), at ``tau`` (s; default the
        measured cluster times)."""
        tau = self.tau if tau is None else np.asarray(tau, dtype=float)
        return np.sqrt(self.coefficients @ (tau[None, :] ** _POWERS[:, None]))

    def tuning(self):
        """The alignment filter's noise from these figures, as keyword arguments of
        ``AlignConfig`` (``dataclasses.replace(config, **figures.tuning())``), one per sensor
        axis (tuples of 3, x y z): ``arw`` (the gyros' N, rad/sqrt(s)), ``vrw`` (the
        accelerometers' N, m/s/sqrt(s)), ``gyro_pulse`` and ``accel_pulse`` (the quanta whose
        white noise ``q / sqrt(12)`` is the measured Q: ``sqrt(12) Q``, rad and m/s)."""
        q, n = self.quantization, self.random_walk
        k = math.sqrt(12.0)
        return {"arw": tuple(n[:3].tolist()), "vrw": tuple(n[3:].tolist()),
                "gyro_pulse": tuple((k * q[:3]).tolist()), "accel_pulse": tuple((k * q[3:]).tolist())}

    def columns(self):
        """The RUNS.csv columns (:data:`NOISE_COLUMNS`), file units: each the mean over the
        three gyros or the three accelerometers."""
        g, a = slice(0, 3), slice(3, 6)
        return {
            "gyro_arw_dph_rthz": float(self.random_walk[g].mean() / units.DEG_PER_H),
            "gyro_bias_instability_dph": float(self.bias_instability[g].mean() / units.DEG_PER_H),
            "gyro_quantization_arcsec": float(self.quantization[g].mean() / units.ARCSEC),
            "gyro_rrw_dph_rth": float(self.rate_random_walk[g].mean() * math.sqrt(units.HOUR)
                                      / units.DEG_PER_H),
            "accel_vrw_ug_rthz": float(self.random_walk[a].mean() / units.MICRO_G),
            "accel_bias_instability_ug": float(self.bias_instability[a].mean() / units.MICRO_G),
            "accel_quantization_mps": float(self.quantization[a].mean()),
        }

    def summary(self):
        """One line of the figures in file units (the means over the three sensors); a term that
        no sensor of the three resolves (its coefficient held at zero by the non-negative fit, or
        within twice its own 1-sigma of zero) is said to be not resolved by the logs, not printed
        as a measured figure (its RUNS.csv column keeps the fitted mean)."""
        c = self.columns()
        with np.errstate(invalid="ignore"):
            held = ~(self.coefficients > 2.0 * self.coefficients_std)     # (6, 4); NaN: held at 0

        def fig(key, term, group, text):
            j = TERMS.index(term)
            rows = slice(0, 3) if group == "gyro" else slice(3, 6)
            return "not resolved by these logs" if held[rows, j].all() else text.format(c[key])

        return (f"gyro ARW {c['gyro_arw_dph_rthz']:.4g} deg/h/sqrt(Hz) ({c['gyro_arw_dph_rthz'] / 60:.3g} "
                f"deg/sqrt(h)), bias instability "
                + fig("gyro_bias_instability_dph", "bias_instability", "gyro", "{:.3g} deg/h")
                + ", quantization " + fig("gyro_quantization_arcsec", "quantization", "gyro", "{:.3g} arcsec")
                + ", rate random walk " + fig("gyro_rrw_dph_rth", "rate_random_walk", "gyro", "{:.3g} deg/h/sqrt(h)")
                + f"; accelerometer VRW {c['accel_vrw_ug_rthz']:.4g} ug/sqrt(Hz), bias instability "
                + fig("accel_bias_instability_ug", "bias_instability", "accel", "{:.3g} ug")
                + ", quantization " + fig("accel_quantization_mps", "quantization", "accel", "{:.3g} m/s"))


@functools.lru_cache(maxsize=32)
def _stretches(n, block, length, count):
    """The stretches of :func:`_short_allan` for ``n`` increments (cached per log shape):
    ``(first, edges, blocks, starts)``, the first sample edge of each (count,), its sample
    edges (count, length + 1), the block each of its samples starts in and that block's first
    sample edge (count, length); int, read-only."""
    first = np.round(np.linspace(0, (n - length) // block, count)).astype(np.int64) * block
    edges = first[:, None] + np.arange(length + 1)
    blocks = (first // block)[:, None] + np.arange(length) // block
    starts = blocks * block
    for a in (first, edges, blocks, starts):
        a.flags.writeable = False
    return first, edges, blocks, starts


def _short_allan(log, residual, sizes, segments=SEGMENTS, length=SEGMENT_SAMPLES):
    """Allan deviation at clusters shorter than a block (``sizes`` in samples) from the raw
    samples of ``segments`` stretches of ``length`` samples spread evenly over the log (each
    starting at a block edge), fully overlapping within each: the fitted deterministic part
    is taken off every sample (its angle by the angle-addition series from the block edge's;
    the rule's error over one sample, ``d alpha^2 / 24``, is below 1e-6), the Allan
    difference of two adjacent sums of ``m`` samples (``sizes``: powers of two, the sums by
    doubling). Returns ``(tau, adev (6, k), clusters)``, ``clusters = min(n, segments x length) / m``.

    Its cost (10-minute log, CPU after ``align``, 2026-11-26): about 0.25 ms, 0.05 of it reading
    the stretches from memory (0.025 when they are in the cache). Measured and not taken, none
    faster in double precision: the stretches gathered by one ``np.take`` per array (2.5-2.8 times the
    slices' time); the fitted part taken off by one product with the samples (6 x 10) or while
    copying them; each stretch's cos and sin by phase tables (:func:`hse_opt.align.blocks._cos_sin`'s
    route: within 1e-12 of these deviations); the squares from the sums' own squares (``sum d_m^2
    = 2 (2 F_m - ends) - F_2m``: a pass fewer a level, more small calls); the first differences and
    pair sums from one complex product; the straddling differences zeroed for one dot product a
    channel. The cos and sin interpolated between the block edges' (0.015-0.022 ms less) leave a
    noise-free log at 100 deg/s an accelerometer VRW 1e3 times that of the series (not taken)."""
    t, enc = np.asarray(log.t, dtype=float), np.asarray(log.encoder, dtype=float)
    n = t.shape[0] - 1                                            # increments: rows 1..n
    dt = (t[-1] - t[0]) / n
    block = residual.block
    length = min(length, n)
    count = max(1, min(segments, n // length))
    first, edges, blocks, starts = _stretches(n, block, length, count)
    compiled = _short_compiled(log, residual, t, enc, first, length, sizes, count)
    if compiled is not None:
        ms, norm, clusters = _short_plan(tuple(sizes), count, length)
        return ms * dt, np.sqrt(compiled.sum(axis=1) / norm) / (ms * dt), clusters.copy()
    rows = 6 * count
    work = np.empty((2, rows * length))                           # r, then sums and d in turn
    r = work[0].reshape(6, count, length)
    gyro, accel = np.asarray(log.gyro), np.asarray(log.accel)
    X = np.empty((4, count, length))                              # the regressors per sample
    a, te = np.empty((count, length + 1)), X[0]
    for j, s0 in enumerate(first.tolist()):                      # samples s0 + 1 .. s0 + length
        r[:3, j] = gyro[s0 + 1:s0 + 1 + length].T
        r[3:, j] = accel[s0 + 1:s0 + 1 + length].T
        a[j] = enc[s0:s0 + length + 1]
        np.subtract(t[s0 + 1:s0 + 1 + length], t[s0:s0 + length], out=te[j])
    h, da = X[0], np.subtract(a[:, 1:], a[:, :-1], out=X[3])
    # each sample's mid angle from the angle of the block edge it starts in: cos and sin by
    # the angle-addition formulas from the edge's (taken per block where the stretch is whole
    # blocks, per sample otherwise)
    mid = np.multiply(da, 0.5, out=X[1])
    mid += a[:, :-1]
    if length % block:
        mid -= enc.take(starts)
        ce, se = residual.edge_cos.take(blocks), residual.edge_sin.take(blocks)
    else:
        per_block = (count, length // block, block)
        a_edge = a[:, :-1:block, None]
        mid = mid.reshape(per_block)
        mid -= a_edge
        ce, se = (v.take(blocks[:, ::block])[:, :, None] for v in (residual.edge_cos, residual.edge_sin))
    cd, sd = _cos_sin_small(mid)
    rotate(ce, se, cd, sd, X[1:3].reshape((2,) + cd.shape), work[1, :count * length].reshape(cd.shape))
    X[1:3] *= h
    da -= residual.rate * h
    # (each entry a dot product of four: the same bytes whatever the threads, and below
    # OpenBLAS's size for a second thread)
    det = np.matmul(residual.coefficients.T, X.reshape(4, -1), out=work[1].reshape(6, -1))
    r -= det.reshape(r.shape)
    # sums of m consecutive samples by doubling (sizes are powers of two): cheaper than the
    # cumulative sum; the Allan difference is then of two adjacent sums. The 6 x count rows
    # are doubled as one flat array (a sum that straddles two rows is never read: each row's
    # first length - 2m + 1 differences are), the sums and the differences taking the two
    # buffers in turn
    ms, norm, clusters = _short_plan(tuple(sizes), count, length)
    ss = np.empty((rows, len(ms)))
    size, width, at = work.shape[1], 1, 0                         # the sums of width in work[at]
    for i, m in enumerate(sizes):
        while width < m:
            sums = work[at]
            np.add(sums[width:size], sums[:size - width], out=work[1 - at, :size - width])
            size, width, at = size - width, 2 * width, 1 - at
        sums, d = work[at], work[1 - at]
        np.subtract(sums[m:size], sums[:size - m], out=d[:size - m])
        valid = d.reshape(rows, length)[:, :length - 2 * m + 1]
        _vecdot(valid, valid, out=ss[:, i])
    adev = np.sqrt(ss.reshape(6, count, -1).sum(axis=1) / norm) / (ms * dt)
    return ms * dt, adev, clusters.copy()


def _short_compiled(log, residual, t, enc, first, length, sizes, count):
    """:func:`_short_allan`'s squared differences, shape (6, count, len(sizes)), by the compiled
    kernel (:mod:`hse_opt.align._kernels`, the same steps in one pass a stretch) where it is
    built and the log's arrays are contiguous float64 rows; else None (numpy's route)."""
    rows = [_compiled.rows(log.gyro), _compiled.rows(log.accel)]
    if any(r is None for r in rows) or not _compiled.takes(t, enc) or any(m & (m - 1) for m in sizes):
        return None
    ss = np.empty((6, count, len(sizes)))
    _compiled.kernels.short_allan((*rows[0], *rows[1]), enc, t, first, length, residual.block,
                        np.ascontiguousarray(residual.coefficients), residual.rate, residual.edge_cos,
                        residual.edge_sin, [int(m) for m in sizes], ss)
    return ss


@functools.lru_cache(maxsize=32)
def _short_plan(sizes, count, length):
    """The constants of :func:`_short_allan` for cluster ``sizes`` (tuple, samples) over
    ``count`` stretches of ``length`` samples: ``(sizes, norm, clusters)``, float arrays (k,),
    read-only: ``norm = 2 count (length - 2m + 1)`` (twice the start points) and the
    independent clusters ``count length / m``.

    Raises
    ------
    ValueError
        A size is no power of two.
    """
    bad = [m for m in sizes if m < 1 or m & (m - 1)]
    if bad:
        raise ValueError(f"short cluster sizes must be powers of two, got {bad[0]}")
    ms = np.asarray(sizes)
    norm = 2.0 * count * (length - 2 * ms + 1)
    clusters = np.array([count * length / m for m in sizes])
    for a in (ms, norm, clusters):
        a.flags.writeable = False
    return ms, norm, clusters


def cluster_sizes(n, steps_per_octave=2):
    """Cluster sizes ``m = round(2^(j / steps))``, unique, 1 <= m <= n // 2 (int array)."""
    top = max(1, n // 2)
    j = np.arange(int(math.floor(steps_per_octave * math.log2(top))) + 1)
    if steps_per_octave == 1:                                 # whole octaves: distinct already
        return np.left_shift(1, j)
    return np.unique(np.round(2.0 ** (j / steps_per_octave)).astype(np.int64))


def allan_deviation(increments, tau0, *, max_terms=MAX_TERMS, sizes=None):
    """Overlapping Allan deviation of the rate whose increments over ``tau0`` are given
    (module docstring, step 3).

    Parameters
    ----------
    increments : array_like, shape (c, n)
        Per channel, the integral of the rate over each of ``n`` consecutive intervals of
        ``tau0`` (rad, m/s, ...).
    tau0 : float
        Interval, s.
    max_terms : int
        Start points per cluster time (about; at most twice): every one where the shortest
        cluster has fewer than ``2 max_terms``.
    sizes : array_like of int, optional
        Cluster sizes (intervals per cluster); default :func:`cluster_sizes`.

    Returns
    -------
    tau : numpy.ndarray, shape (k,)
        s.
    adev : numpy.ndarray, shape (c, k)
        Rate units (increment unit per s).
    clusters : numpy.ndarray, shape (k,)
        Independent clusters behind each value, ``min(n / m, start points)``.
    """
    x = np.atleast_2d(np.asarray(increments, dtype=float))
    n = x.shape[1]
    ms = cluster_sizes(n) if sizes is None else np.asarray(sizes, dtype=np.int64)
    plan, lattice, cnt, clusters = _plan(n, tuple(ms.tolist()), max_terms)
    if lattice is None:
        ss = _squares(x, plan)
    elif _compiled.takes(x):
        ss = np.empty((len(plan), x.shape[0]))
        _compiled.kernels.octave_squares(x, plan, lattice, ss)     # (the same sums, compiled)
    else:
        ss = _octave_squares(x, plan, lattice)
    adev = np.sqrt(ss.T / (2.0 * cnt)) / (ms * tau0)
    return ms * tau0, adev, clusters.copy()


@functools.lru_cache(maxsize=64)
def _plan(n, sizes, max_terms):
    """The start points of :func:`allan_deviation` for ``n`` intervals and cluster ``sizes``
    (tuple; module docstring, step 3), cached per log shape: ``(plan, lattice, count,
    clusters)``, ``plan`` a tuple of ``(m, step, count)`` (start points ``k = 0, step, ..``,
    ``count`` of them), ``lattice`` the stride ``s`` of the clusters of at least ``s`` where
    :func:`_octave_squares` takes the plan (sizes that are powers of two, each shorter than
    ``s`` dividing its stride), else None, ``count`` and the independent clusters ``min(n /
    m, count)`` as read-only float arrays (k,)."""
    if not sizes or min(sizes) < 1 or max(sizes) > n // 2:
        raise ValueError(f"cluster sizes must lie in 1..{n // 2} for {n} intervals")
    steps = [max(1, (n + 1 - 2 * m) // max_terms) for m in sizes]
    s = 1 << (max(steps).bit_length() - 1)              # the lattice
    plan = tuple((m, s if m >= s else step, (n - 2 * m) // (s if m >= s else step) + 1)
                 for m, step in zip(sizes, steps))
    octave = not any(m & (m - 1) or (m < s and step % m) for m, step, _ in plan)
    cnt = np.array([p[2] for p in plan], dtype=float)
    clusters = np.minimum(n / np.asarray(sizes, dtype=float), cnt)
    for a in (cnt, clusters):
        a.flags.writeable = False
    return plan, s if octave else None, cnt, clusters


def _squares(x, plan):
    """Per ``(m, step, count)`` of ``plan``, the sum over the start points ``k = 0, step, ..``
    (``count`` of them) of ``(theta_{k+2m} - 2 theta_{k+m} + theta_k)^2``, ``theta`` the
    cumulative sum of ``x`` (c, n) from 0; (k, c). Any plan: ``theta`` read by strided views."""
    c, n = x.shape
    theta = np.empty((c, n + 1))
    theta[:, 0] = 0.0
    np.cumsum(x, axis=1, out=theta[:, 1:])
    ss = np.empty((len(plan), c))
    d = np.empty(c * max(cnt for _, _, cnt in plan))
    for i, (m, step, cnt) in enumerate(plan):
        di = d[:c * cnt].reshape(c, cnt)
        np.multiply(theta[:, m::step][:, :cnt], 2.0, out=di)
        np.subtract(theta[:, 2 * m::step][:, :cnt], di, out=di)
        di += theta[:, :(cnt - 1) * step + 1:step]
        _vecdot(di, di, out=ss[i])
    return ss


def _octave_squares(x, plan, s):
    """:func:`_squares` without a cumulative sum, for a plan of :func:`_plan` whose cluster
    sizes are powers of two (a log's) and whose clusters shorter than the lattice ``s`` (the
    stride of the longer ones) have strides they divide.

    The increments are summed over ``s`` by pairs (``S_1 = x``, ``S_2``, ``S_4``, ..: the
    lattice sums ``S_s``). A cluster shorter than ``s`` is the difference of two adjacent sums
    ``S_m``, read every ``step / m``-th. The first pairs (rows of even length, a stride of
    the single interval that is even, as in a 10-minute log) come from one complex product:
    each row read as ``x[2p] + i x[2p + 1]`` times ``1 + i`` is ``(x[2p] - x[2p + 1]) + i
    S_2[p]``, both exact, in one pass over the record where two strided ones took a third
    longer. A longer one, ``q = m / s`` lattice sums, is the
    difference of two sums ``D_q`` of ``q`` consecutive lattice sums, ``q`` apart, at every
    lattice point; ``D_q`` by doubling (``D_2q[j] = D_q[j] + D_q[j + q]``). The same start
    points as :func:`_squares`; no sum runs over the record, so no rounding grows with it.
    The lattice arrays are rows of one width in flat buffers, added as one flat array each (a
    sum across two rows is never read), as in :func:`_short_allan`."""
    c, n = x.shape
    width = n // s + 1                                  # every lattice row: this many entries
    lattice = np.empty((3, c, width))                   # S_s then D_q (doubled in two); d
    flat = lattice.reshape(3, -1)
    sums = {1: x}                                       # S_w: sums over w intervals, (c, n // w)
    w, pairs = 1, None
    if s > 1 and n % 2 == 0 and x.flags.c_contiguous and plan[0][0] == 1 and plan[0][1] % 2 == 0:
        # x's rows as pairs x[2p] + i x[2p + 1], times 1 + i: (x[2p] - x[2p + 1]) + i S_2[p],
        # exactly (the products are by one), in one pass where two strided ones were
        pairs = np.multiply(x.view(np.complex128), _ONE_I)
        sums[2] = pairs.imag
        if s == 2:
            lattice[0, :, :n // 2] = pairs.imag
        w = 2
    while w < s:
        prev, half = sums[w], n // (2 * w)
        out = lattice[0, :, :half] if 2 * w == s else None
        sums[2 * w] = np.add(prev[:, 0:2 * half:2], prev[:, 1:2 * half:2], out=out)
        w *= 2
    if s == 1:
        lattice[0, :, :n] = x
    lattice[0, :, n // s:] = 0.0                        # read only by sums across rows
    ss = np.empty((len(plan), c))
    at, q, size = 0, 1, flat.shape[1]                   # D_q in flat[at]: row entries 0 .. n // s - q
    for i, (m, step, cnt) in enumerate(plan):
        if m < s and m == 1 and pairs is not None:     # minus the differences: the same squares
            d = pairs.real[:, 0::step // 2][:, :cnt]
        elif m < s:
            S, r = sums[m], step // m
            d = np.subtract(S[:, 1::r][:, :cnt], S[:, 0::r][:, :cnt], out=lattice[2, :, :cnt])
        else:
            while q < m // s:
                np.add(flat[at, :size - q], flat[at, q:size], out=flat[1 - at, :size - q])
                size, q, at = size - q, 2 * q, 1 - at
            last = (c - 1) * width + cnt                # flat entries of d needed
            np.subtract(flat[at, q:last + q], flat[at, :last], out=flat[2, :last])
            d = lattice[2, :, :cnt]
        _vecdot(d, d, ss[i])
    return ss


#: ``1 + i``: a pair ``a + i b`` times it is ``(a - b) + i (a + b)``, exactly
_ONE_I = np.complex128(1.0 + 1.0j)


def noise_from_log(log, *, block_period=BLOCK_PERIOD, max_terms=MAX_TERMS, sums=None):
    """The Allan curves and IEEE 952 terms of one raw log's six channels.

    Parameters
    ----------
    log : RawLog
    block_period : float
        The block the deterministic part is fitted on, s (module docstring, step 2); shorter
        clusters come from the raw samples (step 3).
    max_terms : int
        Start points per cluster time (step 3).
    sums : BlockSums, optional
        The log's block sums when already taken (:func:`block_sums`, shared with the quality
        checks); used when they are this log's over these blocks, else taken here.

    Returns
    -------
    NoiseFigures

    Raises
    ------
    ValueError
        The log is too short (fewer than :data:`~hse_opt.align.blocks.MIN_BLOCKS` blocks).
    """
    res = deterministic_residual(log, block_period=block_period, sums=sums)
    short, sizes = _log_sizes(res.blocks.shape[1], res.block)
    tau, adev, clusters = allan_deviation(res.blocks, res.tau0, max_terms=max_terms, sizes=sizes)
    if short:
        tau_s, adev_s, clusters_s = _short_allan(log, res, short)
        tau, adev = np.concatenate([tau_s, tau]), np.concatenate([adev_s, adev], axis=1)
        clusters = np.concatenate([clusters_s, clusters])
    coef, std = fit_allan(tau, adev, clusters)
    return NoiseFigures(tau=tau, adev=adev, clusters=clusters, coefficients=coef, coefficients_std=std)


@functools.lru_cache(maxsize=32)
def _log_sizes(nb, block):
    """The cluster sizes of :func:`noise_from_log` for ``nb`` blocks of ``block`` samples
    (cached per log shape): ``(short, sizes)``, the octaves shorter than a block in samples
    (tuple) and those of ``nb`` blocks (int array, read-only)."""
    short = tuple(m for m in cluster_sizes(block, steps_per_octave=1).tolist() if m < block)
    sizes = cluster_sizes(nb, steps_per_octave=1)
    sizes.flags.writeable = False
    return short, sizes


def combine_noise(figures):
    """One campaign's figures from its logs': the Allan variances at equal cluster times
    (within 1e-6 relative) pooled with their independent clusters as weights, then fitted.

    Parameters
    ----------
    figures : sequence of NoiseFigures

    Returns
    -------
    NoiseFigures
        ``n_logs`` the sum of the inputs'.
    """
    figures = list(figures)
    if not figures:
        raise ValueError("no noise figures to combine; allowed: one or more logs")
    keys = {}
    for f in figures:
        for i, t in enumerate(f.tau.tolist()):
            key = round(math.log2(t) * 1e6)
            acc = keys.setdefault(key, [t, np.zeros(f.adev.shape[0]), 0.0])
            acc[1] = acc[1] + f.clusters[i] * f.adev[:, i] ** 2
            acc[2] += f.clusters[i]
    order = sorted(keys)
    tau = np.array([keys[k][0] for k in order])
    clusters = np.array([keys[k][2] for k in order])
    adev = np.sqrt(np.column_stack([keys[k][1] / keys[k][2] for k in order]))
    coef, std = fit_allan(tau, adev, clusters)
    return NoiseFigures(tau=tau, adev=adev, clusters=clusters, coefficients=coef, coefficients_std=std,
                        n_logs=sum(f.n_logs for f in figures))
