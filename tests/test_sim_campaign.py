"""Campaign runner: PLAN -> RUNS, seeds, carry-over, parallel and Dask, CLI helper
(issue 3, item 4)."""
import argparse
import csv
import math

import numpy as np
import pytest

from hse_opt.sim.campaign import (RUNS_COLUMNS, add_simulate_arguments, read_plan_csv, run_campaign,
                                  simulate_heading_error, simulate_main, write_runs_csv)
from hse_opt.sim.truth import TruthConfig

DPS = math.pi / 180
ARCSEC = math.pi / 180 / 3600


def _plan(n=6, duration=60.0):
    return [{"run": 10 + i, "rate_dps": (40.0 if i % 2 == 0 else -20.0), "azimuth_deg": 90.0 * (i // 2),
             "t_start_s": 100.0 * i, "duration_s": duration, "tilt_x_arcsec": 30.0 * i,
             "tilt_y_arcsec": -20.0, "fixture": float(i)} for i in range(n)]


@pytest.fixture(scope="module")
def serial_rows():
    return run_campaign(_plan(), TruthConfig.default(), seed=42, jobs=1)


def test_rows_follow_the_runs_contract(serial_rows):
    plan = _plan()
    assert [r["run"] for r in serial_rows] == [p["run"] for p in plan]
    for r, p in zip(serial_rows, plan):
        assert list(r)[:len(RUNS_COLUMNS)] == list(RUNS_COLUMNS)
        assert r["fixture"] == p["fixture"] and r["tilt_x_arcsec"] == p["tilt_x_arcsec"]
        assert r["rate_dps"] == p["rate_dps"] and r["t_start_s"] == p["t_start_s"]
        assert r["latitude_deg"] == pytest.approx(28.07)
        assert all(math.isfinite(r[c]) for c in RUNS_COLUMNS)
        # the alignment's own leveling sees the mount tilt (-55, -120) plus the plan's tilt
        assert r["roll_arcsec"] == pytest.approx(-55.0 + p["tilt_x_arcsec"], abs=2.0)
        assert r["pitch_arcsec"] == pytest.approx(-120.0 + p["tilt_y_arcsec"], abs=2.0)


def test_parallel_and_reordered_runs_give_identical_rows(serial_rows):
    rows2 = run_campaign(_plan(), TruthConfig.default(), seed=42, jobs=2, chunk_size=2)
    assert rows2 == serial_rows
    rev = run_campaign(_plan()[::-1], TruthConfig.default(), seed=42, jobs=1)
    assert {r["run"]: r for r in rev} == {r["run"]: r for r in serial_rows}
    other = run_campaign(_plan(), TruthConfig.default(), seed=43, jobs=1)
    assert all(a["heading_err_arcsec"] != b["heading_err_arcsec"] for a, b in zip(other, serial_rows))


def test_dask_local_cluster_gives_identical_rows(serial_rows):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, processes=False, threads_per_worker=1,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        done = []
        rows = run_campaign(_plan(), TruthConfig.default(), seed=42, client=client,
                            progress=lambda d, n: done.append((d, n)))
    assert rows == serial_rows
    assert done[-1] == (6, 6) and [d for d, _ in done] == sorted(d for d, _ in done)


def test_progress_callback_reports_every_run():
    calls = []
    run_campaign(_plan(3), TruthConfig.default(), seed=1, progress=lambda d, n: calls.append((d, n)))
    assert calls == [(1, 3), (2, 3), (3, 3)]


def test_time_since_power_on_carries_the_warmup_and_temperature():
    """Noise-free system with only the thermal mount rotation: each run's heading error is
    the run-average of a exp(-t_on / tau) over its own window; a plan without t_start_s
    runs back to back from power-on; temp_c is the thermal model's mean over the run."""
    a, tau = -12.0, 600.0
    truth = TruthConfig.ideal().updated({"mount": {"warmup_xi_z_arcsec": a, "warmup_tau_s": tau}})
    plan = [{"run": i, "rate_dps": 40.0, "azimuth_deg": 0.0, "duration_s": 300.0} for i in range(3)]
    rows = run_campaign(plan, truth, seed=0)
    th = truth.thermal
    for i, r in enumerate(rows):
        t0, t1 = 300.0 * i, 300.0 * (i + 1)
        assert r["t_start_s"] == t0
        mean_xi = a * tau / 300.0 * (math.exp(-t0 / tau) - math.exp(-t1 / tau))
        assert r["heading_err_arcsec"] == pytest.approx(mean_xi, abs=0.1)
        mean_temp = th.ambient_c + th.rise_c * (1 - th.tau / 300.0 * (math.exp(-t0 / th.tau) - math.exp(-t1 / th.tau)))
        assert r["temp_c"] == pytest.approx(mean_temp, abs=1e-3)
    assert rows[0]["heading_err_arcsec"] < rows[1]["heading_err_arcsec"] < rows[2]["heading_err_arcsec"] < 0


def test_temperature_covariate_effect():
    """xi_z following the temperature: heading offset = k (mean temp - reference)."""
    k = 2.0
    truth = TruthConfig.ideal().updated({"mount": {"xi_z_tempco_arcsec_per_c": k},
                                         "thermal": {"swing_c": 3.0, "swing_period_s": 7200.0}})
    rows = run_campaign([{"run": 0, "rate_dps": 40.0, "azimuth_deg": 10.0, "t_start_s": 5000.0,
                          "duration_s": 300.0}], truth, seed=0)
    expect = k * (rows[0]["temp_c"] - truth.thermal.reference_c)
    assert rows[0]["heading_err_arcsec"] == pytest.approx(expect, abs=0.05)
    assert abs(expect) > 5


def test_stand_azimuth_harmonic_is_in_the_reference():
    amp, ph = 4.0, 25.0
    truth = TruthConfig.ideal().updated({"stand": {"azimuth_harmonics": [
        {"order": 2, "amplitude_arcsec": amp, "phase_deg": ph}]}})
    for az_deg in (0.0, 70.0, 200.0):
        az = az_deg * DPS
        stand = simulate_heading_error(truth, 40 * DPS, az, duration=120.0)
        true = simulate_heading_error(truth, 40 * DPS, az, duration=120.0, reference="true")
        assert true == pytest.approx(0.0, abs=1e-3 * ARCSEC)
        assert stand / ARCSEC == pytest.approx(amp * math.sin(2 * az + ph * DPS), abs=1e-3)


def test_plan_objects_with_to_columns_are_accepted(serial_rows):
    class FakePlan:
        def to_columns(self):
            p = _plan()
            return {k: np.array([r[k] for r in p], np.int64 if k == "run" else float) for k in p[0]}
    assert run_campaign(FakePlan(), TruthConfig.default(), seed=42) == serial_rows


@pytest.mark.parametrize("row, match", [
    ({"rate_dps": 0.5}, r"PLAN row 2 \(run 11\).*rate_dps = 0\.5.*lock-in"),
    ({"duration_s": 5.0}, "duration_s = 5.*one table revolution"),
    ({"tilt_y_arcsec": 5000.0}, "tilt_y_arcsec.*too large"),
    ({"run": 10}, "not unique"),
])
def test_bad_plan_rows_are_rejected_naming_row_and_column(row, match):
    plan = _plan(3)
    plan[1].update(row)
    with pytest.raises(ValueError, match=match):
        run_campaign(plan, TruthConfig.default(), seed=0)


def test_bad_seed_and_jobs():
    with pytest.raises(ValueError, match="seed"):
        run_campaign(_plan(1), TruthConfig.default(), seed=-1)
    with pytest.raises(ValueError, match="jobs"):
        run_campaign(_plan(1), TruthConfig.default(), seed=0, jobs=0)


def test_runs_csv_round_trip(tmp_path, serial_rows):
    p = tmp_path / "RUNS.csv"
    write_runs_csv(serial_rows, p)
    with open(p, newline="") as fh:
        rd = list(csv.reader(fh))
    assert rd[0][:len(RUNS_COLUMNS)] == list(RUNS_COLUMNS) and "fixture" in rd[0]
    back = [dict(zip(rd[0], map(float, row))) for row in rd[1:]]
    for a, b in zip(back, serial_rows):
        assert all(a[k] == b[k] for k in b)


def _args(tmp_path, *extra):
    parser = add_simulate_arguments(argparse.ArgumentParser())
    return parser.parse_args([str(tmp_path / "PLAN.csv"), "-o", str(tmp_path / "RUNS.csv"),
                              "--no-progress", *extra])


def _write_plan(tmp_path, rows):
    with open(tmp_path / "PLAN.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def test_simulate_main_end_to_end(tmp_path, serial_rows, capsys):
    _write_plan(tmp_path, _plan())
    assert read_plan_csv(tmp_path / "PLAN.csv") == _plan()
    assert simulate_main(_args(tmp_path, "--seed", "42", "--write-truth", str(tmp_path / "T.toml"))) == 0
    with open(tmp_path / "RUNS.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [float(r["heading_err_arcsec"]) for r in rows] == [r["heading_err_arcsec"] for r in serial_rows]
    assert TruthConfig.from_toml(tmp_path / "T.toml") == TruthConfig.default()
    # bad input: exit status 2, message on stderr naming what is wrong
    bad = _plan(2)
    bad[1]["rate_dps"] = 0.5
    _write_plan(tmp_path, bad)
    assert simulate_main(_args(tmp_path)) == 2
    assert "rate_dps" in capsys.readouterr().err
    (tmp_path / "bad.toml").write_text("[gyro]\narw_dph_rhz = 0.01\n")
    _write_plan(tmp_path, _plan(1))
    assert simulate_main(_args(tmp_path, "--truth", str(tmp_path / "bad.toml"))) == 2
    assert "arw_dph_rthz" in capsys.readouterr().err
    (tmp_path / "PLAN.csv").unlink()
    assert simulate_main(_args(tmp_path)) == 2
