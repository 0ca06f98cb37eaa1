"""What the fit tells the user to look at (issue 14, item 5), against definitions: the
externally studentised residual is the t statistic of a mean-shift dummy for that run in a
refit; chi2_red far from 1 against the chi-square quantiles; identical replicates in the
diagnosis."""
import json

import numpy as np
import pytest
from scipy import stats

from hse_opt import units
from hse_opt.cli import main
from hse_opt.data import save_runs
from hse_opt.diagnose import diagnose
from hse_opt.fit import fit
from hse_opt.fit.checks import check_lines, outliers, studentized
from hse_opt.validation.synthetic import diagnostic_plan, model_runs

BASE_TILT = (-120 * units.ARCSEC, -55 * units.ARCSEC)


def runs_with_outlier(seed=1, shift_arcsec=1000.0, with_std=True):
    runs = model_runs(diagnostic_plan(), {"offset": 3.0, "lambda2": 4.95}, np.random.default_rng(seed),
                      base_tilt=BASE_TILT)
    h = runs.heading_err.copy()
    h[17] += shift_arcsec * units.ARCSEC
    runs = runs.replace(heading_err=h)
    return runs if with_std else runs.replace(heading_std=None)


def test_studentised_residual_is_the_mean_shift_t_statistic():
    runs = runs_with_outlier(shift_arcsec=60.0, with_std=False)
    f = fit(runs)
    t, h = studentized(f, runs)
    for i in (17, 3):
        dummy = runs.replace(covariates={"d": (np.arange(len(runs)) == i).astype(float)})
        g = fit(dummy, ["hse", "covariate:d"])   # residual weighting: t = value / std
        v, s = g.value("k_d")
        assert abs(t[i]) == pytest.approx(abs(v / s), rel=1e-4)


def test_outlier_named_chi2_far_from_one_and_robust_suggested(tmp_path, capsys):
    runs = runs_with_outlier()
    f = fit(runs)
    assert [r for r, _ in outliers(f, runs)] == [17]
    lines = check_lines(f, runs)
    assert any("chi2_red" in x and "far from 1" in x for x in lines)
    assert any("run 17" in x and "--robust" in x for x in lines)
    path = tmp_path / "RUNS.csv"
    save_runs(runs, path)
    assert main(["fit", str(path)]) == 0
    out = capsys.readouterr().out
    assert "look at:" in out and "run 17" in out
    assert main(["fit", str(path), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["outliers"][0]["run"] == 17 and d["checks"]
    # a clean campaign: chi2_red inside the chi-square interval, nothing to look at
    clean = model_runs(diagnostic_plan(), {"offset": 3.0, "lambda2": 4.95}, np.random.default_rng(5),
                       base_tilt=BASE_TILT)
    fc = fit(clean)
    lo, hi = stats.chi2.ppf([0.005, 0.995], fc.dof) / fc.dof
    assert lo <= fc.chi2_red <= hi and check_lines(fc, clean) == []


def test_identical_replicates_are_said():
    # noise of 1e-12 rad (2e-7 arcsec): no noise at all for a heading error
    exact = model_runs(diagnostic_plan(sessions=8), {"offset": 3.0, "lambda2": 4.95}, np.random.default_rng(2),
                       base_tilt=BASE_TILT, sigma=1e-12)
    # identical replicates but a lack of fit between groups: no F = inf
    h = exact.heading_err + 5 * units.ARCSEC * np.sin(3 * exact.azimuth)
    d = diagnose(exact.replace(heading_err=h, heading_std=None), refit=False)
    assert d.lack_of_fit is not None and d.lack_of_fit.p_value is None
    assert "identical" in d.lack_of_fit.note
    assert d.fit.weighting == "residual" and any("are copies of another row" in n for n in d.notes)


def test_chi2_quantile_matches_scipy():
    """The chi-square check's interval (bisection on the closed-form chi2_sf, no scipy at
    start-up) against scipy.stats over even and odd dof, both tails."""
    from hse_opt.fit.result import chi2_isf
    for dof in (1, 2, 3, 10, 11, 96, 97, 9996, 9997):
        for q in (1e-12, 0.005, 0.5, 0.995):
            assert chi2_isf(q, dof) == pytest.approx(stats.chi2.isf(q, dof), rel=1e-9)
    with pytest.raises(ValueError, match="q 1.0"):
        chi2_isf(1.0, 3)


@pytest.mark.parametrize("shift_arcsec", [0.0, 25.0, 32.0, 36.0, 40.0, 60.0])
def test_outliers_are_the_exact_bonferroni_t_test(shift_arcsec):
    """The outlier test skips scipy when the largest residual passes the normal test (Student's
    t has the heavier tails); around the threshold it must name exactly the runs scipy's t test
    rejects (shifts of 25-40 arcsec on a 7.6-arcsec run straddle it)."""
    for seed in range(3):
        runs = runs_with_outlier(seed=seed, shift_arcsec=shift_arcsec)
        f = fit(runs)
        t, _ = studentized(f, runs)
        p = len(t) * 2 * stats.t.sf(np.abs(t), f.dof - 1)
        expected = sorted(int(r) for r in f.run[p < 0.01])
        assert sorted(r for r, _ in outliers(f, runs)) == expected
