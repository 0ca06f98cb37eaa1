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
from hse_opt.design.field import design_field, field_plan
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


# -- continuing a field campaign (issue 24, item 4) ------------------------------------------------
def _field_runs_so_far(seed=0):
    """Four 10-minute field runs at two positions (20 and 60 deg/s each), their headings hidden,
    heading errors from the measurement model with lambda2 = 4.2 arcsec."""
    from hse_opt.data import Plan, Runs
    from hse_opt.validation.synthetic import model_runs
    rng = np.random.default_rng(seed)
    rows = [(f"A{k + 1}", h, r) for k, h in enumerate((30.0, 200.0)) for r in (20.0, 60.0)]
    n = len(rows)
    t = 3600.0 + 700.0 * np.arange(n)
    plan = Plan(run=np.arange(1, n + 1), rate=np.array([r[2] for r in rows]) * units.DEG_PER_S,
                azimuth=np.radians([r[1] for r in rows]), t_start=t, duration=np.full(n, 600.0))
    truth = model_runs(plan, {"lambda2": 4.2}, rng, base_tilt=(-150 * units.ARCSEC, 40 * units.ARCSEC))
    return Runs.from_columns({
        "run": list(plan.run), "rate_dps": list(plan.rate / units.DEG_PER_S), "azimuth_deg": [None] * n,
        "heading_deg": list(np.degrees(plan.azimuth + truth.heading_err)), "latitude_deg": [28.07] * n,
        "duration_s": [600.0] * n, "t_start_s": list(t), "pitch_arcsec": list(truth.pitch / units.ARCSEC),
        "roll_arcsec": list(truth.roll / units.ARCSEC), "heading_std_arcsec": list(truth.heading_std / units.ARCSEC),
        "position": [r[0] for r in rows]}, source="<field runs so far>")


def test_continuing_a_campaign_counts_the_runs_so_far():
    """Its predicted sigma is that of the union plan evaluated directly (runs so far with their
    measured tilts, then the new runs), smaller than the runs so far alone, and the new runs fit
    the time left after the last run."""
    from hse_opt.data import Plan
    from hse_opt.design.field import continue_campaign
    runs = _field_runs_so_far()
    left = 2 * units.HOUR
    c = continue_campaign(runs, "hse", left)
    end_so_far = float(np.max(runs.t_start + runs.duration))
    assert c.plan.t_start.min() >= end_so_far and np.max(c.plan.t_start + c.plan.duration) <= end_so_far + left
    assert c.plan.run.min() == runs.run.max() + 1
    # the union by hand: measured tilts as offsets from the stand's, each position its constant
    stand = Stand()
    before = Plan(run=runs.run, rate=runs.rate, azimuth=runs.azimuth, t_start=runs.t_start, duration=runs.duration,
                  tilt_x=runs.roll - stand.tilt[0], tilt_y=runs.pitch - stand.tilt[1], position=runs.position)
    cat = lambda f: np.concatenate([getattr(before, f), getattr(c.plan, f)])  # noqa: E731
    union = Plan(**{f: cat(f) for f in ("run", "rate", "azimuth", "t_start", "duration", "tilt_x", "tilt_y",
                                        "position")})
    direct = evaluate(union, "hse", field=True)
    assert c.evaluation.std_of("lambda2") == pytest.approx(direct.std_of("lambda2"), rel=1e-12)
    assert direct.n_runs == len(runs) + len(c.plan)
    alone = evaluate(before, "hse", field=True).std_of("lambda2")
    assert c.evaluation.std_of("lambda2") < alone
    # the measured tilts enter: the runs so far at another tilt give another sigma
    other = continue_campaign(runs.replace(pitch=runs.pitch + 600 * units.ARCSEC), "hse", left)
    assert other.evaluation.std_of("lambda2") != pytest.approx(c.evaluation.std_of("lambda2"), rel=1e-6)


def test_design_field_cli_continues_a_campaign_with_prior_and_report(tmp_path, capsys):
    import json
    from hse_opt.data import save_runs
    from hse_opt.design.field import continue_campaign
    from hse_opt.fit.file import load_fit
    runs = _field_runs_so_far()
    save_runs(runs, tmp_path / "RUNS.csv")
    before = (tmp_path / "RUNS.csv").read_bytes()
    out = tmp_path / "NEXT.csv"
    assert main(["design", "--field", "--runs", str(tmp_path / "RUNS.csv"), "--budget-h", "2", "--json",
                 "-o", str(out), "--report", str(tmp_path / "rep")]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["runs_so_far"] == 4 and (tmp_path / "rep" / "report.html").exists()
    assert (tmp_path / "RUNS.csv").read_bytes() == before
    lib = continue_campaign(runs, "hse", 2 * units.HOUR)
    assert d["predicted_std"]["lambda2"]["value"] == pytest.approx(lib.evaluation.std_of("lambda2"), rel=1e-9)
    assert load_plan(out).run.size == d["n_runs"] == lib.plan.run.size
    # --prior: an earlier calibration lowers the predicted sigma (before: silently ignored)
    assert main(["fit", str(tmp_path / "RUNS.csv"), "--json", "-o", str(tmp_path / "FIT.json")]) == 0
    capsys.readouterr()
    assert main(["design", "--field", "--budget-h", "3", "--json", "-o", str(tmp_path / "F.csv")]) == 0
    plain = json.loads(capsys.readouterr().out)["predicted_std"]["lambda2"]["value"]
    assert main(["design", "--field", "--budget-h", "3", "--json", "--prior", str(tmp_path / "FIT.json"),
                 "-o", str(tmp_path / "F2.csv")]) == 0
    with_prior = json.loads(capsys.readouterr().out)["predicted_std"]["lambda2"]["value"]
    prior_sd = load_fit(tmp_path / "FIT.json").value("lambda2")[1]
    assert with_prior < plain and with_prior == pytest.approx((plain ** -2 + prior_sd ** -2) ** -0.5, rel=0.2)


def test_runs_without_field_and_without_times_are_named(tmp_path, capsys):
    from hse_opt.data import save_runs
    runs = _field_runs_so_far()
    save_runs(runs, tmp_path / "RUNS.csv")
    assert main(["design", "--runs", str(tmp_path / "RUNS.csv"), "-o", str(tmp_path / "P.csv")]) == 2
    assert "--field" in capsys.readouterr().err
    save_runs(runs.replace(t_start=None), tmp_path / "R2.csv")
    assert main(["design", "--field", "--runs", str(tmp_path / "R2.csv"), "-o", str(tmp_path / "P.csv")]) == 2
    err = capsys.readouterr().err
    assert "t_start_s" in err and len(err.strip().splitlines()) == 1 and not (tmp_path / "P.csv").exists()
