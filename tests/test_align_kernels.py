"""The raw-log path's compiled passes over a record (hse_opt/align/_kernels.c, issue 25's
benchmark): built wherever a C compiler is present, and against independent references: each
block's sums against math.fsum (exactly rounded) of its samples, the encoder's extremes against
numpy's max and min of np.diff, and everything the quality checks and the Allan analysis take
of a log against numpy's route (the same figures, the same findings)."""
import math
import shutil

import numpy as np
import pytest

from hse_opt.align import _compiled, blocks
from hse_opt.align.noise import noise_from_log
from hse_opt.align.quality import assess
from hse_opt.units import DEG_PER_S

COMPILER = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
_kernels = _compiled.kernels
#: two routes' sums of a block of 32 (64) like-signed terms in different orders differ by a few
#: units of the last place of the largest sum at most: 64 of them is a bound
ROUNDING = 64 * np.finfo(float).eps
needs_kernels = pytest.mark.skipif(_kernels is None, reason="hse_opt.align._kernels is not built (no C compiler "
                                   "when the package was installed): numpy's route only")


def test_the_kernels_are_built_where_a_compiler_is():
    """setup.py's extension is optional (an install without a C compiler goes on without it);
    with a compiler present a failed build must not pass unnoticed."""
    if COMPILER is None:
        pytest.skip("no C compiler (cc, gcc or clang) on PATH: the extension is optional")
    assert _kernels is not None, "a C compiler is present but hse_opt.align._kernels was not built"


def _exact_blocks(x, block, nb, weights=None):
    """Each block's sum of x[1 + b block .. (b + 1) block] (weighted when given), by fsum."""
    rows = x[1:nb * block + 1].reshape(nb, block)
    if weights is not None:
        rows = rows * weights                       # (each product rounded once)
    return np.array([math.fsum(r) for r in rows]), np.abs(rows).sum(axis=1)


@needs_kernels
@pytest.mark.parametrize("block, nb", [(32, 101), (32, 100), (6, 37), (13, 20), (64, 9), (1, 50), (7, 1), (8, 0)])
def test_a_channel_s_block_sums_are_its_samples_summed(block, nb):
    """Sums and weighted sums (increment i of a block weighted block + 1 - i) within a few
    units of the last place of the sum of magnitudes of the exactly rounded sums, for blocks of
    a whole number of lanes (32, 64, 8), of lanes and a tail (13, 7), of a tail alone (6, 1),
    odd and even counts; the plain sums are the same bytes whether the weighted ones are taken."""
    rng = np.random.default_rng(block * 1000 + nb)
    x = 8e-4 + 1e-6 * rng.standard_normal(nb * block + 1 + 3)          # a turning gyro's increments
    s, w, s_alone = np.empty(nb), np.empty(nb), np.empty(nb)
    _kernels.block_sums(x, block, nb, s, w)
    _kernels.block_sums(x, block, nb, s_alone)
    exact, mag = _exact_blocks(x, block, nb)
    assert np.all(np.abs(s - exact) <= 4 * np.finfo(float).eps * mag)
    exact_w, mag_w = _exact_blocks(x, block, nb, np.arange(block, 0, -1, dtype=float))
    assert np.all(np.abs(w - exact_w) <= 8 * np.finfo(float).eps * mag_w)
    assert np.array_equal(s, s_alone)


@needs_kernels
@pytest.mark.parametrize("n, block, nb", [(3201, 32, 100), (3230, 32, 100), (500, 6, 83), (40, 13, 3), (2, 1, 1)])
def test_the_encoder_s_steps_extremes_and_weighted_sums(n, block, nb):
    """The largest and smallest of all n - 1 steps (the tail past the blocks too) are numpy's
    max and min of np.diff, bit for bit; a NaN step makes both NaN (as numpy's); the weighted
    sums sum (enc[start + i] - enc[start]), i = 1 .. block, as fsum of the steps does."""
    rng = np.random.default_rng(n)
    enc = np.cumsum(np.full(n, 1.4e-3) + 1e-6 * rng.standard_normal(n))
    enc[-1] += 0.01 if n > nb * block + 1 else 0.0                  # the largest step past the blocks
    w = np.empty(nb)
    largest, smallest = _kernels.encoder_steps(enc, block, nb, w)
    d = np.diff(enc)
    assert (largest, smallest) == (d.max(), d.min())
    exact, mag = _exact_blocks(np.concatenate(([0.0], d)), block, nb, np.arange(block, 0, -1, dtype=float))
    assert np.all(np.abs(w - exact) <= 8 * np.finfo(float).eps * mag)
    enc[n // 2] = np.nan
    assert all(math.isnan(v) for v in _kernels.encoder_steps(enc, block, nb, w))


@needs_kernels
def test_the_kernels_refuse_what_they_cannot_read():
    x = np.zeros(65)
    out = np.empty(2)
    with pytest.raises(TypeError, match="float64"):
        _kernels.block_sums(x.astype(np.float32), 32, 2, out)
    with pytest.raises(ValueError, match="at least 65 needed"):
        _kernels.block_sums(x[:64], 32, 2, out)
    with pytest.raises(ValueError, match="sums: 1 values, at least 2 needed"):
        _kernels.block_sums(x, 32, 2, out[:1])
    with pytest.raises((TypeError, BufferError, ValueError)):
        _kernels.block_sums(np.zeros((65, 2))[:, 0], 32, 2, out)      # not contiguous
    with pytest.raises(ValueError, match="block >= 1"):
        _kernels.encoder_steps(x, 0, 2, out)


def _log(seed, rate_dps=40.0, duration=120.0, truth=None):
    from hse_opt.sim import RunSpec, TruthConfig, generate
    return generate(truth or TruthConfig.default(), RunSpec(rate=rate_dps * DEG_PER_S, azimuth=0.3, duration=duration,
                                                            t_start=7200.0), np.random.default_rng(seed))


def _both_routes(log, monkeypatch):
    """(compiled, numpy): the block sums, the quality checks and the Allan figures by each."""
    out = []
    for kernels in (_kernels, None):
        monkeypatch.setattr(_compiled, "kernels", kernels)
        sums = blocks.block_sums(log)
        quality = assess(log, sums=sums)
        out.append((sums, quality, noise_from_log(quality.log, sums=sums)))
    return out


def _at_100_hz():
    import dataclasses
    from hse_opt.sim import TruthConfig
    from hse_opt.sim.truth import TimingConfig
    return dataclasses.replace(TruthConfig.default(), timing=TimingConfig(sample_period=0.01))


@needs_kernels
@pytest.mark.parametrize("seed, rate_dps, duration, hz", [(1, 40.0, 120.0, 500), (2, -10.0, 120.0, 500),
                                                          (3, 100.0, 120.0, 500), (4, 40.0, 10.0, 500),
                                                          (5, 40.0, 600.0, 100)])
def test_the_compiled_route_gives_numpy_s_figures_and_findings(seed, rate_dps, duration, hz, monkeypatch):
    """A log's block sums within rounding of numpy's route, the encoder's statistics the same
    bytes, the same findings (none on a clean log; a gyro's step and an encoder's jump found at
    the same sample, with the same action), Allan deviations within 1e-8 relative and the IEEE
    952 terms within 1e-9 of each channel's largest: 500 Hz logs of 2 minutes (eight stretches
    of 1024 samples for the short clusters, each whole blocks of 32) and of 10 s (four), and a
    100 Hz log (blocks of 6: the stretches end inside a block)."""
    log = _log(seed, rate_dps, duration, None if hz == 500 else _at_100_hz())
    gyro, enc = log.gyro.copy(), log.encoder.copy()
    gyro[len(log) // 3, 1] += 1e-6                                  # a step of 0.2 arcsec
    enc[2 * len(log) // 3] += 1.5e-4                                # an encoder sample 30 arcsec off
    faulty = type(log)(log.t, gyro, log.accel, enc, log.meta)
    for case in (log, faulty):
        (cs, cq, cn), (ns, nq, nn) = _both_routes(case, monkeypatch)
        assert np.allclose(cs.sums, ns.sums, rtol=0, atol=ROUNDING * np.abs(ns.sums).max())
        assert np.allclose(cs.weighted, ns.weighted, rtol=0, atol=ROUNDING * np.abs(ns.weighted).max())
        assert np.allclose(cs.weighted_encoder, ns.weighted_encoder, rtol=1e-14, atol=0)
        a, b = cs.encoder_steps, ns.encoder_steps
        assert (a.largest, a.smallest, a.step, a.step_sigma) == (b.largest, b.smallest, b.step, b.step_sigma)
        assert np.array_equal(a.first, b.first)
        assert [(f.check, f.sample, f.action) for f in cq.findings] == \
               [(f.check, f.sample, f.action) for f in nq.findings]
        # (the residual is 1e-5 of the sums and less: their rounding moves it by 1e-11 of
        # itself and the longest clusters' deviations by up to 5e-10; measured on these logs)
        assert np.allclose(cn.adev, nn.adev, rtol=1e-8, atol=0)
        scale = np.abs(nn.coefficients).max(axis=1, keepdims=True)
        assert np.all(np.abs(cn.coefficients - nn.coefficients) <= 1e-9 * scale)
    assert not _both_routes(log, monkeypatch)[0][1].findings
    assert {f.check for f in _both_routes(faulty, monkeypatch)[0][1].findings} >= {"encoder"}


@needs_kernels
def test_a_row_major_log_takes_numpy_s_route(monkeypatch):
    """A log whose channels are not contiguous rows (an (n, 3) C-ordered array, as a CSV reader
    may give) is summed by numpy's route, with the same figures to rounding."""
    from hse_opt.align import RawLog
    log = _log(4)
    rowmajor = RawLog(log.t, np.ascontiguousarray(log.gyro), np.ascontiguousarray(log.accel), log.encoder, log.meta)
    assert _compiled.rows(rowmajor.gyro) is None and _compiled.rows(log.gyro) is not None
    a, b = blocks.block_sums(log), blocks.block_sums(rowmajor)
    assert np.allclose(a.sums, b.sums, rtol=0, atol=ROUNDING * np.abs(a.sums).max())
    assert np.allclose(a.weighted, b.weighted, rtol=0, atol=ROUNDING * np.abs(a.weighted).max())


@needs_kernels
def test_the_quanta_are_numpy_s_on_quantized_noisy_flat_and_nan_rows():
    """The kernel's quantum of each row is numpy's route's (_row_quanta): a pulse counter
    dithered by jitter (its pulse), white noise (its smallest change), a row that does not
    change, one that changes in only 10 samples (no quantum: 0), one with a NaN (NaN). (Its
    threshold, 1e-9 of the mean magnitude, is summed in another order: a change within one
    unit of its last place could fall the other side of it.)"""
    from hse_opt.align._quanta import QUANTUM_CHANGES, _row_quanta
    rng = np.random.default_rng(7)
    q = 1e-6
    angle = np.cumsum(np.full(4001, 7.3e-5)) + 3 * q * rng.standard_normal(4001)
    rows = [np.diff(np.floor(angle / q) * q), rng.standard_normal(4000), np.zeros(4000),
            np.r_[np.zeros(3990), np.arange(10.0)], np.r_[np.nan, np.arange(3999.0) * 1e-3]]
    got = np.array(_kernels.quanta(rows, QUANTUM_CHANGES))
    assert np.array_equal(got, _row_quanta(np.stack(rows)), equal_nan=True)
    assert got[0] == pytest.approx(q, rel=1e-6) and got[2] == got[3] == 0.0 and math.isnan(got[4])


@needs_kernels
@pytest.mark.parametrize("rate_dps, wobble", [(40.0, 0.0), (100.0, 0.0), (-10.0, 0.0), (40.0, 0.5)])
def test_the_fit_s_regressors_against_their_closed_forms(rate_dps, wobble):
    """The kernel's block-edge cos and sin against numpy's cos and sin of the edges' angles
    (within 1e-13: its phase tables and series round at the angles' size, tens of rad), its
    regressors against their closed forms
    (``dt``, ``cos(alpha_m) sinc(d alpha / 2) dt``, ``sin(...)``, ``d alpha - Omega dt`` by
    numpy's cos, sin and sinc; within the sinc series' truncation, ``(d alpha / 2)^6 / 5040``
    at most, as numpy's route, plus 2e-13 of rounding), G and H against numpy's products;
    a table whose angle strays from a steady turn by more than the series take (``wobble``
    0.5 rad) gets libm's cos and sin."""
    rng = np.random.default_rng(int(abs(rate_dps) + 10 * wobble))
    block, nb = 32, 301
    n = nb * block + 1
    t = 7200.0 + 0.002 * np.arange(n)
    enc = 0.3 + rate_dps * DEG_PER_S * (t - t[0]) + 1e-6 * rng.standard_normal(n)
    enc += wobble * np.sin(2 * np.pi * (t - t[0]) / 3.0)
    y = rng.standard_normal((6, nb))
    ce, se, X, G, H = np.empty(nb + 1), np.empty(nb + 1), np.empty((4, nb)), np.empty((4, 4)), np.empty((4, 6))
    rate = _kernels.fit(enc, t, block, nb, y, ce, se, X, G, H)
    a, te = enc[::block], t[::block]
    assert rate == (a[-1] - a[0]) / (te[-1] - te[0])
    assert np.abs(ce - np.cos(a)).max() < 1e-13 and np.abs(se - np.sin(a)).max() < 1e-13
    da, dt = np.diff(a), np.diff(te)
    mid = a[:-1] + da / 2
    ref = np.array([dt, np.cos(mid) * np.sinc(da / 2 / np.pi) * dt, np.sin(mid) * np.sinc(da / 2 / np.pi) * dt,
                    da - rate * dt])
    tol = np.abs(da / 2).max() ** 6 / 5040 + 2e-13
    assert np.all(np.abs(X - ref).max(axis=1) <= tol * np.abs(ref).max(axis=1))
    # (each entry within 64 units of the last place of its Cauchy-Schwarz bound)
    norms = np.sqrt(np.concatenate([np.diag(X @ X.T), np.square(y).sum(axis=1)]))
    bound = 64 * np.finfo(float).eps * np.outer(norms[:4], norms)
    assert np.all(np.abs(G - X @ X.T) <= bound[:, :4]) and np.all(np.abs(H - X @ y.T) <= bound[:, 4:])
    out = np.empty_like(y)
    coef = np.ascontiguousarray(rng.standard_normal((4, 6)))
    _kernels.residual(y, coef, X, out)
    assert np.allclose(out, y - coef.T @ X, rtol=0, atol=1e-15 * np.abs(y).max())


@needs_kernels
@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_a_log_read_from_a_file_takes_the_compiled_route(tmp_path, suffix, monkeypatch):
    """A raw-log CSV (read row by row) and an .npz come back with each channel contiguous, so
    the checks' compiled passes read them; their figures are the numpy route's to rounding."""
    from hse_opt.align.rawlog import load_rawlog, save_rawlog
    log = _log(5)
    save_rawlog(log, tmp_path / f"log{suffix}")
    read = load_rawlog(tmp_path / f"log{suffix}")
    assert _compiled.rows(read.gyro) is not None and _compiled.rows(read.accel) is not None
    assert read.t.strides == read.encoder.strides == (8,)
    (cs, cq, cn), (ns, nq, nn) = _both_routes(read, monkeypatch)
    assert np.allclose(cs.sums, ns.sums, rtol=0, atol=ROUNDING * np.abs(ns.sums).max())
    assert np.allclose(cn.adev, nn.adev, rtol=1e-8, atol=0)


@needs_kernels
@pytest.mark.parametrize("seed, rate_dps", [(1, 40.0), (2, -10.0), (3, 100.0)])
def test_check_3b_s_statistic_is_numpy_s(seed, rate_dps):
    """The kernel's step statistic (before its slow part is fitted out) against numpy's route:
    within 1e-10 of its largest (it is the difference of sums about 1e4 times its size, whose
    rounding, in another order, is 1e-12 of it)."""
    from hse_opt.align import steps
    log = _log(seed, rate_dps)
    s = blocks.block_sums(log)
    res = s.residual
    beta = steps.shares(res)
    W, E = steps.weighted_sums(log.encoder, log.gyro, res.block, res.blocks.shape[1], s)
    got = steps._statistic_compiled(res, beta, W, E)
    ref = steps._statistic(res, beta, res.coefficients[:, :3].copy(), W, E)
    assert got.shape == ref.shape == (3, res.blocks.shape[1] - 7)
    assert np.abs(got - ref).max() <= 1e-10 * np.abs(ref).max()


@needs_kernels
@pytest.mark.parametrize("n", [9375, 9374, 4000, 300, 65])
def test_the_octave_squares_are_the_cumulative_sums_second_differences(n):
    """The kernel's squared second differences on a log's octave plan against the definition by
    cumulative sums (noise._squares, another route: within 1e-10, its rounding over the record)
    and against numpy's lattice route (the same sums: within 1e-14)."""
    from hse_opt.align.noise import MAX_TERMS, _octave_squares, _plan, _squares, cluster_sizes
    x = np.random.default_rng(n).standard_normal((6, n)) + 3.0
    plan, lattice, _, _ = _plan(n, tuple(cluster_sizes(n, steps_per_octave=1).tolist()), MAX_TERMS)
    assert lattice is not None
    ss = np.empty((len(plan), 6))
    _kernels.octave_squares(x, plan, lattice, ss)
    assert np.allclose(ss, _squares(x, plan), rtol=1e-10, atol=0)
    assert np.allclose(ss, _octave_squares(x, plan, lattice), rtol=1e-14, atol=0)
    with pytest.raises(ValueError, match="octave"):
        _kernels.octave_squares(x, [(3, 4, 10)], lattice, ss)



@needs_kernels
def test_check_3b_on_blocks_of_one_increment():
    """A block of one increment (a log sampled below 23 Hz, or a short step span): its weighted
    sum is its sum, the weighted regressors' correction is 0; both routes give the statistic
    (numpy's divided by zero, the compiled one gave NaN), within 1e-10 of its largest."""
    from hse_opt.align import steps
    log = _log(6, duration=20.0)
    res = blocks.deterministic_residual(log, block_period=0.002)
    assert res.block == 1
    beta = steps.shares(res)
    W, E = steps.weighted_sums(log.encoder, log.gyro, 1, res.blocks.shape[1])
    ref = steps._statistic(res, beta, res.coefficients[:, :3].copy(), W, E)
    got = steps._statistic_compiled(res, beta, W, E)
    assert np.isfinite(ref).all() and np.abs(got - ref).max() <= 1e-10 * np.abs(ref).max()


@needs_kernels
def test_the_kernels_refuse_sizes_that_overflow_and_shapes_that_disagree():
    """Counts whose products overflow are refused before any read (they passed the length
    checks by wrapping round), and arrays whose lengths disagree with the others' are named."""
    x, out = np.zeros(65), np.empty(2)
    for call in (lambda: _kernels.block_sums(x, 2 ** 62, 2, out), lambda: _kernels.encoder_steps(x, 2 ** 62, 2, out),
                 lambda: _kernels.fit(x, x, 2 ** 62, 2, np.zeros(12), np.empty(3), np.empty(3), np.empty(8),
                                      np.empty(16), np.empty(24))):
        with pytest.raises(ValueError, match="block >= 1 and 0 <= nb"):
            call()
    with pytest.raises(ValueError, match="octave"):
        _kernels.octave_squares(np.zeros((2, 64)), [(1, 2 ** 61 + 2 ** 59, 5)], 2, np.empty(2))
    rows = [np.zeros(100)] * 6
    with pytest.raises(ValueError, match="past the log"):
        _kernels.short_allan(rows, np.zeros(100), np.zeros(100), np.array([2 ** 63 - 100]), 16, 1, np.zeros((4, 6)),
                             0.0, np.ones(101), np.zeros(101), [1, 2], np.empty((6, 1, 2)))
    with pytest.raises(ValueError, match="X: 12 values, exactly 16 needed"):
        _kernels.residual(np.zeros((6, 4)), np.zeros((4, 6)), np.zeros((4, 3)), np.empty((6, 4)))


@needs_kernels
def test_repeated_cluster_sizes_take_either_route(monkeypatch):
    """allan_deviation with a size given twice: the compiled route gives numpy's figures (it
    refused sizes that were not strictly ascending)."""
    from hse_opt.align.noise import allan_deviation
    x = np.random.default_rng(9).standard_normal((2, 20000))
    got = allan_deviation(x, 1.0, sizes=[8, 8, 16])[1]
    monkeypatch.setattr(_compiled, "kernels", None)
    assert np.allclose(got, allan_deviation(x, 1.0, sizes=[8, 8, 16])[1], rtol=1e-14, atol=0)
