"""The calibration fit (issue 4, items 3-7), each against an independent reference: the truth
of twin experiments, scipy's optimisers on the same objective, the paper's closed forms,
fits with the constraint substituted by hand."""
import dataclasses
import importlib
import json

import numpy as np
import pytest
from scipy.optimize import least_squares

from hse_opt import units
from hse_opt.data import Runs
from hse_opt.datasets import paper_table1
from hse_opt.fit import (COMPENSATED_COLUMN, COMPENSATION_STD_COLUMN, Constraint, FitResult, Prior,
                         SolverError, compensate, compensated_parameters, compensation, fit, load_fit,
                         replicate_groups, save_fit)
from hse_opt.information import UnidentifiableError, propagated_std, separating_runs
from hse_opt.model import Model, closed_form
from hse_opt.paper_procedure import compensate_eq14, paper_procedure

LINEAR = Model(["hse", "axis_bias", "sync_delay"])
TRUTH_LINEAR = dict(offset=3.0, lambda2=4.2, bias_z=0.2, delay=40.0)
NONLINEAR = Model(["hse", "warmup"])
TRUTH_NONLINEAR = dict(offset=3.0, lambda2=4.2, warmup_amp=60.0, warmup_tau=1800.0)


def design(n_sessions=1, per=48, rates_dps=(20, 40, 60), sigma_arcsec=7.6, pitch=6e-4, roll=-4e-4,
           azimuths_deg=tuple(range(0, 360, 45))):
    """Runs cycling over both senses of each rate, then over stand azimuths; ``n_sessions``
    power-ons of ``per`` back-to-back 10-minute runs; a fixed stand tilt."""
    rates = np.array([s * r for r in rates_dps for s in (1, -1)], dtype=float)
    az = np.asarray(azimuths_deg, dtype=float)
    i = np.arange(n_sessions * per)
    n = i.size
    return dict(run=i, rate=rates[i % rates.size] * units.DEG_PER_S,
                azimuth=az[(i // rates.size) % az.size] * units.DEG, latitude=np.full(n, 0.49),
                duration=np.full(n, 600.0), t_start=(i % per) * 700.0, pitch=np.full(n, pitch),
                roll=np.full(n, roll), heading_std=np.full(n, sigma_arcsec * units.ARCSEC))


def twin(model, d, truth, rng, noise=True):
    """Runs whose heading error is the measurement model at ``truth`` plus Gaussian noise."""
    mm = model.measurement(True)
    X = mm.inputs(d["rate"], d["azimuth"], d["latitude"], d["duration"], d["t_start"], d["pitch"],
                  d["roll"])
    y = mm.predict(mm.vector(truth), X)
    if noise:
        y = y + d["heading_std"] * rng.standard_normal(y.size)
    return Runs(heading_err=y, **d)


def _jac(mm, X, runs):
    """Jacobian of the standardised residuals for scipy (display units)."""
    return lambda v: -mm.jacobian(v * mm.scale, X) * mm.scale / runs.heading_std[:, None]


def subset(runs, idx):
    return runs.subset(np.asarray(idx))


@pytest.fixture
def rng():
    return np.random.default_rng(4)


# -- twin experiments -------------------------------------------------------------------------
def _twin_rms(model, d, truth, seeds):
    mm = model.measurement(True)
    t = mm.vector(truth) / mm.scale
    z, chi2_red = [], []
    for seed in seeds:
        f = fit(twin(model, d, truth, np.random.default_rng(seed)), model)
        z.append((f.values - t) / f.std)
        chi2_red.append(f.chi2_red)
    return np.sqrt(np.mean(np.square(z), axis=0)), np.mean(chi2_red)


def test_twin_linear_sigmas_are_honest():
    rms, chi2_red = _twin_rms(LINEAR, design(), TRUTH_LINEAR, range(200))
    assert np.all((rms > 0.9) & (rms < 1.1)), rms
    assert chi2_red == pytest.approx(1.0, abs=0.05)


def test_twin_nonlinear_warmup_sigmas_are_honest():
    d = design(n_sessions=4, per=12, rates_dps=(40,), sigma_arcsec=3.0)
    rms, chi2_red = _twin_rms(NONLINEAR, d, TRUTH_NONLINEAR, range(200))
    assert np.all((rms > 0.9) & (rms < 1.1)), rms
    assert chi2_red == pytest.approx(1.0, abs=0.05)


def test_nonlinear_fit_matches_scipy_by_both_solvers(rng):
    runs = twin(NONLINEAR, design(n_sessions=4, per=12, rates_dps=(40,), sigma_arcsec=3.0),
                TRUTH_NONLINEAR, rng)
    f = fit(runs, NONLINEAR)  # warmup_tau's declared range does not bind: Gauss-Newton
    assert f.method == "gauss-newton" and f.binding == ()
    # scipy's trust-region least squares on the same standardised residuals (its own
    # finite differences stall on the model's 1e-12 rounding: give it the Jacobian)
    mm = NONLINEAR.measurement(True)
    X = mm.inputs_from_runs(runs)
    resid = lambda v: (runs.heading_err - mm.predict(v * mm.scale, X)) / runs.heading_std  # noqa: E731
    ref = least_squares(resid, mm.vector(TRUTH_NONLINEAR) / mm.scale * 1.1, method="trf",
                        jac=_jac(mm, X, runs), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert np.all(np.abs(f.values - ref.x) < 2e-4 * f.std)
    assert f.chi2 == pytest.approx(2 * ref.cost, abs=1e-5)
    # IPOPT, brought in by an inequality that does not bind, finds the same point
    g = fit(runs, NONLINEAR, constraints=[Constraint({"warmup_amp": 1.0, "lambda2": 1.0}, upper=500.0)])
    assert g.method == "ipopt" and g.active == ()
    assert np.all(np.abs(g.values - f.values) < 1e-5 * f.std)
    np.testing.assert_allclose(g.std, f.std, rtol=1e-6)
    # started next to the lower end of the range, Gauss-Newton steps out of it: IPOPT takes over
    s = fit(runs, NONLINEAR, start={"warmup_tau": 31.0})
    assert s.method == "ipopt" and s.binding == ()
    assert np.all(np.abs(s.values - f.values) < 1e-5 * f.std)
    # a bound on the time constant that binds: IPOPT, held exactly, as scipy's bounded solver
    cap = float(f.value("warmup_tau")[0] - 2 * f.value("warmup_tau")[1])
    b = fit(runs, NONLINEAR, bounds={"warmup_tau": (30.0, cap)})
    assert b.method == "ipopt" and b.binding == ("warmup_tau",) and b.value("warmup_tau") == (cap, 0.0)
    ub = np.full(4, np.inf)
    ub[3] = cap
    ref_b = least_squares(resid, np.r_[ref.x[:3], 0.9 * cap], jac=_jac(mm, X, runs), bounds=(-np.inf, ub),
                          method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert np.all(np.abs(b.values - ref_b.x) < 2e-4 * f.std)


def test_residual_jacobian_evaluator_equals_the_models_functions(rng):
    # the fit's one-call [h, dh/dp] (exact-size map) against MeasurementModel.predict/jacobian
    # (separate Functions, padded power-of-two maps), for several run counts
    fitmod = importlib.import_module("hse_opt.fit.problem")
    mm = Model(["hse", "axis_bias", "warmup"]).measurement(True)
    ev = fitmod.residual_jacobian(mm)
    for n in (1, 7, 100):
        d = design(per=n)
        X = mm.inputs(d["rate"], d["azimuth"], d["latitude"], d["duration"], d["t_start"], d["pitch"],
                      d["roll"])
        p = mm.vector(offset=2.0, lambda2=4.2, bias_z=0.1, warmup_amp=30.0, warmup_tau=900.0)
        hJ = ev(p, X)
        np.testing.assert_allclose(hJ[:, 0], mm.predict(p, X), rtol=0, atol=1e-15)
        np.testing.assert_allclose(hJ[:, 1:], mm.jacobian(p, X), rtol=1e-12, atol=1e-15)
        assert (n, False) in ev._cache  # mapped exactly, not padded


# -- constraints --------------------------------------------------------------------------------
def test_bounds_that_do_not_bind_change_nothing(rng):
    runs = twin(LINEAR, design(), TRUTH_LINEAR, rng)
    free = fit(runs, LINEAR)
    lo = free.values - 5 * free.std
    hi = free.values + 5 * free.std
    bounded = fit(runs, LINEAR, bounds={n: (a, b) for n, a, b in zip(free.names, lo, hi)},
                  constraints=[Constraint({"lambda2": 1.0, "delay": 0.01}, upper=100.0)])
    assert free.method == "qr" and bounded.method == "ipopt"
    assert bounded.binding == () and bounded.active == ()
    assert np.all(np.abs(bounded.values - free.values) < 1e-6 * free.std)
    np.testing.assert_allclose(bounded.std, free.std, rtol=1e-8)
    np.testing.assert_allclose(bounded.correlation, free.correlation, atol=1e-8)
    assert bounded.chi2 == pytest.approx(free.chi2, abs=1e-6)


def test_binding_bound_holds_exactly_and_matches_scipy(rng):
    runs = twin(LINEAR, design(), TRUTH_LINEAR, rng)
    free = fit(runs, LINEAR)
    cap = float(free.value("lambda2")[0] - 2 * free.value("lambda2")[1])
    f = fit(runs, LINEAR, bounds={"lambda2": (None, cap)})
    assert f.binding == ("lambda2",)
    assert f.value("lambda2") == (cap, 0.0)  # exactly on the bound, held by it
    assert any("lambda2 is held at its bound" in n for n in f.notes)
    # independent: scipy's bounded trust-region reflective solver on the same residuals
    mm = LINEAR.measurement(True)
    X = mm.inputs_from_runs(runs)
    ub = np.full(4, np.inf)
    ub[1] = cap
    ref = least_squares(lambda v: (runs.heading_err - mm.predict(v * mm.scale, X)) / runs.heading_std,
                        np.zeros(4), jac=_jac(mm, X, runs), bounds=(-np.inf, ub), xtol=1e-15, ftol=1e-15,
                        gtol=1e-15, method="trf")
    assert np.all(np.abs(f.values - ref.x) < 1e-5 * free.std)
    # and the same as holding lambda2 fixed there
    fixed = fit(runs, LINEAR, fix={"lambda2": cap})
    assert np.all(np.abs(f.values - fixed.values) < 1e-6 * free.std)
    np.testing.assert_allclose(f.std, fixed.std, rtol=1e-9)


def test_linear_equality_equals_substitution(rng):
    # lambda2 = 0.1 * delay, done by hand: delay enters as delay + lambda2/0.1 ... instead fit
    # with the constraint and compare with a scipy fit over the substituted parameters
    runs = twin(LINEAR, design(), TRUTH_LINEAR, rng)
    c = Constraint.equal({"lambda2": 1.0, "delay": -0.1}, 0.0)
    f = fit(runs, LINEAR, constraints=[c])
    assert f.method == "qr"
    assert f.value("lambda2")[0] == pytest.approx(0.1 * f.value("delay")[0], rel=1e-12)
    mm = LINEAR.measurement(True)
    X = mm.inputs_from_runs(runs)

    def resid(u):  # u = (offset, bias_z, delay)
        v = np.array([u[0], 0.1 * u[2], u[1], u[2]])
        return (runs.heading_err - mm.predict(v * mm.scale, X)) / runs.heading_std
    dv_du = np.array([[1, 0, 0], [0, 0, 0.1], [0, 1, 0], [0, 0, 1.0]])
    ref = least_squares(resid, np.zeros(3), jac=lambda u: _jac(mm, X, runs)(dv_du @ u) @ dv_du,
                        xtol=1e-15, ftol=1e-15, gtol=1e-15)
    free = fit(runs, LINEAR)
    assert np.all(np.abs(f.values[[0, 2, 3]] - ref.x) < 1e-4 * free.std[[0, 2, 3]])
    # covariance: the reduced problem's, mapped back (J of the substitution)
    J = ref.jac
    cov_u = np.linalg.inv(J.T @ J)
    np.testing.assert_allclose(f.covariance[np.ix_([0, 2, 3], [0, 2, 3])], cov_u, rtol=1e-5)
    assert f.std[1] == pytest.approx(0.1 * f.std[3], rel=1e-9)
    assert f.dof == len(runs) - 3


def test_active_inequality_is_reported_and_holds(rng):
    runs = twin(LINEAR, design(), TRUTH_LINEAR, rng)
    free = fit(runs, LINEAR)
    target = free.value("lambda2")[0] + 0.01 * free.value("delay")[0] - 3.0
    c = Constraint({"lambda2": 1.0, "delay": 0.01}, upper=target)
    f = fit(runs, LINEAR, constraints=[c])
    assert f.active == (str(c),)
    assert f.value("lambda2")[0] + 0.01 * f.value("delay")[0] == pytest.approx(target, abs=1e-9)
    eq = fit(runs, LINEAR, constraints=[Constraint.equal({"lambda2": 1.0, "delay": 0.01}, target)])
    assert np.all(np.abs(f.values - eq.values) < 1e-6 * free.std)


def test_infeasible_constraints_and_bad_input_are_value_errors(rng):
    runs = twin(LINEAR, design(), TRUTH_LINEAR, rng)
    with pytest.raises(ValueError, match="lower <= upper"):
        fit(runs, LINEAR, bounds={"lambda2": (5, 1)})
    with pytest.raises(ValueError, match="unknown parameter"):
        fit(runs, LINEAR, bounds={"lambda3": (0, 1)})
    with pytest.raises(ValueError, match="cannot all hold"):
        fit(runs, LINEAR, bounds={"lambda2": (0, 1)},
            constraints=[Constraint({"lambda2": 1.0}, lower=2.0)])
    with pytest.raises(ValueError, match="fixed at 2"):
        fit(runs, LINEAR, fix={"lambda2": 2.0}, bounds={"lambda2": (3, 4)})
    with pytest.raises(ValueError, match="not all zero"):
        Constraint({"lambda2": 0.0}, 0, 1)


# -- prior: the on-line update ---------------------------------------------------------------------
def test_online_update_equals_batch(rng):
    runs = twin(LINEAR, design(), TRUTH_LINEAR, rng)
    n = len(runs)
    first, second = subset(runs, range(0, n, 2)), subset(runs, range(1, n, 2))
    batch = fit(runs, LINEAR)
    old = fit(first, LINEAR)
    new = fit(second, LINEAR, prior=old)
    assert np.all(np.abs(new.values - batch.values) < 1e-6 * batch.std)
    # the prior is the old fit's information at the old estimate: equal to the batch's up to
    # the model's slight nonlinearity (the gyrocompass' atan2)
    np.testing.assert_allclose(new.std, batch.std, rtol=1e-5)
    np.testing.assert_allclose(new.correlation, batch.correlation, atol=1e-6)
    assert old.chi2 + new.chi2 == pytest.approx(batch.chi2, rel=1e-8)
    assert old.dof + new.dof == batch.dof


def test_prior_from_fit_through_ipopt_equals_batch(rng):
    # the same update with an inequality that does not bind: the IPOPT path carries the prior too
    runs = twin(LINEAR, design(), TRUTH_LINEAR, rng)
    n = len(runs)
    batch = fit(runs, LINEAR)
    new = fit(subset(runs, range(1, n, 2)), LINEAR, prior=fit(subset(runs, range(0, n, 2)), LINEAR),
              constraints=[Constraint({"delay": 1.0}, -1e4, 1e4)])
    assert new.method == "ipopt" and new.active == ()
    assert np.all(np.abs(new.values - batch.values) < 1e-6 * batch.std)


def test_prior_identifies_what_the_data_cannot(rng):
    # Table 1 cannot separate offset from lambda2*tilt_const; a prior on the latter can
    runs = paper_table1()
    prior = Prior.independent({"lambda2*tilt_const": 0.0}, {"lambda2*tilt_const": 0.5})
    f = fit(runs, prior=prior)
    fixed = fit(runs, fix={"lambda2*tilt_const": 0.0})
    assert f.value("lambda2*tilt_cos")[0] == pytest.approx(fixed.value("lambda2*tilt_cos")[0], abs=1e-9)
    assert f.std[0] > fixed.std[0]  # the offset now carries the prior's uncertainty
    assert any("Gaussian prior" in n for n in f.notes)


# -- robust ---------------------------------------------------------------------------------------
def test_huber_equals_scipy_huber_and_names_the_outlier(rng):
    runs = twin(LINEAR, design(), TRUTH_LINEAR, rng)
    y = np.array(runs.heading_err)
    y[7] += 15 * runs.heading_std[7]
    runs = runs.replace(heading_err=y)
    plain = fit(runs, LINEAR)
    f = fit(runs, LINEAR, robust=True)
    assert f.downweighted[0] == int(runs.run[7]) and f.method == "qr+huber"
    mm = LINEAR.measurement(True)
    X = mm.inputs_from_runs(runs)
    ref = least_squares(lambda v: (runs.heading_err - mm.predict(v * mm.scale, X)) / runs.heading_std,
                        plain.values, jac=_jac(mm, X, runs), loss="huber", f_scale=1.345, xtol=1e-15,
                        ftol=1e-15, gtol=1e-15)
    assert np.all(np.abs(f.values - ref.x) < 1e-5 * plain.std)
    truth = mm.vector(TRUTH_LINEAR) / mm.scale
    assert np.max(np.abs(f.values - truth) / f.std) < np.max(np.abs(plain.values - truth) / plain.std)



def test_robust_scale_is_the_gaussian_consistent_mad_and_huber_uses_it(rng):
    """Without heading_std a robust fit takes sigma from the residuals' median absolute
    deviation (MAD / Phi^-1(3/4), from its definition), and its estimate is scipy's Huber fit
    with that scale."""
    from scipy.stats import norm

    runs = twin(LINEAR, design(), TRUTH_LINEAR, rng)
    y = np.array(runs.heading_err)
    y[[3, 11]] += 20 * runs.heading_std[[3, 11]]
    runs = Runs(**{**{k: getattr(runs, k) for k in ("run", "rate", "azimuth", "latitude", "duration",
                                                    "t_start", "pitch", "roll")}, "heading_err": y})
    f = fit(runs, LINEAR, robust=True)
    assert f.weighting == "robust-scale" and set(f.downweighted[:2]) == {int(runs.run[3]), int(runs.run[11])}
    r = f.residuals
    mad = np.median(np.abs(r - np.median(r))) / norm.ppf(0.75)
    np.testing.assert_allclose(f.sigma, mad, rtol=1e-12)
    mm = LINEAR.measurement(True)
    X = mm.inputs_from_runs(runs)
    ref = least_squares(lambda v: (y - mm.predict(v * mm.scale, X)) / mad, f.values,
                        jac=lambda v: -mm.jacobian(v * mm.scale, X) * mm.scale / mad, loss="huber",
                        f_scale=1.345, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert np.all(np.abs(f.values - ref.x) < 1e-5 * f.std)

# -- identifiability ------------------------------------------------------------------------------
def test_lambda2_and_sync_delay_at_one_azimuth_are_named_and_separated(rng):
    d = design(azimuths_deg=(30.0,), per=18)
    model = Model(["hse", "sync_delay"])
    runs = twin(model, d, dict(lambda2=4.2, delay=40.0), rng)
    with pytest.raises(UnidentifiableError) as err:
        fit(runs, model)
    assert {"lambda2", "delay"} <= set(err.value.names)
    msg = str(err.value)
    assert "every run is at azimuth 30 deg" in msg.lower() and "Runs that would separate them" in msg
    # the proposed runs do separate them
    mm = model.measurement(True)
    X = mm.inputs_from_runs(runs)
    cand = separating_runs(lambda Xc: mm.jacobian(mm.nominal, Xc), X, err.value.direction, mm.scale,
                           tilt_known=True)
    assert all(abs(c["azimuth_deg"] - 30) > 1 for c in cand)
    assert cand[0]["text"] in msg
    extra = {**{k: v[:6].copy() for k, v in d.items()}, "run": np.arange(100, 106)}
    extra["azimuth"] = np.full(6, cand[0]["azimuth_deg"] * units.DEG)
    both = twin(model, {k: np.concatenate([d[k], extra[k]]) for k in d}, dict(lambda2=4.2, delay=40.0),
                rng)
    f = fit(both, model)
    assert f.std[f.names.index("lambda2")] < 10


def test_table1_tilt_const_is_absorbed_into_the_offset_but_user_parameters_are_not():
    """Default fit of Table 1 (one rate, no tilt columns): the constant tilt term the tool
    creates cannot be told from the offset; it is held at 0 with a note, which is the fit with
    it fixed by hand and the textbook least squares of offset + cos/sin(azimuth) (issue 14,
    item 6). A parameter of the user's model confounded with the offset is still an error."""
    runs = paper_table1()
    f = fit(runs)
    assert f.value("lambda2*tilt_const") == (0.0, 0.0)
    assert any("lambda2*tilt_const held at 0, absorbed into the offset" in n for n in f.notes)
    psi = np.asarray(runs.azimuth)
    A = np.column_stack([np.ones(psi.size), np.cos(psi), np.sin(psi)])
    coef, *_ = np.linalg.lstsq(A, runs.heading_err, rcond=None)
    assert np.allclose(f.residuals, runs.heading_err - A @ coef, atol=1e-4 * units.ARCSEC)
    with pytest.raises(UnidentifiableError) as err:
        fit(runs, ["hse", "sync_delay"], fix={"lambda2*tilt_const": 0.0})
    assert set(err.value.names) == {"offset", "delay"}
    assert "-40 deg/s at any azimuth" in str(err.value)


def test_no_information_is_named(rng):
    # (the 1st harmonic acts through lambda2: once the fit has solved lambda2 it is seen)
    model = Model(["hse", "encoder_harmonic"])
    runs = twin(Model(["hse"]), design(), dict(lambda2=4.2), rng)
    with pytest.raises(UnidentifiableError, match="no information on enc_c2, enc_s2:"):
        fit(runs, model)


# -- the paper's procedure -------------------------------------------------------------------------
def _single_position(rng, tilt_jitter=0.0, truth=None):
    """The paper's step 1: 3 alignments at each of 20, 40, 60 deg/s at one stand position."""
    d = design(azimuths_deg=(91.8795,), per=9, pitch=7e-4, roll=3e-4)
    n = d["run"].size
    d["rate"] = np.repeat([20.0, 40.0, 60.0], 3) * units.DEG_PER_S
    d["pitch"] = d["pitch"] + tilt_jitter * rng.standard_normal(n)
    d["roll"] = d["roll"] + tilt_jitter * rng.standard_normal(n)
    del d["heading_std"]
    runs = twin(Model(["hse"]), {**d, "heading_std": np.full(n, 1.0)}, truth or dict(offset=2.0,
                lambda2=4.2), rng, noise=False)
    y = runs.heading_err + 7.6 * units.ARCSEC * rng.standard_normal(n)
    return Runs(heading_err=y, **d)


def test_paper_procedure_equals_general_fit_restricted_to_the_paper_model(rng):
    runs = _single_position(rng)
    cal = paper_procedure(runs)
    f = fit(runs)  # the paper's model (offset, lambda2), tilt known
    # 6 replicate degrees of freedom: too few for a pure-error sigma, both take the residuals'
    assert cal.weighting == f.weighting == "residual" and f.lack_of_fit.dof == (1, 6)
    l2, s2 = f.value("lambda2")
    # the full gyrocompass also sees the north error Omega C13 M33 that Eq. 14 drops: a
    # relative 1e-4 at a 1-mrad tilt, a thousandth of a sigma here
    assert abs(cal.lambda2_arcsec - l2) < 1e-3 * s2
    assert cal.lambda2_std / units.ARCSEC == pytest.approx(s2, rel=1e-3)
    assert list(cal.count) == [3, 3, 3]


def test_paper_procedure_reproduces_the_paper_numbers():
    # Eq. 15 with the paper's K_HSE = 17.4 arcsec/(rad/s) and the C23 that gives lambda2 = 4.2
    K = 17.4 * units.ARCSEC
    L = 0.49
    c23 = 3 * 7.292115e-5 * np.cos(L) * K / (4.2 * units.ARCSEC)
    rates = np.repeat([20.0, 40.0, 60.0], 3) * units.DEG_PER_S
    n = rates.size
    runs = Runs(run=np.arange(n), rate=rates, azimuth=np.zeros(n), latitude=np.full(n, L),
                duration=np.full(n, 600.0),
                heading_err=-K * rates + np.tile([0.5, 0.0, -0.5], 3) * units.ARCSEC)  # repeat scatter
    cal = paper_procedure(runs, c23=c23)
    assert cal.k_hse_arcsec_per_radps == pytest.approx(17.4, rel=1e-12)
    assert cal.lambda2_arcsec == pytest.approx(4.2, rel=1e-12)
    # 6 replicate degrees of freedom (fewer than 8): the sigma is the residuals', whose sum of
    # squares is the repeat scatter's (orthogonal to the model): 6 x 0.25 arcsec^2 over 9 - 2 dof
    assert cal.weighting == "residual"
    assert cal.sigma / units.ARCSEC == pytest.approx(np.sqrt(6 * 0.25 / 7), rel=1e-9)


def test_paper_procedure_rejects_several_positions():
    with pytest.raises(ValueError, match="one stand position"):
        paper_procedure(paper_table1())


def test_compensation_symbolic_equals_eq14_and_removes_the_hse(rng):
    runs = _single_position(rng)
    f = fit(runs)
    cal = paper_procedure(runs)
    later = twin(Model(["hse"]), design(per=16), dict(lambda2=cal.lambda2_arcsec), rng, noise=False)
    a = compensate(later, f)
    lam = f.value("lambda2")[0] * units.ARCSEC
    b = compensate_eq14(later, lam, f.value("lambda2")[1] * units.ARCSEC)
    corr_a = (later.heading_err / units.ARCSEC - a.covariates[COMPENSATED_COLUMN])
    corr_b = (later.heading_err / units.ARCSEC - b.covariates[COMPENSATED_COLUMN])
    # the symbolic model's full gyrocompass against the first-order closed form derived by hand
    # (issue 2), which keeps the heading offset of Lambda's turn about the axis ...
    first = closed_form.heading_error_first_order(later.rate, 0.49, np.full(3, lam / 3), np.zeros(3),
                                                  np.full(3, -1 / np.sqrt(3)), later.azimuth,
                                                  later.pitch, later.roll) / units.ARCSEC
    np.testing.assert_allclose(corr_a, first, atol=2e-3)
    # ... and against the paper's Eq. 14, which drops that constant offset
    assert np.ptp(corr_a - corr_b) < 2e-3 and abs(np.mean(corr_a - corr_b)) > 0.1
    # the 1-sigma: |d correction / d lambda2| sigma(lambda2), the closed forms being linear in it
    s2 = f.value("lambda2")[1] * units.ARCSEC
    np.testing.assert_allclose(a.covariates[COMPENSATION_STD_COLUMN], np.abs(first / lam) * s2, rtol=1e-3)
    np.testing.assert_allclose(b.covariates[COMPENSATION_STD_COLUMN], np.abs(corr_b / lam) * s2, rtol=1e-9)
    # noise-free runs with lambda2 = the fitted one: only the 1e-3-arcsec model difference is left
    assert np.abs(a.covariates[COMPENSATED_COLUMN]).max() < 2e-3
    assert np.ptp(later.heading_err) / units.ARCSEC > 5
    assert compensated_parameters(f) == ("lambda2",)


def test_compensation_sigma_equals_monte_carlo_over_the_covariance(rng):
    # three compensated parameters (lambda2, bias_z, delay), strongly correlated by runs of one
    # sense at three azimuths; with the equality the covariance is singular (rank 2) and the
    # propagation must stay real and honest
    runs = twin(LINEAR, design(azimuths_deg=(10, 100, 200), per=36), TRUTH_LINEAR, rng)
    runs = runs.subset(np.flatnonzero(runs.rate > 0))
    later = twin(LINEAR, design(per=16, rates_dps=(10, 25, 50, 70)), TRUTH_LINEAR, rng)
    mm = LINEAR.measurement(True)
    X = mm.inputs_from_runs(later)
    for f in (fit(runs, LINEAR), fit(runs, LINEAR, constraints=[Constraint.equal({"lambda2": 1.0,
                                                                                 "delay": -0.1}, 0.0)])):
        corr, std = compensation(later, f)
        use = np.isin(mm.names, compensated_parameters(f))
        assert use.sum() == 3 and np.abs(np.triu(f.correlation[np.ix_(use, use)], 1)).max() > 0.9
        draws = rng.multivariate_normal(f.values[use], f.covariance[np.ix_(use, use)], 4000,
                                        method="eigh")
        p = np.tile(mm.nominal, (draws.shape[0], 1))
        p[:, use] = draws * mm.scale[use]
        mc = np.array([mm.predict(q, X) for q in p])
        np.testing.assert_allclose(std, mc.std(axis=0), rtol=0.06)  # 1/sqrt(2 * 4000) = 1.1 %
        assert np.all(np.abs(mc.mean(axis=0) - corr) < 5 * std / np.sqrt(draws.shape[0]) + 1e-15)
        assert np.ptp(std) > 0.1 * std.max()  # the runs differ: the test sees the correlations
    # a covariance that is no covariance (a damaged FIT.json) is refused, not clipped
    bad = f.covariance.copy()
    i, j = f.names.index("lambda2"), f.names.index("bias_z")
    bad[i, j] = bad[j, i] = 2 * np.sqrt(bad[i, i] * bad[j, j])
    with pytest.raises(ValueError, match="not positive semidefinite .*lambda2, bias_z"):
        compensation(later, dataclasses.replace(f, covariance=bad))


def test_propagated_std_of_a_rank_one_covariance_is_the_closed_form(rng):
    # C = v v' (perfectly correlated parameters, eigenvalues 0 up to rounding): J C J' = (J v)^2
    v = rng.normal(size=5) * np.logspace(-3, 3, 5)
    J = rng.normal(size=(7, 5)) / np.logspace(-3, 3, 5)
    np.testing.assert_allclose(propagated_std(J, np.outer(v, v)), np.abs(J @ v), rtol=1e-7)
    with pytest.raises(ValueError, match="negative variance"):
        propagated_std(J, -np.outer(v, v), list("abcde"))


def test_compensate_refuses_to_overwrite_and_needs_tilt(rng):
    runs = _single_position(rng)
    f = fit(runs)
    out = compensate(runs, f)
    with pytest.raises(ValueError, match="already present"):
        compensate(out, f)
    with pytest.raises(ValueError, match="pitch_arcsec/roll_arcsec"):
        compensate(paper_table1(), f)


# -- FIT.json ---------------------------------------------------------------------------------------
def test_fit_json_round_trip(tmp_path, rng):
    runs = twin(LINEAR, design(), TRUTH_LINEAR, rng)
    f = fit(runs, LINEAR, bounds={"delay": (None, 30.0)},
            constraints=[Constraint({"lambda2": 1.0}, lower=-100.0)], robust=True)
    path = tmp_path / "FIT.json"
    save_fit(f, path)
    assert [p.name for p in tmp_path.iterdir()] == ["FIT.json"]
    g = load_fit(path)
    assert isinstance(g, FitResult) and g.model == f.model
    assert json.dumps(g.to_dict()) == json.dumps(f.to_dict())
    assert json.loads(path.read_text())["parameters"] == f.to_dict()["parameters"]
    np.testing.assert_array_equal(g.p, f.p)
    np.testing.assert_allclose(compensate(runs, g).covariates[COMPENSATED_COLUMN],
                               compensate(runs, f).covariates[COMPENSATED_COLUMN], rtol=0, atol=1e-12)
    bad = tmp_path / "bad.json"
    bad.write_text('{"effects": ["hse"]}')
    with pytest.raises(ValueError, match="bad.json: not a FIT.json"):
        load_fit(bad)


def test_solver_failure_raises_with_status(rng, monkeypatch):
    fitmod = importlib.import_module("hse_opt.fit.solvers")
    runs = twin(NONLINEAR, design(n_sessions=2, per=12, rates_dps=(40,)), TRUTH_NONLINEAR, rng)
    monkeypatch.setitem(fitmod._IPOPT_OPTIONS, "ipopt.max_iter", 1)
    fitmod._nlp_solver.cache_clear()
    try:
        with pytest.raises(SolverError, match="Maximum_Iterations_Exceeded") as err:
            fit(runs, NONLINEAR, constraints=[Constraint({"warmup_amp": 1.0}, upper=500.0)])
        assert err.value.status == "Maximum_Iterations_Exceeded"
    finally:
        fitmod._nlp_solver.cache_clear()


def test_paper_procedure_without_replicates_matches_numpy_polyfit(rng):
    runs = _single_position(rng, tilt_jitter=2e-4)  # leveling differs by ~40 arcsec: no replicates
    cal = paper_procedure(runs)
    assert cal.weighting == "residual"
    assert cal.c23 == pytest.approx(np.mean(closed_form.c23(runs.azimuth, runs.pitch, runs.roll)), rel=1e-12)
    (slope, icpt), cov = np.polyfit(runs.rate, runs.heading_err, 1, cov=True)
    assert cal.k_hse == pytest.approx(-slope, rel=1e-10)
    assert cal.intercept == pytest.approx(icpt, rel=1e-10)
    assert cal.k_hse_std == pytest.approx(np.sqrt(cov[0, 0]), rel=1e-10)


@pytest.mark.parametrize("constraints, method", [
    ((), "gauss-newton"), ((Constraint({"warmup_amp": 1.0}, upper=500.0),), "ipopt")])
def test_sigma_from_residuals(rng, constraints, method):
    # no heading_std and no replicates: one sigma from the residuals; the estimate is the
    # weighted fit's and the covariance scales by (s / sigma)^2 - by both solvers
    d = design(n_sessions=4, per=12, rates_dps=(40,), sigma_arcsec=3.0)
    d["azimuth"] = d["azimuth"] + 1e-3 * np.arange(d["run"].size)  # no two runs alike
    runs = twin(NONLINEAR, d, TRUTH_NONLINEAR, rng)
    known = fit(runs, NONLINEAR, constraints=constraints)
    est = fit(runs.replace(heading_std=None), NONLINEAR, constraints=constraints)
    assert est.weighting == "residual" and est.method == known.method == method
    assert np.all(np.abs(est.values - known.values) < 1e-4 * known.std)
    s = np.sqrt(np.sum(known.residuals ** 2) / known.dof)
    assert est.sigma[0] == pytest.approx(s, rel=1e-6)
    np.testing.assert_allclose(est.std, known.std * s / (3.0 * units.ARCSEC), rtol=1e-4)
    assert est.chi2_red == pytest.approx(1.0, rel=1e-9)


def test_pure_error_replicates_are_runs_the_model_cannot_tell_apart():
    # 8 power-ons of one 8-run sequence: each (sense, azimuth) twice a session, at two times
    # since power-on; the warm-up model tells those apart, the paper's model cannot
    d = design(n_sessions=8, per=8, rates_dps=(40,), sigma_arcsec=3.0, azimuths_deg=(0, 90))
    runs = twin(NONLINEAR, d, TRUTH_NONLINEAR, np.random.default_rng(7))
    assert replicate_groups(runs, Model(["hse"]).measurement(True))[1] == 4
    labels, g = replicate_groups(runs, NONLINEAR.measurement(True))
    assert g == 8 and len(set(zip(labels, d["run"] % 8))) == 8  # the same partition
    f = fit(runs.replace(heading_std=None), NONLINEAR)
    assert f.weighting == "pure-error"
    # reference: the scatter of the noise the twin drew, within the 8 positions of the sequence
    mm = NONLINEAR.measurement(True)
    e = runs.heading_err - mm.predict(mm.vector(TRUTH_NONLINEAR), mm.inputs_from_runs(runs))
    k = d["run"] % 8
    means = np.bincount(k, e) / np.bincount(k)
    assert f.sigma[0] == pytest.approx(np.sqrt(np.sum((e - means[k]) ** 2) / (e.size - 8)), rel=1e-9)


def test_a_bilinear_effect_is_fitted_from_a_start_where_it_has_no_signature():
    # without mount_xi the encoder's 1st harmonic reaches heading only through lambda2 (a product):
    # at the nominal start (lambda2 = 0) it has no signature; the fit solves the paper's
    # parameters first and then sees it. Its 2nd harmonic has none at all: held by the user
    from hse_opt.validation.synthetic import diagnostic_plan, model_runs
    truth = dict(offset=3.0, lambda2=4.2, enc_c1=320.0, enc_s1=240.0)
    runs = model_runs(diagnostic_plan(), truth, np.random.default_rng(1),
                      base_tilt=(-120 * units.ARCSEC, -55 * units.ARCSEC))
    with pytest.raises(UnidentifiableError, match="no information on enc_c2, enc_s2"):
        fit(runs, "hse,encoder_harmonic")
    f = fit(runs, "hse,encoder_harmonic", fix={"enc_c2": 0.0, "enc_s2": 0.0})
    z = [(f.value(n)[0] - v) / f.value(n)[1] for n, v in truth.items()]
    assert np.all(np.abs(z) < 4), z


def test_information_criteria_and_condition_number_from_their_definitions(rng):
    runs = twin(LINEAR, design(), TRUTH_LINEAR, rng)
    f = fit(runs, LINEAR)
    n, k = len(runs), 4
    mm = LINEAR.measurement(True)
    X = mm.inputs_from_runs(runs)
    chi2 = np.sum(((runs.heading_err - mm.predict(f.p, X)) / runs.heading_std) ** 2)  # at the estimate
    assert f.chi2 == pytest.approx(chi2, rel=1e-9) and f.dof == n - k
    assert f.aic == pytest.approx(chi2 + 2 * k, rel=1e-9)
    assert f.bic == pytest.approx(chi2 + k * np.log(n), rel=1e-9)
    # the condition number of the column-normalised weighted Jacobian (numpy's SVD)
    A = mm.jacobian(f.p, X) * mm.scale / runs.heading_std[:, None]
    assert f.condition == pytest.approx(np.linalg.cond(A / np.linalg.norm(A, axis=0)), rel=1e-6)
    with pytest.raises(ValueError, match="read-only"):
        f.values[0] = 0.0


def test_report_data_is_consistent(rng):
    from hse_opt.fit import report_data
    runs = twin(LINEAR, design(), TRUTH_LINEAR, rng)
    f = fit(runs, LINEAR, bounds={"delay": (None, 30.0)})
    d = report_data(f, runs)
    r = d["runs"]
    np.testing.assert_allclose(np.add(r["predicted_arcsec"], r["residual_arcsec"]), r["heading_err_arcsec"],
                               atol=1e-9)
    mm = LINEAR.measurement(True)  # the prediction is the model at the estimate
    np.testing.assert_allclose(r["predicted_arcsec"], mm.predict(f.p, mm.inputs_from_runs(runs)) / units.ARCSEC,
                               atol=1e-9)
    assert [p["state"] for p in d["parameters"]] == ["free", "free", "free", "at bound"]
    json.dumps(d, allow_nan=False)
    with pytest.raises(ValueError, match="not the ones the fit used"):
        report_data(f, subset(runs, range(10)))
