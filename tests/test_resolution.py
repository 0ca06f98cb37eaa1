"""The shortest plan that resolves a systematic risk (hse_opt.diagnose.resolution), checked
against the alias budget of a real fit: the budget computed the other way (QR of the weighted
Jacobian, hse_opt.aliasing) before the runs are added, and a fit of the campaign with the
plan's runs made after."""
import sys
from pathlib import Path

import numpy as np
import pytest

from hse_opt import units
from hse_opt.aliasing import alias_budget
from hse_opt.diagnose import diagnose
from hse_opt.diagnose.resolution import resolving_plan
from hse_opt.fit import fit
from hse_opt.validation.synthetic import model_runs
from hse_opt.data import Plan

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "studies"))
import robustness  # noqa: E402


def _stand_campaign(k):
    rng = np.random.default_rng(3)
    for _ in range(k):
        robustness.campaign("stand", "none", rng)
    return robustness.campaign("stand", "none", rng)[0]


def _ratios(f, budget, effect):
    return [s / sd for by, sd in zip(budget.systematic_by, f.std) for e, s in by.items() if e == effect]


@pytest.mark.parametrize("k", [0, 1])
def test_the_plans_starting_ratio_is_the_alias_budgets(k):
    runs = _stand_campaign(k)
    d = diagnose(runs)
    assert d.verdict == "inconclusive"
    for risk in d.budget.risks:
        plan = resolving_plan(d.fit, runs, [risk.effect], level=d.budget.level)
        assert plan.ratio_before == pytest.approx(max(_ratios(d.fit, d.budget, risk.effect)), rel=1e-6)


def _with_plan(runs, f, plan, rng):
    """The campaign with the plan's runs made: headings from the fitted model plus the runs' noise."""
    rows = [r for r in plan.runs for _ in range(r["count"])]
    n = len(rows)
    t0 = float(np.max(runs.t_start)) + 700.0
    extra = Plan(run=np.arange(n) + int(runs.run.max()) + 1,
                 rate=np.array([r["rate_dps"] for r in rows]) * units.DEG_PER_S,
                 azimuth=np.radians([r["azimuth_deg"] for r in rows]), t_start=t0 + 700.0 * np.arange(n),
                 duration=np.full(n, float(np.median(runs.duration))),
                 tilt_x=np.array([r["roll_arcsec"] for r in rows]) * units.ARCSEC,
                 tilt_y=np.array([r["pitch_arcsec"] for r in rows]) * units.ARCSEC)
    made = model_runs(extra, dict(zip(f.names, f.values)), rng, model=list(f.model.effect_names),
                      sigma=float(np.median(runs.heading_std)))
    return runs.append(made)


def test_after_the_plan_the_effect_is_no_longer_a_risk_to_a_real_fit():
    runs = _stand_campaign(1)
    d = diagnose(runs)
    effect = "sync_delay"
    assert _ratios(d.fit, d.budget, effect) and max(_ratios(d.fit, d.budget, effect)) > 2
    plan = resolving_plan(d.fit, runs, [effect], level=d.budget.level)
    assert plan.resolved and 1 <= plan.n_runs <= 12
    both = _with_plan(runs, d.fit, plan, np.random.default_rng(7))
    g = fit(both, d.fit.model)
    after = alias_budget(g, both, effects=[effect], level=d.budget.level)
    assert max(_ratios(g, after, effect), default=0.0) <= 1.05
    # one run fewer is not enough: the count is the fewest the search found
    if plan.n_runs > 1:
        fewer = resolving_plan(d.fit, runs, [effect], level=d.budget.level, max_runs=plan.n_runs - 1)
        assert not fewer.resolved


def test_the_issues_field_campaign_needs_new_positions():
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_aliasing import _field_campaign
    runs = _field_campaign(0)
    d = diagnose(runs)
    plan = resolving_plan(d.fit, runs, ["sync_delay"], level=d.budget.level)
    assert not plan.resolved and plan.ratio_after > 10
    note = next(n for n in d.notes if n.startswith("inconclusive: sync_delay"))
    assert "positions so far cannot resolve it" in note and "design --field --runs" in note


def test_runs_append_is_the_inverse_of_a_split():
    runs = _stand_campaign(0)
    a, b = runs.subset(np.arange(5)), runs.subset(np.arange(5, len(runs)))
    both = a.append(b)
    for name in ("run", "rate", "azimuth", "heading_err", "t_start", "pitch", "roll", "heading_std"):
        np.testing.assert_array_equal(getattr(both, name), getattr(runs, name))
    with pytest.raises(ValueError, match="different columns"):
        a.append(b.replace(heading_std=None))
    with pytest.raises(Exception, match="run id"):
        a.append(a)


@pytest.mark.parametrize("campaign, effect", [("field", "sync_delay"), ("stand", "scale_nonlinearity")])
def test_the_sigma_fitted_with_the_effect_is_a_real_fits(campaign, effect):
    """The other way out, fit the effect: the plan's sigma of each parameter at risk against
    hse-opt's own fit with the effect added."""
    if campaign == "field":
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from test_aliasing import _field_campaign
        runs = _field_campaign(0)
    else:
        runs = _stand_campaign(1)
    d = diagnose(runs)
    plan = resolving_plan(d.fit, runs, [effect], level=d.budget.level)
    assert not plan.resolved and plan.fitted
    g = fit(runs, list(d.fit.model.effect_names) + [effect])
    for name, _, now, with_effect, _ in plan.fitted:
        assert now == pytest.approx(d.fit.value(name)[1], rel=1e-9)
        assert with_effect == pytest.approx(g.value(name)[1], rel=0.02)
        assert with_effect > now
    note = next(n for n in d.notes if n.startswith(f"inconclusive: {effect}"))
    assert f"hse-opt fit --effects {effect}" in note
