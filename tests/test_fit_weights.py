"""Which sigma the runs get when they carry none, and the replicates' test of the fit
(docs/weights.md): a pure-error sigma from fewer than ``PURE_ERROR_MIN_DOF`` replicate degrees
of freedom is too uncertain to be taken as known, so the pooled residual variance is used; the
lack-of-fit F test is one rule for ``fit`` and ``diagnose``. References: Student's t and the
chi-square distribution (scipy.stats) for the Monte Carlo of the sigma's coverage, numpy group
means for the F statistic, scipy's F distribution for the closed-form tail."""
import numpy as np
import pytest
from scipy import stats

from hse_opt import units
from hse_opt.data import Plan
from hse_opt.diagnose import diagnose
from hse_opt.fit import fit
from hse_opt.fit.result import f_sf
from hse_opt.fit.weights import PURE_ERROR_MIN_DOF
from hse_opt.validation.synthetic import model_runs

SIGMA = 10 * units.ARCSEC
TRUTH = {"offset": 2.0, "lambda2": 4.2}


def _sheet(n_repeat):
    """A lab's sheet: 5 rates x 4 azimuths, the first ``n_repeat`` settings measured again
    (``n_repeat`` replicate degrees of freedom), five-minute runs an hour apart."""
    rate = np.repeat([20.0, 40.0, 60.0, -40.0, -60.0], 4)
    az = np.tile([0.0, 90.0, 180.0, 270.0], 5)
    rate, az = np.concatenate([rate, rate[:n_repeat]]), np.concatenate([az, az[:n_repeat]])
    n = rate.size
    return Plan(run=np.arange(1, n + 1), rate=rate * units.DEG_PER_S, azimuth=np.radians(az),
                duration=np.full(n, 300.0), t_start=3600.0 + 700.0 * np.arange(n), source="sheet")


def _monte_carlo(n_repeat, reps, seed):
    """Per sheet: the fit's sigma over the true one, |lambda2 error| / its std; the weighting."""
    plan, rng = _sheet(n_repeat), np.random.default_rng(seed)
    ratio, z, weighting = np.empty(reps), np.empty(reps), set()
    for i in range(reps):
        runs = model_runs(plan, TRUTH, rng, sigma=SIGMA, base_tilt=(7e-4, 3e-4)).replace(heading_std=None)
        f = fit(runs)
        value, std = f.value("lambda2")
        ratio[i], z[i] = f.sigma[0] / SIGMA, abs(value - TRUTH["lambda2"]) / std
        weighting.add(f.weighting)
    return ratio, z, weighting


def _within(share, p, reps, k=4.0):
    """``share`` of ``reps`` trials within ``k`` binomial standard errors of probability ``p``."""
    return abs(share - p) <= k * np.sqrt(p * (1 - p) / reps)


def test_two_replicate_dof_give_the_residual_sigma_and_its_coverage():
    """The trial's 22-run sheet (20 settings, 2 repeated): a pure-error sigma from 2 degrees of
    freedom is below a third of the true sigma on one sheet in ten (chi2_2 / 2 < 1/9: 10.5 %),
    and lambda2 +- 1.96 std then covers the truth on 81 % of the sheets (Student's t, 2 dof).
    The pooled residual sigma (20 dof) covers it as t with 20 dof says (93.6 %)."""
    reps = 1000
    ratio, z, weighting = _monte_carlo(2, reps, seed=1)
    assert weighting == {"residual"}
    assert stats.chi2.cdf(2 / 9, 2) > 0.1                  # what pure error from 2 dof would do
    assert np.mean(ratio < 1 / 3) < 0.005                  # (closed form for 20 dof: 3e-7)
    dof = 22 - 2
    for q in (1.0, 1.96):
        assert _within(np.mean(z < q), 2 * stats.t.cdf(q, dof) - 1, reps), q
    assert np.mean(z < 1.96) > 0.9 > 2 * stats.t.cdf(1.96, 2) - 1


def test_enough_replicate_dof_give_the_pure_error_sigma_and_its_coverage():
    """From PURE_ERROR_MIN_DOF replicate degrees of freedom the pure error is the sigma: its
    scatter is the chi-square's with those dof, the coverage Student's t's."""
    reps, nu = 1000, PURE_ERROR_MIN_DOF
    ratio, z, weighting = _monte_carlo(nu, reps, seed=2)
    assert weighting == {"pure-error"}
    assert _within(np.mean(ratio < 0.75), stats.chi2.cdf(nu * 0.75 ** 2, nu), reps)
    assert _within(np.mean(ratio > 1.25), stats.chi2.sf(nu * 1.25 ** 2, nu), reps)
    for q in (1.0, 1.96):
        assert _within(np.mean(z < q), 2 * stats.t.cdf(q, nu) - 1, reps), q
    # one replicate degree of freedom fewer: the residuals' sigma
    ratio, z, weighting = _monte_carlo(nu - 1, 50, seed=3)
    assert weighting == {"residual"}


def test_fit_and_diagnose_give_one_lack_of_fit_test_with_measured_tilts():
    """Measured tilts (a few arcsec of leveling noise) differ within a replicate group, so the
    model's columns are not quite constant there; the pure error is still the scatter within
    the groups, n - groups degrees of freedom, in fit and in diagnose alike (the trial saw
    F(19, 1) from diagnose where fit counted 2). F by hand from numpy's group means."""
    rng = np.random.default_rng(4)
    plan = _sheet(2)
    runs = model_runs(plan, TRUTH, rng, sigma=SIGMA, base_tilt=(7e-4, 3e-4)).replace(heading_std=None)
    n = len(runs)
    runs = runs.replace(pitch=runs.pitch + 3 * units.ARCSEC * rng.standard_normal(n),
                        roll=runs.roll + 3 * units.ARCSEC * rng.standard_normal(n))
    f = fit(runs)
    d = diagnose(runs, refit=False)
    assert f.lack_of_fit.dof == tuple(d.lack_of_fit.dof) == (20 - 2, 2)
    assert d.lack_of_fit.statistic == pytest.approx(f.lack_of_fit.statistic, rel=1e-9)
    assert d.lack_of_fit.p_value == pytest.approx(f.lack_of_fit.p_value, rel=1e-9)
    # by hand: the two repeated settings are runs (1, 21) and (2, 22)
    r = f.residuals
    ss_pe = sum((r[i] - r[j]) ** 2 / 2 for i, j in ((0, 20), (1, 21)))
    F = ((np.sum(r ** 2) - ss_pe) / 18) / (ss_pe / 2)
    assert f.lack_of_fit.statistic == pytest.approx(F, rel=1e-9)
    assert f.lack_of_fit.p_value == pytest.approx(stats.f.sf(F, 18, 2), rel=1e-9)
    text = "\n".join(f.summary())
    assert "lack of fit F(18, 2)" in text and "2 replicate degrees of freedom: too few" in text
    from hse_opt.report.fit_sections import fit_section      # and the report's statistics table
    page = "".join(b for b in fit_section(f, runs).blocks if isinstance(b, str))
    assert f"F(18, 2) = {F:.4g}, p = {stats.f.sf(F, 18, 2):.3g}" in page


def test_f_tail_matches_scipy():
    """The F tail without scipy (incomplete beta by its continued fraction) against scipy."""
    for d1 in (1, 2, 5, 18, 200):
        for d2 in (1, 2, 8, 100):
            for F in (1e-4, 0.3, 1.0, 4.0, 50.0, 1e4):
                assert f_sf(F, d1, d2) == pytest.approx(stats.f.sf(F, d1, d2), rel=1e-9, abs=1e-300)
    assert f_sf(0.0, 3, 4) == 1.0 and f_sf(np.inf, 3, 4) == 0.0


def test_fit_json_carries_the_lack_of_fit_and_refuses_a_malformed_one(tmp_path):
    """FIT.json keeps the test (the same F, dof, p back); a file whose entry is malformed is
    refused naming the entry, and one written before it (no entry) loads without it."""
    import json

    from hse_opt.fit import load_fit, save_fit
    runs = model_runs(_sheet(2), TRUTH, np.random.default_rng(5), sigma=SIGMA,
                      base_tilt=(7e-4, 3e-4)).replace(heading_std=None)
    f = fit(runs)
    save_fit(f, tmp_path / "FIT.json")
    assert load_fit(tmp_path / "FIT.json").lack_of_fit == f.lack_of_fit
    d = json.loads((tmp_path / "FIT.json").read_text())
    d["lack_of_fit"]["dof"] = [0, 2]
    (tmp_path / "BAD.json").write_text(json.dumps(d))
    with pytest.raises(ValueError, match="lack_of_fit.*allowed"):
        load_fit(tmp_path / "BAD.json")
    del d["lack_of_fit"]
    (tmp_path / "OLD.json").write_text(json.dumps(d))
    assert load_fit(tmp_path / "OLD.json").lack_of_fit is None


def test_a_lack_of_fit_is_said_among_the_checks_with_a_pure_error_sigma():
    """12 replicate degrees of freedom (a pure-error sigma) and a 25-arcsec 2nd azimuth
    harmonic the model lacks: the check names the lack of fit with its F test (p < 0.01, the
    checks' level); without the harmonic, nothing is said (the chi-square check is for the
    runs' own sigmas only: with a pure-error sigma chi2 = dof_pe + F-part, not chi-square)."""
    from hse_opt.fit.checks import ALPHA, check_lines
    runs = model_runs(_sheet(12), TRUTH, np.random.default_rng(1), sigma=SIGMA,
                      base_tilt=(7e-4, 3e-4)).replace(heading_std=None)
    clean = fit(runs)
    assert clean.weighting == "pure-error" and clean.lack_of_fit.p_value > ALPHA and check_lines(clean, runs) == []
    bent = runs.replace(heading_err=runs.heading_err + 25 * units.ARCSEC * np.cos(2 * runs.azimuth))
    f = fit(bent)
    assert f.lack_of_fit.p_value < ALPHA
    assert [ln for ln in check_lines(f, bent) if ln.startswith("the replicate groups' means stray")] == [
        f"the replicate groups' means stray from the model more than the replicates scatter ({f.lack_of_fit.text()}): "
        "a missing effect (hse-opt diagnose), or replicates that are not independent"]
