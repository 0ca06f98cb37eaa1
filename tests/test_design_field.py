"""Design on field campaigns: ``evaluate(..., field=True)`` and ``design_field``.

Reference: the variance of lambda2 by the closed form -- Eq. 14's regressor with each
position's weighted mean removed, 1 / sum((x - mean_p x)^2 / sigma^2) -- and the paper's
procedure (one position, 20/40/60 deg/s) against the designed plan in the same time.
"""
import numpy as np
import pytest

from hse_opt import units
from hse_opt.cli import main
from hse_opt.data import load_plan
from hse_opt.design import Costs, Stand, evaluate
from hse_opt.field import design_field, field_plan
from hse_opt.information import UnidentifiableError
from hse_opt.model import closed_form as cf


def _closed_form_std(plan, stand):
    sigma = stand.sigma(plan.duration)
    pitch, roll = stand.tilt[1] + plan.tilt_y, stand.tilt[0] + plan.tilt_x
    x = cf.heading_error_eq14(plan.rate, stand.latitude, units.ARCSEC, plan.azimuth, pitch, roll) / sigma
    w = 1 / sigma ** 2
    for label in np.unique(plan.position):
        m = plan.position == label
        x[m] -= np.sum(w[m] * x[m] * sigma[m]) / np.sum(w[m]) / sigma[m]
    return 1 / np.sqrt(np.sum(x ** 2))


def test_field_evaluation_is_the_within_position_closed_form():
    stand, costs = Stand(), Costs(azimuth_change=1800.0)
    plan = field_plan([(20.0, 60.0, -40.0), (60.0, -60.0)], [2, 3], [0.3, 2.5], costs,
                      tilts=[(100 * units.ARCSEC, -200 * units.ARCSEC), (0.0, 300 * units.ARCSEC)])
    ev = evaluate(plan, stand=stand, field=True)
    assert ev.names == ("lambda2",)                       # offset: not estimable without a reference
    assert ev.std_of("lambda2") == pytest.approx(_closed_form_std(plan, stand), rel=2e-3)
    # one rate per position: nothing to see
    one = field_plan([(40.0,)], [4], [0.3], costs)
    with pytest.raises(UnidentifiableError):
        evaluate(one, stand=stand, field=True)


def test_design_field_beats_the_papers_single_position_plan_in_its_time():
    stand, costs = Stand(), Costs(azimuth_change=1800.0)
    heading = float(np.arctan2(stand.tilt[1], -stand.tilt[0]))
    paper = field_plan([(20.0,) * 3 + (40.0,) * 3 + (60.0,) * 3], [1], [heading], costs)
    budget = float(np.max(paper.t_start + paper.duration))
    best = design_field(budget, costs=costs, stand=stand, heading0=heading)
    assert float(np.max(best.plan.t_start + best.plan.duration)) <= budget
    s_paper = _closed_form_std(paper, stand)
    s_best = _closed_form_std(best.plan, stand)
    assert best.evaluation.std_of("lambda2") == pytest.approx(s_best, rel=2e-3)
    assert s_best < 0.5 * s_paper
    # every plan tried fits the budget, and none beats the one chosen
    assert all(h <= budget / units.HOUR + 1e-9 and s >= best.evaluation.std_of("lambda2") - 1e-12
               for *_, s, h in best.tried)


def test_design_field_command_writes_a_plan_that_evaluates_the_same(tmp_path, capsys):
    out = tmp_path / "FIELD_PLAN.csv"
    assert main(["design", "--field", "--budget-h", "3", "--azimuth-change-s", "1800", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    plan = load_plan(out)
    assert plan.position is not None and float(np.max(plan.t_start + plan.duration)) <= 3 * units.HOUR
    assert main(["design", "--evaluate", str(out), "--field", "--json"]) == 0
    import json
    ev = json.loads(capsys.readouterr().out)
    assert f"{ev['predicted_std']['lambda2']['value']:.4g}" in printed
