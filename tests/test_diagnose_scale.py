"""One likelihood scale for every candidate's refit (issue 14, item 1), against definitions.

A candidate that makes time since power-on matter (the warm-up) splits the replicate groups of
data without ``heading_std``: the refit alone would fall back from pure-error to residual
weighting and its BIC would be on another scale. The diagnosis holds the base model's noise
model; the references here are the pure-error sigma computed by hand from the replicate groups
and BIC by its definition."""
import math

import numpy as np
import pytest

from hse_opt import units
from hse_opt.datasets import paper_table1
from hse_opt.diagnose import diagnose
from hse_opt.validation.synthetic import diagnostic_plan, model_runs

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")


def pure_error_by_hand(y, keys):
    """sqrt(sum of squared deviations from each group's mean / (n - groups))."""
    groups = {}
    for v, k in zip(y, map(tuple, keys)):
        groups.setdefault(k, []).append(v)
    ss = sum(float(np.sum((np.array(g) - np.mean(g)) ** 2)) for g in groups.values())
    return math.sqrt(ss / (len(y) - len(groups)))


def bic_fixed(residuals, sigma, dof):
    n = len(residuals)
    return float(np.sum((np.asarray(residuals) / sigma) ** 2)) + (n - dof) * math.log(n)


def test_table1_warmup_on_the_pure_error_scale():
    runs = paper_table1().replace(position=None, heading_err_compensated_arcsec=None)
    d = diagnose(runs, fix={"lambda2*tilt_const": 0.0}, covariates=[])
    assert d.fit.weighting == "pure-error"
    # Table 1: three repeats at each of four positions (the azimuth) are the replicate groups
    s = pure_error_by_hand(runs.heading_err, np.round(np.column_stack([runs.azimuth]), 9))
    assert s / units.ARCSEC == pytest.approx(9.52, abs=0.01)
    c = d.candidate("warmup")
    assert c.fit.weighting != "residual"       # the refit kept the base model's sigma
    ref = bic_fixed(c.fit.residuals, s, c.fit.dof) - bic_fixed(d.fit.residuals, s, d.fit.dof)
    assert c.delta_bic == pytest.approx(ref, abs=1e-6)
    # the score test does not reject (p 0.51) and Delta-BIC agrees: no support (was -252)
    assert c.p_value > 0.3 and c.delta_bic > 0
    assert "9.52 arcsec" in d.likelihood and "Delta chi2" in d.likelihood
    assert d.to_dict()["likelihood_scale"] == d.likelihood
    assert any("one likelihood scale" in line for line in d.summary())


@pytest.mark.parametrize("seed", [1, 2])
def test_grouped_noise_candidates_share_the_base_scale(seed):
    """Replicated settings, no heading_std, no hidden effect: every candidate's Delta-BIC is on
    the base model's pure-error scale, and where the score test does not reject at 0.05 no
    candidate gains in BIC."""
    plan = diagnostic_plan(sessions=8)   # sessions s and s + 4 repeat settings: replicates
    sigma = 3.0 * units.ARCSEC
    runs = model_runs(plan, {"offset": 3.0, "lambda2": 4.2}, np.random.default_rng(seed),
                      base_tilt=(-120 * units.ARCSEC, -55 * units.ARCSEC), sigma=sigma)
    runs = runs.replace(heading_std=None)
    d = diagnose(runs)
    assert d.fit.weighting == "pure-error"
    keys = np.column_stack([runs.rate, np.mod(runs.azimuth, 2 * np.pi), runs.duration, runs.latitude,
                            np.round(runs.pitch / (10 * units.ARCSEC)), np.round(runs.roll / (10 * units.ARCSEC))])
    s = pure_error_by_hand(runs.heading_err, np.round(keys, 9))
    assert float(d.fit.sigma[0]) == pytest.approx(s, rel=1e-9)
    refitted = [c for c in d.candidates if c.delta_bic is not None]
    assert {"warmup", "sync_delay"} <= {c.effect for c in refitted}
    for c in refitted:
        ref = bic_fixed(c.fit.residuals, s, c.fit.dof) - bic_fixed(d.fit.residuals, s, d.fit.dof)
        assert c.delta_bic == pytest.approx(ref, abs=1e-6), c.effect
        if c.p_value > 0.05:
            assert c.delta_bic > 0, c.effect


def test_residual_scale_without_sigmas_or_replicates():
    """No heading_std and no replicates: one unknown sigma, profiled per model (definition:
    n ln(RSS1/RSS0) + Delta k ln n)."""
    plan = diagnostic_plan(sessions=1, runs_per_session=24)
    runs = model_runs(plan, {"offset": 3.0, "lambda2": 4.2, "delay": 60.0}, np.random.default_rng(3),
                      base_tilt=(-120 * units.ARCSEC, -55 * units.ARCSEC), sigma=2 * units.ARCSEC)
    runs = runs.replace(heading_std=None, t_start=runs.t_start + 1e3 * np.arange(len(runs)))
    d = diagnose(runs, candidates=["sync_delay"])
    assert d.fit.weighting == "residual" and "profiled" in d.likelihood
    c = d.candidate("sync_delay")
    n = len(runs)
    ref = n * math.log(np.sum(c.fit.residuals ** 2) / np.sum(d.fit.residuals ** 2)) \
        + (d.fit.dof - c.fit.dof) * math.log(n)
    assert c.delta_bic == pytest.approx(ref, abs=1e-6)
