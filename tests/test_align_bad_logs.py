"""Raw logs that used to give a silently wrong RUNS.csv or stop the whole batch (issue 25 item 5,
issue 27): each is now one stderr line naming the file, the other logs are still written, and
the exit status is 2 - or, where the data are right, they are taken as they are.

References: the simulator's true attitude and the generated logs' own timestamps; files broken
by hand in each test.
"""
import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hse_opt import units
from hse_opt.align import LabCalibration, align, align_logs, load_rawlog, runs_from_rows, save_calibration
from hse_opt.app.cli import main
from hse_opt.data import DataError, DataWarning, load_runs, save_runs
from hse_opt.sim import RunSpec, TruthConfig, align_config_from_truth, generate, save_rawlog, true_attitude

ROOT = Path(__file__).resolve().parents[1]
#: an orthogonal, noise-free system: the orthogonal calibration aligns it exactly
TRUTH = TruthConfig.ideal().updated({"gyro": {"axes_nonorth_arcsec": [0.0, 0.0, 0.0]}})


@pytest.fixture(scope="module")
def logdir(tmp_path_factory):
    d = tmp_path_factory.mktemp("logs")
    for i, (rate, az) in enumerate([(40.0, 30.0), (-40.0, 120.0), (20.0, 210.0)]):
        spec = RunSpec(rate=rate * units.DEG_PER_S, azimuth=math.radians(az), duration=20.0, t_start=900.0 + 60 * i)
        log = generate(TRUTH, spec, np.random.default_rng(i))
        object.__setattr__(log, "meta", {**log.meta, "run": i + 1})
        save_rawlog(log, d / f"r{i}.npz")
    save_rawlog(log, d / "r2.csv")          # the CSV form of r2, for the sidecar cases
    os.remove(d / "r2.npz")
    return d


def _align(args, capsys):
    status = main(["align", *map(str, args), "--no-progress"])
    err = capsys.readouterr().err
    return status, [ln for ln in err.splitlines() if "error:" in ln], err


def test_the_same_log_given_twice_is_one_run(logdir, tmp_path, capsys):
    out = tmp_path / "RUNS.csv"
    shutil.copy(logdir / "r0.npz", tmp_path / "copy_of_r0.npz")
    status, errors, err = _align([logdir, logdir / "r0.npz", tmp_path / "copy_of_r0.npz", "-o", out], capsys)
    assert status == 2 and len(load_runs(out)) == 3            # r0, r1, r2 once each (was 5 runs)
    assert len(errors) == 2 and "r0.npz: given twice" in errors[0]
    assert f"copy_of_r0.npz: the same log as {logdir / 'r0.npz'}" in errors[1]
    assert "3 of 5 logs aligned" in err


@pytest.mark.parametrize("case", ["list sidecar", "list metadata", "directory", "missing", "fifo", "bad json"])
def test_a_log_that_cannot_be_read_is_a_data_error_naming_the_file(logdir, tmp_path, capsys, case):
    work = tmp_path / "logs"
    shutil.copytree(logdir, work)
    if case == "list sidecar":
        bad = work / "r2.csv"
        (work / "r2.csv.json").write_text("[1, 2]")
        expected = "r2.csv.json: the sidecar is a JSON list; allowed: a JSON object"
    elif case == "list metadata":
        bad = work / "r1.npz"
        z = dict(np.load(bad))
        z["meta_json"] = np.array("[28.07]")
        np.savez(bad, **z)
        expected = "r1.npz: meta_json is a JSON list; allowed: a JSON object"
    elif case == "directory":
        bad = work / "sub.npz"
        bad.mkdir()
        expected = "sub.npz: is a directory; allowed: a regular raw-log file"
    elif case == "missing":
        bad = work / "gone.npz"
        expected = "gone.npz: cannot read: No such file or directory"
    elif case == "fifo":
        bad = work / "pipe.npz"
        os.mkfifo(bad)
        expected = "pipe.npz: is a FIFO; allowed: a regular raw-log file"
    else:
        bad = work / "r2.csv"
        (work / "r2.csv.json").write_text("{latitude_deg: 28}")
        expected = "r2.csv.json: the sidecar is not valid JSON"
    with pytest.raises(DataError) as info:                 # the library: a ValueError naming the file
        load_rawlog(bad)
    assert isinstance(info.value, ValueError) and expected in str(info.value)
    # the command: the other logs still written, one line for the bad one, exit 2 (a FIFO did hang:
    # run in a child with a timeout)
    out = tmp_path / "RUNS.csv"
    args = [sys.executable, "-c", "import sys; from hse_opt.app.cli import main; sys.exit(main(sys.argv[1:]))",
            "align", str(work), "-o", str(out), "--no-progress"]
    if case == "missing":
        args.insert(5, str(bad))
    run = subprocess.run(args, capture_output=True, text=True, timeout=120, cwd=tmp_path,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    lines = [ln for ln in run.stderr.splitlines() if "error:" in ln]
    if case == "missing":      # a path on the command line that does not exist: nothing is run
        assert run.returncode == 2 and len(lines) == 1 and "gone.npz: no such file or directory" in lines[0]
        assert not out.exists()
        return
    assert run.returncode == 2 and len(lines) == 1 and expected in lines[0], run.stderr
    good = 2 if case in ("list sidecar", "list metadata", "bad json") else 3
    assert len(load_runs(out)) == good


def test_a_metadata_value_out_of_range_names_the_log_not_a_row(logdir, tmp_path, capsys):
    """Was '<aligned logs>, row 2, column azimuth_deg' and no output at all."""
    work = tmp_path / "logs"
    shutil.copytree(logdir, work)
    z = dict(np.load(work / "r1.npz"))
    meta = json.loads(str(z["meta_json"]))
    z["meta_json"] = np.array(json.dumps({**meta, "azimuth_deg": 1e6}))
    np.savez(work / "r1.npz", **z)
    out = tmp_path / "RUNS.csv"
    status, errors, _ = _align([work, "-o", out], capsys)
    assert status == 2 and len(errors) == 1 and "<aligned logs>" not in errors[0]
    assert f"{work / 'r1.npz'}, column 'azimuth_deg'" in errors[0] and "allowed" in errors[0]
    assert load_runs(out).run.tolist() == [1, 3]


def test_duration_is_the_span_the_processor_aligns(logdir):
    rows, errors = align_logs([str(logdir / "r0.npz")], LabCalibration.orthogonal().align_config())
    log = load_rawlog(logdir / "r0.npz")
    assert not errors and rows[0]["duration_s"] == pytest.approx(log.t[-1] - log.t[0], abs=1e-6)
    assert rows[0]["duration_s"] == pytest.approx((len(log) - 1) * 0.002, abs=1e-6)   # was len(log) * 0.002


def test_a_level_base_is_read_not_refused_as_radians(tmp_path):
    """Every pitch and roll below 0.05 arcsec (a level base) was refused as 'pitch_arcsec look
    like radians' - the alignment's own output. Now the rows load, with a warning."""
    rows = [{"rate_dps": r, "heading_deg": 30.0, "latitude_deg": 28.07, "duration_s": 600.0,
             "pitch_arcsec": 0.01 * s, "roll_arcsec": -0.02 * s, "heading_std_arcsec": 8.0, "azimuth_deg": 30.0,
             "log": f"r{k}.npz"} for k, (r, s) in enumerate([(40.0, 1), (-40.0, -1), (20.0, 2)])]
    runs, _ = runs_from_rows(rows)
    assert runs.pitch / units.ARCSEC == pytest.approx([0.01, -0.01, 0.02], rel=1e-12)
    save_runs(runs, tmp_path / "RUNS.csv")
    with pytest.warns(DataWarning, match="a level base, or values in radians or degrees"):
        assert len(load_runs(tmp_path / "RUNS.csv")) == 3


def test_the_logs_latitude_is_used_not_the_simulated_systems(tmp_path):
    """align_config_from_truth fixed the truth's latitude over the log's: a log recorded at 45 deg
    aligned with the processor of a 28.07-deg system was off by tens of arcsec, silently."""
    at45 = TRUTH.updated({"site": {"latitude_deg": 45.0}})
    spec = RunSpec(rate=40 * units.DEG_PER_S, azimuth=math.radians(30.0), duration=60.0)
    log = generate(at45, spec, np.random.default_rng(7))
    res = align(log, align_config_from_truth(TRUTH))              # TRUTH is at 28.07 deg
    dh = (res.heading - true_attitude(at45, spec)["heading"] + np.pi) % (2 * np.pi) - np.pi
    assert abs(dh) < 1e-4 * units.ARCSEC
    cal = LabCalibration.orthogonal()
    save_calibration(cal, tmp_path / "CAL.toml")
    assert math.isclose(res.heading, align(log, cal.align_config()).heading, abs_tol=1e-12)
