"""The IEEE 952 fit of an Allan curve (hse_opt.align.allan_fit) against the procedure written
out here with scipy's NNLS (Lawson-Hanson) one channel at a time, and on inputs without a
finite curve.

The procedure (hse_opt.align.noise, step 4): weights from each variance's relative 1-sigma
``sqrt(2 / (K - 1))`` times the model of the pass before (the variances themselves first),
three passes, the columns scaled to unit norm with a ridge of 1e-13, the refit with the
model's 10 % in quadrature where the weighted residuals exceed MISFIT per degree of freedom;
the 1-sigma from the inverse normal matrix on the terms left free.
"""
import math
import warnings

import numpy as np
import pytest
from scipy.optimize import nnls

from hse_opt.align.allan_fit import MISFIT, MODEL_ERROR, fit_allan

TAU = 0.002 * 2.0 ** np.arange(18)
T = TAU[:, None] ** np.arange(-2, 2)


def _scipy_fit(tau, adev, clusters):
    """The procedure (module docstring) with scipy's NNLS, channel by channel: (coef, std,
    refitted)."""
    T = tau[:, None] ** np.arange(-2, 2)
    rel = np.sqrt(2.0 / np.maximum(clusters - 1.0, 1.0))
    coef, std, refitted = [], [], []
    for v in np.asarray(adev) ** 2:
        fits = []
        for r in (rel, np.sqrt(rel ** 2 + MODEL_ERROR ** 2)):
            model = v
            for _ in range(3):
                A = T / (model * r)[:, None]
                norm = np.sqrt(np.sum(A ** 2, axis=0))
                A = A / norm
                y, _ = nnls(np.vstack([A, math.sqrt(1e-13) * np.eye(4)]), np.concatenate([v / (model * r), np.zeros(4)]))
                x = y / norm
                model = T @ x
            free = y > 0
            s = np.full(4, np.nan)
            s[free] = np.sqrt(np.diag(np.linalg.inv(A[:, free].T @ A[:, free] + 1e-13 * np.eye(free.sum())))) / norm[free]
            chi2 = np.sum(((v - model) / (model * r)) ** 2) / (tau.size - 4)
            fits.append((x, s, chi2))
        pick = int(fits[0][2] > MISFIT)
        coef.append(fits[pick][0])
        std.append(fits[pick][1])
        refitted.append(pick)
    return np.array(coef), np.array(std), np.array(refitted)


def _curves(rng, n, most=1000.0):
    """``n`` Allan deviations on TAU: random terms (some zero), each point's variance scattered
    by about its own relative 1-sigma (log-normally); every third channel with a bump of 1.5 to
    3 times over three points, which the four terms cannot follow. At most ``most``
    independent clusters behind a point."""
    clusters = np.minimum(2.0 ** (19 - np.arange(18)), most)
    coef = rng.uniform(0.1, 1, (n, 4)) * np.array([1e-12, 1e-10, 1e-12, 1e-14]) * (rng.uniform(size=(n, 4)) < 0.7)
    coef[:, 1] += 1e-11                                          # a random walk in every channel
    avar = coef @ T.T
    avar *= np.exp(np.sqrt(2 / (clusters - 1)) * rng.standard_normal(avar.shape))
    avar[::3, 6:9] *= rng.uniform(1.5, 3.0, (len(avar[::3]), 1))
    return np.sqrt(avar), clusters


@pytest.mark.parametrize("channels, most, tau", [(60, 1000.0, TAU), (7, 300.0, TAU), (6, 1000.0, TAU[:15])])
def test_the_fit_is_the_procedure_with_scipys_nnls(channels, most, tau):
    """Every set of cluster times, clusters and channels fitted (what a fit of them needs is
    made once for them and kept)."""
    rng = np.random.default_rng(25)
    adev, clusters = _curves(rng, channels, most)
    adev, clusters = adev[:, :tau.size], clusters[:tau.size]
    coef, std = fit_allan(tau, adev, clusters)
    ref, ref_std, refitted = _scipy_fit(tau, adev, clusters)
    # both paths and several sets of free terms are covered
    assert 0 < refitted.sum() < len(refitted)
    assert len({tuple(r > 0) for r in ref}) >= 3
    assert np.array_equal(coef > 0, ref > 0)
    big = np.abs(ref).max(axis=1, keepdims=True)
    assert np.allclose(coef, ref, rtol=1e-9, atol=1e-12 * big)
    assert np.array_equal(np.isnan(std), np.isnan(ref_std))
    assert np.allclose(std, ref_std, rtol=1e-9, atol=0, equal_nan=True)


@pytest.mark.parametrize("factor", [1e-100, 1e-30, 1e40, 1e150])
def test_the_terms_scale_with_the_variances_over_any_range(factor):
    """Allan deviations in any unit: the terms and their 1-sigma scale by the factor squared
    (the fit scales each channel by a power of two; 1e150 squared is near the largest double)."""
    adev, clusters = _curves(np.random.default_rng(3), 6)
    coef, std = fit_allan(TAU, adev, clusters)
    scaled, scaled_std = fit_allan(TAU, adev * factor, clusters)
    assert np.allclose(scaled / factor ** 2, coef, rtol=1e-12, atol=0)
    assert np.allclose(scaled_std / factor ** 2, std, rtol=1e-12, atol=0, equal_nan=True)


def test_a_channel_without_a_finite_curve_gets_no_terms_and_leaves_the_others_alone():
    adev, clusters = _curves(np.random.default_rng(4), 6)
    good, good_std = fit_allan(TAU, adev[2:], clusters)
    bad = adev.copy()
    bad[0, 5] = np.nan            # NaN in the curve: NaN terms
    bad[1] = 0.0                  # a channel of no noise at all: zero terms
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        coef, std = fit_allan(TAU, bad, clusters)
    assert np.isnan(coef[0]).all() and np.array_equal(coef[1], np.zeros(4))
    assert np.isnan(std[:2]).all()
    assert np.allclose(coef[2:], good, rtol=1e-12, atol=0)
    assert np.allclose(std[2:], good_std, rtol=1e-12, atol=0, equal_nan=True)


def test_fits_on_the_same_cluster_times_take_each_their_own_clusters():
    """What a fit needs is kept per cluster times, clusters and channels: one after another on
    the same curves, each fit is still the procedure with its own clusters' weights."""
    adev, clusters = _curves(np.random.default_rng(6), 6)
    for most in (1000.0, 30.0, 1000.0):
        weights = np.minimum(clusters, most)
        coef, _ = fit_allan(TAU, adev, weights)
        ref, _, _ = _scipy_fit(TAU, adev, weights)
        assert np.allclose(coef, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max(axis=1, keepdims=True)), most
    assert not np.allclose(fit_allan(TAU, adev, np.minimum(clusters, 30.0))[0], coef, rtol=1e-3, atol=0)
