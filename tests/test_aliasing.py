"""What a campaign cannot rule out (hse_opt.aliasing, hse_opt.information.confounded), each
against an independent reference: the alias shift against a brute-force refit of data the
measurement model generates with the effect present, the power against a seeded Monte Carlo
of the nested-model F test, the confounded groups against a hand-built Jacobian whose
correlation is known in closed form."""
import numpy as np
import pytest
from scipy import stats

from hse_opt import units
from hse_opt.aliasing import POWER_LIMIT, alias_budget, effect_power
from hse_opt.fit import fit
from hse_opt.information import CONFOUNDED_CORRELATION, confounded
from hse_opt.validation.synthetic import diagnostic_plan, model_runs

from conftest import DIAGNOSTIC_BASE, DIAGNOSTIC_TILT


def _runs(values, seed, plan=None, model=None):
    plan = diagnostic_plan(sessions=2, runs_per_session=12) if plan is None else plan
    return model_runs(plan, {**DIAGNOSTIC_BASE, **values}, np.random.default_rng(seed),
                      base_tilt=DIAGNOSTIC_TILT, model=model)


@pytest.mark.parametrize("effect, values", [("sync_delay", {"delay": 200.0}),
                                            ("scale_nonlinearity", {"sf_nonlin": 0.1})])
def test_alias_shift_equals_a_brute_force_refit(effect, values):
    model = ["hse", effect]
    clean = _runs({}, 7, model=model)
    dirty = _runs(values, 7, model=model)          # the same noise, the effect present
    f0, f1 = fit(clean), fit(dirty)
    budget = alias_budget(f0, clean, [effect])
    r = budget.effect(effect)
    (name, edge), = zip(r.parameters, r.edge)
    moved = (f1.values - f0.values) * edge / values[name]   # the shift at the plausible edge
    np.testing.assert_allclose(r.full_shift, np.abs(moved), rtol=1e-2, atol=1e-6)  # linearised at the fit
    assert r.full_shift.max() > 1e-2               # a real shift, not rounding


def test_alias_shift_of_a_two_parameter_effect_is_its_worst_vertex():
    effect = "azimuth_harmonic2"
    plan = diagnostic_plan(sessions=1, runs_per_session=10, n_azimuths=5)
    clean = _runs({}, 3, plan)
    f0 = fit(clean)
    r = alias_budget(f0, clean, [effect]).effect(effect)
    assert r.parameters == ("az_c2", "az_s2") and r.edge == (20.0, 20.0)
    worst = np.zeros(len(f0.names))
    for s in (1.0, -1.0):                          # the box's vertices up to sign
        f1 = fit(_runs({"az_c2": 20.0, "az_s2": 20.0 * s}, 3, plan))
        worst = np.maximum(worst, np.abs(f1.values - f0.values))
    np.testing.assert_allclose(r.full_shift, worst, rtol=1e-2, atol=1e-6)  # linearised at the fit


def test_power_matches_a_monte_carlo_of_the_f_test():
    """The noncentral-F power against the rejection rate of the nested-model F test (base
    model against base + sync_delay, refitted) over seeded campaigns with the delay present."""
    plan = diagnostic_plan(sessions=1, runs_per_session=12)
    template = _runs({}, 0, plan)
    level = 0.05
    sigma = template.heading_std
    sizes = np.linspace(5.0, 200.0, 40)
    powers = np.array([effect_power("hse", template, "sync_delay", {"delay": d}, sigma=sigma, level=level)
                       for d in sizes])
    delay = float(np.interp(0.5, powers, sizes))     # where the power is about one half
    predicted = effect_power("hse", template, "sync_delay", {"delay": delay}, sigma=sigma, level=level)
    reps, hits = 300, 0
    rng = np.random.default_rng(20261126)
    for _ in range(reps):
        runs = model_runs(plan, {**DIAGNOSTIC_BASE, "delay": delay}, rng, base_tilt=DIAGNOSTIC_TILT,
                          model=["hse", "sync_delay"])
        f0, f1 = fit(runs, "hse"), fit(runs, "hse,sync_delay")
        dof = f1.dof
        F = (f0.chi2 - f1.chi2) / (f1.chi2 / dof)
        hits += F > stats.f.isf(level, 1, dof)
    rate = hits / reps
    assert 0.35 < predicted < 0.65
    assert abs(rate - predicted) < 3.5 * np.sqrt(predicted * (1 - predicted) / reps), (rate, predicted)


def test_threshold_is_where_the_power_reaches_the_limit():
    runs = _runs({}, 5)
    f = fit(runs)
    r = alias_budget(f, runs, ["sync_delay"]).effect("sync_delay")
    at = r.threshold * r.edge[0]
    p = effect_power("hse", runs, "sync_delay", {"delay": at}, sigma=f.sigma, level=r.level,
                     p=dict(zip(f.names, f.values)))
    assert p == pytest.approx(POWER_LIMIT, abs=1e-3)
    assert r.threshold_text() == f"undetectable here below {at:.3g} us (delay)"


def test_an_effect_in_the_models_span_is_undetectable_and_shifts_in_full():
    """One azimuth and one rate: the encoder-free sync_delay's heading error is a constant
    here, which the offset absorbs in full: power = the level, no threshold, the offset moves
    by the whole signature (the model: h = delay x rate x w_ie-term, hand-computed below)."""
    plan = diagnostic_plan(sessions=1, runs_per_session=8, rates_dps=(40.0,), n_azimuths=1, tilt_arcsec=0.0)
    plan = plan.replace(rate=np.abs(plan.rate))
    runs = _runs({}, 11, plan)
    f = fit(runs, "hse", fix={"lambda2": 4.2})
    r = alias_budget(f, runs, ["sync_delay"]).effect("sync_delay")
    assert r.power < 0.01 and not np.isfinite(r.threshold)
    assert r.threshold_text() == "undetectable here at any size"
    # the offset absorbs the delay's constant heading error at the edge
    from hse_opt.model import Model
    mm = Model(["hse", "sync_delay"]).measurement(True)
    X = mm.inputs_from_runs(runs)
    p = mm.vector(lambda2=4.2)
    h = (mm.predict(mm.vector(lambda2=4.2, delay=500.0), X) - mm.predict(p, X)) / units.ARCSEC
    assert np.ptp(h) < 1e-6 * np.abs(h).max()
    i = f.names.index("offset")
    assert r.shift[i] == pytest.approx(abs(h[0]), rel=1e-6)


@pytest.mark.parametrize("r_true, expect", [(0.995, True), (0.9, False)])
def test_confounded_groups_on_a_hand_built_jacobian(r_true, expect):
    rng = np.random.default_rng(4)
    n = 400
    x, y, z = np.linalg.qr(rng.normal(size=(n, 3)))[0].T * np.sqrt(n)   # orthogonal, norm sqrt(n)
    A = np.column_stack([x, r_true * x + np.sqrt(1 - r_true ** 2) * y, z])
    F = A.T @ A
    C = np.linalg.inv(F)
    groups = confounded(F, C, ["a", "b", "c"])
    if not expect:
        assert groups == ()
        return
    (g,) = groups
    assert g.names == ("a", "b")
    # closed forms: corr(a_hat, b_hat) = -r; VIF = 1 / (1 - r^2) for both
    assert g.correlation == pytest.approx(r_true, rel=1e-9)
    np.testing.assert_allclose(g.inflation, [1 / np.sqrt(1 - r_true ** 2)] * 2, rtol=1e-9)
    assert g.correlation > CONFOUNDED_CORRELATION
    assert "a, b are confounded" in g.text()


def test_confounded_by_inflation_alone_three_way():
    """A column that is nearly the mean of two orthogonal others: no two *columns* correlate
    above 0.71, yet the three cannot be separated; the group names all three with the variance
    inflations of the closed form diag(C) diag(F)."""
    rng = np.random.default_rng(5)
    n = 500
    u, v, w = np.linalg.qr(rng.normal(size=(n, 3)))[0].T
    e = 0.05
    A = np.column_stack([(u + v) / np.sqrt(2) + e * w, u, v])
    F = A.T @ A
    C = np.linalg.inv(F)
    col = F / np.sqrt(np.outer(np.diag(F), np.diag(F)))
    assert np.abs(col[np.triu_indices(3, 1)]).max() < 0.71
    (g,) = confounded(F, C, ["a", "b", "c"])
    assert set(g.names) == {"a", "b", "c"}
    vif = np.diag(C) * np.diag(F)
    np.testing.assert_allclose(sorted(g.inflation), sorted(np.sqrt(vif)), rtol=1e-9)
    assert min(vif) > 100
