"""Check 3b's weighted sums and statistic (hse_opt.align.steps) against per-sample references
computed here from their definitions, and the loader's arrays being aligned."""
import math

import numpy as np
import pytest

from hse_opt.align import steps
from hse_opt.sim import RunSpec, TruthConfig, generate, load_rawlog, save_rawlog
from hse_opt.units import ARCSEC, DEG_PER_S


@pytest.fixture(scope="module")
def log():
    return generate(TruthConfig.default(), RunSpec(rate=40 * DEG_PER_S, azimuth=0.3, duration=80.0, t_start=7200.0),
                    np.random.default_rng(3))


def test_weighted_sums_match_per_sample_sums(log):
    enc, gyro, h = log.encoder, log.gyro, 32
    nb = (enc.size - 1) // h
    W, E = steps.weighted_sums(enc, gyro, h, nb)
    w = np.arange(h, 0, -1, dtype=float)
    d = np.diff(enc)[:nb * h].reshape(nb, h)                  # the encoder's steps, block by block
    x = gyro[1:nb * h + 1].reshape(nb, h, 3)
    assert np.abs(W - np.einsum("bic,i->cb", x, w)).max() < 1e-14 * np.abs(gyro).max() * h * h
    # from the steps, not by parts from the angles: the rounding of the sum (1e-16 of |E|), not
    # that of h angles of up to |enc| (70 rad here, 1e-9 of |E|); each block's exact sum (fsum
    # of exact steps: a difference of two angles within a factor 2 of each other is exact)
    exact = np.array([math.fsum(r) for r in d * w])
    assert np.abs(E - exact).max() < 4 * np.finfo(float).eps * np.abs(exact).max()


def test_the_block_sums_carry_check_3bs_weighted_sums_for_their_own_arrays_only(log):
    """block_sums with the checks' passes (the gyros' weighted sums right after their plain
    ones, the encoder's) gives the bytes weighted_sums takes from the samples themselves; a
    repaired copy's arrays are summed anew; the Allan analysis alone (checks=False) takes
    neither, and its plain sums are the same."""
    from hse_opt.align.blocks import block_sums
    s = block_sums(log)
    h, nb = s.block, s.sums.shape[1]
    W, E = steps.weighted_sums(log.encoder, log.gyro, h, nb)
    W2, E2 = steps.weighted_sums(log.encoder, log.gyro, h, nb, s)
    assert W2 is s.weighted and E2 is s.weighted_encoder
    assert np.array_equal(W, W2) and np.array_equal(E, E2)
    assert np.array_equal(s.sums, block_sums(log, checks=False).sums)
    # a copy with one gyro sample off by 1 arcsec: its own weighted sums, not the log's
    bad = log.gyro.copy()
    bad[1000, 2] += ARCSEC
    W3, E3 = steps.weighted_sums(log.encoder, bad, h, nb, s)
    b, i = divmod(999, h)                                     # increment 1000: block b, weight h - i
    assert E3 is s.weighted_encoder and (W3 - W)[2, b] == pytest.approx((h - i) * ARCSEC, rel=1e-6)
    assert np.count_nonzero(W3 != W) == 1
    enc2 = log.encoder.copy()
    enc2[1000] += ARCSEC                                      # steps 999 (+) and 1000 (-): weights h - i, h - i - 1
    W4, E4 = steps.weighted_sums(enc2, log.gyro, h, nb, s)
    assert W4 is s.weighted and (E4 - E)[b] == pytest.approx(ARCSEC, rel=1e-3)
    assert np.count_nonzero(np.abs(E4 - E) > 1e-12) == 1
    assert steps.weighted_sums(log.encoder, log.gyro, h // 2, 2 * nb, s)[0].shape == (3, 2 * nb)
    alone = block_sums(log, checks=False)
    assert alone.weighted is None and alone.weighted_encoder is None and alone.encoder_steps is None


def test_the_encoder_steps_seen_in_one_pass_are_numpys_and_the_steps_are_taken_on_demand(log):
    """What checks 1 and 3 read of the encoder's steps, taken with the block sums (their
    extremes, numpy's median of every 29th and the median absolute deviation, steps 1 ..
    4000): numpy's own figures of np.diff; the steps are not kept, but given when asked for;
    the quanta made from them are the quanta made from the log."""
    from hse_opt.align._quanta import Quanta
    from hse_opt.align.blocks import block_sums
    s = block_sums(log)
    seen, d = s.encoder_steps, np.diff(log.encoder)
    assert seen.encoder is log.encoder and "steps" not in vars(seen)
    assert (seen.largest, seen.smallest) == (d.max(), d.min())
    sub = d[::29]
    assert seen.step == np.median(sub)
    assert seen.step_sigma == pytest.approx(1.4826 * np.median(np.abs(sub - np.median(sub))), rel=1e-15)
    assert np.array_equal(seen.first, d[1:4001])
    assert np.array_equal(seen.steps, d)
    q, q0 = Quanta.of(log.encoder, log.gyro, log.accel, seen=seen), Quanta.of(log.encoder, log.gyro, log.accel)
    assert q.seen is seen and q0.seen is not seen
    assert (q.step, q.step_sigma, q.count) == (q0.step, q0.step_sigma, q0.count)
    assert np.array_equal(q.pulses, q0.pulses)
    enc2 = log.encoder.copy()                               # another encoder's steps are not taken
    assert Quanta.of(enc2, log.gyro, log.accel, seen=seen).seen is not seen


def _per_sample_statistic(log, residual, beta):
    """D from its definition, sample by sample: each increment less the fitted deterministic part
    (the residual's coefficients, ``beta`` for the encoder's steps beyond the mean rate), ``e``
    its cumulative sum, D(p) the mean of ``e`` over the K increments after p less that over the K
    before, a constant, a sinusoid of the table angle and a quadratic in time fitted out by least
    squares on every GRID-th value."""
    t, enc, gyro = log.t, log.encoder, log.gyro
    h, nb = residual.block, residual.blocks.shape[1]
    K, M = steps.GRID * h, nb * h
    coef = residual.coefficients[:, :3]
    dt, da = np.diff(t)[:M], np.diff(enc)[:M]
    mid = enc[:M] + 0.5 * da
    sinc = np.sinc(da / (2 * np.pi))
    det = (np.outer(dt, coef[0]) + np.outer(np.cos(mid) * sinc * dt, coef[1])
           + np.outer(np.sin(mid) * sinc * dt, coef[2]) + np.outer(da - residual.rate * dt, beta))
    x = gyro[1:M + 1] - det
    e = np.vstack([np.zeros(3), np.cumsum(x, axis=0)])        # e at increments 0 .. M
    p = h * np.arange(steps.GRID, nb + 1 - steps.GRID)
    ref = np.array([[e[q + 1:q + K + 1, j].mean() - e[q - K + 1:q + 1, j].mean() for q in p] for j in range(3)])
    u = np.linspace(-1.0, 1.0, p.size)
    A = np.stack([np.ones(p.size), np.cos(enc[p]), np.sin(enc[p]), u, u * u], axis=1)
    G = steps.GRID                                          # (fitted on every GRID-th edge, a K apart)
    return ref - (A @ np.linalg.lstsq(A[::G], ref[:, ::G].T, rcond=None)[0]).T, p


def test_statistic_matches_its_per_sample_definition(log):
    """D(p) from the Allan analysis' block sums and fit and one pass of weighted sums equals its
    definition computed sample by sample (the fitted part's per-sample terms, the encoder's
    steps in the ratio beta) within 0.2 % of its robust 1-sigma; a 0.2-arcsec step in gyro_y
    shows as d (1 - |p - p0| / K) at its peak."""
    from hse_opt.align.blocks import deterministic_residual
    k0 = 20011
    bad = log.gyro.copy()
    bad[k0, 1] += 0.2 * ARCSEC
    log2 = type(log)._trusted(log.t, bad, log.accel, log.encoder, log.meta)
    residual = deterministic_residual(log2, block_period=steps.block_period(0.25))
    assert residual.block == 32
    beta = steps.shares(residual)
    # the fitted constant rate over the encoder's against the increments' sum over its turn (they
    # differ by the Earth's rate over the log's fraction of a revolution: a few 1e-6)
    total = np.array([math.fsum(bad[1:, j]) for j in range(3)]) / float(log.encoder[-1] - log.encoder[0])
    assert np.allclose(beta, total, rtol=1e-5, atol=0.0)
    D, p, _ = steps.step_statistic(log.t, log.encoder, bad, residual, beta)
    ref, p_ref = _per_sample_statistic(log2, residual, beta)
    assert np.array_equal(p, p_ref)
    sigma = 1.4826 * np.median(np.abs(ref - np.median(ref, axis=1)[:, None]), axis=1)
    assert np.abs(D - ref).max() < 2e-3 * sigma.min()
    g0 = int(np.argmax(np.abs(D[1])))
    K = steps.GRID * residual.block
    assert abs(int(p[g0]) - (k0 - 1)) <= residual.block // 2
    assert abs(D[1, g0]) > 7 / 8 * 0.2 * ARCSEC - 6 * sigma[1]


def test_one_blas_thread_gives_the_bytes_of_two():
    """The record's block sums on one BLAS thread (hse_opt.align._blas) are the bytes numpy's
    matrix product gives on two: each output is one dot product in the kernel's order."""
    from threadpoolctl import threadpool_limits
    from hse_opt.align._blas import block_dot
    x = np.random.default_rng(5).standard_normal((3, 20000, 32))
    w = np.arange(32, 0, -1, dtype=float)
    with threadpool_limits(limits=2, user_api="blas"):
        two = x @ w
    assert np.array_equal(block_dot(x, w), two)
    assert np.abs(two - np.einsum("cbi,i->cb", x, w)).max() < 1e-13 * np.abs(x).max() * 32 * 32


def test_one_thread_limits_blas_only_where_it_has_more_and_restores_it():
    """hse_opt.align._blas.one_thread: BLAS on one thread inside whatever it had, its count
    back after (read by threadpoolctl's own report, not by the context's)."""
    from threadpoolctl import threadpool_info, threadpool_limits
    from hse_opt.align._blas import one_thread

    def counts():
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    for limit in (2, 1):
        with threadpool_limits(limits=limit, user_api="blas"):
            before = counts()
            with one_thread():
                assert counts() == [1] * len(before)
            assert counts() == before


def test_loaded_arrays_are_aligned_and_equal(log, tmp_path):
    path = tmp_path / "log.npz"
    save_rawlog(log, path)
    back = load_rawlog(path)
    for name in ("t", "gyro", "accel", "encoder"):
        a, b = getattr(back, name), getattr(log, name)
        assert a.flags.aligned and (a.flags.c_contiguous or a.flags.f_contiguous)
        assert np.array_equal(a, b)


@pytest.mark.parametrize("n", [100, 2900, 2901, 2902, 30001, 30030])
def test_jitter_from_every_29th_step_as_from_all_steps(n):
    from hse_opt.align import _stats
    enc = np.cumsum(np.random.default_rng(n).standard_normal(n))
    sub = _stats.every_29th_step(enc)
    d = np.diff(enc)
    assert np.array_equal(sub, d[::29] if d.size >= 2900 else d)
    assert _stats.step_stats(sub, True) == _stats.step_stats(d)


@pytest.mark.parametrize("shape", [(1,), (2,), (7,), (2342,), (3, 2342), (8, 1171), (3, 10)])
def test_row_median_is_numpys_median(shape):
    """The checks' median (one partition; for an even count the lower middle value the largest
    below the upper) equals numpy's, ties and all."""
    from hse_opt.align import _stats
    x = np.random.default_rng(shape[-1]).standard_normal(shape)
    x[..., ::3] = np.round(x[..., ::3], 1)                    # ties
    assert np.array_equal(_stats.row_median(x.copy()), np.median(x, axis=-1))
    assert np.array_equal(_stats.median(x.T), np.median(x, axis=-1))


def test_the_checks_normal_equations_give_numpys_least_squares():
    """The slow model's coefficients (Cholesky in Python floats) against numpy's SVD least
    squares on check 3's regressors, on every row, within 1e-13 of the largest; a regressor
    dependent on the others is left to numpy's solve, as before."""
    from hse_opt.align import _stats
    rng = np.random.default_rng(11)
    m = 1171
    A = _stats.regressors(np.linspace(0.0, 40.0, m))
    Y = A.T @ rng.standard_normal((5, 6)) + 1e-3 * rng.standard_normal((m, 6))
    ref = np.linalg.lstsq(A.T, Y, rcond=None)[0]
    got = _stats.fit(A, Y.T)
    assert np.abs(got - ref).max() < 1e-13 * np.abs(ref).max()
    keep = rng.random(m) > 0.1
    ref = np.linalg.lstsq(A[:, keep].T, Y[keep], rcond=None)[0]
    assert np.abs(_stats.fit(A, Y.T, keep) - ref).max() < 1e-13 * np.abs(ref).max()
    N = A @ A.T
    N[4] = N[3]
    N[:, 4] = N[:, 3]                                         # the drift's square a copy of the drift
    N[4, 4] *= 1.0 + 1e-14
    R = A @ Y
    assert np.array_equal(_stats.solve_normal(N, R), np.linalg.solve(N, R))
