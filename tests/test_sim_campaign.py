"""Campaign runner: PLAN -> RUNS, seeds, carry-over, parallel and Dask, ``hse-opt simulate``
(issue 3, item 4)."""
import math

import numpy as np
import pytest

from hse_opt.cli import main
from hse_opt.data import DataError, Plan, Runs, load_plan, load_runs, save_plan, save_runs
from hse_opt.sim.campaign import run_campaign, simulate_heading_error
from hse_opt.sim.truth import TruthConfig

DPS = math.pi / 180
ARCSEC = math.pi / 180 / 3600


def _plan(n=6, duration=60.0):
    return [{"run": 10 + i, "rate_dps": (40.0 if i % 2 == 0 else -20.0), "azimuth_deg": 90.0 * (i // 2),
             "t_start_s": 100.0 * i, "duration_s": duration, "tilt_x_arcsec": 30.0 * i,
             "tilt_y_arcsec": -20.0, "fixture": float(i)} for i in range(n)]


@pytest.fixture(scope="module")
def serial_runs():
    return run_campaign(_plan(), TruthConfig.default(), seed=42, jobs=1)


def _same(a, b):
    """Two Runs tables hold the same values, bit for bit."""
    assert isinstance(a, Runs) and isinstance(b, Runs)
    for f in ("run", "rate", "azimuth", "heading_err", "latitude", "duration", "t_start", "pitch", "roll",
              "heading_std"):
        assert getattr(a, f).tobytes() == getattr(b, f).tobytes(), f
    assert list(a.covariates) == list(b.covariates)
    for k in a.covariates:
        assert a.covariates[k].tobytes() == b.covariates[k].tobytes(), k
    return True


def test_runs_follow_the_contract(serial_runs):
    runs, plan = serial_runs, _plan()
    assert list(runs.run) == [p["run"] for p in plan]
    assert list(runs.covariates) == ["temp_c", "tilt_x_arcsec", "tilt_y_arcsec", "fixture"]
    assert list(runs.covariates["fixture"]) == [p["fixture"] for p in plan]
    assert list(runs.covariates["tilt_x_arcsec"]) == [p["tilt_x_arcsec"] for p in plan]
    assert np.array_equal(runs.rate, Plan.from_columns({k: [p[k] for p in plan] for k in plan[0]}).rate)
    assert list(runs.t_start) == [p["t_start_s"] for p in plan]
    assert np.allclose(runs.latitude, 28.07 * DPS, rtol=1e-15)
    assert runs.notes == ()                      # every optional column is there
    for i, p in enumerate(plan):
        # the alignment's own leveling sees the mount tilt (-55, -120) plus the plan's tilt
        assert runs.roll[i] / ARCSEC == pytest.approx(-55.0 + p["tilt_x_arcsec"], abs=2.0)
        assert runs.pitch[i] / ARCSEC == pytest.approx(-120.0 + p["tilt_y_arcsec"], abs=2.0)
    assert np.all(runs.heading_std > 10 * ARCSEC)   # one-minute runs: tens of arcsec


def test_parallel_and_reordered_runs_give_identical_results(serial_runs):
    _same(run_campaign(_plan(), TruthConfig.default(), seed=42, jobs=2, chunk_size=2), serial_runs)
    rev = run_campaign(_plan()[::-1], TruthConfig.default(), seed=42, jobs=1)
    assert list(rev.heading_err[::-1]) == list(serial_runs.heading_err)
    other = run_campaign(_plan(), TruthConfig.default(), seed=43, jobs=1)
    assert np.all(other.heading_err != serial_runs.heading_err)


def test_dask_local_cluster_gives_identical_results(serial_runs):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, processes=False, threads_per_worker=1,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        done = []
        runs = run_campaign(_plan(), TruthConfig.default(), seed=42, client=client,
                            progress=lambda d, n: done.append((d, n)))
    _same(runs, serial_runs)
    assert done[-1] == (6, 6) and [d for d, _ in done] == sorted(d for d, _ in done)


@pytest.mark.slow
def test_cli_simulate_on_a_dask_scheduler_address(tmp_path, serial_runs, capsys):
    """The cluster path as a user takes it: a scheduler with worker processes, reached by
    its address (``--dask tcp://...``); the work is pickled to the workers and back."""
    distributed = pytest.importorskip("distributed")
    plan, out = tmp_path / "PLAN.csv", tmp_path / "RUNS.csv"
    _write_plan(plan, _plan())
    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                                  dashboard_address=None) as cluster:
        assert cluster.scheduler_address.startswith("tcp://")
        assert main(["simulate", str(plan), "-o", str(out), "--seed", "42", "--no-progress",
                     "--dask", cluster.scheduler_address]) == 0
    _same(load_runs(out), serial_runs.replace(source=str(out)))


def test_progress_callback_reports_every_run():
    calls = []
    run_campaign(_plan(3), TruthConfig.default(), seed=1, progress=lambda d, n: calls.append((d, n)))
    assert calls == [(1, 3), (2, 3), (3, 3)]


def test_time_since_power_on_carries_the_warmup_and_temperature():
    """Noise-free system with only the thermal mount rotation, runs back to back from
    power-on: each run's heading error is the run-average of a exp(-t_on / tau) over its own
    window; temp_c is the thermal model's mean over the run."""
    a, tau = -12.0, 600.0
    truth = TruthConfig.ideal().updated({"mount": {"warmup_xi_z_arcsec": a, "warmup_tau_s": tau}})
    plan = [{"run": i, "rate_dps": 40.0, "azimuth_deg": 0.0, "t_start_s": 300.0 * i, "duration_s": 300.0}
            for i in range(3)]
    runs = run_campaign(plan, truth, seed=0)
    th = truth.thermal
    for i in range(3):
        t0, t1 = 300.0 * i, 300.0 * (i + 1)
        mean_xi = a * tau / 300.0 * (math.exp(-t0 / tau) - math.exp(-t1 / tau))
        assert runs.heading_err[i] / ARCSEC == pytest.approx(mean_xi, abs=0.1)
        mean_temp = th.ambient_c + th.rise_c * (1 - th.tau / 300.0 * (math.exp(-t0 / th.tau) - math.exp(-t1 / th.tau)))
        assert runs.covariates["temp_c"][i] == pytest.approx(mean_temp, abs=1e-3)
    assert runs.heading_err[0] < runs.heading_err[1] < runs.heading_err[2] < 0


def test_temperature_covariate_effect():
    """xi_z following the temperature: heading offset = k (mean temp - reference)."""
    k = 2.0
    truth = TruthConfig.ideal().updated({"mount": {"xi_z_tempco_arcsec_per_c": k},
                                         "thermal": {"swing_c": 3.0, "swing_period_s": 7200.0}})
    runs = run_campaign([{"run": 0, "rate_dps": 40.0, "azimuth_deg": 10.0, "t_start_s": 5000.0,
                          "duration_s": 300.0}], truth, seed=0)
    expect = k * (runs.covariates["temp_c"][0] - truth.thermal.reference_c)
    assert runs.heading_err[0] / ARCSEC == pytest.approx(expect, abs=0.05)
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


def test_plan_object_and_rows_give_the_same_runs(serial_runs, tmp_path):
    rows = _plan()
    save_plan(Plan.from_columns({k: [r[k] for r in rows] for k in rows[0]}), tmp_path / "PLAN.csv")
    _same(run_campaign(load_plan(tmp_path / "PLAN.csv"), TruthConfig.default(), seed=42), serial_runs)


@pytest.mark.parametrize("row, match", [
    ({"rate_dps": 3.0}, r"<plan>, row 2, column 'rate_dps': .*lock-in"),
    ({"duration_s": 5.0}, r"<plan>, row 2, column 'duration_s': value 5.0 is shorter than one table revolution"),
    ({"tilt_y_arcsec": 5000.0}, r"row 2, column 'tilt_y_arcsec': value 5000.0 is out of range"),
    ({"run": 10}, r"row 2, column 'run': run id 10 repeats row 1"),
    ({"temp_c": 20.0}, r"column 'temp_c': clashes with the simulated"),
])
def test_bad_plans_are_rejected_naming_row_and_column(row, match):
    plan = _plan(3)
    for r in plan:
        r.update({k: v for k, v in row.items() if k == "temp_c"})
    plan[1].update(row)
    with pytest.raises(DataError, match=match):
        run_campaign(plan, TruthConfig.default(), seed=0)


def test_lockin_of_the_true_system_is_checked():
    """The data layer's generic 5 deg/s limit passes a 6 deg/s run; a system whose gyros lock
    in at 4 deg/s cannot make it (each skewed gyro sees about rate / sqrt(3))."""
    plan = [{"run": 0, "rate_dps": 6.0, "azimuth_deg": 0.0, "t_start_s": 0.0, "duration_s": 240.0}]
    truth = TruthConfig.ideal().updated({"gyro": {"lockin_dps": 4.0}})
    with pytest.raises(DataError, match=r"row 1, column 'rate_dps': run 0: rate_dps = 6 is inside the gyros' lock-in"):
        run_campaign(plan, truth, seed=0)
    assert len(run_campaign(plan, TruthConfig.ideal(), seed=0)) == 1


def test_bad_seed_and_jobs():
    with pytest.raises(ValueError, match="seed"):
        run_campaign(_plan(1), TruthConfig.default(), seed=-1)
    with pytest.raises(ValueError, match="jobs"):
        run_campaign(_plan(1), TruthConfig.default(), seed=0, jobs=0)


def test_runs_file_round_trip_is_exact(tmp_path, serial_runs):
    save_runs(serial_runs, tmp_path / "RUNS.csv")
    _same(load_runs(tmp_path / "RUNS.csv"), serial_runs.replace(source=str(tmp_path / "RUNS.csv")))


def _write_plan(path, rows):
    save_plan(Plan.from_columns({k: [r[k] for r in rows] for k in rows[0]}), path)


def test_cli_simulate_end_to_end(tmp_path, serial_runs, capsys):
    plan, out, truth = tmp_path / "PLAN.csv", tmp_path / "RUNS.csv", tmp_path / "T.toml"
    _write_plan(plan, _plan())
    assert main(["simulate", str(plan), "-o", str(out), "--seed", "42", "--jobs", "2", "--no-progress",
                 "--write-truth", str(truth)]) == 0
    assert "6 runs written" in capsys.readouterr().err
    runs = load_runs(out)                       # a valid RUNS.csv
    _same(runs, serial_runs.replace(source=str(out)))
    assert TruthConfig.from_toml(truth) == TruthConfig.default()


@pytest.mark.parametrize("edit, message", [
    (lambda p: p.write_text(p.read_text().replace("11,-20,", "11,-2,")),
     r"PLAN.csv, row 2 \(line 3\), column 'rate_dps': value '-2' is inside the lock-in limit"),
    (lambda p: p.write_text(p.read_text().replace("60,", "abc,", 1)),
     r"PLAN.csv, row 1 \(line 2\), column 'duration_s': value 'abc' is not a number"),
    (lambda p: p.write_text(p.read_text().replace(",60,", ",5,")),
     r"PLAN.csv, row 1 \(line 2\), column 'duration_s': value '5' is shorter than one table revolution"),
    (lambda p: p.unlink(), r"PLAN.csv: cannot read the plan"),
])
def test_cli_simulate_bad_plan_exits_2_naming_file_row_column(tmp_path, capsys, edit, message):
    plan, out = tmp_path / "PLAN.csv", tmp_path / "RUNS.csv"
    _write_plan(plan, _plan(2))
    edit(plan)
    assert main(["simulate", str(plan), "-o", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hse-opt simulate: error: ") and len(err.splitlines()) == 1
    import re
    assert re.search(message, err), err
    assert not out.exists()                     # nothing written


def test_cli_simulate_unwritable_output_exits_2(tmp_path, capsys):
    plan = tmp_path / "PLAN.csv"
    _write_plan(plan, _plan(1))
    out = tmp_path / "no_such_dir" / "RUNS.csv"
    assert main(["simulate", str(plan), "-o", str(out), "--no-progress"]) == 2
    assert f"-o {out}: the folder {out.parent} does not exist" in capsys.readouterr().err


def test_cli_simulate_bad_truth_exits_2_naming_key(tmp_path, capsys):
    plan, out, truth = tmp_path / "PLAN.csv", tmp_path / "RUNS.csv", tmp_path / "bad.toml"
    _write_plan(plan, _plan(1))
    truth.write_text("[gyro]\narw_dph_rhz = 0.01\n")
    assert main(["simulate", str(plan), "--truth", str(truth), "-o", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "bad.toml" in err and "'arw_dph_rhz'" in err and "'arw_dph_rthz'" in err
