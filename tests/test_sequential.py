"""The sequential plan of a running campaign (hse_opt.design.sequential) against a direct
evaluation of the union plan (hse_opt.design.evaluate: another code path, the projector of
the field elimination instead of per-position sums)."""
import numpy as np
import pytest

from hse_opt import units
from hse_opt.data import Plan, Runs
from hse_opt.design import Costs, Stand, evaluate
from hse_opt.design.sequential import next_runs

STAND = Stand()  # the default system's tilt (-55, -120) arcsec, 28.07 deg
COSTS = Costs(warmup=3600.0, azimuth_change=600.0, rate_change=60.0)


def _runs(rates, azimuths, positions=None, duration=600.0):
    n = len(rates)
    sigma = STAND.sigma(np.full(n, duration)) / units.ARCSEC
    t = 3600.0 + 700.0 * np.arange(n)
    cols = {"run": np.arange(1, n + 1), "rate_dps": rates, "latitude_deg": np.full(n, STAND.latitude / units.DEG),
            "duration_s": np.full(n, duration), "t_start_s": t,
            "pitch_arcsec": np.full(n, STAND.tilt[1] / units.ARCSEC),
            "roll_arcsec": np.full(n, STAND.tilt[0] / units.ARCSEC), "heading_std_arcsec": sigma}
    if positions is None:
        cols.update(azimuth_deg=azimuths, heading_err_arcsec=np.zeros(n))
    else:
        cols.update(heading_deg=azimuths, position=positions)
    return Runs.from_columns(cols, source="test")


def _union(runs, cont, field):
    """The runs so far and the planned ones as one plan."""
    n = len(runs)
    rate = np.concatenate([runs.rate / units.DEG_PER_S, [r.rate_dps for r in cont.runs]])
    az = np.concatenate([runs.azimuth / units.DEG, [r.azimuth_deg for r in cont.runs]])
    t = np.concatenate([runs.t_start, [r.t_start_s for r in cont.runs]])
    dur = np.concatenate([runs.duration, [r.duration_s for r in cont.runs]])
    cols = {"run": np.arange(1, rate.size + 1), "rate_dps": rate, "azimuth_deg": az, "t_start_s": t,
            "duration_s": dur}
    if field:
        cols["position"] = list(runs.position) + [r.position for r in cont.runs]
    return Plan.from_columns(cols, source="union", allow_small_azimuths=True), n


def test_surveyed_continuation_equals_the_union_plans_evaluation():
    runs = _runs([20, 40, 60, -40], [0, 0, 90, 90])
    cont = next_runs(runs, "hse", 3 * units.HOUR, costs=COSTS)
    assert len(cont.runs) >= 5
    plan, n = _union(runs, cont, field=False)
    now = evaluate(Plan.from_columns({k: v[:n] for k, v in _columns(plan).items()}, source="so far"), "hse",
                   stand=STAND).std_of("lambda2")
    end = evaluate(plan, "hse", stand=STAND).std_of("lambda2")
    assert cont.sigma_now == pytest.approx(now, rel=1e-6)
    assert cont.sigma_end == pytest.approx(end, rel=1e-6)
    assert cont.sigma_end < cont.sigma_now
    # every step's sigma is the evaluation of the plan up to it
    k = len(cont.runs) // 2
    mid = Plan.from_columns({c: v[:n + k] for c, v in _columns(plan).items()}, source="mid")
    assert cont.runs[k - 1].sigma_after == pytest.approx(evaluate(mid, "hse", stand=STAND).std_of("lambda2"),
                                                        rel=1e-6)
    # the plan fits the time left after the last run, with the setups
    last_end = float(np.max(runs.t_start + runs.duration))
    assert cont.runs[0].t_start_s >= last_end
    assert cont.runs[-1].t_start_s + cont.runs[-1].duration_s <= last_end + 3 * units.HOUR + 1e-6


def _columns(plan):
    cols = {"run": plan.run, "rate_dps": plan.rate / units.DEG_PER_S, "azimuth_deg": plan.azimuth / units.DEG,
            "t_start_s": plan.t_start, "duration_s": plan.duration}
    if plan.position is not None:
        cols["position"] = plan.position
    return cols


def test_field_continuation_eliminates_each_positions_heading_as_evaluate_does():
    runs = _runs([20, 60, 40, -40], [10, 10, 200, 200], positions=["A", "A", "B", "B"])
    cont = next_runs(runs, "hse", 4 * units.HOUR, costs=COSTS)
    plan, n = _union(runs, cont, field=True)
    end = evaluate(plan, "hse", stand=STAND, field=True).std_of("lambda2")
    assert cont.sigma_end == pytest.approx(end, rel=1e-6)
    now = evaluate(Plan.from_columns({c: v[:n] for c, v in _columns(plan).items()}, source="so far"), "hse",
                   stand=STAND, field=True).std_of("lambda2")
    assert cont.sigma_now == pytest.approx(now, rel=1e-6)
    # the planned runs stay at the known positions or go to new ones in pairs
    labels = [r.position for r in cont.runs]
    for lab in set(labels) - {"A", "B"}:
        assert labels.count(lab) >= 2
        assert cont.runs[labels.index(lab)].new_position


def test_one_field_run_plans_a_second_before_lambda2_is_estimable():
    runs = _runs([40], [30], positions=["A"])
    cont = next_runs(runs, "hse", 2 * units.HOUR, costs=COSTS)
    assert not np.isfinite(cont.sigma_now)          # one run at a position without reference: nothing
    assert np.isfinite(cont.sigma_end)
    assert cont.next is not None


def test_no_time_left_plans_nothing_and_says_so():
    runs = _runs([20, 40, 60], [0, 0, 0])
    cont = next_runs(runs, "hse", 0.0, costs=COSTS)
    assert cont.runs == () and cont.plan is None and cont.next is None
    assert "fits" in cont.notes[0]


def test_target_sigma_stops_the_plan():
    runs = _runs([20, 40, 60, -40], [0, 0, 90, 90])
    full = next_runs(runs, "hse", 6 * units.HOUR, costs=COSTS)
    target = 0.5 * (full.sigma_now + full.sigma_end)
    short = next_runs(runs, "hse", 6 * units.HOUR, costs=COSTS, target_sigma=target)
    assert len(short.runs) < len(full.runs) and short.runs == full.runs[:len(short.runs)]
    assert short.sigma_end <= target
    # it ends at the first run that reaches the target with every effect the whole plan
    # protects still protected (the diagnosis's power on the runs so far and the runs to it)
    guarded = [p.effect for p in full.protection if p.protected]
    assert guarded and all(p.power >= 0.8 for p in short.protection if p.effect in guarded)
    plan, n = _union(runs, full, field=False)
    k = len(short.runs) - 1                  # the plan one run shorter
    shorter = Plan.from_columns({c: v[:n + k] for c, v in _columns(plan).items()}, source="shorter")
    from hse_opt.aliasing import effect_power
    from hse_opt.model import as_model
    X = STAND.inputs(as_model("hse").measurement(True), shorter.rate, shorter.azimuth, 0.0, 0.0, shorter.duration,
                     shorter.t_start)
    weaker = min(effect_power("hse", X, e, sigma=STAND.sigma(shorter.duration), positions=np.zeros(n + k, int))
                 for e in guarded)
    assert short.runs[-2].sigma_after > target or weaker < 0.8


def test_bad_arguments_are_named():
    runs = _runs([20, 40], [0, 0])
    with pytest.raises(ValueError, match="target 'nope'"):
        next_runs(runs, "hse", 3600.0, target="nope")
    with pytest.raises(ValueError, match="time left"):
        next_runs(runs, "hse", -1.0)


def test_a_new_position_gets_a_label_no_position_has():
    runs = _runs([40], [30], positions=["new1"])          # as the one-run case above: a new position next
    cont = next_runs(runs, "hse", 3 * units.HOUR, costs=COSTS)
    new = [r.position for r in cont.runs if r.new_position]
    assert new and "new1" not in new
    assert cont.runs[0].new_position and cont.runs[0].position == "new2"
