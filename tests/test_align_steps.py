"""Check 3b's block sums and statistic (hse_opt.align.steps) against per-sample references
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


def test_block_sums_match_per_sample_sums(log):
    enc, gyro, h = log.encoder, log.gyro, 16
    R, E, total = steps.block_sums(enc, gyro, h)
    nb = (enc.size - 1) // h
    w = np.arange(h, 0, -1, dtype=float)
    d = np.diff(enc)[:nb * h].reshape(nb, h)                  # the encoder's steps, block by block
    x = gyro[1:nb * h + 1].reshape(nb, h, 3)
    scale = np.abs(gyro).max() * h
    assert np.abs(R[:, :, 0] - x.sum(axis=1).T).max() < 1e-14 * scale
    assert np.abs(R[:, :, 1] - np.einsum("bic,i->cb", x, w)).max() < 1e-14 * scale * h
    assert np.abs(E[0] - d.sum(axis=1)).max() < 1e-14 * np.abs(d).max() * h
    assert np.abs(E[1] - d @ w).max() < 1e-14 * np.abs(d).max() * h * h
    exact = np.array([math.fsum(gyro[1:, j]) for j in range(3)])
    assert np.abs(total - exact).max() <= 1e-15 * np.abs(gyro).sum()


def test_statistic_matches_its_per_sample_definition(log):
    """D(p): the mean of the cumulative residual e over the K increments after p less that over
    the K before, with check 3's slow model fitted out by least squares; a 0.2-arcsec step in
    gyro_y shows as d (1 - |p - p0| / K) at its peak."""
    t, enc, gyro = log.t, log.encoder, log.gyro.copy()
    k0 = 20011
    gyro[k0, 1] += 0.2 * ARCSEC
    K = 128
    beta = np.array([math.fsum(gyro[1:, j]) for j in range(3)]) / float(enc[-1] - enc[0])
    D, p, _ = steps.step_statistic(t, enc, gyro, K, beta)
    M = ((enc.size - 1) // (K // steps.GRID)) * (K // steps.GRID)
    x = gyro[1:M + 1] - beta * np.diff(enc[:M + 1])[:, None]
    x = x - x.mean(axis=0)
    e = np.vstack([np.zeros(3), np.cumsum(x, axis=0)])        # e at increments 0 .. M
    ref = np.array([[e[q + 1:q + K + 1, j].mean() - e[q - K + 1:q + 1, j].mean() for q in p] for j in range(3)])
    c, s = np.cos(enc[p]), np.sin(enc[p])
    u = np.linspace(-1.0, 1.0, p.size)
    A = np.stack([np.ones(p.size), c, s, u, u * u], axis=1)
    ref -= (A @ np.linalg.lstsq(A, ref.T, rcond=None)[0]).T
    sigma = 1.4826 * np.median(np.abs(ref - np.median(ref, axis=1)[:, None]), axis=1)
    assert np.abs(D - ref).max(axis=1).max() < 1e-6 * sigma.min()
    g0 = int(np.argmax(np.abs(D[1])))
    assert abs(int(p[g0]) - (k0 - 1)) <= K // steps.GRID
    assert abs(D[1, g0]) > 15 / 16 * 0.2 * ARCSEC - 6 * sigma[1]


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
