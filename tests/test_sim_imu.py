"""Raw data generation against independent references (issue 3, item 2).

The references here integrate the paper's physics (docs/conventions.md) directly (Gauss-Legendre quadrature
of the body rate and specific force built from rotation matrices), not the generator's
closed forms.
"""
import math

import numpy as np
import pytest

from hse_opt.frames import c_b_s, dcm_zyx, earth_rate_n, rot_z
from hse_opt.sim._fastmath import cos_sin, cos_sin_linear
from hse_opt.sim.imu import generate
from hse_opt.sim.truth import RunSpec, TruthConfig

ARCSEC = math.pi / 180 / 3600
DPH = math.pi / 180 / 3600
NODES, WEIGHTS = np.polynomial.legendre.leggauss(12)


def _alpha(truth, run, alpha0, t):
    """Table angle from the rate model: W (1 + r cos(h |W| t + phi)) integrated."""
    tb = truth.table
    W = run.rate * (1 + tb.rate_error)
    nu = tb.ripple_order * abs(W)
    a = alpha0 + W * t
    if tb.ripple:
        a += W * tb.ripple / nu * (np.sin(nu * t + tb.ripple_phase) - np.sin(tb.ripple_phase))
    return a


def _alpha_dot(truth, run, t):
    tb = truth.table
    W = run.rate * (1 + tb.rate_error)
    return W * (1 + tb.ripple * np.cos(tb.ripple_order * abs(W) * t + tb.ripple_phase))


def _reference_increments(truth, run, alpha0, k):
    """Gyro and accelerometer outputs over sample interval k by quadrature."""
    dt = truth.timing.sample_period
    ta, tb_ = k * dt, (k + 1) * dt
    ts = 0.5 * (tb_ - ta) * NODES + 0.5 * (ta + tb_)
    ws = 0.5 * (tb_ - ta) * WEIGHTS
    gam = truth.stand.mount_tilt[0] + run.tilt[0]
    the = truth.stand.mount_tilt[1] + run.tilt[1]
    C_b0_n = dcm_zyx(run.azimuth, the, gam)           # no stand tilt / azimuth error here
    w_ie_n = earth_rate_n(truth.site.latitude)
    g_n = np.array([0.0, 0.0, truth.site.gravity])
    K_g_inv = np.array([[1, 0, 0],
                        [math.sin(truth.gyro.axes_nonorth[0]), math.cos(truth.gyro.axes_nonorth[0]), 0],
                        [math.sin(truth.gyro.axes_nonorth[1]), math.sin(truth.gyro.axes_nonorth[2]), 0]])
    K_g_inv[2, 2] = math.sqrt(1 - K_g_inv[2, 0] ** 2 - K_g_inv[2, 1] ** 2)
    Cbs0 = c_b_s(np.asarray(truth.mount.r_zb_s_true))
    m = truth.mount
    gyro = np.zeros(3)
    acc = np.zeros(3)
    for t, w in zip(ts, ws):
        C_b_n = C_b0_n @ rot_z(_alpha(truth, run, alpha0, t))
        xi = m.warmup_xi_z * math.exp(-(run.t_start + t) / m.warmup_tau)
        xidot = -xi / m.warmup_tau
        C_b_s = Cbs0 @ rot_z(-xi)
        w_ib_b = C_b_n.T @ w_ie_n + np.array([0, 0, _alpha_dot(truth, run, t) + xidot])
        f_b = -C_b_n.T @ g_n
        th, t_on = truth.thermal, run.t_start + t
        temp = th.ambient_c + th.rise_c * (1 - math.exp(-t_on / th.tau)) + th.swing_c * math.sin(
            2 * math.pi * t_on / th.swing_period + th.swing_phase)
        bias = (np.asarray(truth.gyro.bias) + np.asarray(truth.gyro.bias_warmup) * math.exp(
            -t_on / truth.gyro.bias_warmup_tau) + np.asarray(truth.gyro.bias_tempco) * (temp - th.reference_c))
        gyro += w * (K_g_inv @ C_b_s @ w_ib_b + bias)
        acc += w * (C_b_s @ f_b)
    return gyro, acc


@pytest.fixture(scope="module")
def tilted_system():
    t = TruthConfig.ideal().updated({
        "table": {"ripple_ppm": 300.0, "ripple_order": 2, "ripple_phase_deg": 40.0, "rate_error_ppm": 50.0},
        "gyro": {"axes_nonorth_arcsec": [60.0, -90.0, 45.0], "bias_dph": [0.01, -0.02, 0.03],
                 "bias_warmup_dph": [0.05, 0.02, -0.04], "bias_warmup_tau_s": 300.0,
                 "bias_tempco_dph_per_c": [0.02, -0.01, 0.005]},
        "thermal": {"tau_s": 250.0, "swing_c": 4.0, "swing_period_s": 600.0, "swing_phase_deg": 30.0},
        "mount": {"r_zb_s_true": [-0.5772, -0.578, -0.57685020585937], "warmup_xi_z_arcsec": -30.0,
                  "warmup_tau_s": 200.0},
        "stand": {"mount_tilt_arcsec": [300.0, -500.0]},
        "site": {"latitude_deg": 41.0},
    })
    run = RunSpec(rate=-37 * math.pi / 180, azimuth=2.1, duration=20.0, t_start=50.0,
                  tilt=(100 * ARCSEC, 0.0), alpha0=0.7)
    return t, run, generate(t, run)


@pytest.mark.parametrize("k", [0, 1, 777, 4321, 9999])
def test_increments_match_quadrature_of_the_physics(tilted_system, k):
    t, run, log = tilted_system
    gyro, acc = _reference_increments(t, run, 0.7, k)
    # gyro increments are ~1e-3 rad, the Earth-rate part ~1e-7: demand 3e-15 rad (a few
    # ulp of the increment; 3e-8 of the Earth-rate part, with no systematic part)
    np.testing.assert_allclose(log.gyro[k], gyro, rtol=0, atol=3e-15)
    # the generator takes alpha linear inside each 2 ms interval; the 300 ppm ripple bends it
    # by alpha_ddot dt^2 / 8 ~ 1e-10 rad, i.e. 1e-10 of the horizontal specific force
    # (g x 600 arcsec tilt x dt ~ 6e-5 m/s): a periodic 1e-14 m/s, allowed here
    np.testing.assert_allclose(log.accel[k], acc, rtol=0, atol=2e-14)


def test_encoder_delay_harmonics_and_resolution():
    res = 0.18 * ARCSEC
    t = TruthConfig.ideal().updated({"encoder": {"resolution_arcsec": 0.18, "sync_delay_us": 250.0,
                                                 "harmonics": [{"order": 1, "amplitude_arcsec": 2.0, "phase_deg": 20.0},
                                                               {"order": 3, "amplitude_arcsec": 0.7}]},
                                     "table": {"ripple_ppm": 100.0}})
    run = RunSpec(rate=0.7, duration=30.0, alpha0=0.3)
    log = generate(t, run)
    tk = 0.002 * np.arange(1, len(log) + 1)
    a = _alpha(t, run, 0.3, tk - 250e-6)
    a = a + 2 * ARCSEC * np.sin(a + math.radians(20)) + 0.7 * ARCSEC * np.sin(3 * a)
    np.testing.assert_allclose(log.encoder, np.round(a / res) * res, rtol=0, atol=1e-12)
    counts = log.encoder / res
    assert np.abs(counts - np.round(counts)).max() < 1e-6
    assert np.allclose(log.t, run.t_start + tk)


def test_pulse_quantization_carries_the_remainder():
    q = 1.5 * ARCSEC
    base = TruthConfig.ideal().updated({"table": {"ripple_ppm": 0.0}})
    run = RunSpec(rate=0.7, duration=60.0, alpha0=0.1)
    exact = generate(base, run)
    quant = generate(base.updated({"gyro": {"pulse_arcsec": 1.5}, "accel": {"pulse_mps": 1e-4}}),
                     run, np.random.default_rng(2))
    pulses = quant.gyro / q
    assert np.abs(pulses - np.round(pulses)).max() < 1e-6
    # a counter never loses a pulse: the running sums differ by less than one quantum
    # (the counter's initial phase is random), and the difference is not drifting
    d = np.cumsum(quant.gyro, axis=0) - np.cumsum(exact.gyro, axis=0)
    assert np.abs(d).max() < q * (1 + 1e-9)
    assert np.ptp(d, axis=0).min() > 0.9 * q           # really quantized
    assert abs(d[-5000:].mean(axis=0) - d[:5000].mean(axis=0)).max() < 0.05 * q
    dv = np.cumsum(quant.accel, axis=0) - np.cumsum(exact.accel, axis=0)
    assert np.abs(dv).max() < 1e-4 * (1 + 1e-9)
    # the counter sits after the scale factor when there is one
    sf = {"gyro": {"sf_error_ppm": [300.0, 0.0, -200.0]}}
    exact = generate(base.updated(sf), run)
    quant = generate(base.updated(sf).updated({"gyro": {"pulse_arcsec": 1.5}}), run, np.random.default_rng(2))
    assert np.abs(quant.gyro / q - np.round(quant.gyro / q)).max() < 1e-6
    d = np.cumsum(quant.gyro, axis=0) - np.cumsum(exact.gyro, axis=0)
    assert np.abs(d).max() < q * (1 + 1e-9)


def test_white_noise_has_the_specified_density():
    base = TruthConfig.ideal().updated({"table": {"ripple_ppm": 0.0}})
    noisy = base.updated({"gyro": {"arw_dph_rthz": 0.05}, "accel": {"vrw_ug_rthz": 20.0}})
    run = RunSpec(rate=0.7, duration=120.0, alpha0=0.1)
    n_g = generate(noisy, run, np.random.default_rng(11)).gyro - generate(base, run).gyro
    n_a = generate(noisy, run, np.random.default_rng(11)).accel - generate(base, run).accel
    dt = 0.002
    # ARW N (rad/sqrt(s)): per-sample angle noise N sqrt(dt); 60000 samples -> 0.3 % std error
    assert n_g.std(axis=0) == pytest.approx(np.full(3, 0.05 * DPH * math.sqrt(dt)), rel=0.015)
    assert n_a.std(axis=0) == pytest.approx(np.full(3, 20e-6 * 9.80665 * math.sqrt(dt)), rel=0.015)
    for x in (n_g[:, 0], n_a[:, 2]):
        r1 = np.corrcoef(x[1:], x[:-1])[0, 1]
        assert abs(r1) < 0.02                       # white


def test_scale_factor_and_nonlinearity():
    base = TruthConfig.ideal().updated({"table": {"ripple_ppm": 0.0}})
    sf = base.updated({"gyro": {"sf_error_ppm": [100.0, -50.0, 20.0],
                                "sf_nonlinearity_ppm_per_dps": [2.0, 0.0, -1.0]}})
    run = RunSpec(rate=0.7, duration=10.0, alpha0=0.1)
    g0, g1 = generate(base, run).gyro, generate(sf, run).gyro
    rate_dps = np.abs(g0) / 0.002 * 180 / math.pi
    expect = g0 * (1 + np.array([100, -50, 20]) * 1e-6 + np.array([2.0, 0.0, -1.0]) * 1e-6 * rate_dps)
    np.testing.assert_allclose(g1, expect, rtol=1e-12)


def test_noise_needs_a_generator_and_runs_are_reproducible():
    t = TruthConfig.default()
    run = RunSpec(rate=0.7, duration=20.0)
    with pytest.raises(ValueError, match="rng"):
        generate(t, run)
    a = generate(t, run, np.random.default_rng(5))
    b = generate(t, run, np.random.default_rng(5))
    np.testing.assert_array_equal(a.gyro, b.gyro)
    np.testing.assert_array_equal(a.encoder, b.encoder)


def test_fast_cos_sin_matches_numpy():
    rng = np.random.default_rng(0)
    ph = 0.3 + 0.0014 * np.arange(300001) + 1e-4 * np.sin(0.01 * np.arange(300001)) \
        + rng.uniform(-4e-7, 4e-7, 300001)
    c, s = cos_sin(ph)
    assert np.abs(c - np.cos(ph)).max() < 1e-13 and np.abs(s - np.sin(ph)).max() < 1e-13
    c, s = cos_sin_linear(-2.0, 0.003, 100003)
    ph = -2.0 + 0.003 * np.arange(100003)
    assert np.abs(c - np.cos(ph)).max() < 1e-13 and np.abs(s - np.sin(ph)).max() < 1e-13


def test_doubled_tables_match_extended_precision():
    """The phase and exponential tables built by doubling against numpy's long double
    cos/sin/exp of the same arguments, at sizes that are and are not powers of two."""
    from hse_opt.sim._fastmath import PhaseTable, exp_linear
    if np.finfo(np.longdouble).eps >= np.finfo(float).eps:
        pytest.skip("numpy's long double is double on this platform: no extended reference")
    for n in (1, 63, 64, 65, 1000, 16385):
        k = np.arange(n, dtype=np.longdouble)
        for dphi in (0.0014, -0.3, 2.5):
            t = PhaseTable(dphi, n)
            assert np.abs(t.c - np.cos(k * dphi)).max() < 4e-15
            assert np.abs(t.s - np.sin(k * dphi)).max() < 4e-15
        for rate in (-1e-5, -2e-3, 1e-4):
            e = exp_linear(rate, n)
            assert np.abs(e / np.exp(k * rate) - 1).max() < 4e-15


def test_fast_normal_is_standard_normal():
    """The Box-Muller noise source against the normal distribution (KS test, moments) and
    its independence from sample to sample."""
    from scipy import stats

    from hse_opt.sim._fastmath import box_muller_f32, uniform_bits
    rng = np.random.default_rng(3)
    z = box_muller_f32(uniform_bits(rng, 200002, True)[None], (2.5,))[0, :200001].astype(float) / 2.5
    assert z.dtype == float and z.size == 200001
    assert stats.kstest(z, "norm").pvalue > 0.01
    assert abs(z.mean()) < 5 / math.sqrt(z.size) and abs(z.std() - 1) < 5 / math.sqrt(2 * z.size)
    assert abs(stats.kurtosis(z)) < 5 * math.sqrt(24 / z.size)
    for lag in (1, 2, (z.size + 1) // 2):       # including the Box-Muller pair offset
        assert abs(np.corrcoef(z[lag:], z[:-lag])[0, 1]) < 5 / math.sqrt(z.size)


def test_uniforms_from_whole_words_are_the_generators_float32_uniforms():
    """``uniform_bits`` read from the 64-bit words equals numpy's own
    ``Generator.random(dtype=float32)`` for every bit generator, including one left with a
    pending half word (then it falls back) and MT19937 (32-bit words: never split); the
    Box-Muller noise built on it equals the textbook float32 formulas on numpy's uniforms."""
    from hse_opt.sim._fastmath import box_muller_f32, splits_words, uniform_bits
    for bg in (np.random.PCG64, np.random.PCG64DXSM, np.random.SFC64, np.random.Philox, np.random.MT19937):
        for pending in (False, True):
            ref, ours = np.random.Generator(bg(9)), np.random.Generator(bg(9))
            if pending:                                  # leaves half a word behind
                ref.random(3, dtype=np.float32), ours.random(3, dtype=np.float32)
            split = splits_words(ours)
            assert split == (bg is not np.random.MT19937 and not pending)
            for k in (2, 1000, 49152):
                u = ref.random(k, dtype=np.float32)
                bits = uniform_bits(ours, k, split)
                np.testing.assert_array_equal(bits.astype(np.float32) * np.float32(2.0 ** -24), u)
            assert ref.random() == ours.random()         # the streams stay in step
    ref, ours = np.random.default_rng(4), np.random.default_rng(4)
    u = ref.random(2000, dtype=np.float32)
    z = box_muller_f32(uniform_bits(ours, 2000, True).reshape(2, 1000), (1.5, 0.25))
    for i, sig in enumerate((1.5, 0.25)):
        r1, a1 = u[1000 * i:1000 * i + 500], u[1000 * i + 500:1000 * (i + 1)]
        rad = np.sqrt(np.float32(-2.0) * np.log(np.float32(1.0) - r1)) * np.float32(sig)
        ang = a1 * np.float32(2.0 * math.pi)
        np.testing.assert_array_equal(z[i], np.concatenate([np.cos(ang) * rad, np.sin(ang) * rad]))


def test_table_jitter_is_seen_by_gyros_and_encoder_alike():
    """A system whose only imperfection is the table's servo jitter (here 5 arcsec) aligns
    exactly: the gyros and the encoder see the same jittered angle."""
    from hse_opt.sim.campaign import default_align_config
    from hse_opt.align import align
    t = TruthConfig.ideal().updated({"table": {"jitter_arcsec": 5.0}})
    run = RunSpec(rate=-0.7, azimuth=1.0, duration=120.0, tilt=(300 * ARCSEC, -200 * ARCSEC))
    log = generate(t, run, np.random.default_rng(1))
    enc_dev = log.encoder - log.encoder[0] - (-0.7) * (log.t - log.t[0])
    assert 3 * ARCSEC < enc_dev.std() < 7 * ARCSEC      # the encoder sees the jitter
    res = align(log, default_align_config(t))
    assert abs(res.heading - 1.0) < 0.02 * ARCSEC


@pytest.mark.parametrize("rate_dps", [-40.0, 40.0])
def test_pulse_quantization_locks_without_jitter_and_is_white_with_it(rate_dps):
    """RLG pulses of 0.5 arcsec (a readout without interpolation), nothing else random.
    Without table jitter the counters' remainders follow the table angle: at -40 deg/s
    (gyro 3 counts 332.2497 pulses per sample, next to a quarter) the heading error is a bias
    of tens of arcsec. With the
    default 0.5 arcsec jitter the remainders are dithered and the error is white: its scatter
    over seeds is the random walk q |Omega| sqrt(dt/12) of hse_opt.align.quantization_arw
    through the gyrocompass, N / (w_ie cos L sqrt(T)) (formula written out here)."""
    from hse_opt.sim.campaign import default_align_config, simulate_alignment
    base = TruthConfig.default().updated({"mount": {"warmup_xi_z_arcsec": 0.0},
                                          "gyro": {"bias_warmup_dph": [0.0, 0.0, 0.0]}})
    pulses = base.updated({"gyro": {"arw_dph_rthz": 0.0, "pulse_arcsec": 0.5},
                           "accel": {"vrw_ug_rthz": 0.0, "pulse_mps": 0.0}, "encoder": {"resolution_arcsec": 0.0}})
    cfg = default_align_config(base.updated({"gyro": {"pulse_arcsec": 0.5}}))
    T, rate = 300.0, rate_dps * math.pi / 180
    run = RunSpec(rate=rate, azimuth=0.0, duration=T, t_start=1500.0, alpha0=0.4)
    ref = simulate_alignment(base.noise_free(), run, None, cfg)[0].heading
    errs = {}
    for jitter in (0.0, 0.5):
        t = pulses.updated({"table": {"jitter_arcsec": jitter}})
        errs[jitter] = np.array([simulate_alignment(t, run, np.random.default_rng(s), cfg)[0].heading - ref
                                 for s in range(24)]) / ARCSEC
    q, dt, lat = 0.5 * ARCSEC, 0.002, base.site.latitude
    white = q * abs(rate) * math.sqrt(dt / 12) / (7.292115e-5 * math.cos(lat) * math.sqrt(T)) / ARCSEC
    rms = np.sqrt(np.mean(errs[0.5] ** 2))
    assert 0.7 * white < rms < 1.4 * white                  # 24 seeds: 15 % standard error
    if rate_dps < 0:
        assert np.sqrt(np.mean(errs[0.0] ** 2)) > 3 * white  # locked: a bias, not noise


def test_a_quantum_too_small_for_the_counter_is_named():
    """The pulse counters sum in int64 fixed point; a quantum so small that a chunk would count
    more than 2**44 pulses is refused, naming the key and the smallest allowed value."""
    t = TruthConfig.ideal().updated({"gyro": {"pulse_arcsec": 1e-9}})
    with pytest.raises(ValueError, match=r"gyro.pulse_arcsec = 1e-09 is too small .* allowed gyro.pulse_arcsec >= "):
        generate(t, RunSpec(rate=0.7, duration=10.0, alpha0=0.1), np.random.default_rng(0))
    # 1e-5 arcsec: 3e7 pulses per sample on the z gyro, 5e11 in a chunk; the counter still
    # carries every pulse against the exact increments' running sum
    q = 1e-5 * ARCSEC
    run = RunSpec(rate=0.7, duration=40.0, alpha0=0.1)
    exact = generate(TruthConfig.ideal(), run)
    quant = generate(TruthConfig.ideal().updated({"gyro": {"pulse_arcsec": 1e-5}}), run, np.random.default_rng(0))
    pulses = quant.gyro / q
    assert np.abs(pulses - np.round(pulses)).max() < 1e-6
    d = np.cumsum(quant.gyro, axis=0) - np.cumsum(exact.gyro, axis=0)
    assert np.abs(d).max() < q * (1 + 1e-3) and np.ptp(d, axis=0).min() > 0.5 * q
