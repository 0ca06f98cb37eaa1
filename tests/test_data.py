"""Tests of hse_opt.data (PLAN/RUNS load, validate, save) and hse_opt.datasets."""
import hashlib
import os
import pickle
import stat

import numpy as np
import pytest

from hse_opt.data import DataError, Plan, Runs, load_plan, load_runs, save_plan, save_runs
from hse_opt.data.table import _looks_like_radians
from hse_opt.datasets import paper_table1, paper_table1_path
from hse_opt.units import ARCSEC, DEG, DEG_PER_S

HEADER = "run,rate_dps,azimuth_deg,heading_err_arcsec,latitude_deg,duration_s,temp_c"
ROWS = ["1,40,0,5.16,28.07,600,20.5",
        "2,-40,91.8795,12.26,28.07,600,21",
        "3,40,181.2953,-0.54,28.07,600,21.5"]


def write(tmp_path, lines, name="runs.csv"):
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def random_runs(n=200, seed=1):
    rng = np.random.default_rng(seed)
    return Runs(run=np.arange(n) + 1, rate=rng.choice([-1, 1], n) * rng.uniform(10, 60, n) * DEG_PER_S,
                azimuth=rng.uniform(0, 2 * np.pi, n), heading_err=rng.normal(0, 20, n) * ARCSEC,
                latitude=rng.uniform(-1.5, 1.5, n), duration=rng.uniform(300, 900, n),
                t_start=rng.uniform(0, 1e4, n), pitch=rng.normal(0, 1e-3, n), roll=rng.normal(0, 1e-3, n),
                heading_std=rng.uniform(1, 3, n) * ARCSEC, covariates={"temp_c": rng.normal(25, 3, n)})


def assert_same(a, b):
    assert type(a) is type(b) and len(a) == len(b)
    for col in a._COLUMNS:
        x, y = getattr(a, col.attr), getattr(b, col.attr)
        assert (x is None) == (y is None), col.name
        if x is not None:
            assert x.dtype == y.dtype and np.array_equal(x, y), col.name
    assert list(a.covariates) == list(b.covariates)
    for k in a.covariates:
        assert np.array_equal(a.covariates[k], b.covariates[k]), k


# -- round trips ------------------------------------------------------------------------------
def test_load_converts_to_si(tmp_path):
    runs = load_runs(write(tmp_path, [HEADER, *ROWS]))
    assert runs.run.dtype == np.int64 and list(runs.run) == [1, 2, 3]
    assert runs.rate[1] == -40 * DEG_PER_S
    assert runs.azimuth[1] == pytest.approx(91.8795 * DEG, rel=1e-15)
    assert runs.heading_err[0] == pytest.approx(5.16 * ARCSEC, rel=1e-15)
    assert runs.t_start is None and runs.pitch is None and runs.heading_std is None
    assert list(runs.covariates) == ["temp_c"] and runs.covariates["temp_c"][1] == 21.0
    assert any("t_start_s" in n for n in runs.notes) and any("pitch_arcsec" in n for n in runs.notes)
    assert runs.source == str(tmp_path / "runs.csv")
    with pytest.raises(ValueError):
        runs.rate[0] = 0.0  # read-only


def test_round_trip_random_si_values_is_exact(tmp_path):
    runs = random_runs()
    path = tmp_path / "r.csv"
    save_runs(runs, path)
    again = load_runs(path)
    assert_same(runs, again)
    text = path.read_text()
    save_runs(again, path)
    assert path.read_text() == text


def test_round_trip_is_bitwise_for_edge_values(tmp_path):
    """Signed zeros, subnormals, the largest double and last-bit neighbours come back bit for bit."""
    vals = np.array([-0.0, 0.0, 5e-324, -5e-324, 2.2250738585072014e-308, 1.7976931348623157e308,
                     0.1 + 0.2, np.nextafter(1.0, 2.0), np.nextafter(1.0, 0.0), -1 / 3])
    n = vals.size
    phys = np.where(np.abs(vals) > 1, -1e-3, vals)  # the physical columns within their ranges (hse_opt.ranges)
    plan = Plan(run=np.arange(n), rate=np.full(n, 0.7), azimuth=phys, t_start=np.abs(phys),
                duration=np.full(n, 600.0), tilt_x=phys * 1e-2, tilt_y=-phys * 1e-2, covariates={"c": vals})
    path = tmp_path / "plan.csv"
    save_plan(plan, path)
    back = load_plan(path, allow_small_azimuths=True)
    for a, b in ((plan.azimuth, back.azimuth), (plan.tilt_x, back.tilt_x), (plan.tilt_y, back.tilt_y),
                 (plan.t_start, back.t_start), (plan.covariates["c"], back.covariates["c"])):
        assert a.tobytes() == b.tobytes()


def test_round_trip_keeps_written_decimals(tmp_path):
    src = write(tmp_path, ["temp_c," + HEADER.replace(",temp_c", "")] +
                [r.rsplit(",", 1)[1] + "," + r.rsplit(",", 1)[0] for r in ROWS])
    out = tmp_path / "out.csv"
    save_runs(load_runs(src), out)
    lines = out.read_text().splitlines()
    assert lines[0] == HEADER  # contract columns first, covariates after
    assert lines[1:] == ["1,40,0,5.16,28.07,600,20.5", "2,-40,91.8795,12.26,28.07,600,21",
                         "3,40,181.2953,-0.54,28.07,600,21.5"]


def test_plan_round_trip(tmp_path):
    plan = Plan.from_columns({"run": [1, 2], "rate_dps": [20.0, -60.0], "azimuth_deg": [0.0, 123.456],
                              "t_start_s": [0, 900], "duration_s": [600, 600], "tilt_x_arcsec": [0, 200.5],
                              "tilt_y_arcsec": [-100, 0], "temp_c": [20, 21]})
    assert plan.tilt_x[1] == pytest.approx(200.5 * ARCSEC, rel=1e-15)
    path = tmp_path / "plan.csv"
    save_plan(plan, path)
    assert path.read_text().splitlines()[0] == \
        "run,rate_dps,azimuth_deg,t_start_s,duration_s,tilt_x_arcsec,tilt_y_arcsec,temp_c"
    assert_same(plan, load_plan(path))


def test_from_columns_accepts_floats_as_written(tmp_path):
    cols = {"run": np.array([1, 2, 3]), "rate_dps": [40.0, -40.0, 40.0],
            "azimuth_deg": np.array([0.0, 91.8795, 181.2953]), "heading_err_arcsec": [5.16, 12.26, -0.54],
            "latitude_deg": [28.07] * 3, "duration_s": [600] * 3, "temp_c": [20.5, 21, 21.5]}
    assert_same(Runs.from_columns(cols), load_runs(write(tmp_path, [HEADER, *ROWS])))
    runs = Runs.from_columns(cols)
    assert_same(Runs.from_columns(runs.to_columns()), runs)


def test_input_file_is_not_modified(tmp_path):
    path = write(tmp_path, [HEADER, *ROWS])
    before, mtime = hashlib.sha256(path.read_bytes()).hexdigest(), path.stat().st_mtime_ns
    load_runs(path)
    assert hashlib.sha256(path.read_bytes()).hexdigest() == before and path.stat().st_mtime_ns == mtime
    assert sorted(os.listdir(tmp_path)) == ["runs.csv"]


# -- atomic writes ----------------------------------------------------------------------------
def test_failed_replace_leaves_target_and_no_temp(tmp_path, monkeypatch):
    path = write(tmp_path, ["old content"])

    def broken_replace(src, dst):
        raise OSError("disk gone")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError, match="disk gone"):
        save_runs(random_runs(5), path)
    assert path.read_text() == "old content\n" and sorted(os.listdir(tmp_path)) == ["runs.csv"]


def test_invalid_table_is_not_written(tmp_path):
    path = write(tmp_path, ["old content"])
    runs = random_runs(5)
    runs.heading_err.setflags(write=True)  # a user forcing a NaN into a table
    runs.heading_err[2] = np.nan
    with pytest.raises(DataError, match=r"row 3, column 'heading_err_arcsec'.*not finite"):
        save_runs(runs, path)
    assert path.read_text() == "old content\n" and sorted(os.listdir(tmp_path)) == ["runs.csv"]


def test_save_keeps_mode_of_replaced_file(tmp_path):
    path = write(tmp_path, ["old"])
    path.chmod(0o640)
    save_runs(random_runs(3), path)
    assert path.stat().st_mode & 0o777 == 0o640


# -- validation -------------------------------------------------------------------------------
def edit(row, col, value):
    """ROWS with data row ``row`` (1-based), column ``col`` set to ``value``."""
    j = HEADER.split(",").index(col)
    rows = [r.split(",") for r in ROWS]
    rows[row - 1][j] = value
    return [HEADER] + [",".join(r) for r in rows]


ROW_ERRORS = [  # (lines, row, column, words in the message)
    (edit(2, "rate_dps", "abc"), 2, "rate_dps", ["'abc' is not a number", "allowed: a finite number"]),
    (edit(3, "heading_err_arcsec", "nan"), 3, "heading_err_arcsec", ["not finite"]),
    (edit(1, "azimuth_deg", "inf"), 1, "azimuth_deg", ["not finite"]),
    (edit(2, "duration_s", ""), 2, "duration_s", ["is empty"]),
    (edit(3, "run", "1"), 3, "run", ["run id 1 repeats row 1", "allowed: unique"]),
    (edit(2, "run", "2.5"), 2, "run", ["not an integer", "allowed: an integer run id"]),
    (edit(2, "latitude_deg", "95"), 2, "latitude_deg", ["value 95", "allowed: |latitude_deg| <= 90"]),
    (edit(1, "latitude_deg", "-90.5"), 1, "latitude_deg", ["-90.5"]),
    (edit(3, "duration_s", "0"), 3, "duration_s", ["allowed: duration_s > 0"]),
    (edit(1, "duration_s", "-600"), 1, "duration_s", ["-600"]),
    (edit(2, "rate_dps", "2"), 2, "rate_dps", ["lock-in", "allowed: |rate_dps| >= 5 deg/s"]),
    (edit(1, "rate_dps", "0.6981"), 1, "rate_dps", ["lock-in", "rad/s"]),
]


@pytest.mark.parametrize("lines, row, column, words", ROW_ERRORS)
def test_row_errors_name_file_row_line_column(tmp_path, lines, row, column, words):
    path = write(tmp_path, lines)
    with pytest.raises(DataError) as info:
        load_runs(path)
    msg = str(info.value)
    assert msg.startswith(str(path) + ", ")
    assert f"row {row} (line {row + 1}), column '{column}'" in msg and "allowed" in msg
    for w in words:
        assert w in msg
    assert (info.value.row, info.value.line, info.value.column) == (row, row + 1, column)


def test_line_numbers_count_blank_lines(tmp_path):
    lines = edit(3, "latitude_deg", "100")
    path = write(tmp_path, lines[:2] + [""] + lines[2:])
    with pytest.raises(DataError, match=r"row 3 \(line 5\), column 'latitude_deg'"):
        load_runs(path)


@pytest.mark.parametrize("lines, pattern", [
    ([], r"runs\.csv: the file is empty; allowed: a header row with run, rate_dps"),
    ([HEADER], r"runs\.csv, line 1: no data rows; allowed: at least one row"),
    ([HEADER.replace("latitude_deg,", ""), *[",".join(r.split(",")[:4] + r.split(",")[5:]) for r in ROWS]],
     r"line 1, column 'latitude_deg': required column is missing; allowed: a header with run, rate_dps"),
    ([HEADER.replace("azimuth_deg", "azimuth_rad"), *ROWS],
     r"column 'azimuth_deg': required column is missing \(found 'azimuth_rad'"),
    ([HEADER, ROWS[0], ROWS[1] + ",7"], r"row 2 \(line 3\): has 8 fields but the header has 7"),
    ([HEADER + ",temp_c", *[r + ",1" for r in ROWS]], r"line 1, column 'temp_c': column name repeats"),
    ([HEADER.replace(",", ";"), *ROWS], r"line 1: the header has one column; allowed: comma-separated"),
    ([HEADER + ",rate", *[r + ",1" for r in ROWS]],
     r"line 1, column 'rate': .*looks like 'rate_dps' without its unit"),
    ([HEADER + ",pitch_arcsec", *[r + ",1" for r in ROWS]],
     r"column 'pitch_arcsec': is given without 'roll_arcsec'; allowed: both or neither"),
    ([HEADER + ",heading_std_arcsec", *[r + ",0" for r in ROWS]],
     r"row 1 \(line 2\), column 'heading_std_arcsec': value 0 .*allowed: heading_std_arcsec > 0"),
    ([HEADER + ",t_start_s", *[r + ",-5" for r in ROWS]],
     r"row 1 \(line 2\), column 't_start_s': value -5 .*allowed: t_start_s >= 0"),
])
def test_file_and_header_errors(tmp_path, lines, pattern):
    path = tmp_path / "runs.csv"
    path.write_text("".join(line + "\n" for line in lines))
    with pytest.raises(DataError, match=pattern) as info:
        load_runs(path)
    assert str(info.value).startswith(str(path))


def radian_rows():
    rows = [r.split(",") for r in ROWS] + [["4", "40", "0", "1", "28.07", "600", "20"]]
    for r, az in zip(rows, ["0", "1.5708", "3.1416", "4.7124"]):
        r[2] = az
    return [HEADER] + [",".join(r) for r in rows]


def test_azimuths_in_radians_are_caught(tmp_path):
    path = write(tmp_path, radian_rows())
    with pytest.raises(DataError, match=r"runs\.csv, column 'azimuth_deg': the values of rows 1-4 look like "
                                        r"radians.*allowed: degrees, or allow_small_azimuths=True"):
        load_runs(path)
    assert load_runs(path, allow_small_azimuths=True).azimuth[1] == pytest.approx(1.5708 * DEG, rel=1e-15)


@pytest.mark.parametrize("azimuths_deg", [
    [0, 0, 0], [3.5, 3.5, 3.5], [0, 1, 2], [-0.05, 0.1, 0.3], [0, 91.8795, 181.2953], [359.9, 0.1, 5.5]])
def test_degree_azimuths_are_not_taken_for_radians(azimuths_deg):
    assert not _looks_like_radians(np.array(azimuths_deg, float))


def test_lock_in_limit_is_a_parameter(tmp_path):
    path = write(tmp_path, edit(2, "rate_dps", "2"))
    assert load_runs(path, min_rate_dps=1.0).rate[1] == pytest.approx(2 * DEG_PER_S, rel=1e-15)
    assert load_runs(write(tmp_path, edit(2, "rate_dps", "0")), min_rate_dps=0).rate[1] == 0.0
    with pytest.raises(ValueError, match="min_rate_dps"):
        load_runs(path, min_rate_dps=-1)


def test_from_columns_errors_name_source_row_and_column():
    cols = {"run": [1, 2], "rate_dps": [40, 40], "azimuth_deg": [0, 90], "heading_err_arcsec": [1, 2],
            "latitude_deg": [28, 91], "duration_s": [600, 600]}
    with pytest.raises(DataError, match=r"^sim, row 2, column 'latitude_deg': value 91"):
        Runs.from_columns(cols, source="sim")
    with pytest.raises(DataError, match=r"column 'duration_s': has 1 values but 'run' has 2"):
        Runs.from_columns({**cols, "duration_s": [600]})
    # a text column is metadata, not an error (tests/test_data_text.py)
    assert Runs.from_columns({**cols, "latitude_deg": [28, 28], "note": ["x", "y"]}).metadata["note"].tolist() == ["x", "y"]


def test_plan_requires_t_start(tmp_path):
    path = write(tmp_path, ["run,rate_dps,azimuth_deg,duration_s", "1,40,0,600"], "plan.csv")
    with pytest.raises(DataError, match=r"plan\.csv, line 1, column 't_start_s': required column is missing"):
        load_plan(path)


def test_direct_construction_checks_structure():
    runs = random_runs(4)
    with pytest.raises(DataError, match=r"column 'duration_s': has shape \(3,\); allowed: \(4,\) like 'run'"):
        runs.replace(duration=runs.duration[:3])
    with pytest.raises(DataError, match=r"row 2, column 'run': value 1.5 is not an integer"):
        runs.replace(run=[1, 1.5, 3, 4])
    with pytest.raises(DataError, match=r"column 'pitch_arcsec': is given without 'roll_arcsec'"):
        runs.replace(roll=None)


# -- helpers ----------------------------------------------------------------------------------
def test_subset_and_replace():
    runs = random_runs(6)
    sub = runs.subset(runs.rate > 0)
    assert len(sub) == np.sum(runs.rate > 0) and np.array_equal(sub.t_start, runs.t_start[runs.rate > 0])
    assert np.array_equal(runs.subset([4, 0]).covariates["temp_c"], runs.covariates["temp_c"][[4, 0]])
    assert len(runs.subset([])) == 0
    with pytest.raises(DataError, match="repeats"):
        runs.subset([1, 1])
    with pytest.raises(ValueError, match="boolean mask"):
        runs.subset(np.ones(3, bool))
    new = runs.replace(heading_err=np.zeros(6), humidity_pct=np.arange(6.0), temp_c=None)
    assert np.all(new.heading_err == 0) and list(new.covariates) == ["humidity_pct"]
    assert np.all(runs.heading_err != 0) and list(runs.covariates) == ["temp_c"]  # the original is untouched
    with pytest.raises(KeyError):
        runs.replace(nothing=None)


def test_data_error_pickles():
    err = DataError("f.csv", "bad; allowed: good", 2, 3, "run")
    again = pickle.loads(pickle.dumps(err))
    assert str(again) == str(err) == "f.csv, row 2 (line 3), column 'run': bad; allowed: good"


# -- the paper's table ------------------------------------------------------------------------
def test_paper_table1():
    runs = paper_table1()
    assert len(runs) == 12 and list(runs.run) == list(range(1, 13))
    assert np.all(runs.rate == 40 * DEG_PER_S) and np.all(runs.duration == 600.0)
    assert runs.latitude[0] == pytest.approx(0.49, abs=1e-3)
    assert sorted(set(np.round(runs.azimuth / DEG, 4))) == [0.0, 91.8795, 181.2953, 272.8711]
    # independent reference: the peak-to-peak values printed in the paper's Table 1
    assert np.ptp(runs.heading_err) / ARCSEC == pytest.approx(40.50, abs=1e-9)
    assert np.ptp(runs.covariates["heading_err_compensated_arcsec"]) == pytest.approx(28.50, abs=1e-9)
    assert list(runs.position) == ["1"] * 3 + ["2"] * 3 + ["3"] * 3 + ["4"] * 3  # a label column
    assert len(runs.notes) == 3
    assert paper_table1_path().name == "paper_table1.csv" and paper_table1_path().is_file()


def test_written_files_get_the_usual_mode_and_a_missing_folder_is_named(tmp_path):
    from hse_opt.data import write_text_atomic
    from hse_opt.sim.truth import TruthConfig
    mask = os.umask(0)
    os.umask(mask)
    for name in ("report.html", "TRUTH.toml"):  # text through data, TOML through the simulator
        path = tmp_path / name
        if name.endswith(".toml"):
            TruthConfig.default().to_toml(path)
        else:
            write_text_atomic(path, "x")
        assert stat.S_IMODE(os.stat(path).st_mode) == 0o666 & ~mask  # readable by others, not 0600
    with pytest.raises(FileNotFoundError, match="nowhere/x.json: cannot write: the folder"):
        write_text_atomic(tmp_path / "nowhere" / "x.json", "x")
