import numpy as np
import pytest

from conftest import ALL_EFFECTS
from hse_opt import units
from hse_opt.model import Geometry, Model, paper_model

ARCSEC = units.ARCSEC


def _runs(m, rng, n, tilt=True):
    return m.inputs(rate=rng.choice([-1, 1], n) * rng.uniform(15, 80, n) * units.DEG_PER_S,
                    azimuth=rng.uniform(0, 2 * np.pi, n), latitude=rng.uniform(-1.2, 1.2, n),
                    duration=rng.uniform(300, 900, n), t_start=rng.uniform(0, 7200, n),
                    pitch=rng.uniform(-2e-3, 2e-3, n) if tilt else None,
                    roll=rng.uniform(-2e-3, 2e-3, n) if tilt else None,
                    covariates={"temp_c": rng.normal(25, 3, n)})


def _params(m, rng):
    return np.array([(rng.uniform(-20, 20) if q.name != "warmup_tau" else rng.uniform(300, 3000))
                     * q.scale for q in m.params])


@pytest.mark.parametrize("tilt", [True, False])
def test_batch_equals_one_run_at_a_time(tilt, rng):
    m = Model(ALL_EFFECTS).measurement(tilt_known=tilt)
    X = _runs(m, rng, 37, tilt)
    p = _params(m, rng)
    h, J = m.predict(p, X), m.jacobian(p, X)
    for i in (0, 17, 36):
        assert h[i] == pytest.approx(float(m.h(p, X[:, i])), rel=1e-12, abs=1e-18)
        np.testing.assert_allclose(J[i], np.array(m.J(p, X[:, i])).ravel(), rtol=1e-12, atol=1e-18)


@pytest.mark.parametrize("tilt", [True, False])
def test_jacobian_against_central_differences(tilt, rng):
    m = Model(ALL_EFFECTS).measurement(tilt_known=tilt)
    X = _runs(m, rng, 25, tilt)
    p = _params(m, rng)
    J = m.jacobian(p, X)
    for k, q in enumerate(m.params):
        # steps large against the ~1e-12 rad rounding left by removing the ~1 rad/s table rate
        step = q.scale * (1.0 if q.name != "warmup_tau" else 10.0)
        e = np.zeros_like(p)
        e[k] = step
        fd = (m.predict(p + e, X) - m.predict(p - e, X)) / (2 * step)
        # tau enters through exp(-t/tau): its FD truncation error is ~1e-5 at a 10 s step
        np.testing.assert_allclose(J[:, k], fd, rtol=1e-5 if q.name != "warmup_tau" else 1e-4, atol=2e-12 / step,
                                   err_msg=q.name)


def test_free_tilt_model_reproduces_a_tilted_truth(rng):
    """Truth: tilt-known model with a mount tilt fixed in b0 and a stand tilt fixed in n.
    The free-tilt model with coefficients = parameter x C23 coefficients predicts the same
    headings up to terms second order in the tilt."""
    model = Model(["hse", "axis_bias", "scale_nonlinearity", "sync_delay"])
    known, free = model.measurement(True), model.measurement(False)
    n = 40
    psi = rng.uniform(0, 2 * np.pi, n)
    rate = rng.choice([20, 40, 60], n) * units.DEG_PER_S
    theta_m, gamma_m, phi_n = 1.5e-3, -0.7e-3, 0.6e-3  # rad; phi_n: stand tilt about north
    theta = theta_m - np.sin(psi) * phi_n
    gamma = gamma_m + np.cos(psi) * phi_n
    X = known.inputs(rate, psi, 0.49, pitch=theta, roll=gamma)
    truth = {"offset": 3.0, "lambda2": 4.2, "bias_z": 0.01, "sf_nonlin": 0.02, "delay": 30.0}
    h = known.predict(known.vector(truth), X)
    coef = {"tilt_cos": -gamma_m / units.MRAD, "tilt_sin": theta_m / units.MRAD,
            "tilt_const": -phi_n / units.MRAD}
    values = {k: v for k, v in truth.items() if k in free.names}
    for name in ("lambda2", "bias_z", "sf_nonlin"):
        for label, c in coef.items():
            values[f"{name}*{label}"] = truth[name] * c
    # lambda2's untilted part (the skew part of Lambda) is a constant absorbed by the offset
    lam_only = known.predict(known.vector(lambda2=4.2), known.inputs(rate, psi, 0.49, pitch=0 * psi, roll=0 * psi))
    assert np.ptp(lam_only) < 1e-6 * ARCSEC
    values["offset"] = truth["offset"] + lam_only[0] / ARCSEC
    h_free = free.predict(free.vector(values), free.inputs(rate, psi, 0.49))
    assert np.abs(h_free - h).max() < 0.01 * ARCSEC
    assert np.abs(h).max() > 10 * ARCSEC  # the tilt-coupled signal is really there


def test_free_tilt_parameters_and_composition():
    free = paper_model().measurement(tilt_known=False)
    assert free.names == ("offset", "lambda2*tilt_cos", "lambda2*tilt_sin", "lambda2*tilt_const")
    m = paper_model() + "sync_delay" + "covariate:temp_c"
    assert m.effect_names == ("hse", "sync_delay", "covariate:temp_c")
    assert m.measurement().covariates == ("temp_c",)
    with pytest.raises(ValueError, match="more than once"):
        paper_model() + "hse"


@pytest.mark.parametrize("kwargs, match", [
    (dict(latitude=np.radians(91.0)), "latitude of run index 0 is 91 deg; allowed: -90 to 90"),
    (dict(rate=np.nan), "'rate' of run index 0 is nan; allowed: finite"),
    (dict(pitch=0.1), "pitch of run index 0 is 5.72958 deg; allowed: |tilt| <= 2 deg"),
    (dict(duration=-5.0), "duration of run index 0 is -5.0 s; allowed: > 0"),
])
def test_bad_run_inputs_name_the_argument(kwargs, match):
    m = paper_model().measurement()
    args = dict(rate=0.7, azimuth=0.1, latitude=0.49, pitch=0.0, roll=0.0, duration=600.0)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match.replace("|", r"\|").replace("(", r"\(")):
        m.inputs(**args)


def test_bad_names_and_geometry():
    m = paper_model().measurement()
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) \['lamda2'\]; this model has: offset, lambda2"):
        m.vector(lamda2=4.2)
    with pytest.raises(ValueError, match="'lambda2' = nan"):
        m.vector(lambda2=float("nan"))
    with pytest.raises(ValueError, match="unknown effect 'warm_up'; allowed: hse, axis_bias"):
        Model(["hse", "warm_up"])
    with pytest.raises(ValueError, match=r"r_zb_s must be a unit vector; \|r_zb_s\| = 1.000759"):
        Geometry(r_zb_s=[-0.5775, -0.5775, -0.5775 * 1.0015])
    with pytest.raises(ValueError, match="covariate columns \\['temp_c'\\] are required"):
        Model(["hse", "covariate:temp_c"]).measurement().inputs(0.7, 0.0, 0.49, pitch=0, roll=0)


def test_inputs_broadcast_scalars_and_name_mismatched_lengths():
    """A scalar shared by the runs (here the rate) broadcasts against arrays; lengths that do
    not broadcast are an error naming each argument's shape."""
    mm = Model(["hse"]).measurement(tilt_known=True)
    az = np.array([0.0, 1.0, 2.0])
    X = mm.inputs(0.5, az, 0.49, 600.0, 0.0, 1e-3, -1e-3)
    assert X.shape[1] == 3
    explicit = mm.inputs(np.full(3, 0.5), az, np.full(3, 0.49), np.full(3, 600.0), np.zeros(3),
                         np.full(3, 1e-3), np.full(3, -1e-3))
    assert np.array_equal(X, explicit)
    with pytest.raises(ValueError, match=r"rate \(2,\), azimuth \(3,\)"):
        mm.inputs(np.ones(2), az, 0.49, 600.0, 0.0, 0.0, 0.0)


def test_run_inputs_view_names_the_rows_and_c23_is_the_exact_axis_east_component(rng):
    """The named view reads back what :meth:`MeasurementModel.inputs` was given; ``c23`` is the first-order C23 of scipy's exact Z-Y-X
    direction cosine matrix (residual second order in the tilt)."""
    from scipy.spatial.transform import Rotation

    from hse_opt.model.inputs import RunInputs, Tilt, c23

    m = Model(["hse", "covariate:temp_c"]).measurement(tilt_known=True)
    n = 50
    given = dict(rate=rng.uniform(0.1, 1.0, n), azimuth=rng.uniform(0, 2 * np.pi, n),
                 latitude=rng.uniform(-1, 1, n), duration=rng.uniform(300, 900, n),
                 t_start=rng.uniform(0, 7200, n), pitch=rng.uniform(-2e-3, 2e-3, n),
                 roll=rng.uniform(-2e-3, 2e-3, n))
    temp = rng.normal(25, 3, n)
    v = RunInputs(m.inputs(**given, covariates={"temp_c": temp}), m.covariates)
    for name, value in given.items():
        np.testing.assert_array_equal(getattr(v, name), value)
    np.testing.assert_array_equal(v.covariates["temp_c"], temp)
    np.testing.assert_array_equal(v.tilt.roll, given["roll"])
    np.testing.assert_array_equal(v.tilt.pitch, given["pitch"])
    exact = Rotation.from_euler("ZYX", np.column_stack([v.azimuth, v.pitch, v.roll])).as_matrix()[:, 1, 2]
    np.testing.assert_allclose(v.c23, exact, rtol=0, atol=4e-6 * 2e-3)  # ~tilt^2
    assert np.abs(v.c23 - exact).max() < 1e-3 * np.abs(exact).max()
    np.testing.assert_array_equal(c23(v.azimuth, v.tilt), v.c23)
    v.tilt = Tilt(roll=np.zeros(n), pitch=np.full(n, 1e-3))  # writing through the view
    np.testing.assert_array_equal(v.X[RunInputs.INDEX['roll']], 0.0)
    np.testing.assert_allclose(v.c23, 1e-3 * np.sin(v.azimuth))
    at = RunInputs(m.inputs(0.7, [0.0, np.pi / 2], 0.5, pitch=[0.0, 200 * ARCSEC], roll=[100 * ARCSEC, 0.0],
                            covariates={"temp_c": 20.0}))
    np.testing.assert_allclose(at.c23 / ARCSEC, [-100.0, 200.0], atol=1e-9)  # roll at psi 0, pitch at 90
