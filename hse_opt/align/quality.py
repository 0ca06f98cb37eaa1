"""Raw-log quality before alignment: what a recording can get wrong, each finding named with
the sample and its time; a log is repaired by a documented rule or refused, never aligned
into a silently wrong heading.

:func:`assess` runs the checks below on a :class:`~hse_opt.align.rawlog.RawLog` (after
:func:`~hse_opt.align.rawlog.validate_rawlog` and :func:`~hse_opt.align.rawlog.check_rawlog`,
which already refuse non-finite values, timestamps that go back, gaps longer than 1.5 sample
periods, dead channels and wrong units) and returns a :class:`Quality`: the log to align
(repaired, or the input unchanged), the findings, and whether the log is refused.
``hse-opt align`` writes :meth:`Quality.summary` into the RUNS.csv text column ``quality``
(``ok``, or what was repaired or noted) and refuses a log with one line on stderr.

Checks, rules and thresholds (:class:`Thresholds`; the reasons are physical)
----------------------------------------------------------------------------
1. **Encoder samples** (per sample). Each step ``alpha_k - alpha_{k-1}`` is compared with
   the table's step (the median step): a step is off when it deviates by more than
   ``max(encoder_sigmas x its robust 1-sigma, encoder_floor)``. The 1-sigma (1.4826 x the
   median absolute deviation) is the servo jitter and the encoder's resolution seen in the
   steps (0.8 arcsec for the paper-like stand: 0.5 arcsec jitter, 0.18 arcsec resolution);
   10 sigma has no false alarm in 10^15 Gaussian steps. The floor, 2 arcsec, keeps a
   noise-free log from flagging rounding (and the threshold is at least three of the steps'
   quanta, the encoder's resolution); an isolated sample off by less moves the heading
   by < 1e-5 arcsec (0.7 arcsec per rad measured mid-run).

   *Encoder resolution.* Known (``assess(..., encoder_counts_per_rev=...)``, the calibration
   file's ``encoder.counts_per_rev``, else the log's metadata, which a mapping file sets), one
   count is the least quantum here and in check 3 (unknown, a jitter-free coarse encoder whose
   steps are whole counts for the first samples had a later one-count step refused as a jump;
   a jump of 4 counts is still refused: ``tests/test_align_quality.py``).

   *Repair*: a run of at most ``repair_samples`` (3) consecutive samples whose first and
   last neighbours agree with the table's rate (the steps around them add up to the rate's
   within the threshold: a glitch, a repeated stale reading; a sample off by a whole turn
   is already unwrapped by the loader, and one off by more than pi/2 otherwise refused there) is
   replaced by the linear interpolation of those neighbours; at the log's first or last
   samples by extrapolation from the good neighbour with the gyros' turn in each step. The
   row says so (``repaired: encoder at sample k (t = ... s): ...``).
   *Refusal*: a step that does not come back (the encoder jumped: lost counts or a slipped
   zero, or the table jerked; the message gives the gyros' turn over that interval), or
   more than ``repair_samples`` bad samples in a row (the encoder stuck, or the table
   stalled); an encoder that holds one reading over half the log or more (its median step is
   0) while the gyros turn more than a hundred times the Earth's rate is *frozen*, named from
   the first sample that repeats the reading, with the gyros' turn meanwhile. An uncorrected jump of ``d`` turns b0 by ``d`` for the rest of the run: the
   heading moves by about ``d`` times the fraction of the run after it.
2. **Table rate** (windows of ``window_s``, 0.512 s: 8 of the Allan analysis' 64-ms blocks,
   whose sums the channel check shares at 500 Hz). The rate over each window from the
   (repaired) encoder against the median: a window below ``stall`` (0.5) times it is a
   stall; a relative deviation above ``rate_ripple`` (5e-3) plus ``rate_sigmas`` (5) times
   the windows' own noise (the jitter at their edges, from the differences of neighbouring
   windows: 1e-4 to 6e-4 for 0.5 to 5 arcsec of jitter at 7 deg/s; the multiplier raised to
   the Bonferroni level of the false-alarm figure below, 5.9 for a 10-minute log's 1171
   windows) refuses the log. Reason: the
   filter assumes the table-fixed errors turn at one rate; a once-per-revolution ripple of
   1e-2 moves a noise-free 10-minute heading by 2.0 arcsec at 5 deg/s and 0.56 arcsec at
   10 deg/s (4 cycles per revolution: 0.42 and 0.04 arcsec), the paper's stand holds 1e-4.
3. **Sensor channels** (windows of ``window_s``). First the norms, which no fit can bend:
   the gyros' turn over the encoder's (median over the windows) must lie within
   ``1 +- gyro_scale`` (5e-3: an RLG's scale factor is known to ppm and a triad's axes to
   arcseconds, 1e-4; a wrong pulse weight, a channel clipped or stuck throughout, or 3 % on
   one gyro is beyond it), and the accelerometers' specific force within ``gravity``
   (9.7-9.9 m/s^2: gravity at sea level is 9.78-9.83 m/s^2, 5 km up 0.015 less, plus the
   sensors' scale); each window's value of both, relative to the median, is a fault beyond
   ``max(channel_sigmas x robust 1-sigma, norm_floor)``. Then each gyro's and
   accelerometer's window sum is fitted: on a static base with the IMU fixed to the table
   top, every channel is a constant plus a sinusoid of the table angle (the horizontal
   Earth rate and gravity turning with the table), plus, for a gyro, its share ``beta_j``
   of the table's turn (``beta_j = sum gyro_j / sum d alpha``: the axis's cosine to z_b,
   0.577 for the paper's triad), plus slow drifts (warm-up, temperature: a quadratic in
   time); the fit leaves out the windows whose norms are off, and then those whose
   residuals are. The residuals are pulse quantization (one pulse per window: the counters
   carry their remainders) and noise; a window deviating by more than
   ``max(channel_sigmas x s, z x s + 2 q, floor)`` (``s`` the channel's robust 1-sigma; the
   floors: ``gyro_floor`` 1e-3 arcsec, ``accel_floor`` 1e-7 m/s, one per mille of the
   paper's pulses, above a noise-free log's model residual) is a fault. The middle term is
   the false-alarm design figure (*Noise model and false alarms* below): 0.78-0.83 arcsec
   for the gyros of the paper-like system at 10 deg/s (0.67 from the 10 sigma alone), 4.7e-4
   to 5e-4 m/s for its accelerometers (six 10-minute logs). A window:

   * all three gyros in one window, in the ratio of their ``beta_j`` and the accelerometers
     not: an encoder jump too small for check 1 (the encoder turned by ``d`` the gyros did
     not: refused, naming the step that deviates most in the window); a pair of adjacent
     windows with opposite jumps is one encoder sample off at their common edge (repaired
     by the neighbours' interpolation);
   * one sample of one channel that alone explains its window's residual (a spike: the
     sample's deviation from its neighbours' mean, for a gyro less its share of the
     table's step deviation, matches the residual within the threshold): replaced by the
     neighbours' mean (plus, for a gyro, that share) (*repaired*); unless the gyro's own
     sample shows no spike where the encoder's step stands out of the window: a jump (refused);
   * otherwise refused: *saturated* (the bad windows hold the channel's extreme value of
     the log ``saturated_samples`` (3) or more samples in a row, and that value lies beyond
     what a static base gives the channel: a gyro sample beyond the table's largest step
     (x 1 + ``gyro_scale``) plus the Earth's rate, an accelerometer sample beyond 9.9 m/s^2
     over the interval, plus two quanta; a coarse channel touching its observed maximum a
     few times is not clipping), *stuck* (the channel repeats one value for
     ``stuck_samples`` (25) or more samples in the bad windows and that run explains the
     windows' residual: its samples' excess over the fitted values; a coarse channel holding
     one count while its true value stays within it explains nothing; the finding names the
     run's first sample), a *bias step* (the windows' residuals sit at one level before a
     window and another after it, the step dominating them: named at its sample, placed
     within the two windows at the change by their share of the step, with its size per
     second), or a fault that does not follow the table's turn.

   What the window test lets pass: a gyro error in one sample below the gyro threshold (0.8
   arcsec for the paper-like system), which the filter takes like a rate error ``d / T``
   over the run: 5 arcsec in gyro_y at mid-run moves a 10-minute heading by 103 arcsec
   (repaired: 0.2), 0.6 arcsec by 12 arcsec, 1.5 of its sigmas. Check 3b finds those.

   *Noise model and false alarms.* A window residual is a Gaussian part (the sensors'
   white noise and the table's jitter summed over the window; its 1-sigma ``s`` from the
   median absolute deviation, which the quantization below only inflates) plus a bounded
   quantization part: the window sum of a counter that carries its remainder is off by
   less than one pulse ``q`` (the channel's smallest step between samples, uniform
   remainders at both ends: a triangular error on (-q, q)), a gyro's also by ``beta_j``
   times one encoder count (the window's turn), and the windows' median by as much again:
   ``2 q`` bounds it. The Gaussian part is tested at ``z``, the Bonferroni level of
   ``false_alarm`` (1e-4 per log) over the log's windows and eight channels (six sensors,
   two norms), widened by three standard errors of ``s`` (relative 1.166 / sqrt(m) for m
   windows): 6.3 for a 10-minute log, 8.0 for 20 s. So the window tests' false-alarm
   probability on a clean log is below 1e-4 by construction; the 10-sigma floor keeps the margin for the
   residual's non-Gaussian part (drifts the quadratic does not follow). Measured on clean
   simulated logs (``studies/quality_false_alarms.py --full``: six systems, 20 s, 2 and
   10 minutes, 10-60 deg/s both senses, 3,600 logs, the checks given each encoder's
   resolution and check 3b on): 0 with a finding. Without the resolution 2 (both check 1
   on a 20-arcsec encoder without jitter whose step is a whole number of counts in the
   first 4,000 samples: the steps' quantum is not seen there, and a later one-count step is
   taken for a jump); 14 before the bounds above, all of that encoder (``--seeds 100``, 20
   and 60 s: 1 of 1,200, 6 before; ``tests/test_align_quality.py``: 0 of 400 short logs of
   ten systems). The checks' first version refused 1 in 20 default 20-s logs (a window at
   the quantization's edge, then called saturation).
3b. **Gyro steps** (below the window test; :mod:`hse_opt.align.steps`: statistic, threshold,
   rules, figures): a sample's error of 0.2 arcsec that stays in one gyro's angle (half a
   sigma of a 10-minute heading) is found at its sample and taken off.
4. **Temperature** (only for a log that carries a temperature channel: ``temperature``;
   a mapping file's ``temp_c`` column). A drift of more than ``temp_drift_c`` (1 degC)
   between the first and the last window is noted (not refused): a gyro bias
   temperature coefficient of 2e-4 deg/h/degC (TRUTH.toml's ``bias_tempco_dph_per_c``)
   makes 1 degC a bias change the table's rotation does not average within the run, up
   to 3 arcsec of heading by Eq. 12.
5. **Metadata types** (:func:`check_metadata`): the keys the processor and RUNS.csv read
   have their types (numbers finite, ``run`` an integer, ``position`` a label); a wrong
   type refuses the log naming the key and what is allowed.

Cost: a few passes over the samples and one least-squares fit of a thousand windows (its 5x5
normal equations by Cholesky in Python floats, :func:`~hse_opt.align._stats.solve_normal`: the
first LAPACK solve after the alignment cost 0.037 ms, cold); the
window sums come from the Allan analysis' block sums when ``hse-opt align`` passes them
(``sums``: one pass over the samples for both; check 3b's weighted sums come with them),
and the quanta and the encoder's step statistics that checks 1, 3 and 3b take are worked out
once (:class:`~hse_opt.align._quanta.Quanta`). Checks 1-5 without 3b on a 10-minute 500 Hz log
(``benchmarks/align.py``'s, 2026-11-26): 5.2 M instructions (callgrind, one BLAS thread; were
7.3 M) against the alignment's 47 M; CPU on one core of the busy 2-core machine (load 3-4)
0.36 ms when repeated (were 0.56) and 0.7-0.8 ms after the alignment as ``hse-opt align`` runs
them, its caches cold (were 0.9-1.0); the floor is the per-sample encoder check (the steps,
their extremes and every 29th's median: 0.15-0.18 ms of it; with ``hse-opt align``'s block sums
they come from the pass check 3b's sums of the encoder take:
:class:`~hse_opt.align._quanta.EncoderSteps`). Check 3b: :mod:`hse_opt.align.steps`.
"""
from __future__ import annotations

import functools
import math
from statistics import NormalDist

import numpy as np

from hse_opt import units
from hse_opt.align._blas import block_dot
from hse_opt.align.rotations import EARTH_RATE
from hse_opt.align.blocks import CHANNELS, _block_sums, deterministic_residual
from hse_opt.align.findings import _THRESHOLDS, Finding, LogRefused, Quality, Thresholds
from hse_opt.align.metadata import encoder_counts, metadata_problems
from hse_opt.align.steps import block_period, check_steps
from hse_opt.align._quanta import Quanta
from hse_opt.align._stats import MAD as _MAD, fit as _fit, median as _median, regressors as _regressors, \
    robust_flags as _robust_flags, row_median as _row_median

__all__ = ["Thresholds", "Finding", "Quality", "LogRefused", "assess", "check_metadata"]

#: the encoder step threshold is at least this many quanta of the steps (:func:`~hse_opt.align._quanta.quantum`)
_QUANTA = 3.0
#: the quantization part of a window sum's deviation from the windows' median is below this
#: many quanta (the sum of a counter that carries its remainder is off by less than one, the
#: median by less than one more): added to the Gaussian part's bound
#: (:func:`~hse_opt.align._stats.robust_flags`)
_QUANT_BOUND = 2.0


# -- metadata ------------------------------------------------------------------------------------
def check_metadata(meta):
    """The refusals (a list of :class:`Finding`) for a raw log's metadata ``meta`` (dict): its
    keys of the wrong type or value (:func:`hse_opt.align.metadata.metadata_problems`)."""
    return [Finding("metadata", None, None, "refused", text) for text in metadata_problems(meta)]


# -- 1. encoder samples --------------------------------------------------------------------------
def _clusters(idx, gap):
    """Split sorted indices into runs whose neighbours are at most ``gap`` apart: [(i1, i2)]."""
    if idx.size == 0:
        return []
    cut = np.flatnonzero(np.diff(idx) > gap)
    starts = np.concatenate(([0], cut + 1))
    ends = np.concatenate((cut, [idx.size - 1]))
    return [(int(idx[a]), int(idx[b])) for a, b in zip(starts, ends)]


def _check_encoder(t, enc, gyro, th, findings, quanta):
    """Check 1; returns the encoder (a repaired copy, or ``enc`` itself). ``quanta``: the
    log's :class:`~hse_opt.align._quanta.Quanta` (the table's step and its 1-sigma, the
    encoder's count, its steps' extremes; the steps themselves are taken only for a log
    with an encoder fault)."""
    n = enc.size
    c, s = quanta.step, quanta.step_sigma
    if c == 0.0:            # one reading held over half the log or more: frozen, if the table turned
        frozen = _frozen_encoder(t, enc, gyro, quanta.steps)
        if frozen is not None:
            findings.append(frozen)
            return enc
    thr = max(th.encoder_sigmas * s, th.encoder_floor, _QUANTA * quanta.count)
    if quanta.seen.largest - c <= thr and c - quanta.seen.smallest <= thr:
        return enc
    d = quanta.steps
    dev = d - c
    bad = np.flatnonzero(np.abs(dev) > thr)
    out = enc.copy()
    gnorm = None
    for i1, i2 in _clusters(bad, th.repair_samples):
        # steps i1..i2 are those into samples i1+1 .. i2+1; samples i1+1 .. i2 lie between the
        # anchors enc[i1] and enc[i2 + 1]
        total = float(enc[i2 + 1] - enc[i1]) - (i2 - i1 + 1) * c
        first, last = i1 + 1, i2
        edge = (i1 == 0 and i2 < th.repair_samples) or (i2 == n - 2 and n - 1 - i1 <= th.repair_samples)
        if edge and abs(total) > thr:
            # the log's first samples 0 .. i2 or last samples i1 + 1 .. n - 1: extrapolated from
            # the good neighbour by the gyros' turn (|gyro_k| scaled to the encoder's step)
            if gnorm is None:
                gnorm = _gyro_turn(gyro)
            if i1 == 0:
                k = np.arange(0, i2 + 1)
                steps = np.sqrt(np.einsum("ij,ij->i", gyro[1:i2 + 2], gyro[1:i2 + 2])) * (c / gnorm)
                out[k] = enc[i2 + 1] - np.cumsum(steps[::-1])[::-1]
            else:
                k = np.arange(i1 + 1, n)
                steps = np.sqrt(np.einsum("ij,ij->i", gyro[i1 + 1:], gyro[i1 + 1:])) * (c / gnorm)
                out[k] = enc[i1] + np.cumsum(steps)
            a, b = int(k[0]), int(k[-1])
            j = int(np.argmax(np.abs(enc[k] - out[k])))
            findings.append(Finding("encoder", a, float(t[a]), "repaired",
                                    (f"samples {a}-{b}" if b > a else "the sample") + " off the table's "
                                    f"rate by {_arcsec(enc[k[j]] - out[k[j]])}: extrapolated from the neighbour by "
                                    "the gyros' turn"))
            continue
        if abs(total) <= thr and 1 <= last - first + 1 <= th.repair_samples:
            k = np.arange(first, last + 1)
            out[k] = enc[i1] + (k - i1) * (enc[i2 + 1] - enc[i1]) / (i2 + 1 - i1)
            off = enc[first:last + 1] - out[first:last + 1]
            j = int(np.argmax(np.abs(off)))
            span = f"samples {first}-{last}" if last > first else "the sample"
            findings.append(Finding("encoder", first, float(t[first]), "repaired",
                                    f"{span} off by {_arcsec(off[j])} from the neighbours' "
                                    "interpolation: replaced by it"))
            continue
        if gnorm is None:
            gnorm = _gyro_turn(gyro)
        k = i1 + 1
        seen = float(np.linalg.norm(gyro[k])) * math.copysign(1.0, c)
        # the gyros' turn in each bad step against the encoder's (scaled to the encoder's)
        g_steps = np.sqrt(np.einsum("ij,ij->i", gyro[k:i2 + 2], gyro[k:i2 + 2])) * (c / gnorm)
        g_turn, e_turn = float(g_steps.sum()), float(enc[i2 + 1] - enc[i1])
        agree = bool(np.abs(d[i1:i2 + 1] - g_steps).max() <= thr)
        if i2 == i1:
            what = (f"encoder jumps by {_arcsec(dev[i1])} at this step and does not come back (the table's "
                    f"step {_arcsec(c)}, allowed within {_arcsec(thr)}; the gyros turned "
                    f"{_arcsec(seen)} against their usual {_arcsec(gnorm * math.copysign(1.0, c))}: "
                    + ("the table jerked" if agree else "lost counts or a slipped zero")
                    + ")")
        else:
            stuck = int(np.count_nonzero(d[i1:i2 + 1] == 0.0)) >= i2 - i1     # (and one catch-up step)
            cause = ("the table stalled or jerked: the gyros turned with it" if agree else
                     "the encoder is stuck" if stuck else "the encoder disagrees with the gyros")
            what = (f"encoder steps off the table's {_arcsec(c)} by more than {_arcsec(thr)} over samples "
                    f"{k}-{i2 + 1} ({i2 + 1 - i1} steps; the encoder turned {_arcsec(e_turn)}, the gyros "
                    f"{_arcsec(g_turn)}: {cause}; allowed: at most {th.repair_samples} bad samples in a row "
                    "between samples that keep the rate)")
        findings.append(Finding("encoder", k, float(t[k]), "refused", what))
    return out


def _frozen_encoder(t, enc, gyro, d):
    """The refusal of an encoder that holds one reading (its longest run of zero steps ``d``)
    while the gyros turn more than a hundred times the Earth's rate would (a static table); None
    when they do not."""
    starts, lengths = _runs(d == 0.0)
    if not starts.size:
        return None
    r = int(np.argmax(lengths))
    i0, length = int(starts[r]), int(lengths[r])
    a, b = i0 + 1, i0 + length                  # samples a..b repeat sample i0's reading
    span = float(t[b] - t[i0])
    turned = float(np.linalg.norm(gyro[a:b + 1].sum(axis=0)))      # the gyros' turn meanwhile, rad
    if not turned > 100.0 * EARTH_RATE * span:
        return None
    share = length / d.size
    return Finding("encoder", a, float(t[a]), "refused",
                   f"the encoder is frozen at {float(enc[i0]):.6g} rad from sample {a} to {b} (t = {t[a]:.6g}-"
                   f"{t[b]:.6g} s: {length} samples, {share:.0%} of the log) while the gyros turned "
                   f"{turned / units.DEG:.4g} deg ({turned / span / units.DEG_PER_S:.3g} deg/s): a stopped counter "
                   "or a lost encoder signal; allowed: an encoder reading that follows the table's turn")


def _gyro_turn(gyro):
    """Median |gyro increment| over every 7th sample, rad (the table's turn seen by the gyros)."""
    g = gyro[1::7]
    return float(_median(np.sqrt(np.einsum("ij,ij->i", g, g))))


def _arcsec(x):
    """An angle in rad as display text (arcsec, or rad when large)."""
    x = float(x)
    return f"{x:+.4g} rad" if abs(x) >= 0.1 else f"{x / units.ARCSEC:+.4g} arcsec"


# -- windows: 2. rate and 3. channels -----------------------------------------------------------
def _windows(n, dt, th):
    """(L, m): samples per window and whole windows over samples 1 .. m L."""
    L = max(8, int(round(th.window_s / dt)))
    return L, (n - 1) // L


def _check_rate(t, enc, L, m, th, findings):
    """Check 2 on windows of L samples; returns the window turns (m,) for check 3."""
    edges, te = enc[0:m * L + 1:L], t[0:m * L + 1:L]
    turn = edges[1:] - edges[:-1]
    rate = turn / (te[1:] - te[:-1])
    med = float(_median(rate))
    if med == 0.0:
        return turn
    rel = rate / med - 1.0
    # the windows' own noise (the jitter at their edges: white, so it shows in the differences
    # of neighbouring windows, where a ripple over many windows does not) is allowed on top
    noise = _MAD * float(_row_median(np.abs(rel[1:] - rel[:-1]))) / math.sqrt(2.0) if rel.size > 2 else 0.0
    sigmas = max(th.rate_sigmas, _level(th, m, m))
    allowed = th.rate_ripple + sigmas * noise
    w = int(np.argmax(np.abs(rel)))
    if rate[w] / med < th.stall or abs(rel[w]) > allowed:
        k = w * L
        kind = ("the table stalls" if rate[w] / med < th.stall else "the table's rate varies")
        findings.append(Finding("rate", k, float(t[k]), "refused",
                                f"{kind}: {rate[w] / units.DEG_PER_S:.6g} deg/s over samples {k}-{k + L} against the "
                                f"median {med / units.DEG_PER_S:.6g} deg/s ({rel[w]:+.3g}; allowed within "
                                f"{allowed:.3g}: {th.rate_ripple:g} plus {sigmas:.3g} times the windows' "
                                f"own noise, {noise:.2g}; a stall below {th.stall:g} of the rate)"))
    return turn


def _window_sums(x, L, m):
    """Sums of ``x[1 + w L : 1 + (w + 1) L]`` for w < m, shape (m, 3)."""
    return _block_sums(x, m * L + 1, m, L).T


def _channel_sums(log, L, m, sums):
    """The six channels' window sums, shape (m, 6): from the Allan analysis' block sums
    ``sums`` (:class:`~hse_opt.align.blocks.BlockSums`) when they are this log's and a window
    is a whole number of their blocks (the default windows at 125 x 2^k Hz: ``k`` blocks each,
    by a matrix-vector product, 0.012 ms against ``einsum``'s 0.021 for 1171 windows of 8),
    else summed here."""
    if sums is not None and sums.log is log and L % sums.block == 0:
        k = L // sums.block
        return block_dot(sums.sums[:, :m * k].reshape(6, m, k), np.ones(k)).T
    return np.hstack([_window_sums(log.gyro, L, m), _window_sums(log.accel, L, m)])


def _middles(log, enc, L, m, sums):
    """cos and sin of the table angle at the middles of check 3's ``m`` windows of ``L``
    samples (samples ``L // 2 + w L``) from the Allan analysis' fit (its block edges'), when
    ``sums`` are ``log``'s, ``enc`` is its encoder and the middles are block edges; else None."""
    if sums is None or sums.log is not log or enc is not log.encoder or L % (2 * sums.block):
        return None
    k = L // sums.block
    r = sums.residual
    return r.edge_cos[k // 2:k // 2 + k * m:k], r.edge_sin[k // 2:k // 2 + k * m:k]


def _level(th, tests, m):
    """The multiplier of a robust 1-sigma at which ``tests`` two-sided Gaussian tests have a
    false-alarm probability of ``th.false_alarm`` together (Bonferroni), widened by three
    standard errors of a 1-sigma from the median absolute deviation of ``m`` values (relative
    standard error 1.166 / sqrt(m)): e.g. 6.3 for 8 x 1171 tests (a 10-minute log's windows,
    six channels and two norms), 8.0 for 8 x 39 (20 s); 5.9 for a 10-minute log's 1171 rate
    windows."""
    return _z(th.false_alarm / (2.0 * tests)) * (1.0 + 3.0 * 1.166 / math.sqrt(max(m, 1)))


@functools.lru_cache(maxsize=64)
def _z(p):
    """The standard normal's upper ``p`` quantile (once per log length: a few microseconds of
    Python each)."""
    return -NormalDist().inv_cdf(p)


def _check_channels(t, enc, gyro, accel, turn, L, m, th, findings, X, quanta, middles=None):
    """Check 3 on the window sums ``X`` (m, 6); returns (gyro, accel, enc), repaired copies
    where a spike rule applied. ``quanta``: the log's :class:`~hse_opt.align._quanta.Quanta`
    (the channels' pulses, the encoder's count); ``middles``: cos and sin of the table angle
    at the windows' middles when known (:func:`_middles`). Each channel's window values are a
    row here (numpy's operations along a short last axis cost more than the arithmetic)."""
    if m < 8:
        return gyro, accel, enc
    total = float(turn.sum())
    beta = X[:, :3].sum(axis=0) / total
    # the norms first: the gyros' turn against the encoder's, the specific force; no fit to
    # bend, so a fault in many windows (a clipped range) cannot hide in a fitted sinusoid
    norms = np.empty((3, m))        # rows: the ratio, the force, then |turn| (for its median)
    sq = np.square(X.T, order="C")  # the channels' rows (X is the block sums' product's transpose)
    np.add(sq[0::3], sq[1::3], out=norms[:2])
    norms[:2] += sq[2::3]
    np.sqrt(norms[:2], out=norms[:2])
    np.abs(turn, out=norms[2])
    norms[0] /= norms[2]
    scale, f_med, turn_med = _median(norms.T).tolist()
    if abs(scale - 1.0) > th.gyro_scale:
        findings.append(Finding("channel", 1, float(t[1]), "refused",
                                f"the gyros turn {scale:.6g} times the encoder's turn (median over windows of {L} "
                                f"samples); allowed: within 1 +- {th.gyro_scale:g} (a wrong pulse weight, a channel "
                                "clipped or stuck throughout, or an encoder with the wrong counts per revolution)"))
        return gyro, accel, enc
    g = f_med / float(t[L] - t[0])
    if not th.gravity[0] <= g <= th.gravity[1]:
        findings.append(Finding("channel", 1, float(t[1]), "refused",
                                f"the accelerometers' specific force is {g:.6g} m/s^2 (median over windows of {L} "
                                f"samples); allowed: {th.gravity[0]:g}-{th.gravity[1]:g} m/s^2 (gravity on a static "
                                "base; a channel clipped or stuck throughout, or a wrong pulse weight)"))
        return gyro, accel, enc
    q = quanta.pulses                                                         # one pulse
    # the encoder's count (the smallest change of its steps) quantizes each window's turn, which
    # the gyros' ratio and residuals (less beta_j x turn) carry: bounded like their own pulses
    qe = quanta.count
    level = _level(th, 8 * m, m)
    sigmas = max(th.channel_sigmas, level)
    # rows 0-1 the norms (relative to their medians), 2-7 the channels' residuals of the fit;
    # the quantization bounds and floors of each row
    V = np.empty((8, m))
    np.divide(norms[:2], np.array([[scale], [f_med]]), out=V[:2])
    quant = np.empty(8)
    quant[0] = _QUANT_BOUND * (math.sqrt(3.0) * float(q[:3].max()) + qe * scale) / (turn_med * scale)
    quant[1] = _QUANT_BOUND * (math.sqrt(3.0) * float(q[3:].max())) / f_med
    np.multiply(np.abs(beta), qe, out=quant[2:5])
    quant[2:5] += q[:3]
    quant[5:] = q[3:]
    quant[2:] *= _QUANT_BOUND
    floor = np.array([th.norm_floor] * 2 + [th.gyro_floor] * 3 + [th.accel_floor] * 3)
    Y = np.empty((6, m))            # the window sums less each gyro's share of the turn, rows
    np.multiply(beta[:, None], turn, out=Y[:3])
    np.subtract(X.T[:3], Y[:3], out=Y[:3])
    Y[3:] = X.T[3:]
    A = _regressors(enc[L // 2:L // 2 + L * m:L], middles)
    # the fit over all windows, flagged with the norms (the same values as after them when no
    # norm is off; otherwise fitted again without those windows)
    np.subtract(Y, _fit(A, Y).T @ A, out=V[2:])
    dev, thr, bad = _robust_flags(V, sigmas, floor, quant, level)
    nbad = bad[0] | bad[1]
    dev, thr, bad = dev[2:], thr[2:], bad[2:]
    quant, floor = quant[2:], floor[2:]
    keep = None
    if nbad.any():
        keep = ~nbad
        dev, thr, bad = _robust_flags(Y - _fit(A, Y, keep).T @ A, sigmas, floor, quant, level)
    if bad.any():               # refit without the bad windows (a fault must not bend the fit)
        keep = (~nbad if keep is None else keep) & ~bad.any(axis=0)
        if keep.sum() >= 8:
            dev, thr, bad = _robust_flags(Y - _fit(A, Y, keep).T @ A, sigmas, floor, quant, level)
    if nbad.any():
        # a window whose norm is off with no channel past its threshold: the worst channel
        alone = nbad & ~bad.any(axis=0)
        if alone.any():
            w = np.flatnonzero(alone)
            bad[np.argmax(np.abs(dev[:, w]) / thr[:, None], axis=0), w] = True
    if not bad.any():
        return gyro, accel, enc

    dev, bad = dev.T, bad.T         # (m, 6): each window's channels
    gyro, accel, enc = gyro.copy(), accel.copy(), enc.copy()
    handled = np.zeros_like(bad)
    _encoder_windows(t, enc, bad, dev, thr, beta, L, handled, findings)
    arrays = (gyro, gyro, gyro, accel, accel, accel)
    for j in range(6):
        ws = np.flatnonzero(bad[:, j] & ~handled[:, j])
        if ws.size:
            _channel_fault(t, enc, arrays[j][:, j % 3], j, beta, ws, dev[:, j], thr[j], L, th, findings,
                           fitted=X[:, j] - dev[:, j], bound=_static_range(t, enc, j, q[j], th))
    return gyro, accel, enc


def _encoder_windows(t, enc, bad, dev, thr, beta, L, handled, findings):
    """Encoder faults too small for check 1: all three gyros off in one window in the ratio of
    their shares ``beta`` of the turn, the accelerometers not (``enc`` repaired in place)."""
    delta = {}
    for w in np.flatnonzero(bad[:, :3].all(axis=1) & ~bad[:, 3:].any(axis=1)).tolist():
        dj = -dev[w, :3] / beta
        if np.all(np.isfinite(dj)) and np.ptp(dj) <= 0.3 * np.abs(dj).max():
            delta[w] = float(np.mean(dj))
    for w in sorted(delta):
        if handled[w, 0]:
            continue
        d_w = delta[w]
        handled[w, :3] = True
        nxt = delta.get(w + 1)
        if nxt is not None and abs(d_w + nxt) <= 0.3 * abs(d_w):
            k = (w + 1) * L                        # the common edge sample of windows w, w + 1
            new = 0.5 * (enc[k - 1] + enc[k + 1])
            findings.append(Finding("encoder", k, float(t[k]), "repaired",
                                    f"the sample off by {_arcsec(enc[k] - new)} against the gyros' turn "
                                    "over the windows either side: replaced by the neighbours' interpolation"))
            enc[k] = new
            handled[w + 1, :3] = True
            continue
        s0 = 1 + w * L
        dd = np.diff(enc[s0 - 1:s0 + L])
        k = s0 + int(np.argmax(np.abs(dd - _median(dd))))
        findings.append(Finding("encoder", k, float(t[k]), "refused",
                                f"the encoder turned {_arcsec(d_w)} more than the gyros over samples {s0}-"
                                f"{s0 + L - 1} and does not come back (a jump: lost counts or a slipped zero; "
                                f"allowed: within {_arcsec(np.max(thr[:3] / np.abs(beta)))})"))


def _static_range(t, enc, j, q, th):
    """The largest |sample| channel ``j`` can give on a static base, in its unit: for a gyro
    the table's largest step (1 + ``gyro_scale``) plus the Earth's rate over the longest
    interval, for an accelerometer gravity's upper bound (``gravity``) over it; plus two quanta
    ``q`` (a counter carrying its remainder). A value beyond it is out of what the channel
    measures there: a clipped range holds it (:func:`_channel_fault`)."""
    dt = float(np.max(np.diff(t)))
    if j < 3:
        return float(np.max(np.abs(np.diff(enc)))) * (1.0 + th.gyro_scale) + EARTH_RATE * dt + 2.0 * q
    return th.gravity[1] * dt + 2.0 * q


def _runs(flags):
    """(start, length) of the runs of True in a 1-D boolean array (empty arrays when none)."""
    e = np.diff(np.concatenate(([0], flags.view(np.int8), [0])))
    starts, ends = np.flatnonzero(e == 1), np.flatnonzero(e == -1)
    return starts, ends - starts


def _channel_fault(t, enc, x, j, beta, ws, dev, thr, L, th, findings, fitted, bound):
    """One channel's bad windows ``ws``: a one-sample spike is repaired in ``x`` (in place);
    anything else refuses the log (one finding for the channel, its first bad stretch).

    Saturated and stuck are named only on evidence a clean quantized channel cannot give:
    saturated, the extreme value held ``saturated_samples`` consecutive samples and beyond
    ``bound`` (:func:`_static_range`: a noisy channel touching its observed maximum a few
    times is not clipping); stuck, a value repeated ``stuck_samples`` samples whose run
    explains the stretch's residual (its samples' excess over the fitted window values
    ``fitted`` / L; a coarse channel holding one count while its true value stays within that
    count explains nothing). Otherwise the channel does not follow the table's turn."""
    name, unit = CHANNELS[j], ("gyro" if j < 3 else "accel")
    n = x.size
    stretches = _clusters(ws, 1)
    for w1, w2 in stretches:
        s0, s1 = 1 + w1 * L, min(n - 1, (w2 + 1) * L)
        encoder_step = None
        if w1 == w2:        # one window: a spike if one sample's deviation explains the residual
            seg = x[s0 - 1:s1 + 2]
            spike = seg[1:-1] - 0.5 * (seg[:-2] + seg[2:])
            own, dd = spike.copy(), None
            if j < 3:       # a gyro follows the table's steps (its jitter): their part is no spike
                de = np.diff(enc[s0 - 2:s1 + 2]) if s0 >= 2 else None
                if de is not None and de.size == seg.size:
                    dd = np.abs(de[1:-1] - 0.5 * (de[:-2] + de[2:]))
                    spike -= beta[j] * (de[1:-1] - 0.5 * (de[:-2] + de[2:]))
            i = int(np.argmax(np.abs(spike)))
            k = s0 + i
            # the gyro's own sample shows no spike where its share of the encoder's step does, and
            # that step stands out of the window's (twice any other but its neighbours'): the
            # encoder stepped (a jump), which repairing the gyro would copy into its angle
            if dd is not None and abs(own[i]) < 0.5 * abs(spike[i]) and \
                    dd[i] >= 2.0 * np.delete(dd, range(max(0, i - 1), i + 2)).max(initial=0.0):
                encoder_step = (k, (own[i] - spike[i]) / beta[j])
            elif 0 < k < n - 1 and abs(spike[i] - dev[w1]) <= thr:
                findings.append(Finding("channel", k, float(t[k]), "repaired",
                                        f"{name} spike of {_value(spike[i], unit)} against its neighbours: "
                                        "replaced by their mean" + (" and its share of the table's step" if j < 3
                                                                    else "")))
                x[k] -= spike[i]
                continue
        seg = x[s0:s1 + 1]
        k, what = s0, None
        if encoder_step is not None:
            k, step = encoder_step
            what = (f"the encoder steps by {_arcsec(step)} at sample {k} and does not come back while {name} does "
                    "not (a jump: lost counts or a slipped zero)")
        hi, lo = float(x.max()), float(x.min())
        for ext in ((hi, lo) if what is None else ()):
            if abs(ext) <= bound:
                continue
            at, length = _runs(seg == ext)
            if at.size and length.max() >= th.saturated_samples:
                k = s0 + int(at[0])
                what = (f"{name} saturated: {int(length.sum())} samples at its extreme {_value(ext, unit)} (a "
                        f"clipped range: beyond the {_value(bound, unit)} a static base gives, held up to "
                        f"{int(length.max())} samples in a row)")
                break
        if what is None:
            change = np.flatnonzero(np.diff(seg) != 0.0)
            starts = np.concatenate(([0], change + 1))
            runs = np.diff(np.concatenate((starts, [seg.size])))
            r = int(np.argmax(runs))
            a = int(starts[r])
            # the run's excess over the fitted values against the stretch's residual
            w_of = (a + np.arange(int(runs[r]))) // L + w1
            excess = float(np.sum(seg[a:a + int(runs[r])] - fitted[w_of] / L))
            total = float(np.sum(dev[w1:w2 + 1]))
            explains = abs(excess - total) <= max(thr * math.sqrt(w2 - w1 + 1), 0.5 * abs(total))
            if runs[r] >= th.stuck_samples and explains:
                a = s0 + int(starts[r])
                v = x[a]
                b = a + int(runs[r])
                while a > 0 and x[a - 1] == v:          # the whole run (it may start before the window)
                    a -= 1
                while b < n and x[b] == v:
                    b += 1
                k = a
                what = f"{name} stuck at {_value(v, unit)} for {b - a} samples ({a}-{b - 1})"
        if what is None:
            step = _level_step(dev, thr, L, n)
            if step is not None:
                k, size = step
                per_s = size / (L * float(np.median(np.diff(t[s0 - 1:s1 + 1]))))
                what = (f"{name} bias steps by " + (f"{per_s / units.DEG_PER_H:+.4g} deg/h" if j < 3 else
                                                    f"{per_s:+.4g} m/s^2") + f" at about sample {k} "
                        f"(t = {t[k]:.6g} s: the windows before and after it sit at two levels)")
            else:
                what = f"{name} does not follow the table's turn"
        more = len(stretches) - 1
        findings.append(Finding("channel" if encoder_step is None else "encoder", k, float(t[k]), "refused",
                                f"{what}: windows of samples {s0}-{s1} off the fit by up to "
                                f"{_value(np.abs(dev[w1:w2 + 1]).max(), unit)}"
                                + (f" (and {more} more bad stretch{'es' if more > 1 else ''})" if more else "")
                                + f"; allowed: within {_value(thr, unit)} of a constant, a sinusoid of the table "
                                "angle" + (", the gyro's share of the turn" if j < 3 else "") + " and slow drift"))
        return


def _level_step(dev, thr, L, n):
    """``(sample, size)`` of one level change in a channel's window residuals ``dev`` (m,) that
    explains them (a bias step: the residual beyond it at most half its size), else None. The
    windows either side are compared through eight-window medians; the step's sample within the
    two windows at the change from their share of it (about a window's tenth at a step ten
    times the windows' noise)."""
    m = dev.size
    if m < 4:
        return None
    h = min(8, m // 2)
    from numpy.lib.stride_tricks import sliding_window_view
    med = np.median(sliding_window_view(dev, h), axis=1)            # med[i]: windows i .. i + h - 1
    jump = med[h:] - med[:-h]                                       # after window c - 1 vs before: c = h .. m - h
    if not jump.size:
        return None
    c = h + int(np.argmax(np.abs(jump)))        # near the change (a median ignores a few windows)
    a0 = max(0, c - h)
    c = a0 + 1 + int(np.argmax(np.abs(np.diff(dev[a0:c + h]))))     # the first window past the largest jump
    lo, hi = float(np.median(dev[max(0, c - 1 - h):c - 1])) if c > 1 else float(dev[0]), \
        float(np.median(dev[c + 1:c + 1 + h])) if c + 1 < m else float(dev[-1])
    size = hi - lo
    if not abs(size) > thr:
        return None
    fit = np.where(np.arange(m) < c, lo, hi)
    rest = np.abs(dev - fit)
    rest[max(0, c - 1):c + 1] = 0.0                                 # the windows the step falls in
    if rest.max() > 0.5 * abs(size):
        return None
    after = float(np.clip(((dev[c - 1] - lo) + (dev[c] - lo)) / size, 0.0, 2.0))   # windows after the step
    k = 1 + (c - 1) * L + int(round((2.0 - after) * L))
    return min(max(k, 1), n - 1), size


def _value(x, unit):
    x = float(x)
    return f"{x / units.ARCSEC:+.4g} arcsec" if unit == "gyro" else f"{x:+.4g} m/s"


# -- 3b. gyro steps (per sample) ---------------------------------------------------------------
def _check_gyro_steps(log, sums, enc, gyro, accel, th, findings, quanta):
    """Check 3b (:func:`hse_opt.align.steps.check_steps`, given the quanta, the jitter and the
    fit of the Allan analysis, refitted if a check repaired the log); returns the gyros."""
    now = log if (gyro is log.gyro and accel is log.accel and enc is log.encoder) else \
        type(log)._trusted(log.t, gyro, accel, enc, log.meta)
    try:
        residual = deterministic_residual(now, block_period=block_period(th.step_span_s), sums=sums)
    except ValueError:                                                 # shorter than 8 spans
        return gyro
    spikes = {(f.sample, CHANNELS.index(f.detail.split(" ")[0])) for f in findings
              if f.check == "channel" and f.action == "repaired" and " spike of " in f.detail}
    gyro, found = check_steps(log.t, enc, gyro, residual, jitter=quanta.jitter, q=quanta.pulses[:3],
                              level=lambda m: _level(th, 6.0 * m, m), floor=th.gyro_floor, qe=quanta.count,
                              bound=_QUANT_BOUND, most=th.repair_samples, spikes=spikes, sums=sums)
    findings += [Finding(*f) for f in found]
    return gyro


# -- 4. temperature ------------------------------------------------------------------------------
def _check_temperature(t, temp, L, m, th, findings):
    temp = np.asarray(temp, dtype=float)
    if temp.shape != t.shape:
        raise ValueError(f"temperature has shape {temp.shape}; allowed: one value per sample {t.shape}")
    ok = np.isfinite(temp)
    if not ok.any():
        return
    w = max(1, min(L, temp.size // 4))
    first, last = float(np.nanmean(temp[:w])), float(np.nanmean(temp[-w:]))
    if abs(last - first) > th.temp_drift_c:
        k = int(np.nanargmax(np.abs(temp - first)))
        findings.append(Finding("temperature", k, float(t[k]), "noted",
                                f"the temperature drifts {last - first:+.3g} degC over the run ({first:.4g} -> "
                                f"{last:.4g} degC; above {th.temp_drift_c:g} degC the gyro bias change may "
                                "not average out)"))


# -- the whole assessment ------------------------------------------------------------------------
def assess(log, *, thresholds=None, temperature=None, encoder_counts_per_rev=None, sums=None):
    """Check a raw log and repair what a documented rule allows (module docstring).

    Parameters
    ----------
    log : RawLog
        The log (validated and checked by the loader).
    thresholds : Thresholds, optional
    temperature : array_like, shape (n,), optional
        The IMU temperature at each sample, degC (a mapping file's ``temp_c`` column).
    encoder_counts_per_rev : float, optional
        The encoder's counts per revolution when known (the calibration file's
        ``encoder.counts_per_rev``); the log's metadata ``encoder_counts_per_rev`` serves when
        this is None, and the two differing refuses the log. Its count, ``2 pi / counts``, is
        the encoder's quantum in checks 1 and 3 (module docstring, *Encoder resolution*).
    sums : hse_opt.align.blocks.BlockSums, optional
        The log's block sums for the Allan analysis (:func:`hse_opt.align.blocks.block_sums`),
        taken once for both: check 3's window sums come from them when they are this log's and
        a window is a whole number of their blocks (8 at the default 500 Hz), else from the
        samples.

    Returns
    -------
    Quality
        ``quality.log`` is the log to align (repaired, or ``log`` itself); ``quality.refused``
        says whether to align it at all.
    """
    th = thresholds or _THRESHOLDS
    findings = check_metadata(log.meta)
    counts, problem = encoder_counts(log.meta, encoder_counts_per_rev)
    if problem:
        findings.append(Finding("metadata", None, None, "refused", problem))
    resolution = 0.0 if counts is None else 2.0 * math.pi / counts
    t, enc = log.t, log.encoder
    gyro, accel = log.gyro, log.accel
    n = t.size
    dt = float(t[-1] - t[0]) / (n - 1)
    quanta = Quanta.of(enc, gyro, accel, resolution,      # once for checks 1, 3 and 3b
                       seen=None if sums is None else sums.encoder_steps)
    enc2 = _check_encoder(t, enc, gyro, th, findings, quanta)
    L, m = _windows(n, dt, th)
    if m >= 2 and not any(f.action == "refused" and f.check == "encoder" for f in findings):
        turn = _check_rate(t, enc2, L, m, th, findings)
        if not any(f.check == "rate" for f in findings):
            quanta = Quanta.of(enc2, gyro, accel, resolution, like=quanta)
            gyro, accel, enc2 = _check_channels(t, enc2, gyro, accel, turn, L, m, th, findings,
                                                _channel_sums(log, L, m, sums) if m >= 8 else None, quanta,
                                                _middles(log, enc2, L, m, sums) if m >= 8 else None)
            if not any(f.action == "refused" for f in findings):
                gyro = _check_gyro_steps(log, sums, enc2, gyro, accel, th, findings,
                                         Quanta.of(enc2, gyro, accel, resolution, like=quanta))
    if temperature is not None:
        _check_temperature(t, temperature, L, m, th, findings)
    findings.sort(key=lambda f: (-1 if f.sample is None else f.sample))
    if any(f.action == "repaired" for f in findings):
        log = type(log)._trusted(t, gyro, accel, enc2, log.meta)
    return Quality(log=log, findings=tuple(findings))
