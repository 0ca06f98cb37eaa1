"""The symbolic model against independent references: adaptive quadrature, the algebra of
Eqs. 8-11, the derived first-order closed form, the paper's Eq. 14 and physical sign checks."""
import casadi as ca
import numpy as np
import pytest
from scipy.integrate import quad

from conftest import ALL_EFFECTS, random_case
from hse_opt import frames, units
from hse_opt.model import Model, closed_form as cf, symbolic as S
from hse_opt.model.effects import Effect, Param, effect

ARCSEC = units.ARCSEC


class FreeLambda(Effect):
    """Non-orthogonality errors eps1..eps3 of K_g, each free (a user-declared effect)."""
    name = "free_lambda"
    params = tuple(Param(f"eps{i}", "arcsec", ARCSEC, 0.0, -100.0, 100.0, f"eps{i} of Eq. 1")
                   for i in (1, 2, 3))

    def act(self, p, op, errors):
        errors.add_lambda(ca.vertcat(p["eps1"], p["eps2"], p["eps3"]))


def _integrand_function(effects, rng, size=None):
    """f(alpha) -> computed Earth rate in b0 at random parameters: physical ones (50 display
    units each) or, with ``size``, every parameter ``size`` in SI (to make every harmonic
    visible: the integrand is the same trigonometric polynomial at any size)."""
    model = Model(effects)
    p = {q.name: (900.0 if q.name == "warmup_tau" else
                  rng.uniform(-1, 1) * (size if size else 50 * q.scale)) for q in model.params}
    op = S.Operating(Omega=0.7, psi=0.4, theta=1e-3, gamma=-2e-3, L=0.49, t_start=300.0,
                     duration=600.0, covariates={"temp_c": 3.0})
    errors = S.ErrorModel()
    for e in model.effects:
        e.act(p, op, errors)
    integrand, alpha, degree = S.rate_b0(op, errors)
    return ca.Function("f", [alpha], [integrand]), integrand, alpha, degree


def _quad_mean(f):
    return np.array([quad(lambda a: float(f(a)[i]), 0, 2 * np.pi, epsabs=1e-20, epsrel=1e-10,
                          limit=200)[0] / (2 * np.pi) for i in range(3)])


@pytest.mark.parametrize("effects", [["hse"], ALL_EFFECTS, ["hse", "encoder_harmonic"],
                                     ["hse", "scale_nonlinearity"]])
def test_revolution_average_is_exact_against_quadrature(effects, rng):
    f, integrand, alpha, degree = _integrand_function(effects, rng)
    mean = np.array(ca.evalf(S.revolution_average(integrand, alpha, degree))).ravel()
    np.testing.assert_allclose(mean, _quad_mean(f), rtol=1e-11, atol=1e-19)


@pytest.mark.parametrize("effects", [ALL_EFFECTS, [FreeLambda(), "encoder_harmonic"],
                                     [FreeLambda(), "scale_nonlinearity"], [FreeLambda()]])
def test_stated_degree_is_tight(effects, rng):
    # with every parameter large the top harmonic is visible: degree + 1 samples are exact,
    # degree samples alias the top harmonic onto the mean
    f, integrand, alpha, degree = _integrand_function(effects, rng, size=0.05)
    exact = _quad_mean(f)
    mean = np.array(ca.evalf(S.revolution_average(integrand, alpha, degree))).ravel()
    short = np.array(ca.evalf(S.revolution_average(integrand, alpha, degree - 1))).ravel()
    err = np.abs(mean - exact).max()
    assert err < 1e-10 * np.abs(exact).max()
    assert np.abs(short - exact).max() > 1e3 * err


def test_degrees_stated():
    # paper model: Earth rate in b turns once, projected back once -> degree 2;
    # full catalogue: rate squared by the scale nonlinearity (2) + 1 + encoder 2nd harmonic (2)
    assert Model(["hse"]).measurement().degree == 2
    assert Model(ALL_EFFECTS).measurement().degree == 5


def test_eq6_error_equals_sum_of_eqs_9_to_11(rng):
    # without averaging, for perfect gyros: d_omega = d_omega_xi + d_omega_Lambda + O(d_omega)
    for _ in range(10):
        c = random_case(rng)
        a = rng.uniform(0, 2 * np.pi)
        C_b_n = frames.dcm_zyx(0.7, c["theta"], c["gamma"]) @ frames.rot_z(a)
        C_s_b = frames.c_b_s(c["r"]).T
        w_ib_b = C_b_n.T @ frames.earth_rate_n(c["L"]) + [0, 0, c["rate"]]
        w_g = np.linalg.solve(np.eye(3), C_s_b.T @ w_ib_b)
        e1, e2, e3 = c["eps"]
        Lam = np.array([[0, 0, 0], [e1, 0, 0], [e2, e3, 0]])
        est = C_b_n @ ((np.eye(3) - frames.skew(c["xi"])) @ C_s_b @ (np.eye(3) + Lam) @ w_g - [0, 0, c["rate"]])
        d_omega = est - frames.earth_rate_n(c["L"])
        parts = S.d_omega_parts(ca.DM(C_b_n), ca.DM(C_s_b), ca.DM(Lam), ca.DM(c["xi"]), ca.DM(w_ib_b))
        np.testing.assert_allclose(np.array(sum(parts)).ravel(), d_omega, rtol=1e-9, atol=1e-20)


@pytest.fixture(scope="module")
def paper_fun():
    F = S.error_function()
    ins = F.sx_in()
    h = F.call(ins)[0]
    J = ca.Function("J", ins, [ca.jacobian(h, ca.vertcat(ins[5], ins[6]))])
    return F, J


PSI = np.linspace(0, 2 * np.pi, 16, endpoint=False)


def _model_over_heading(F, J, c):
    args = (c["rate"], PSI, c["theta"], c["gamma"], c["L"])
    z = np.zeros(3)
    full = np.array(F.map(16)(*args, c["eps"], c["xi"], c["r"], z)[0]).ravel()
    jac = np.array(J.map(16)(*args, z, z, c["r"], z)).reshape(16, 6)
    first = jac @ np.r_[c["eps"], c["xi"]]
    return full, first


def test_first_order_model_equals_derived_closed_form(paper_fun, rng):
    """Over the issue's ranges, the symbolic model linearised in eps and xi equals the derived
    first-order closed form: both its heading-dependent part and the remainder."""
    F, J = paper_fun
    worst_dep = worst_rem = 0.0
    for _ in range(200):
        c = random_case(rng)
        _, first = _model_over_heading(F, J, c)
        ref = cf.heading_error_first_order(c["rate"], c["L"], c["eps"], c["xi"], c["r"], PSI,
                                           c["theta"], c["gamma"])
        worst_dep = max(worst_dep, np.abs((first - first.mean()) - (ref - ref.mean())).max())
        worst_rem = max(worst_rem, abs(first.mean() - ref.mean()))
    assert worst_dep < 0.05 * ARCSEC
    assert worst_rem < 0.05 * ARCSEC


def test_heading_independent_remainder_is_the_turn_about_the_axis(paper_fun, rng):
    """To first order the heading-independent part is xi_z - (M21 - M12)/2 (see
    closed_form.heading_error_first_order), here checked against the model's mean over
    heading, with M built independently from the Lambda of Eq. 1 and C_b^s."""
    F, J = paper_fun
    for _ in range(50):
        c = random_case(rng)
        _, first = _model_over_heading(F, J, c)
        C_s_b = frames.c_b_s(c["r"]).T
        e1, e2, e3 = c["eps"]
        M = C_s_b @ np.array([[0, 0, 0], [e1, 0, 0], [e2, e3, 0]]) @ C_s_b.T
        remainder = c["xi"][2] - (M[1, 0] - M[0, 1]) / 2
        # the tilt products C13*C23 and C13 tan L leave a second-order residue
        assert abs(first.mean() - remainder) < 1e-3 * ARCSEC + 2e-3 * abs(remainder) + 5e-7 * 1e-4


def test_eq14_heading_dependent_part_in_the_papers_regime(paper_fun, rng):
    """The full nonlinear model's heading-dependent part equals Eq. 14 as printed within
    0.05 arcsec for the paper's system: calibration errors ~1e-5 rad, tilt <= 2e-3 rad, rates
    20-60 deg/s at the paper's latitude, lab-calibrated axis off ideal by up to 1e-3."""
    F, J = paper_fun
    worst = 0.0
    for _ in range(200):
        c = random_case(rng, eps_max=1e-5, xi_max=1e-5, rate_max_dps=60.0, lat_max_deg=45.0)
        full, _ = _model_over_heading(F, J, c)
        eq14 = cf.heading_error_eq14(c["rate"], c["L"], c["eps"].sum(), PSI, c["theta"], c["gamma"])
        worst = max(worst, np.abs(full - full.mean() - eq14).max())
    assert worst < 0.05 * ARCSEC


def test_eq14_over_the_full_ranges(paper_fun, rng):
    """Over the issue's full ranges (|eps|, |xi| <= 1e-4, tilts <= 2e-3, |Omega| <= 100 deg/s,
    |L| <= 70 deg, axis off ideal by 1e-3) the HSE reaches ~1100 arcsec and the full model
    departs from Eq. 14 by up to a few arcsec: (a) the axis-projected lambda2 = 3 r'Lambda r
    differs from eps1+eps2+eps3 by O(1e-3) relative, (b) products of errors (xi Lambda,
    Lambda^2, the nonlinear gyrocompass) are O(1e-3) relative. With (a) taken into account,
    Eq. 14 holds within 0.05 arcsec + 0.5 % of the HSE amplitude; the first-order model holds
    it within 0.05 arcsec + 0.05 % + the remainder's C13 tan L term (the 3/2 w sin L
    correction and the mount turn's tilt coupling, both in closed_form.heading_error_first_order)."""
    F, J = paper_fun
    for _ in range(200):
        c = random_case(rng)
        full, first = _model_over_heading(F, J, c)
        e1, e2, e3 = c["eps"]
        Lam = np.array([[0, 0, 0], [e1, 0, 0], [e2, e3, 0]])
        lam2_axis = 3 * c["r"] @ Lam @ c["r"]
        eq14 = cf.heading_error_eq14(c["rate"], c["L"], lam2_axis, PSI, c["theta"], c["gamma"])
        amp = np.abs(eq14).max()
        M = frames.c_b_s(c["r"]).T @ Lam @ frames.c_b_s(c["r"])
        c13_term = abs(c["xi"][2] - (M[1, 0] - M[0, 1]) / 2) * np.hypot(2e-3, 2e-3) * abs(np.tan(c["L"]))
        assert np.abs(full - full.mean() - eq14).max() < 0.05 * ARCSEC + 5e-3 * amp + c13_term
        assert np.abs(first - first.mean() - eq14).max() < 0.05 * ARCSEC + 5e-4 * amp + c13_term


def test_linear_eq12_and_gyrocompass_agree_to_first_order(rng):
    FL, FG = S.error_function(heading="linear"), S.error_function()
    for _ in range(50):
        c = random_case(rng, eps_max=1e-5, xi_max=1e-5)
        args = (c["rate"], rng.uniform(0, 6.3), c["theta"], c["gamma"], c["L"], c["eps"], c["xi"],
                c["r"], np.zeros(3))
        hl, hg = float(FL(*args)[0]), float(FG(*args)[0])
        assert abs(hl - hg) < 1e-3 * abs(hg) + 1e-3 * ARCSEC


def test_gyrocompass_sign_by_construction(rng):
    """A computed Earth rate turned about down by +delta (toward east) moves the estimated
    north toward east; every heading then reads small: error = -delta (docs/conventions.md, Signs)."""
    for _ in range(20):
        psi, theta, gamma, L = rng.uniform(0, 6.3), *rng.uniform(-2e-3, 2e-3, 2), rng.uniform(-1, 1)
        delta = rng.uniform(-1e-3, 1e-3)
        C_b0_n = frames.dcm_zyx(psi, theta, gamma)
        w_b0 = C_b0_n.T @ frames.rot_z(delta) @ frames.earth_rate_n(L)
        op = S.Operating(Omega=0.7, psi=psi, theta=theta, gamma=gamma, L=L)
        h = float(ca.evalf(S.heading_error_gyrocompass(op, ca.DM(w_b0))))
        assert h == pytest.approx(-delta, rel=1e-9, abs=1e-15)


def test_first_order_form_of_c_b0_n_changes_heading_at_second_order_in_tilt(rng):
    FE, F1 = S.error_function(form="exact"), S.error_function(form="first_order")
    c = random_case(rng)
    diffs = []
    for k in (1.0, 0.5, 0.25):
        args = (c["rate"], 0.9, k * 2e-3, k * -1.5e-3, c["L"], c["eps"], c["xi"], c["r"], np.zeros(3))
        diffs.append(abs(float(FE(*args)[0]) - float(F1(*args)[0])))
    assert diffs[0] < 0.05 * ARCSEC
    assert diffs[1] < 0.3 * diffs[0] and diffs[2] < 0.3 * diffs[1]


# ---- the catalogue, each against its physics ------------------------------------------------

def _one_effect(name, values, rate=0.7, psi=0.9, theta=1.2e-3, gamma=-0.8e-3, L=0.49,
                t_start=0.0, duration=600.0, cov=None):
    model = Model([name])
    m = model.measurement()
    p = np.array([values.get(q.name, q.nominal) * q.scale for q in m.params])
    X = m.inputs(rate=rate, azimuth=psi, latitude=L, pitch=theta, roll=gamma, t_start=t_start,
                 duration=duration, covariates={"temp_c": cov} if cov is not None else None)
    return m.predict(p, X)[0]


def test_sync_delay_turns_the_earth_rate_by_omega_dt():
    # encoder late by dt: C_b^b0 uses alpha - Omega dt, so the Earth rate seen in b0 is
    # turned by -Omega dt about the axis z_b0: heading error +Omega dt at level; the axis
    # tilted toward north by C13 adds the tan L coupling of a turn about z_b0
    C = frames.dcm_zyx(0.9, 1.2e-3, -0.8e-3)
    for rate in (-1.0, 0.35, 1.0):
        h = _one_effect("sync_delay", {"delay": 50.0}, rate=rate)
        assert h == pytest.approx(rate * 50e-6 * (C[2, 2] + C[0, 2] * np.tan(0.49)), rel=1e-6)


def test_axis_bias_couples_through_c23():
    b = 0.01 * units.DEG_PER_H
    h = _one_effect("axis_bias", {"bias_z": 0.01})
    C23 = frames.dcm_zyx(0.9, 1.2e-3, -0.8e-3)[1, 2]
    assert h == pytest.approx(-b * C23 / (frames.EARTH_RATE * np.cos(0.49)), rel=1e-4)


def test_scale_nonlinearity_is_an_axis_rate_error():
    # gyro i sees Omega r_i (r_i = -1/sqrt 3); output error n sign(w_i) w_i^2 = -n sign(Omega)
    # Omega^2 / 3; in s along (1,1,1), on the axis: -sqrt 3 times it = n Omega |Omega| / sqrt 3
    n, rate = 10.0 * units.PPM / units.DEG_PER_S, -0.7
    h = _one_effect("scale_nonlinearity", {"sf_nonlin": 10.0}, rate=rate)
    C23 = frames.dcm_zyx(0.9, 1.2e-3, -0.8e-3)[1, 2]
    b = n * rate * abs(rate) / np.sqrt(3)
    assert h == pytest.approx(-b * C23 / (frames.EARTH_RATE * np.cos(0.49)), rel=1e-3)


def test_warmup_is_the_window_mean_of_the_transient():
    amp, tau, t0, T = 20.0, 900.0, 120.0, 600.0
    h = _one_effect("warmup", {"warmup_amp": amp, "warmup_tau": tau}, t_start=t0, duration=T)
    mean = quad(lambda t: np.exp(-t / tau), t0, t0 + T)[0] / T
    # a mount turn xi_z about the axis is a heading offset +xi_z (first-order remainder)
    assert h == pytest.approx(amp * mean * ARCSEC, rel=1e-4)


def test_reference_effects():
    h = _one_effect("azimuth_harmonic2", {"az_c2": 3.0, "az_s2": -2.0}, psi=0.9)
    assert h == pytest.approx(-(3.0 * np.cos(1.8) - 2.0 * np.sin(1.8)) * ARCSEC, rel=1e-12)
    h = _one_effect("covariate:temp_c", {"k_temp_c": 0.5}, cov=4.0)
    assert h == pytest.approx(2.0 * ARCSEC, rel=1e-12)
    h = _one_effect("hse", {"offset": 7.0}, theta=0.0, gamma=0.0)
    assert h == pytest.approx(7.0 * ARCSEC, rel=1e-12)


def test_encoder_harmonic_averages_out_at_first_order():
    # the encoder error turns the projection about z by delta(alpha), whose revolution mean is
    # zero for pure harmonics: with the paper's other errors absent the heading does not move
    h = _one_effect("encoder_harmonic", {"enc_c1": 100, "enc_s1": 50, "enc_c2": -80, "enc_s2": 30})
    assert abs(h) < 1e-6 * ARCSEC
    with pytest.raises(ValueError, match="unknown effect 'encoder'"):
        effect("encoder")


def test_the_effect_catalogues_own_example_runs_and_a_table_fixed_bias_averages_out():
    """The "declaring a new effect" example of ``hse_opt.model.effects`` runs as printed, and
    its effect is physical: a gyro bias fixed in the table top turns with it, so its
    revolution mean (the heading) is zero, while a bias of that size fixed in the base
    would move the heading by up to b / (w_ie cos L) (Eq. 12)."""
    import textwrap

    from hse_opt.model import effects
    code = textwrap.dedent(effects.__doc__.split("::\n", 1)[1])
    namespace = {}
    exec(code, namespace)  # noqa: S102 - the package's own docstring
    mm = namespace["model"].measurement(True)
    assert "bias_xb" in mm.names and not set(mm.names) & {"xi_x", "xi_y"}  # no clash with mount_xi
    X = np.zeros((mm.n_x, 4))
    X[0] = [-0.8, -0.2, 0.3, 0.7]                   # rate, rad/s
    X[1] = [0.4, 1.9, 3.3, 5.0]                     # heading
    X[2:4] = 1e-3
    X[4] = 0.49
    X[6] = 600.0
    p = np.array(mm.nominal, dtype=float)
    h0 = mm.predict(p, X)
    p[list(mm.names).index("bias_xb")] = 0.5 * units.DEG_PER_H
    moved = mm.predict(p, X) - h0
    fixed_in_base = 0.5 * units.DEG_PER_H / (frames.EARTH_RATE * np.cos(0.49))   # ~0.04 rad
    assert np.abs(moved).max() < 1e-9 * fixed_in_base
