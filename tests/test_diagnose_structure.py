"""Structure beyond the catalogue, ambiguity and the words' statistics (issue 14 items 2-3,
issue 18 item 2), against independent references: the truth the campaigns were made with,
refits by :func:`hse_opt.fit.fit`, and the documented plausibility ranges."""
import numpy as np
import pytest

from conftest import DIAGNOSTIC_BASE, DIAGNOSTIC_TILT, campaign
from hse_opt import units
from hse_opt.diagnose import diagnose, refine
from hse_opt.fit import fit
from hse_opt.validation.synthetic import diagnostic_plan, model_runs

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

BASE, BASE_TILT = DIAGNOSTIC_BASE, DIAGNOSTIC_TILT



def test_level_shift_is_found_named_and_modelled_with_a_covariate():
    runs = campaign({}, seed=1)
    h = runs.heading_err.copy()
    h[24:] += 25 * units.ARCSEC          # a re-mount after run 23: +25 arcsec from run 24 on
    runs = runs.replace(heading_err=h)
    d = diagnose(runs)
    assert d.verdict == "unexplained structure"
    top = d.structure[0]
    assert top.factor == "level shift" and abs(int(top.function.split()[-1]) - 24) <= 3
    assert top.coefficient == pytest.approx(25.0, abs=4 * top.std + 5.0)
    assert "covariate:shift" in top.text and not top.explained_by
    assert "drifts linearly" not in " ".join(t.text for t in d.structure[:1])
    assert len(refine(runs)) == 1        # refine does not add a catalogue effect for it
    # the suggested covariate column makes the error fall (the truth: the step at run 24)
    shifted = runs.replace(covariates={"shift": (np.arange(len(runs)) >= 24).astype(float)})
    f = fit(shifted, ["hse", "covariate:shift"])
    assert abs(f.value("k_shift")[0]) == pytest.approx(25.0, abs=4 * f.value("k_shift")[1])
    assert f.rms_arcsec < 0.7 * d.rms_arcsec and f.chi2_red < 1.3 < d.chi2_red
    assert diagnose(shifted, f).fits


def test_outlier_is_named_as_such():
    runs = campaign({}, seed=2)
    h = runs.heading_err.copy()
    h[17] += 1000 * units.ARCSEC
    d = diagnose(runs.replace(heading_err=h))
    assert d.verdict == "unexplained structure"
    assert d.outliers[0] == 17
    top = d.structure[0]
    assert top.factor == "outlier" and top.function == "run 17" and "--robust" in top.text
    assert top.coefficient == pytest.approx(1000.0, abs=4 * top.std + 3 * runs.heading_std[17] / units.ARCSEC)


def test_candidates_within_delta_bic_6_are_ambiguous_and_refine_stops():
    """A recorded column that follows the rotation sense (a fan switched with the sense) and a
    sync delay (rate-odd) explain a hidden delay about equally: reported together, with the
    runs that tell them apart, and --refine picks neither."""
    plan = diagnostic_plan(sessions=2, runs_per_session=24, rates_dps=(40.0,))
    rng = np.random.default_rng([7, 1])   # not the campaign's noise stream (the fan would follow the noise)
    fan = (plan.rate > 0).astype(float) + rng.normal(0, 0.02, len(plan))
    runs = campaign({"delay": 150.0}, seed=7, plan=plan, covariates={"fan": fan})
    d = diagnose(runs)
    assert d.verdict == "missing-effect"
    assert set(d.ambiguous) == {"sync_delay", "covariate:fan"}
    a, b = (d.candidate(n) for n in d.ambiguous)
    assert abs(a.delta_bic - b.delta_bic) <= 6.0
    assert d.proposals and all(p["separation"] > 1.0 for p in d.proposals)
    text = "\n".join(d.summary())
    assert "Ambiguous: " in text and "do not pick one" in text
    steps = refine(runs)
    assert len(steps) == 1
    j = d.to_dict()
    assert set(j["ambiguous"]) == {"sync_delay", "covariate:fan"} and j["proposals"]


def test_two_missing_effects_are_not_ambiguous():
    """A sync delay and a stand reading error hidden together: each alone explains about as much
    (Delta-BIC within 6 of each other), but the data need both -- refitting with both
    (hse_opt.fit) lowers chi2 far below either alone. Two missing effects, not two
    explanations of one: not reported as ambiguous, and refine adds both."""
    truth = {"delay": 60.0, "az_c2": 12.0, "az_s2": 6.0}
    runs = campaign(truth, seed=1)
    d = diagnose(runs)
    a, b = d.candidate("sync_delay"), d.candidate("azimuth_harmonic2")
    assert a.significant and b.significant and abs(a.delta_bic - b.delta_bic) <= 6.0
    both = fit(runs, "hse,sync_delay,azimuth_harmonic2")
    for one, extra in (("sync_delay", 2), ("azimuth_harmonic2", 1)):
        assert fit(runs, f"hse,{one}").chi2 - both.chi2 > 20.0 + extra * np.log(len(runs))
    assert d.ambiguous == ()
    steps = refine(runs)
    assert steps[-1].fits and {"sync_delay", "azimuth_harmonic2"} <= set(steps[-1].effects)


def test_implausible_magnitudes_are_named():
    """A 1500-us delay is beyond the documented 500-us range of gyro-encoder offsets."""
    d = diagnose(campaign({"delay": 1500.0}, seed=3))
    c = d.candidate("sync_delay")
    assert c.significant and any(s.startswith("delay = ") and "plausible range [-500, 500]" in s
                                 for s in c.plausibility)
    assert not d.candidate("sync_delay").fit.value("delay")[0] < 1000
    d_ok = diagnose(campaign({"delay": 80.0}, seed=3))
    assert d_ok.candidate("sync_delay").plausibility == ()


def test_words_use_the_verdicts_noise_model():
    """A term's amplitude and sigma are those of the weighted least-squares fit with the runs'
    own sigmas (the fit of the model plus that function by hse_opt.fit), and a term is marked
    not significant exactly when its family-wise p is above the verdict's level."""
    from tests.test_diagnose import Sin3
    runs = model_runs(diagnostic_plan(), {**BASE, "s3": 15.0}, np.random.default_rng(4),
                      model=["hse", Sin3()], base_tilt=BASE_TILT)
    d = diagnose(runs)
    top = d.structure[0]
    f = fit(runs, ["hse", Sin3()])
    v, s = f.value("s3")
    assert top.coefficient == pytest.approx(v, rel=2e-3) and top.std == pytest.approx(s, rel=2e-3)
    level = d.alpha / d.n_tests
    for t in d.structure:
        assert t.significant == (t.p_value < level)
        assert ("not significant" in t.text) == (not t.significant)
