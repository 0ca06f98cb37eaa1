"""What a plan's campaign could not rule out, said by the design before it is run
(hse_opt.validation.expected), against the diagnosis of a campaign simulated to the plan and
against the design's own power computation."""
import json

import numpy as np
import pytest

from hse_opt.data import load_plan
from hse_opt.design import Stand, design
from hse_opt.diagnose import diagnose
from hse_opt.validation.expected import expected_budget
from hse_opt.validation.synthetic import model_runs
from hse_opt import units


@pytest.fixture(scope="module")
def default_design():
    return design(budget=5 * units.HOUR)


def test_the_expected_budget_is_what_diagnose_reports_on_the_campaigns_data(default_design):
    plan = default_design.plan
    stand = Stand()
    expected = expected_budget(plan)
    runs = model_runs(plan, {"lambda2": 4.2, "offset": -12.0}, np.random.default_rng(5), latitude=stand.latitude,
                      base_tilt=(stand.tilt[1], stand.tilt[0]), sigma=stand.sigma(plan.duration))
    d = diagnose(runs)
    # the diagnosis's own level (its family of tests) differs from the default 20 tests: compare at its level
    same_level = expected_budget(plan, tests=d.n_tests)
    # to the linearisation: the model's Jacobian moves a little with the fitted values (1e-5 here)
    np.testing.assert_allclose(same_level.std, d.fit.std, rtol=1e-4)
    np.testing.assert_allclose(same_level.systematic, d.fit.systematic, rtol=1e-3)
    assert [r.effect for r in same_level.risks] == [r.effect for r in d.budget.risks]
    assert expected.risks     # the default plan protects at the plausible edge, not below it


def test_the_expected_powers_are_the_designs_protection(default_design):
    expected = expected_budget(default_design.plan)
    for p in default_design.protection:
        if p.power is not None:
            assert expected.effect(p.effect).power == pytest.approx(p.power, abs=1e-3)   # linearised at the fit, not nominal


def test_design_prints_and_writes_the_expected_budget(tmp_path, capsys):
    from hse_opt.cli import main
    out = tmp_path / "PLAN.csv"
    assert main(["design", "--budget-h", "3", "-o", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    exp = doc["expected_alias_budget"]
    check = expected_budget(load_plan(out))
    assert exp["systematic"] == pytest.approx(dict(zip(check.names, check.systematic)), rel=1e-9)
    assert main(["design", "--budget-h", "3", "-o", str(tmp_path / "P2.csv")]) == 0
    text = capsys.readouterr().out
    at_risk = [n for n, s in exp["systematic"].items() if s > 0]
    if at_risk:
        assert "could still not rule out" in text and all(f"  {n} (+- " in text for n in at_risk)
    else:
        assert "could rule out every assessed effect" in text


def test_a_field_plans_expected_budget_is_what_diagnose_reports_on_its_campaign():
    """The default 3-h field plan: positions whose headings the fit does not know."""
    from hse_opt.design.field import design_field
    from hse_opt.validation.expected import _as_field
    fd = design_field(3 * units.HOUR)
    plan = fd.plan
    assert plan.surveyed is not None and not plan.surveyed.any()
    stand = Stand()
    runs = model_runs(plan, {"lambda2": 4.2}, np.random.default_rng(9), latitude=stand.latitude,
                      base_tilt=(stand.tilt[1], stand.tilt[0]), sigma=stand.sigma(plan.duration))
    d = diagnose(_as_field(runs, plan))
    expected = expected_budget(plan, tests=d.n_tests)
    assert expected.std[expected.names.index("lambda2")] == pytest.approx(fd.evaluation.std_of("lambda2"), rel=1e-4)
    np.testing.assert_allclose(expected.std, d.fit.std, rtol=1e-4)
    np.testing.assert_allclose(expected.systematic, d.fit.systematic, rtol=1e-3)
    # (an effect with no signature beyond the model: power 0 in the protection, the test's level here)
    for p in fd.protection:
        if p.power is not None:
            assert expected_budget(plan).effect(p.effect).power == pytest.approx(p.power, abs=0.003)
    assert any(p.power is not None and p.power > 0.8 for p in fd.protection)
