"""Bad input never becomes a wrong answer (issue 27): an unbalanced quote that would swallow
rows, a covariate column turned into text by one NaN or empty cell. Each case runs the
command line on the paper's Table 1 with one cell changed and holds it against the clean
file's answer or a refusal that names file, row and column."""
import csv
import io
import json
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np
import pytest

from hse_opt.cli import main
from hse_opt.data import DataError, DataWarning, load_runs
from hse_opt.datasets import paper_table1_path

FIX = ["--fix", "lambda2*tilt_const=0"]


def cli(argv):
    err, out = io.StringIO(), io.StringIO()
    with redirect_stderr(err), redirect_stdout(out):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def table1_rows():
    with open(paper_table1_path(), newline="") as fh:
        rows = list(csv.reader(fh))
    rows[0].append("temp_c")
    for k, row in enumerate(rows[1:]):
        row.append(f"{20 + k}.5")
    return rows


def write(path, rows):
    """Rows joined by hand (csv.writer would quote a bad cell and make it legal)."""
    path.write_text("".join(",".join(r) + "\n" for r in rows))
    return path


@pytest.mark.parametrize("row", [4, 12])
def test_unbalanced_quote_is_refused_not_swallowing_rows(tmp_path, row):
    """``"27.5`` in temp_c: the CSV reader would take every line after it into the cell (before:
    fit went on with the rows above it and exit 0). Refused naming the file, row, line and
    column; the file is unchanged."""
    rows = table1_rows()
    rows[row][-1] = '"27.5'
    path = write(tmp_path / "QUOTE.csv", rows)
    before = path.read_bytes()
    assert cli(["fit", paper_table1_path(), *FIX, "-o", tmp_path / "F.json"])[0] == 0
    for argv in (["fit", path, *FIX], ["diagnose", path, *FIX], ["compensate", path, "--fit", tmp_path / "F.json",
                                                                 "-o", tmp_path / "C.csv"]):
        code, out, err = cli(argv)
        assert code == 2 and out == "", (argv, err)
        assert err.count("\n") == 1 and f"{path}, row {row} (line {row + 1}), column 'temp_c'" in err
        assert "allowed: one line per row, quotes in pairs" in err
    assert path.read_bytes() == before and not (tmp_path / "C.csv").exists()
    # a quote closed later in the file swallows the lines between: the same refusal
    rows[row + 2 if row < 10 else 1][0] += '"'
    code, _, err = cli(["fit", write(tmp_path / "Q2.csv", rows), *FIX])
    assert code == 2 and "quoted cell does not end on its line" in err


def test_quotes_in_pairs_within_a_line_are_read(tmp_path):
    """A legal quoted cell (a comma inside it) is still read: the check is about line ends."""
    text = Path(paper_table1_path()).read_text().splitlines()
    text[0] += ",remark"
    text[1:] = [line + ',"cold, start"' for line in text[1:]]
    (tmp_path / "R.csv").write_text("\n".join(text) + "\n")
    runs = load_runs(tmp_path / "R.csv")
    assert len(runs) == 12 and runs.metadata["remark"].tolist() == ["cold, start"] * 12


@pytest.mark.parametrize("cell", ["nan", "", "NaN", "27,5x"])
def test_a_covariate_with_a_hole_is_named_everywhere(tmp_path, cell):
    """One NaN or empty cell in temp_c turns the column into text. Every command says so on
    stderr (file, row, column) and still succeeds where the column is only passed through;
    where it is used (--effects covariate:temp_c, diagnose --covariates) it is refused with the
    row (before: fit said only 'covariate columns [...] are required', compensate wrote 'nan'
    through without a word)."""
    rows = table1_rows()
    rows[7][-1] = cell.replace(",", ";")
    path = write(tmp_path / "HOLE.csv", rows)
    with pytest.warns(DataWarning, match=r"HOLE.csv, row 7, column 'temp_c': .* kept as text \(11 of 12"):
        runs = load_runs(path)
    assert "temp_c" in runs.metadata and "temp_c" not in runs.covariates
    where = f"{path}, row 7, column 'temp_c'"
    code, _, err = cli(["fit", path, *FIX, "-o", tmp_path / "F.json"])
    assert code == 0 and f"hse-opt fit: warning: {where}" in err
    code, _, err = cli(["compensate", path, "--fit", tmp_path / "F.json", "-o", tmp_path / "C.csv"])
    assert code == 0 and f"hse-opt compensate: warning: {where}" in err
    for argv in (["fit", path, *FIX, "--effects", "hse,covariate:temp_c"],
                 ["diagnose", path, *FIX, "--covariates", "temp_c"]):
        code, out, err = cli(argv)
        lines = err.strip("\n").split("\n")
        assert code == 2 and out == "", err
        assert lines[-1].startswith(f"hse-opt {argv[0]}: error: {where}: ") and "allowed: a finite number" \
            in lines[-1], err
        assert all("warning" in line for line in lines[:-1])


def test_a_text_column_without_numbers_is_no_warning(tmp_path):
    """Dates and operators are metadata, as before: no warning (the rule is about numbers)."""
    rows = table1_rows()
    rows[0][-1] = "operator"
    for k, row in enumerate(rows[1:]):
        row[-1] = ("Yu", "Wu")[k % 2]
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        runs = load_runs(write(tmp_path / "OP.csv", rows))
    assert runs.metadata["operator"].tolist()[:2] == ["Yu", "Wu"] and runs.warnings == ()


def test_covariate_lookup_names_the_columns_there_are():
    runs = load_runs(paper_table1_path())
    with pytest.raises(DataError, match=r"column 'temp_c': is not in the file.*allowed: "
                                        r"heading_err_compensated_arcsec"):
        runs.covariate("temp_c", "the effect covariate:temp_c")
    with open(paper_table1_path(), newline="") as fh:
        column = [float(r["heading_err_compensated_arcsec"]) for r in csv.DictReader(fh)]
    assert runs.covariate("heading_err_compensated_arcsec", "x").tolist() == column


# -- copies: rows written twice carry no new information --------------------------------------
FIELD = [("A", 37.0, 150, -400), ("B", 212.0, -300, 250)]


@pytest.fixture(scope="module")
def field_runs(tmp_path_factory):
    """The README's field campaign (two positions without a reference, rates 20/60/-40 twice),
    simulated with the paper-like default system."""
    d = tmp_path_factory.mktemp("field")
    rows = [["run", "rate_dps", "azimuth_deg", "t_start_s", "duration_s", "tilt_x_arcsec", "tilt_y_arcsec",
             "position"]]
    t = 3600
    for label, heading, tx, ty in FIELD:
        for rate in (20, 60, -40, 20, 60, -40):
            rows.append([str(len(rows)), str(rate), str(heading), str(t), "300", str(tx), str(ty), label])
            t += 360
    write(d / "PLAN.csv", rows)
    code, _, err = cli(["simulate", d / "PLAN.csv", "-o", d / "RUNS.csv", "--field", "--seed", "3", "--no-progress"])
    assert code == 0, err
    return d / "RUNS.csv"


def _with_copies(src, dst, which):
    """``src`` with the rows ``which`` (0-based data rows) appended again under new run ids."""
    with open(src, newline="") as fh:
        rows = list(csv.reader(fh))
    j = rows[0].index("run")
    for k, i in enumerate(which):
        again = list(rows[1 + i])
        again[j] = str(1000 + k)
        rows.append(again)
    write(dst, rows)
    return dst


def _fit_json(path, *extra):
    code, out, err = cli(["fit", path, *extra, "--json"])
    assert code == 0, err
    return json.loads(out)


@pytest.mark.parametrize("which", ["all", "some"])
def test_field_copies_change_no_answer_and_are_named(tmp_path, field_runs, which):
    """Field rows appended again under new run ids (before: diagnose went from adequate to
    missing-effect and sigma(lambda2) shrank by sqrt(2), no note): every number of the fit and
    the diagnosis is the clean campaign's (copies add no information), and both say which rows
    are copies."""
    rows = list(range(12)) if which == "all" else [0, 4, 7]
    copies = _with_copies(field_runs, tmp_path / "COPIES.csv", rows)
    clean, dup = _fit_json(field_runs), _fit_json(copies)
    for name, p in clean["parameters"].items():
        assert dup["parameters"][name]["value"] == pytest.approx(p["value"], rel=1e-9, abs=1e-12)
        assert dup["parameters"][name]["std"] == pytest.approx(p["std"], rel=1e-9, abs=1e-12)
    for key in ("chi2", "dof", "chi2_red", "aic", "bic"):
        assert dup[key] == pytest.approx(clean[key], rel=1e-9), key
    note = f"{len(rows)} of {12 + len(rows)} rows are copies of another row (run 1000 = 1,"
    assert any(note in n for n in dup["notes"]), dup["notes"]
    d_clean, d_dup = (json.loads(cli(["diagnose", p, "--json"])[1]) for p in (field_runs, copies))
    assert d_dup["verdict"] == d_clean["verdict"]
    assert d_dup["lack_of_fit_p"] == pytest.approx(d_clean["lack_of_fit_p"], rel=1e-6)
    for c, c2 in zip(d_clean["candidates"], d_dup["candidates"]):
        assert c2["effect"] == c["effect"]
        assert (c2["p_value"] is None) == (c["p_value"] is None)
        if c["p_value"] is not None:
            assert c2["p_value"] == pytest.approx(c["p_value"], rel=1e-6)
    assert any("measurements once" in n for n in d_dup["notes"])


def test_surveyed_copies_of_some_rows_change_no_answer(tmp_path):
    """Table 1 with three of its rows written again: the fit is Table 1's (before: the copies
    counted as runs only when every replicate group was copies; these three pulled the fit)."""
    copies = _with_copies(paper_table1_path(), tmp_path / "T1C.csv", [0, 5, 11])
    clean, dup = _fit_json(paper_table1_path(), *FIX), _fit_json(copies, *FIX)
    for name, p in clean["parameters"].items():
        assert dup["parameters"][name]["value"] == pytest.approx(p["value"], rel=1e-9, abs=1e-12)
        assert dup["parameters"][name]["std"] == pytest.approx(p["std"], rel=1e-9, abs=1e-12)
    assert dup["dof"] == clean["dof"] and dup["n_runs"] == 15
    assert any("3 of 15 rows are copies" in n for n in dup["notes"])


# -- exit codes and words ------------------------------------------------------------------------
def _one_line_error(code, out, err, command, *must):
    assert code == 2 and out == "", err
    assert err.count("\n") == 1 and err.startswith(f"hse-opt {command}: error: "), err
    for text in ("allowed: ", *must):
        assert text in err, (text, err)


@pytest.mark.parametrize("effects", ["hse", "hse,sync_delay", "hse,warmup", "hse,axis_bias"])
def test_one_rate_at_one_azimuth_is_bad_data_naming_the_parameters(tmp_path, effects):
    """Six 40 deg/s runs at azimuth 0 cannot separate the offset from the tilt terms (before:
    exit 1 'Gauss-Newton did not converge'): exit 2, the parameters named, what would help."""
    rows = [["run", "rate_dps", "azimuth_deg", "heading_err_arcsec", "latitude_deg", "duration_s", "t_start_s"]]
    rows += [[str(i), "40", "0", f"{(-1) ** i * 3.5 + i}", "28.07", "600", str(700 * i)] for i in range(1, 7)]
    code, out, err = cli(["fit", write(tmp_path / "SIX.csv", rows), "--effects", effects])
    assert code == 2 and out == "" and err.count("\n") == 1 and "did not converge" not in err, err
    assert "offset" in err and ("cannot be told apart" in err or "cannot fit" in err or "no information" in err)


@pytest.mark.parametrize("option, value", [("--arw-dph-rthz", "0"), ("--arw-dph-rthz", "1e308"),
                                           ("--floor-arcsec", "-1"), ("--warmup-s", "nan"),
                                           ("--azimuth-change-s", "-5"), ("--run-overhead-s", "inf")])
def test_design_options_out_of_range_name_the_option(tmp_path, option, value):
    """--arw-dph-rthz 0 ended 'no plan ... can identify the model: the data carry no information
    on :' after three numpy warnings; the others named 'stand floor' or 'costs.warmup (s)'."""
    code, out, err = cli(["design", option, value, "-o", tmp_path / "P.csv"])
    _one_line_error(code, out, err, "design", f"{option} {float(value):g} is not allowed", f"<= {option.lstrip('-')} <=")
    assert not (tmp_path / "P.csv").exists()


def test_dask_that_is_no_address_names_the_option(tmp_path):
    plan = write(tmp_path / "P.csv", [["run", "rate_dps", "azimuth_deg", "t_start_s", "duration_s"],
                                      ["1", "40", "0", "0", "60"]])
    code, out, err = cli(["simulate", plan, "-o", tmp_path / "S.csv", "--dask", "not an address"])
    _one_line_error(code, out, err, "simulate", "--dask")


@pytest.mark.parametrize("cell, what", [("800", "out of range"), ("1e308", "out of range"), ("", "is empty"),
                                        ("nan", "not finite")])
def test_a_field_heading_is_named_as_heading_deg(tmp_path, field_runs, cell, what):
    """A bad heading_deg in a row without azimuth_deg was reported as azimuth_deg "a stand
    azimuth" (800, 1e308) or as "heading_err_arcsec is given" (empty)."""
    with open(field_runs, newline="") as fh:
        rows = list(csv.reader(fh))
    rows[3][rows[0].index("heading_deg")] = cell
    code, out, err = cli(["fit", write(tmp_path / "H.csv", rows)])
    _one_line_error(code, out, err, "fit", "row 3 (line 4), column 'heading_deg'", what)
    assert "azimuth_deg <=" not in err and "heading_err_arcsec is given" not in err


def test_a_field_position_at_one_rate_is_named(tmp_path, field_runs):
    """Position A at 20 deg/s only: 'cannot fit 1 free parameters' now names the position and
    asks for a second rate or sense."""
    with open(field_runs, newline="") as fh:
        rows = list(csv.reader(fh))
    r, p = rows[0].index("rate_dps"), rows[0].index("position")
    rows = rows[:1] + [row for row in rows[1:] if row[p] == "A" and row[r] == "20"]
    code, out, err = cli(["fit", write(tmp_path / "ONE.csv", rows)])
    _one_line_error(code, out, err, "fit", "position 'A' (20 deg/s)", "one bias rate only",
                    "allowed: two or more rates (or both senses) at a position")


def test_a_header_only_raw_log_says_so_without_a_warning(tmp_path):
    """A CSV raw log with its header only gave '1 values per row, header 8' and numpy's
    UserWarning."""
    from hse_opt.align.rawlog import CSV_COLUMNS
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "empty.csv").write_text(",".join(CSV_COLUMNS) + "\n")
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        code, out, err = cli(["align", logs, "-o", tmp_path / "R.csv"])
    assert code == 2 and "warning" not in err.lower(), err
    assert "empty.csv: no samples below the header; allowed: " in err.splitlines()[0]
    assert not (tmp_path / "R.csv").exists()


# -- found by the fuzz test -----------------------------------------------------------------------
@pytest.mark.parametrize("cell", ["\u0664\u0660", "\uff14\uff10", "4_0"])
def test_digits_that_python_reads_are_not_numbers_in_a_file(tmp_path, cell):
    """Arabic-Indic, full-width and underscored digits: Python's Decimal reads them as 40, a
    spreadsheet never writes them. A rate of 40 deg/s written so was fitted as one."""
    rows = table1_rows()
    rows[5][rows[0].index("rate_dps")] = cell
    code, out, err = cli(["fit", write(tmp_path / "U.csv", rows), *FIX])
    _one_line_error(code, out, err, "fit", "row 5 (line 6), column 'rate_dps'", "ASCII digits only")


def test_a_raw_log_with_full_width_digits_names_the_sample(tmp_path):
    from hse_opt import units
    from hse_opt.sim import RunSpec, TruthConfig, generate, save_rawlog
    log = generate(TruthConfig.default(), RunSpec(rate=60 * units.DEG_PER_S, azimuth=0.5, duration=7.0,
                                                  t_start=60.0), np.random.default_rng(1))
    object.__setattr__(log, "meta", {"latitude_deg": 28.07, "run": 1})
    (tmp_path / "logs").mkdir()
    path = tmp_path / "logs" / "run_1.csv"
    save_rawlog(log, path)
    lines = path.read_text().splitlines()
    cells = lines[101].split(",")
    cells[4] = "\uff11\uff12"
    lines[101] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    code, out, err = cli(["align", tmp_path / "logs", "-o", tmp_path / "R.csv", "--no-progress"])
    assert code == 2 and "sample index 100 (line 102), column accel_x_mps" in err and "allowed: " in err, err


def test_heading_errors_in_another_unit_are_said(tmp_path):
    """Table 1's heading errors times 1000 (milliarcseconds written as arcsec) were fitted with
    exit 0 and no word; the fit now names a scatter 100 times the gyro noise model's."""
    rows = table1_rows()
    j = rows[0].index("heading_err_arcsec")
    for row in rows[1:]:
        row[j] = repr(float(row[j]) * 1000)
    code, out, err = cli(["fit", write(tmp_path / "MAS.csv", rows), *FIX, "--json"])
    assert code == 0, err
    checks = json.loads(out)["checks"]
    assert any("times what a gyrocompass alignment" in str(c) and "another unit" in str(c) for c in checks), checks
    code, out, err = cli(["fit", paper_table1_path(), *FIX, "--json"])
    assert not any("another unit" in str(c) for c in json.loads(out)["checks"])


@pytest.mark.parametrize("text", ["[site]\nlatitude_deg = " + "[" * 5000 + "]" * 5000 + "\n", None])
def test_a_project_file_nested_deeply_or_endless_is_refused(tmp_path, text):
    """A project file of arrays nested 5000 deep was a RecursionError traceback; /dev/zero was
    read for ever."""
    path = "/dev/zero" if text is None else tmp_path / "P.toml"
    if text is not None:
        path.write_text(text)
    code, out, err = cli(["config", "--config", path])
    _one_line_error(code, out, err, "config", str(path))
