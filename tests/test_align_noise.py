"""The noise from the logs (issue 25, item 2): Allan deviation and the IEEE 952 terms against
closed forms on seeded synthetic noise, against allantools (an independent implementation of
the overlapping Allan deviation), and on simulated logs against the TruthConfig's noise.

Tolerances come from the estimator's variance: a point of the Allan deviation made of ``K``
independent clusters has a relative standard deviation ``1 / sqrt(2 (K - 1))`` (IEEE Std 952,
Annex C), ``K = n / m`` for a cluster of ``m`` of ``n`` samples, at most about the number of
start points the estimator averages (``MAX_TERMS``).
"""
import math

import numpy as np
import pytest

from hse_opt import units
from hse_opt.align.noise import (CHANNELS, MAX_TERMS, NOISE_COLUMNS, allan_deviation, combine_noise,
                                 fit_allan, noise_from_log)

TAU0 = 0.002
N_SAMPLES = 2 ** 17


def _clusters(n, m):
    """Independent clusters behind a point, as the test counts them (module docstring)."""
    return min(n / m, MAX_TERMS)


def _white_rate(rng, N, c, n=N_SAMPLES):
    """Increments of white rate noise of density N (rad/sqrt(s)): ADEV = N / sqrt(tau)."""
    return N * math.sqrt(TAU0) * rng.standard_normal((c, n))


def _rate_random_walk(rng, K, c, n=N_SAMPLES):
    """Increments of a rate random walk of K (rad/s/sqrt(s)), a Wiener process in continuous
    time integrated over each interval (the trapezoid of its ends plus the Brownian bridge's
    integral, variance K^2 tau0^3 / 12): ADEV = K sqrt(tau / 3)."""
    ends = np.cumsum(K * math.sqrt(TAU0) * rng.standard_normal((c, n + 1)), axis=1)
    bridge = K * math.sqrt(TAU0 ** 3 / 12.0) * rng.standard_normal((c, n))
    return 0.5 * TAU0 * (ends[:, :-1] + ends[:, 1:]) + bridge


def _quantized(rng, q, c, n=N_SAMPLES):
    """Pulse counts of a quantum q (rad) less the true increments, for an angle that turns
    steadily with a jitter of a few pulses (which dithers the counter): the counter's error in
    the cumulative angle is uniform over one pulse, white, std Q = q / sqrt(12): ADEV =
    sqrt(3) Q / tau."""
    angle = np.cumsum(np.full((c, n + 1), 7.3e-5), axis=1) + 3 * q * rng.standard_normal((c, n + 1))
    return np.diff(np.floor(angle / q) * q - angle, axis=1)


def _flicker(rng, B, c, n=N_SAMPLES):
    """Flicker rate noise with one-sided PSD h / f, h = B^2 / pi, shaped from white noise
    (white of unit variance has one-sided PSD 2 tau0): ADEV floor sqrt(2 ln 2 h) = 0.664 B."""
    f = np.fft.rfftfreq(n, TAU0)
    gain = np.zeros_like(f)
    gain[1:] = np.sqrt(B ** 2 / math.pi / f[1:] / (2.0 * TAU0))
    rate = np.fft.irfft(np.fft.rfft(rng.standard_normal((c, n)), axis=1) * gain, n=n, axis=1)
    return rate * TAU0


@pytest.mark.parametrize("seed", [1, 2])
def test_white_rate_noise_gives_n_over_sqrt_tau_and_its_arw(seed):
    N = 3e-6
    x = _white_rate(np.random.default_rng(seed), N, 3)
    tau, adev, _ = allan_deviation(x, TAU0)
    m = np.round(tau / TAU0)
    sigma = np.array([1 / math.sqrt(2 * (_clusters(N_SAMPLES, k) - 1)) for k in m])
    ratio = adev / (N / np.sqrt(tau))                      # closed form
    assert np.all(np.abs(ratio - 1) < 4.5 * sigma), np.max(np.abs(ratio - 1) / sigma)
    coef, _ = fit_allan(tau, adev, np.array([_clusters(N_SAMPLES, k) for k in m]))
    # the fit's N is no worse than three sigma of its best point
    assert np.allclose(np.sqrt(coef[:, 1]), N, rtol=3 * sigma.min())
    # no quantization or rate random walk beyond what the scatter of the extreme points allows
    # (a variance's relative 1-sigma is twice the deviation's)
    assert np.all(3 * coef[:, 0] / tau[0] ** 2 < 2 * 4.5 * sigma[0] * N ** 2 / tau[0])
    assert np.all(coef[:, 3] * tau[-1] / 3 < 2 * 4.5 * sigma[-1] * N ** 2 / tau[-1])


@pytest.mark.parametrize("seed", [3, 4])
def test_rate_random_walk_gives_k_sqrt_tau_over_3(seed):
    K = 2e-7
    x = _rate_random_walk(np.random.default_rng(seed), K, 3)
    tau, adev, clusters = allan_deviation(x, TAU0)
    m = np.round(tau / TAU0)
    # a random walk's Allan variance is less stable than white noise's: its points are checked
    # where at least 30 independent clusters stand behind them, at 6 sigma of the white-noise rule
    ok = N_SAMPLES / m >= 30
    sigma = np.array([1 / math.sqrt(2 * (_clusters(N_SAMPLES, k) - 1)) for k in m[ok]])
    ratio = adev[:, ok] / (K * np.sqrt(tau[ok] / 3))   # closed form
    assert np.all(np.abs(ratio - 1) < 6 * sigma + 0.02), np.max(np.abs(ratio - 1) / sigma)
    coef, _ = fit_allan(tau, adev, clusters)
    assert np.allclose(np.sqrt(3 * coef[:, 3]), K, rtol=0.15)


@pytest.mark.parametrize("seed", [5, 6])
def test_quantization_gives_sqrt3_q_over_tau(seed):
    q = 0.1 * units.ARCSEC
    Q = q / math.sqrt(12)
    x = _quantized(np.random.default_rng(seed), q, 3)
    tau, adev, clusters = allan_deviation(x, TAU0)
    m = np.round(tau / TAU0)
    sigma = np.array([1 / math.sqrt(2 * (_clusters(N_SAMPLES, k) - 1)) for k in m])
    ratio = adev / (math.sqrt(3) * Q / tau)                 # closed form
    assert np.all(np.abs(ratio - 1) < 4.5 * sigma + 0.01), np.max(np.abs(ratio - 1) / sigma)
    coef, _ = fit_allan(tau, adev, clusters)
    assert np.allclose(np.sqrt(coef[:, 0] / 3), Q, rtol=3 * sigma.min() + 0.005)


def test_flicker_floor_gives_the_bias_instability():
    B = 1e-6
    x = _flicker(np.random.default_rng(7), B, 3)
    tau, adev, clusters = allan_deviation(x, TAU0)
    # the flat floor sqrt(2 ln 2 / pi) B (flicker approximated by a constant: its curve
    # bends near the shortest clusters and the record length, so the middle decades)
    mid = (tau > 0.05) & (tau < 2.0)
    assert np.allclose(adev[:, mid], math.sqrt(2 * math.log(2) / math.pi) * B, rtol=0.15)
    coef, _ = fit_allan(tau, adev, clusters)
    assert np.allclose(np.sqrt(coef[:, 2] * math.pi / (2 * math.log(2))), B, rtol=0.2)


def test_a_sum_of_terms_is_split_into_each():
    rng = np.random.default_rng(8)
    N, K, q = 3e-6, 3e-6, 0.5 * units.ARCSEC   # random walk above white noise from 2 s
    x = _white_rate(rng, N, 3, n=2 ** 18) + _rate_random_walk(rng, K, 3, n=2 ** 18) + _quantized(rng, q, 3, n=2 ** 18)
    tau, adev, clusters = allan_deviation(x, TAU0)
    coef, std = fit_allan(tau, adev, clusters)
    assert np.allclose(np.sqrt(coef[:, 0] / 3), q / math.sqrt(12), rtol=0.05)
    # N shares the middle decades with the random walk: over the 60 channel-records below it
    # scattered by 4 % (1 sigma): 3 sigma
    assert np.allclose(np.sqrt(coef[:, 1]), N, rtol=0.12)
    # a random walk is seen through the few longest clusters: over 60 such channel-records
    # (seeds 0-19) the fitted K scattered by 14 % (1 sigma) about the truth: 3 sigma
    assert np.allclose(np.sqrt(3 * coef[:, 3]), K, rtol=0.4)
    # the fit's own 1-sigma of N covers its error at 4 sigma
    assert np.all(np.abs(coef[:, 1] - N ** 2) < 4 * std[:, 1])


def test_the_fits_nonnegative_solution_is_scipys_nnls():
    """The fit's non-negative least squares (the Karush-Kuhn-Tucker set among all 16 from
    the Schur complements of [G h]) against scipy's active-set NNLS (Lawson-Hanson) on
    weighted Allan-model systems whose solutions hold 0 to 3 terms at zero; the inverse
    normal matrix's diagonal on the solution's set against numpy's inverse."""
    from scipy.optimize import nnls
    from hse_opt.align.allan_fit import _SETS, _nonnegative, _table
    rng = np.random.default_rng(12)
    tau = 0.002 * 2.0 ** np.arange(18)
    T = tau[:, None] ** np.arange(-2, 2)
    A, b = [], []
    for _ in range(40):
        coef = rng.uniform(0, 1, 4) * np.array([1e-12, 1e-10, 1e-12, 1e-14]) * (rng.uniform(size=4) < 0.7)
        avar = (T @ coef) * (1 + 0.3 * rng.standard_normal(18)) + 1e-16
        a = T / (0.1 * np.abs(avar))[:, None]
        a /= np.sqrt(np.sum(a ** 2, axis=0))                  # unit columns, as the fit scales them
        A.append(a)
        b.append(avar / (0.1 * np.abs(avar)))
    A, b = np.array(A), np.array(b)
    G = np.einsum("rki,rkj->rij", A, A) + 1e-13 * np.eye(4)
    h = np.einsum("rki,rk->ri", A, b)
    # scipy on the same objective: |A x - b|^2 + 1e-13 |x|^2
    ref = np.array([nnls(np.vstack([a, math.sqrt(1e-13) * np.eye(4)]), np.concatenate([bb, np.zeros(4)]))[0]
                    for a, bb in zip(A, b)])
    assert len({tuple(r > 0) for r in ref}) >= 4                # several different active sets
    table = _table(len(G))
    table[:24] = np.concatenate([G, h[:, :, None], -h[:, :, None]], axis=2).reshape(len(G), 24).T
    x, var, best = _nonnegative(table, with_variance=True)
    assert np.allclose(x, ref, rtol=1e-8, atol=1e-10 * np.abs(ref).max())
    assert np.array_equal(_SETS[best], ref > 0)
    for g, s, v in zip(G, _SETS[best], var):
        assert np.allclose(v[s], np.diag(np.linalg.inv(g[np.ix_(s, s)])), rtol=1e-9, atol=0)
        assert np.isnan(v[~s]).all()


def test_the_overlapping_allan_deviation_is_allantools_oadev():
    allantools = pytest.importorskip("allantools", reason="allantools is a test extra (pyproject [test])")
    rng = np.random.default_rng(9)
    x = _white_rate(rng, 3e-6, 2, n=20000) + _rate_random_walk(rng, 1e-7, 2, n=20000)
    # every start point: exactly allantools' fully overlapping estimator
    tau, adev, _ = allan_deviation(x, TAU0, max_terms=10 ** 9)
    for c in range(2):
        t_ref, a_ref, _, _ = allantools.oadev(x[c] / TAU0, rate=1 / TAU0, data_type="freq", taus=tau)
        assert np.allclose(t_ref, tau) and np.allclose(adev[c], a_ref, rtol=1e-9, atol=0)
    # the default's subsampled start points: a cluster of at least the lattice s (the largest
    # power of two up to the shortest cluster's stride, here 19999 // MAX_TERMS = 9: s = 8)
    # takes every s-th, i.e. allantools' fully overlapping estimator on the record summed over
    # s where the cluster is whole sums; every one within the estimator's own scatter of all
    # start points
    tau, sub, clusters = allan_deviation(x, TAU0)
    s = 2 ** int(math.log2((20000 - 1) // MAX_TERMS))
    on = np.round(tau / TAU0) % s == 0
    assert s == 8 and on.sum() >= 10
    xs = x[:, :20000 // s * s].reshape(2, -1, s).sum(axis=2)
    for c in range(2):
        t_ref, a_ref, _, _ = allantools.oadev(xs[c] / (s * TAU0), rate=1 / (s * TAU0), data_type="freq",
                                              taus=tau[on])
        assert np.allclose(t_ref, tau[on]) and np.allclose(sub[c, on], a_ref, rtol=1e-9, atol=0)
    sigma = 1 / np.sqrt(2 * (clusters - 1))
    assert np.all(np.abs(sub / adev - 1) < 4 * sigma)


@pytest.mark.parametrize("n, max_terms", [(9374, MAX_TERMS), (9999, MAX_TERMS), (8194, MAX_TERMS), (20000, 300),
                                           (937, MAX_TERMS), (5000, 10 ** 9), (5000, MAX_TERMS), (7000, MAX_TERMS),
                                           (14000, MAX_TERMS)])
def test_octave_clusters_take_the_definitions_start_points(n, max_terms):
    """Octave cluster sizes (as the logs' analysis takes them: a 10-minute log's 9374 blocks at
    500 Hz, 9999 at 100 Hz) against the definition written out here: the start points ``k =
    0, step, 2 step, ..`` with ``step = max(1, (n + 1 - 2m) // max_terms)`` for a cluster
    shorter than the lattice ``s`` (that stride of the shortest cluster, to a power of two
    below) and ``step = s`` for the others, the second differences of the cumulative sum in
    extended precision. Short clusters' strides that are no power of two (3 in a 7.5-minute
    log, 6 in a 15-minute one, 65 and 66 with s = 64), every start point (s = 1); the first
    pairs by the complex product (an even n and an even stride: 9374, 14000,
    5000 with s = 2), by strided sums (9999: n odd; 7000: stride 3), and the cumulative sum
    where a short cluster's stride is no multiple of it (8194, 20000)."""
    rng = np.random.default_rng(n)
    x = _white_rate(rng, 3e-6, 3, n=n) + _rate_random_walk(rng, 1e-6, 3, n=n) + 1e-7   # a bias too
    sizes = 2 ** np.arange(int(math.log2(n // 2)) + 1)
    tau, adev, clusters = allan_deviation(x, TAU0, max_terms=max_terms, sizes=sizes)
    theta = np.concatenate([np.zeros((3, 1)), np.cumsum(x.astype(np.longdouble), axis=1)], axis=1)
    s = 2 ** int(math.log2(max(1, (n - 1) // max_terms)))
    for i, m in enumerate(sizes.tolist()):
        step = s if m >= s else max(1, (n + 1 - 2 * m) // max_terms)
        k = np.arange(0, n - 2 * m + 1, step)
        d = theta[:, k + 2 * m] - 2 * theta[:, k + m] + theta[:, k]
        ref = np.sqrt(np.mean(d ** 2, axis=1) / 2).astype(float) / (m * TAU0)
        assert np.allclose(adev[:, i], ref, rtol=1e-12, atol=0), (m, step)
        assert clusters[i] == min(n / m, k.size) and tau[i] == m * TAU0


def test_campaign_pooling_is_the_cluster_weighted_mean_of_the_variances():
    rng = np.random.default_rng(10)
    logs = [_SyntheticLog(rng, n) for n in (40000, 40000, 60000)]
    figs = [noise_from_log(log) for log in logs]
    pooled = combine_noise(figs)
    assert pooled.n_logs == 3
    i = 5   # a cluster time all three share
    t = figs[0].tau[i]
    w = [f.clusters[list(f.tau).index(t)] for f in figs]
    v = [f.adev[:, list(f.tau).index(t)] ** 2 for f in figs]
    j = int(np.argmin(np.abs(pooled.tau - t)))
    assert np.allclose(pooled.adev[:, j] ** 2, sum(wi * vi for wi, vi in zip(w, v)) / sum(w), rtol=1e-12)
    assert np.allclose(pooled.random_walk[:3], _SyntheticLog.N, rtol=0.05)


class _SyntheticLog:
    """A raw log of white rate noise on a table turning at 40 deg/s with a 0.5 arcsec jitter,
    the Earth rate and gravity modulated at the table rate (by hand, not by the simulator)."""
    N = 5e-6

    def __init__(self, rng, n):
        t = np.arange(n) * TAU0
        rate = 40 * units.DEG_PER_S
        self.encoder = rate * t + 0.5 * units.ARCSEC * rng.standard_normal(n)
        share = np.array([-0.577, -0.578, -0.577])
        w_h = 13 * units.DEG_PER_H
        a = self.encoder
        turn = np.diff(a, prepend=a[0])[:, None] * share
        earth = w_h * np.column_stack([np.cos(a), np.sin(a), -np.cos(a + 1)]) * TAU0
        self.gyro = turn + earth + (_white_rate(rng, self.N, 3, n=n)).T
        self.accel = (np.column_stack([0.1 * np.cos(a), -0.1 * np.sin(a), np.full(n, 5.66)]) * TAU0
                      + _white_rate(rng, 1e-5, 3, n=n).T)
        self.t = t


def test_the_table_turn_earth_rate_and_gravity_are_fitted_out():
    log = _SyntheticLog(np.random.default_rng(11), 60000)
    fig = noise_from_log(log)
    # what remains is the white noise: its ARW and VRW, no quantization, no bias instability
    assert np.allclose(fig.random_walk[:3], _SyntheticLog.N, rtol=0.05)
    assert np.allclose(fig.random_walk[3:], 1e-5, rtol=0.05)
    white = _SyntheticLog.N / np.sqrt(fig.tau)
    assert np.all(fig.adev[:3] < 2.0 * white)      # the 0.5 arcsec jitter alone would be 10 x
    assert set(fig.columns()) == set(NOISE_COLUMNS) and len(CHANNELS) == 6


# -- simulated logs against the TruthConfig's noise ------------------------------------------------

def _sim_log(truth, seed, duration=120.0):
    from hse_opt.sim import RunSpec, generate
    return generate(truth, RunSpec(rate=40 * units.DEG_PER_S, azimuth=0.3, duration=duration, t_start=7200.0),
                    np.random.default_rng(seed))


def test_a_term_the_logs_cannot_resolve_is_said_so_not_printed_as_zero():
    """The printed figures: a simulated system with no flicker (the default truth) leaves the
    gyros' bias instability at zero or within its 1-sigma of it: the line says it is not
    resolved; white rate noise plus a flicker floor (the closed forms above) prints the bias
    instability it resolves, and both print the angle random walk."""
    from hse_opt.align.noise import NoiseFigures
    from hse_opt.sim import TruthConfig
    fig = noise_from_log(_sim_log(TruthConfig.default(), 4))
    b, sb = fig.coefficients[:3, 2], fig.coefficients_std[:3, 2]
    assert not (b > 2 * sb).any()                      # (NaN 1-sigma: held at zero)
    text = fig.summary()
    assert "bias instability not resolved by these logs" in text and "gyro ARW 0." in text
    rng = np.random.default_rng(8)
    x = _white_rate(rng, 3e-7, 6) + _flicker(rng, 1e-6, 6)
    tau, adev, clusters = allan_deviation(x, TAU0)
    coef, std = fit_allan(tau, adev, clusters)
    assert (coef[:, 2] > 2 * std[:, 2]).all()
    shown = NoiseFigures(tau=tau, adev=adev, clusters=clusters, coefficients=coef, coefficients_std=std).summary()
    assert float(shown.split("bias instability ")[1].split(" deg/h")[0]) > 0


def test_simulated_logs_give_the_truths_arw_vrw_and_quanta():
    from hse_opt.sim import TruthConfig
    # a noisier gyro than the default (0.05 deg/h/sqrt(Hz)): its white noise shows above the
    # quantization from 0.5 s, so two-minute logs pin it
    truth = TruthConfig.default().updated({"gyro": {"arw_dph_rthz": 0.05}, "accel": {"vrw_ug_rthz": 20.0}})
    figs = [noise_from_log(_sim_log(truth, seed)) for seed in (1, 2, 3)]
    fig = combine_noise(figs)
    cols = fig.columns()
    assert cols["gyro_arw_dph_rthz"] == pytest.approx(0.05, rel=0.1)
    assert cols["accel_vrw_ug_rthz"] == pytest.approx(20.0, rel=0.1)
    # gyro quantization: the pulses' q / sqrt(12) and the encoder's resolution / sqrt(12)
    # seen through the axis's share of the turn (|r_zb^s| components about 0.577)
    share = np.abs(np.asarray(truth.mount.r_zb_s_true))
    q_gyro = np.sqrt((truth.gyro.pulse / math.sqrt(12)) ** 2 + (share * truth.encoder.resolution / math.sqrt(12)) ** 2)
    assert np.allclose(fig.quantization[:3], q_gyro, rtol=0.1)
    assert cols["accel_quantization_mps"] == pytest.approx(truth.accel.pulse / math.sqrt(12), rel=0.1)


def test_the_clusters_shorter_than_a_block_are_allantools_oadev_of_the_stretches():
    """The clusters of 1..16 samples (shorter than a 32-sample block) against allantools' fully
    overlapping estimator on the raw samples of the eight stretches of 1024 samples spread over
    the log at block edges (module docstring, step 3), the fitted deterministic part taken off
    every sample here with numpy's cos and sin of the mid-sample encoder angle, the variances
    of the stretches averaged (each has as many start points). Within 1e-12."""
    allantools = pytest.importorskip("allantools", reason="allantools is a test extra (pyproject [test])")
    from hse_opt.align.blocks import deterministic_residual
    from hse_opt.sim import TruthConfig
    log = _sim_log(TruthConfig.default(), 4, duration=60.0)
    fig = noise_from_log(log)
    res = deterministic_residual(log)
    t, enc = np.asarray(log.t), np.asarray(log.encoder)
    n, block, count, length = t.size - 1, res.block, 8, 1024
    dt = (t[-1] - t[0]) / n
    first = np.round(np.linspace(0, (n - length) // block, count)).astype(int) * block
    sizes = [1, 2, 4, 8, 16]
    assert block == 32 and np.allclose(fig.tau[:5], np.array(sizes) * dt, rtol=1e-12)
    var = np.zeros((6, len(sizes)))
    for s0 in first:
        i = np.arange(s0 + 1, s0 + 1 + length)                  # the stretch's samples
        h, da = t[i] - t[i - 1], enc[i] - enc[i - 1]
        mid = enc[i - 1] + 0.5 * da
        X = np.array([h, h * np.cos(mid), h * np.sin(mid), da - res.rate * h])
        r = np.column_stack([log.gyro[i], log.accel[i]]).T - res.coefficients.T @ X
        for c in range(6):
            taus, adev, _, _ = allantools.oadev(r[c] / dt, rate=1 / dt, data_type="freq",
                                                taus=np.array(sizes) * dt)
            assert np.allclose(taus, np.array(sizes) * dt)
            var[c] += adev ** 2 / count
    assert np.allclose(fig.adev[:, :5], np.sqrt(var), rtol=1e-12, atol=0)
    assert np.allclose(fig.clusters[:5], count * length / np.array(sizes))


def test_a_noise_free_simulated_log_leaves_nothing():
    from hse_opt.sim import TruthConfig
    truth = TruthConfig.default()
    fig = noise_from_log(_sim_log(truth.noise_free(), 1, duration=60.0))
    # the table turn, its ripple and jitter, the Earth rate and gravity are gone: what is left
    # is far below the default sensors' noise
    assert fig.columns()["gyro_arw_dph_rthz"] < 1e-3 * truth.gyro.arw / units.DEG_PER_H
    assert fig.columns()["accel_vrw_ug_rthz"] < 1e-3 * truth.accel.vrw / units.MICRO_G



@pytest.mark.parametrize("top, bound", [(1e-3, 5e-14), (0.03, 2e-12), (0.2, 3e-9), (1.5, 1e-15)])
def test_small_angles_cos_sin_and_sinc_by_series_within_their_stated_errors(top, bound):
    """blocks._cos_sin_small's series (and numpy's above _SERIES_MAX) against numpy's cos, sin
    and sinc, within the errors its docstring states for the largest angle ``top`` (the sinc's:
    the sine's over ``top``)."""
    from hse_opt.align.blocks import _cos_sin_small
    d = np.linspace(-top, top, 2001)
    c, s, sinc = _cos_sin_small(d, sinc=True)
    assert np.abs(c - np.cos(d)).max() < bound and np.abs(s - np.sin(d)).max() < bound
    assert np.abs(sinc - np.sinc(d / math.pi)).max() < bound / top and sinc[1000] == 1.0
    c2, s2 = _cos_sin_small(d)
    assert np.array_equal(c2, c) and np.abs(s2 - s).max() <= 1e-16 * top


def test_cos_sin_of_a_nearly_linear_angle_is_numpys():
    """blocks._cos_sin (short phase tables, the deviation by series) against numpy's on a turning
    table's edge angles with jitter, and on a stall (numpy's own route)."""
    from hse_opt.align.blocks import _cos_sin
    rng = np.random.default_rng(3)
    a = 0.7 + 0.02 * np.arange(9376) + 1e-4 * rng.standard_normal(9376)
    c, s = _cos_sin(a)
    assert np.abs(c - np.cos(a)).max() < 1e-12 and np.abs(s - np.sin(a)).max() < 1e-12
    a[4000:] = a[4000]                                  # a stall: far from a steady turn
    c, s = _cos_sin(a)
    assert np.array_equal(c, np.cos(a)) and np.array_equal(s, np.sin(a))


def test_the_deterministic_fits_normal_equations_are_least_squares_or_leave_out_what_is_undetermined():
    """blocks._normal_solve against numpy's SVD least squares: the coefficients where the
    regressors determine them (by the LDL^T route), the fitted values where a column is zero or
    two are collinear (a perfect encoder's jitter term, a table at rest: the eigen route), with
    no coefficient blown up by the undetermined direction."""
    from hse_opt.align.blocks import _normal_solve
    rng = np.random.default_rng(7)
    X = rng.standard_normal((4, 300)) * np.array([[1e-3], [2e-3], [2e-3], [1e-5]])
    Y = rng.standard_normal((6, 300)) * 1e-6 + np.array([1.0, -2.0, 0.5, 3.0]) @ X
    ref = np.linalg.lstsq(X.T, Y.T, rcond=None)[0]
    coef = _normal_solve(X @ X.T, X @ Y.T)
    assert np.abs(coef - ref).max() < 1e-9 * np.abs(ref).max()
    for broken in ("zero", "collinear"):
        Xb = X.copy()
        Xb[3] = 0.0 if broken == "zero" else 0.5 * Xb[0]
        coef = _normal_solve(Xb @ Xb.T, Xb @ Y.T)
        ref = np.linalg.lstsq(Xb.T, Y.T, rcond=None)[0]
        assert np.abs(coef.T @ Xb - ref.T @ Xb).max() < 1e-9 * np.abs(Y).max()
        assert np.isfinite(coef).all() and np.abs(coef).max() < 10 * np.abs(ref).max()


def test_the_block_sums_are_the_rows_summed_and_serve_their_own_log_only():
    """The block sums hse-opt align takes once for the quality checks and the Allan analysis
    (block_sums): each block's rows summed (by numpy's reduceat, here), 32 samples (64 ms) at
    500 Hz; the analysis gives the same figures with them as without; a changed copy of the
    log (as a repair makes) is summed anew, not read from the original's sums."""
    from hse_opt.align import RawLog
    from hse_opt.align.blocks import block_sums
    from hse_opt.sim import TruthConfig
    log = _sim_log(TruthConfig.default(), 5, duration=60.0)
    s = block_sums(log)
    nb = s.sums.shape[1]
    assert s.block == 32 and nb == (len(log) - 1) // 32
    rows = np.hstack([log.gyro, log.accel])[1:nb * 32 + 1]
    assert np.allclose(s.sums, np.add.reduceat(rows, np.arange(0, nb * 32, 32), axis=0).T, rtol=1e-12, atol=1e-15)
    shared, alone = noise_from_log(log, sums=s), noise_from_log(log)
    assert np.array_equal(shared.adev, alone.adev) and np.array_equal(shared.coefficients, alone.coefficients)
    gyro = log.gyro + 1e-6 * np.random.default_rng(6).standard_normal(log.gyro.shape)      # a noisier copy
    noisier = RawLog(log.t, gyro, log.accel, log.encoder, log.meta)
    assert s.of(noisier, s.block) is None
    fig = noise_from_log(noisier, sums=s)
    assert np.array_equal(fig.adev, noise_from_log(noisier).adev)
    assert np.all(fig.random_walk[:3] > 10 * shared.random_walk[:3])

def test_a_short_log_is_refused_naming_what_is_needed():
    log = _SyntheticLog(np.random.default_rng(12), 200)
    with pytest.raises(ValueError, match="allowed: at least"):
        noise_from_log(log)


# -- hse-opt align: the columns, the tuning from the data -----------------------------------------

@pytest.fixture(scope="module")
def sim_logs(tmp_path_factory):
    """Three 2-minute simulated logs of a noisy system and one noise-free log, on disk."""
    from hse_opt.align import save_rawlog
    from hse_opt.sim import TruthConfig
    truth = TruthConfig.default().updated({"gyro": {"arw_dph_rthz": 0.05}, "accel": {"vrw_ug_rthz": 20.0}})
    d = tmp_path_factory.mktemp("noisy")
    for seed in (1, 2, 3):
        save_rawlog(_sim_log(truth, seed), d / f"log{seed}.npz")
    free = tmp_path_factory.mktemp("free")
    save_rawlog(_sim_log(TruthConfig.default().noise_free(), 4), free / "free.npz")
    return truth, d, free


def test_align_writes_the_noise_columns_and_prints_the_campaigns_figures(sim_logs, tmp_path, capsys):
    from hse_opt.cli import main
    from hse_opt.data import load_runs
    truth, d, _ = sim_logs
    out = tmp_path / "RUNS.csv"
    assert main(["align", str(d), "-o", str(out), "--no-progress"]) == 0
    runs = load_runs(out)
    assert set(NOISE_COLUMNS) <= set(runs.covariates)
    # each log's own figures, against the truth's (one 2-minute log: 25 %)
    assert np.allclose(runs.covariates["gyro_arw_dph_rthz"], 0.05, rtol=0.25)
    assert np.allclose(runs.covariates["accel_vrw_ug_rthz"], 20.0, rtol=0.25)
    err = capsys.readouterr().err
    assert "noise (Allan, IEEE 952) over 3 logs: gyro ARW" in err
    # outcomes of the log, not settings: never a factor or a covariate candidate
    from hse_opt.factors import is_derived
    assert all(is_derived(c) for c in NOISE_COLUMNS) and not is_derived("temp_c")


def test_the_filter_is_tuned_from_the_logs_noise_unless_a_truth_gives_it(sim_logs, tmp_path):
    from hse_opt.cli import main
    from hse_opt.data import load_runs
    from hse_opt.sim import TruthConfig, save_truth
    truth, d, free = sim_logs
    # the issue: a noise-free log reported heading_std 11.6 arcsec (the default system's
    # tuning whatever the log holds); tuned from the log, the filter's 1-sigma is its own
    assert main(["align", str(free), "-o", str(tmp_path / "free.csv"), "--no-progress"]) == 0
    assert load_runs(tmp_path / "free.csv").heading_std[0] < 0.5 * units.ARCSEC
    # the noisy system (4.2 x the default's ARW): the 1-sigma grows with the data's noise ...
    assert main(["align", str(d), "-o", str(tmp_path / "data.csv"), "--no-progress"]) == 0
    data = load_runs(tmp_path / "data.csv")
    # ... to that of the filter tuned with the truth's own noise (within the pooled ARW's error)
    save_truth(truth, tmp_path / "TRUTH.toml")
    assert main(["align", str(d), "-o", str(tmp_path / "truth.csv"), "--no-progress",
                 "--truth", str(tmp_path / "TRUTH.toml")]) == 0
    told = load_runs(tmp_path / "truth.csv")
    assert np.allclose(data.heading_std, told.heading_std, rtol=0.12)
    # and not the default system's (0.012 deg/h/sqrt(Hz)), which the logs would have had before
    assert np.all(data.heading_std > 3 * _default_sigma(TruthConfig.default(), d, tmp_path))


def _default_sigma(truth, d, tmp_path):
    """The heading 1-sigma the default system's tuning gives these logs, rad."""
    from hse_opt.cli import main
    from hse_opt.data import load_runs
    from hse_opt.sim import save_truth
    save_truth(truth, tmp_path / "DEFAULT.toml")
    assert main(["align", str(d), "-o", str(tmp_path / "dflt.csv"), "--no-progress",
                 "--truth", str(tmp_path / "DEFAULT.toml")]) == 0
    return load_runs(tmp_path / "dflt.csv").heading_std


def test_align_report_plots_the_allan_curves_with_the_fitted_slopes(sim_logs, tmp_path):
    import json
    import re

    from hse_opt.cli import main
    from hse_opt.data import load_runs
    from hse_opt.report import plot_allan
    truth, d, _ = sim_logs
    assert main(["align", str(d), "-o", str(tmp_path / "RUNS.csv"), "--no-progress", "--report",
                 str(tmp_path / "rep")]) == 0
    page = (tmp_path / "rep" / "report.html").read_text()
    data = json.loads(re.search(r'id="hse-opt-data">(.*?)</script>', page, re.S).group(1))
    section = data["Sensor noise (Allan deviation, IEEE Std 952)"]
    runs = load_runs(tmp_path / "RUNS.csv")
    # the page's per-log figures are the RUNS.csv columns; the pooled ARW is the truth's
    for i, name in enumerate(sorted(section["logs"])):
        assert section["logs"][name]["gyro_arw_dph_rthz"] == pytest.approx(runs.covariates["gyro_arw_dph_rthz"][i])
    assert section["pooled"]["gyro_arw_dph_rthz"] == pytest.approx(0.05, rel=0.1)
    assert page.count("data:image/svg+xml;base64,") == 1
    # each dashed line is one fitted term alone: its log-log slope is the term's
    figs = [noise_from_log(_sim_log(truth, seed)) for seed in (1, 2)]
    fig = plot_allan(figs, combine_noise(figs))
    slopes = set()
    for ax in fig.axes:
        for line in ax.get_lines():
            if line.get_linestyle() == "--":
                x, y = np.log(line.get_xdata()), np.log(line.get_ydata())
                slopes.add(round(float((y[-1] - y[0]) / (x[-1] - x[0])), 6))
    assert {-1.0, -0.5} <= slopes <= {-1.0, -0.5, 0.0, 0.5}


def test_the_tuning_pools_up_to_eight_logs_spread_over_the_campaign(monkeypatch, tmp_path):
    from hse_opt.align import AlignConfig, batch
    seen = []

    def record(path, *args, **kw):
        seen.append(path)
        return path, None, f"{path}: not read in this test"
    monkeypatch.setattr(batch, "_noise_one", record)
    paths = [str(tmp_path / f"log{i:02d}.npz") for i in range(20)]
    rows, errors = batch.align_logs(paths, AlignConfig(latitude=0.5), tune_from_data=True)
    assert len(seen) == batch.TUNING_LOGS == 8 and seen[0] == paths[0] and seen[-1] == paths[-1]
    assert seen == sorted(seen) and len(errors) == 20 and not rows     # every log still tried in pass 2
