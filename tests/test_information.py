"""Fisher information, covariance and identifiability (hse_opt.information), each against an
independent reference: finite differences of the model, the KKT matrix, the simulator's noise."""
import numpy as np
import pytest

from hse_opt import units
from hse_opt.frames import EARTH_RATE
from hse_opt.information import (DEFAULT_ARW, Prior, UnidentifiableError, analyse, check_identifiable,
                                 describe_runs, fisher, heading_sigma, invisible, null_space,
                                 separating_runs)
from hse_opt.model import Model
from hse_opt.sim.truth import TruthConfig


def _runs(mm, rng, n=40):
    return mm.inputs(rate=rng.choice([-1, 1], n) * rng.uniform(20, 60, n) * units.DEG_PER_S,
                     azimuth=rng.uniform(0, 2 * np.pi, n), latitude=0.49, duration=600.0,
                     t_start=rng.uniform(0, 7200, n), pitch=rng.uniform(-1e-3, 1e-3, n),
                     roll=rng.uniform(-1e-3, 1e-3, n))


def test_fisher_from_casadi_jacobian_equals_finite_differences(rng):
    mm = Model(["hse", "axis_bias", "sync_delay", "warmup"]).measurement(True)
    X = _runs(mm, rng)
    p = mm.vector(lambda2=4.2, bias_z=0.01, delay=30.0, warmup_amp=20.0, warmup_tau=900.0)
    J = mm.jacobian(p, X)
    J_fd = np.empty_like(J)
    for j, s in enumerate(mm.scale):  # central differences: a tenth of a display unit, 2 s for tau
        dp = np.zeros_like(p)
        dp[j] = (2.0 if mm.names[j] == "warmup_tau" else 0.1) * s
        J_fd[:, j] = (mm.predict(p + dp, X) - mm.predict(p - dp, X)) / (2 * dp[j])
    sigma = np.full(X.shape[1], 7.6 * units.ARCSEC)
    F, F_fd = fisher(J, sigma, mm.scale), fisher(J_fd, sigma, mm.scale)
    d = np.sqrt(np.diag(F))
    np.testing.assert_allclose(F / np.outer(d, d), F_fd / np.outer(d, d), atol=1e-6)
    np.testing.assert_allclose(np.diag(F), np.diag(F_fd), rtol=1e-6)
    # display units: F_ij = sum dh/dz_i dh/dz_j / sigma^2 with z in arcsec, deg/h, us, s
    i = mm.parameter_index("lambda2")
    assert F[i, i] == pytest.approx(np.sum((J_fd[:, i] * units.ARCSEC / sigma) ** 2), rel=1e-5)


def test_heading_sigma_is_the_simulators_arw_figure():
    truth = TruthConfig.default()
    assert DEFAULT_ARW == pytest.approx(truth.gyro.arw, rel=1e-12)
    s = heading_sigma(600.0, 28.07 * units.DEG) / units.ARCSEC
    assert s == pytest.approx(7.6, abs=0.05)
    # by hand: N / (w_ie cos L sqrt(T))
    hand = truth.gyro.arw / (EARTH_RATE * np.cos(truth.site.latitude) * np.sqrt(600.0)) / units.ARCSEC
    assert heading_sigma(600.0, truth.site.latitude, truth.gyro.arw) / units.ARCSEC == pytest.approx(hand)
    # a four times longer alignment halves it; a floor adds in quadrature
    assert heading_sigma(2400.0, 28.07 * units.DEG) / units.ARCSEC == pytest.approx(s / 2, rel=1e-12)
    assert heading_sigma(600.0, 28.07 * units.DEG, floor=5 * units.ARCSEC) / units.ARCSEC == \
        pytest.approx(np.hypot(s, 5), rel=1e-12)
    with pytest.raises(ValueError, match="duration"):
        heading_sigma(0.0, 0.5)


def test_constrained_covariance_equals_kkt_inverse(rng):
    k = 5
    A = rng.standard_normal((30, k))
    F = A.T @ A
    C = rng.standard_normal((2, k))
    info = analyse(F, list("abcde"), ["arcsec"] * k, Z=null_space(C, k))
    K = np.block([[F, C.T], [C, np.zeros((2, 2))]])
    np.testing.assert_allclose(info.covariance, np.linalg.inv(K)[:k, :k], atol=1e-12)
    np.testing.assert_allclose(C @ info.covariance, 0, atol=1e-12)  # no variance across C


def test_pinned_parameter_has_zero_std(rng):
    A = rng.standard_normal((20, 3))
    info = analyse(A.T @ A, ["a", "b", "c"], ["1"] * 3, Z=null_space(np.array([[0.0, 1.0, 0.0]]), 3))
    assert info.std[1] == 0 and info.std[0] > 0 and info.correlation[1, 1] == 0


def test_confounded_and_blind_parameters_are_named(rng):
    a = rng.standard_normal(30)
    A = np.column_stack([a, 2 * a, rng.standard_normal(30)])
    with pytest.raises(UnidentifiableError) as err:
        check_identifiable(A.T @ A, ["offset", "lambda2", "delay"])
    assert set(err.value.names) == {"offset", "lambda2"}
    assert "2*offset" in str(err.value) or "0.5*lambda2" in str(err.value)
    A[:, 2] = 0
    with pytest.raises(UnidentifiableError, match="no information on delay") as err:
        check_identifiable(A.T @ A + np.diag([0, 1, 0]), ["offset", "lambda2", "delay"])
    assert err.value.names == ("delay",)
    # an equality constraint lifts the confounding
    A[:, 2] = rng.standard_normal(30)
    cond = check_identifiable(A.T @ A, ["offset", "lambda2", "delay"], Z=null_space([[1.0, 0, 0]], 3))
    assert np.isfinite(cond)


def test_invisible_parameters(rng):
    mm = Model(["hse", "encoder_harmonic"]).measurement(True)
    X = _runs(mm, rng)
    J = mm.jacobian(mm.nominal, X) * mm.scale
    ranges = np.array([q.upper - q.lower for q in mm.params])
    mask = invisible(J, ranges)
    assert [n for n, m in zip(mm.names, mask) if m] == ["enc_c1", "enc_s1", "enc_c2", "enc_s2"]


def test_prior_marginalises_and_rejects_bad_covariance():
    cov = np.array([[4.0, 1.0, 0.5], [1.0, 2.0, 0.3], [0.5, 0.3, 1.0]])
    prior = Prior(("a", "b", "c"), [1.0, 2.0, 3.0], cov)
    F, b = prior.fisher(["c", "a", "x"])
    sub = cov[np.ix_([2, 0], [2, 0])]
    np.testing.assert_allclose(F[:2, :2], np.linalg.inv(sub))  # marginal, not conditional
    np.testing.assert_allclose(b[:2], np.linalg.inv(sub) @ [3.0, 1.0])
    assert np.all(F[2] == 0) and b[2] == 0
    with pytest.raises(ValueError, match="positive definite"):
        Prior(("a", "b"), [0, 0], [[1.0, 2.0], [2.0, 1.0]])
    with pytest.raises(ValueError, match="fixed, not a prior"):
        Prior.independent({"a": 0.0}, {"a": 0.0})


def test_describe_and_separate_one_azimuth(rng):
    mm = Model(["hse", "sync_delay"]).measurement(True)
    n = 9
    X = mm.inputs(rate=np.repeat([20.0, 40.0, 60.0], 3) * units.DEG_PER_S, azimuth=np.full(n, 0.5),
                  latitude=0.49, pitch=np.full(n, 6e-4), roll=np.full(n, -4e-4))
    text = " ".join(describe_runs(X, tilt_known=True))
    assert "every run is at azimuth 28.65 deg" in text and "same east tilt" in text
    direction = np.array([0.0, 0.0616, 1.0])
    cand = separating_runs(lambda Xc: mm.jacobian(mm.nominal, Xc), X, direction, mm.scale,
                           tilt_known=True)
    assert len(cand) == 3 and all(c["signal"] > 0.1 for c in cand)
    # the best candidates are far from the runs' azimuth; one at the same azimuth is blind
    assert all(abs(np.angle(np.exp(1j * (np.deg2rad(c["azimuth_deg"]) - 0.5)))) > 0.5 for c in cand)
