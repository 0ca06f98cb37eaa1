"""Physical ranges (hse_opt/ranges.py) in the loaders and options, bounded inputs, and the
exit codes of failures a user can cause (one line naming the file or option, exit 2) or a
solver's (exit 1 with its status)."""
import io
import json
import math
from contextlib import redirect_stderr, redirect_stdout

import numpy as np
import pytest

from hse_opt.cli import main
from hse_opt.data import DataError, DataWarning, load_plan, load_runs
from hse_opt.datasets import paper_table1_path
from hse_opt.ranges import RANGES

HEADER = "run,rate_dps,azimuth_deg,heading_err_arcsec,latitude_deg,duration_s"


def runs_file(tmp_path, rows, header=HEADER):
    path = tmp_path / "runs.csv"
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


def cli(argv):
    err = io.StringIO()
    with redirect_stderr(err), redirect_stdout(io.StringIO()):
        code = main([str(a) for a in argv])
    return code, err.getvalue()


@pytest.mark.parametrize("row, column, text", [
    ("1,40,0,1,90,600", "latitude_deg", "-89 <= latitude_deg <= 89"),       # the gyrocompass at a pole
    ("1,40,0,1,-89.5,600", "latitude_deg", "w_ie cos(latitude)"),
    ("1,1e6,0,1,28,600", "rate_dps", "rate_dps <= 1000"),                  # beyond any rate table
    ("1,10,0,1,28,30", "duration_s", "360/|rate_dps| = 36 s"),             # less than one revolution
    ("1,40,0,1,28,1e6", "duration_s", "duration_s <= 86400"),
    ("1,40,1e5,1,28,600", "azimuth_deg", "azimuth_deg <= 720"),
    ("1,40,0,1e999999999,28,600", "heading_err_arcsec", "not finite"),
    ("1e999999999,40,0,1,28,600", "run", "int64"),
])
def test_values_outside_their_physical_range_are_refused_with_the_reason(tmp_path, row, column, text):
    with pytest.raises(DataError) as info:
        load_runs(runs_file(tmp_path, [row]))
    assert info.value.column == column and text in str(info.value) and "row 1 (line 2)" in str(info.value)


def test_the_bounds_themselves_are_allowed(tmp_path):
    """Values on the limits load (the check is <=, in exact decimals), just outside they do not."""
    lo, hi = RANGES["latitude_deg"].lo, RANGES["latitude_deg"].hi
    rows = [f"1,1000,0,1,{lo:g},600", f"2,-1000,90,2,{hi:g},600", "3,40,180,3,28,9"]  # 9 s: one turn at 40
    runs = load_runs(runs_file(tmp_path, rows))
    assert np.ptp(runs.latitude) > 0 and len(runs) == 3
    with pytest.raises(DataError, match="shorter than one table revolution"):
        load_runs(runs_file(tmp_path, rows[:2] + ["3,40,180,3,28,8.99"]))


def test_tilts_in_radians_and_sigmas_in_degrees_are_named(tmp_path):
    """Tilts all below 0.05 arcsec are a warning, not an error: radians give such numbers, and so
    does a level base (the alignment's own output; it was refused)."""
    header = HEADER + ",pitch_arcsec,roll_arcsec"
    with pytest.warns(DataWarning, match="column 'pitch_arcsec': every pitch and roll is below 0.05 arcsec: a "
                                         "level base, or values in radians or degrees"):
        runs = load_runs(runs_file(tmp_path, ["1,40,0,1,28,600,-0.00058,-0.00027",
                                              "2,40,90,1,28,600,-0.00058,-0.00027"], header))
    assert runs.pitch[0] == pytest.approx(-0.00058 * math.pi / 648000, rel=1e-12)
    with pytest.raises(DataError, match="heading_std_arcsec") as info:
        load_runs(runs_file(tmp_path, ["1,40,0,1,28,600,0.0022"], HEADER + ",heading_std_arcsec"))
    assert "look like degrees" in str(info.value)


def test_inputs_are_bounded_in_size(tmp_path):
    code, err = cli(["fit", "/dev/zero"])
    assert code == 2 and "/dev/zero: is larger than 64 MiB" in err
    wide = runs_file(tmp_path, ["1,40,0,1,28,600" + ",1" * 1001], HEADER + "".join(f",c{k}" for k in range(1001)))
    with pytest.raises(DataError, match="at most 1000"):
        load_runs(wide)
    deep = tmp_path / "FIT.json"
    deep.write_text("[" * 100000 + "]" * 100000)
    code, err = cli(["compensate", paper_table1_path(), "--fit", deep, "-o", tmp_path / "C.csv"])
    assert code == 2 and f"{deep}: arrays or objects nested too deeply" in err and err.count("\n") == 1
    toml = tmp_path / "T.toml"
    toml.write_text("[site]\nlatitude_deg = " + "9" * 400 + "\n")
    plan = tmp_path / "P.csv"
    plan.write_text("run,rate_dps,azimuth_deg,t_start_s,duration_s\n1,40,0,0,60\n")
    code, err = cli(["simulate", plan, "--truth", toml, "-o", tmp_path / "S.csv"])
    assert code == 2 and "site.latitude_deg" in err and "[-89.0, 89.0]" in err
    code, err = cli(["design", "--budget-h", "1e9", "-o", tmp_path / "X.csv"])
    assert code == 2 and "--budget-h 1e+09 is not allowed" in err
    assert not (tmp_path / "X.csv").exists() and not (tmp_path / "S.csv").exists()


def test_plan_ranges(tmp_path):
    path = tmp_path / "plan.csv"
    path.write_text("run,rate_dps,azimuth_deg,t_start_s,duration_s,tilt_x_arcsec,tilt_y_arcsec\n1,40,0,1.7e9,600,0,0\n")
    with pytest.raises(DataError, match="t_start_s.*looks like a clock time"):
        load_plan(path)
    path.write_text("run,rate_dps,azimuth_deg,t_start_s,duration_s,tilt_x_arcsec,tilt_y_arcsec\n1,40,0,0,600,0.01,1e4\n")
    with pytest.raises(DataError, match="tilt_y_arcsec"):
        load_plan(path)


@pytest.fixture(scope="module")
def fit_json(tmp_path_factory):
    d = tmp_path_factory.mktemp("fitjson")
    assert cli(["fit", paper_table1_path(), "--fix", "lambda2*tilt_const=0", "-o", d / "FIT.json"])[0] == 0
    return d / "FIT.json"


@pytest.mark.parametrize("change, text", [
    (lambda d: d.update(covariance=[[1.0]]), '"covariance" has shape (1, 1); allowed: finite numbers of shape (4, 4)'),
    (lambda d: d.update(chi2="x"), "could not convert string to float"),
    (lambda d: d.pop("runs"), "missing or has a malformed entry"),
    (lambda d: d.update(effects=["nope"]), "unknown effect 'nope'"),
])
def test_fit_json_errors_name_the_file(fit_json, tmp_path, change, text):
    d = json.loads(fit_json.read_text())
    change(d)
    bad = tmp_path / "BAD.json"
    bad.write_text(json.dumps(d))
    code, err = cli(["compensate", paper_table1_path(), "--fit", bad, "-o", tmp_path / "C.csv"])
    assert code == 2 and err.startswith(f"hse-opt compensate: error: {bad}: ") and text in err, err
    assert err.count("\n") == 1


def test_fixing_every_parameter_is_a_clear_error():
    code, err = cli(["fit", paper_table1_path(), "--fix", "offset=0", "--fix", "lambda2*tilt_cos=0", "--fix",
                     "lambda2*tilt_sin=0", "--fix", "lambda2*tilt_const=0"])
    assert code == 2 and "every parameter is held" in err and "reshape" not in err


def test_a_solver_failure_exits_1_with_its_status_and_a_hint(monkeypatch, tmp_path):
    """IPOPT limited to 2 iterations on a nonlinear fit cannot finish: exit 1, the status, the
    nonlinear parameter and a bound to try, one line, nothing written."""
    from hse_opt.fit import solvers
    monkeypatch.setitem(solvers._IPOPT_OPTIONS, "ipopt.max_iter", 2)
    monkeypatch.setattr(solvers, "gauss_newton", lambda prob, w, z, *a, **k: (z, False))
    solvers._nlp_solver.cache_clear()
    try:
        code, err = cli(["fit", paper_table1_path(), "--fix", "lambda2*tilt_const=0", "--effects", "warmup",
                         "-o", tmp_path / "F.json"])
    finally:
        solvers._nlp_solver.cache_clear()
    assert code == 1 and "status: Maximum_Iterations_Exceeded" in err and "--bound warmup_tau=" in err, err
    assert "internal error" not in err and err.count("\n") == 1 and not (tmp_path / "F.json").exists()


def test_simulate_refuses_rates_its_sampling_cannot_represent(tmp_path):
    """A table-rate ripple of order 1000 per revolution at 2 ms sampling: its Nyquist limit is
    1000 * 0.002 s * |rate| < 180 deg, |rate| < 90 deg/s; 60 deg/s simulates, 100 deg/s does not."""
    truth = tmp_path / "T.toml"
    truth.write_text("[table]\nripple_order = 1000\n")
    plan = tmp_path / "P.csv"
    plan.write_text("run,rate_dps,azimuth_deg,t_start_s,duration_s\n1,60,0,0,60\n")
    assert cli(["simulate", plan, "--truth", truth, "-o", tmp_path / "S.csv", "--no-progress"])[0] == 0
    plan.write_text("run,rate_dps,azimuth_deg,t_start_s,duration_s\n1,100,0,0,60\n")
    code, err = cli(["simulate", plan, "--truth", truth, "-o", tmp_path / "S2.csv", "--no-progress"])
    assert code == 2 and "rate_dps" in err and "allowed |rate_dps| < 90" in err and "500 Hz" in err, err
    assert not (tmp_path / "S2.csv").exists()
