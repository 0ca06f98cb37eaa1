"""Fuzz test of the command line: malformed CSV, TOML and JSON inputs and options for every
command, from a seeded generator (each case is reproducible from its seed).

Every case asserts what a user is promised: exit status 0 or 2 (1 only with a solver's
status), no traceback and no internal error, a failure in one line naming what is wrong, the
inputs unchanged (checksums) and no partial output (the folder listing is the same as before
when the command fails; every output is there, with no temporary file, when it succeeds).

``HSE_FUZZ_CASES=N`` runs N cases per class instead of the CI size (the report's counts come
from ``HSE_FUZZ_CASES=60``).
"""
import hashlib
import io
import json
import os
import re
from collections import Counter
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np
import pytest

from hse_opt.cli import COMMANDS, main
from hse_opt.data import TEMP_TAG
from hse_opt.datasets import paper_table1_path

CASES = int(os.environ.get("HSE_FUZZ_CASES", "0")) or None
FIX = ["--fix", "lambda2*tilt_const=0"]
PLAN = "run,rate_dps,azimuth_deg,t_start_s,duration_s\n1,40,0,0,60\n2,-40,90,100,60\n"
TRUTH = "[site]\nlatitude_deg = 28.07\n\n[gyro]\narw_dph_rthz = 0.012\neps_arcsec = [1.6, 1.2, 1.4]\n"
PROJECT = ('[site]\nlatitude_deg = 28.07\n[system]\narw_dph_rthz = 0.012\n[model]\neffects = "hse"\n'
           '[compute]\njobs = 1\n')

# -- cell, text and byte mutations ------------------------------------------------------------
BAD_CELLS = ["", " ", "abc", "nan", "NaN", "inf", "-inf", "1e999999999", "-1e999999999", "9" * 400,
             "1" + "0" * 400 + ".5", "0x10", "1,5", "1_000", "\u0661\u0662", "１２", "1e-999999999", "+", "--1",
             "True", "None", "'1'", "\"1\"", "1e309", "4.9e-324", "=1+1", "@SUM(A1)", "$(touch x)", "\t7"]
SCALES = [0.0, -1.0, 1e-12, 1e-6, 1e-3, 57.29577951308232, 0.017453292519943295, 3600.0, 1e3, 1e6, 1e12]


def _csv_rows(text):
    return [line.split(",") for line in text.strip("\n").split("\n")]


def _csv_text(rows, newline="\n"):
    return newline.join(",".join(r) for r in rows) + newline


def mutate_csv(text, rng):
    """(class, bytes) of one mutation of a CSV file."""
    rows = _csv_rows(text)
    kind = rng.choice(["cell_text", "cell_scale", "column_drop", "column_duplicate", "header_unit",
                       "row_duplicate", "rows_none", "field_extra", "field_missing", "bytes",
                       "size", "units"])
    r = [list(x) for x in rows]
    n_rows, n_cols = len(r) - 1, len(r[0])
    i, j = int(rng.integers(1, n_rows + 1)), int(rng.integers(n_cols))
    if kind == "cell_text":
        r[i][j] = str(rng.choice(BAD_CELLS))
    elif kind == "cell_scale":
        try:
            r[i][j] = repr(float(r[i][j]) * float(rng.choice(SCALES)))
        except ValueError:
            r[i][j] = "1e6"
    elif kind == "column_drop":
        r = [row[:j] + row[j + 1:] for row in r]
    elif kind == "column_duplicate":
        r = [row + [row[j]] for row in r]
    elif kind == "header_unit":
        r[0][j] = re.sub(r"_(deg|dps|arcsec|s)$", lambda m: "_" + str(rng.choice(["rad", "rps", "mrad", "ms", "h"])),
                         r[0][j]) if "_" in r[0][j] else r[0][j] + "_x"
    elif kind == "row_duplicate":
        r.append(list(r[i]))
    elif kind == "rows_none":
        r = r[:1]
    elif kind == "field_extra":
        r[i].append("1")
    elif kind == "field_missing":
        r[i] = r[i][:-1]
    elif kind == "units":  # a whole column in another unit (radians, rad/s, degrees)
        col = r[0][j]
        factor = {"azimuth_deg": 0.017453292519943295, "rate_dps": 0.017453292519943295,
                  "pitch_arcsec": 4.84813681109536e-06, "roll_arcsec": 4.84813681109536e-06,
                  "heading_std_arcsec": 1 / 3600, "latitude_deg": 0.017453292519943295,
                  "duration_s": 1 / 60}.get(col, 1e3)
        for row in r[1:]:
            try:
                row[j] = repr(float(row[j]) * factor)
            except ValueError:
                pass
    if kind == "bytes":
        data = _csv_text(r).encode()
        how = rng.choice(["nul", "latin1", "bom", "crlf", "semicolon", "truncate", "binary", "empty",
                          "quote", "long_line"])
        if how == "nul":
            k = int(rng.integers(len(data)))
            data = data[:k] + b"\0" + data[k:]
        elif how == "latin1":
            data = data.replace(b"run", "r\u00e9n".encode("latin-1"), 1)
        elif how == "bom":
            data = b"\xef\xbb\xbf" + data
        elif how == "crlf":
            data = _csv_text(r, "\r\n").encode()
        elif how == "semicolon":
            data = data.replace(b",", b";")
        elif how == "truncate":
            data = data[:int(rng.integers(len(data)))]
        elif how == "binary":
            data = rng.bytes(int(rng.integers(1, 2000)))
        elif how == "empty":
            data = b""
        elif how == "quote":
            data = data.replace(b",", b',"', 1)
        else:
            data = data + b"1" * 200_000 + b"\n"
        return f"csv:bytes:{how}", data
    if kind == "size":
        how = rng.choice(["columns", "rows"])
        if how == "columns":  # past the column limit
            r = [row + [f"c{k}" if q == 0 else "1" for k in range(1001)] for q, row in enumerate(r)]
        else:  # many rows of one run id
            r = r + [list(r[1])] * 2000
        return f"csv:size:{how}", _csv_text(r).encode()
    return f"csv:{kind}", _csv_text(r).encode()


def mutate_toml(text, rng):
    kind = rng.choice(["unknown_key", "type", "big_int", "big_float", "nan", "range", "nesting", "syntax",
                       "duplicate", "harmonic", "bytes", "empty"])
    if kind == "unknown_key":
        return "toml:" + kind, (text + "\n[gyro2]\nx = 1\n").encode()
    if kind == "type":
        return "toml:" + kind, text.replace("28.07", '"28.07"').encode()
    if kind == "big_int":
        return "toml:" + kind, text.replace("28.07", "9" * 400).encode()
    if kind == "big_float":
        return "toml:" + kind, text.replace("28.07", "9" * 400 + ".5").encode()
    if kind == "nan":
        return "toml:" + kind, text.replace("0.012", str(rng.choice(["nan", "inf", "-inf"]))).encode()
    if kind == "range":
        return "toml:" + kind, text.replace("28.07", str(rng.choice(["90", "-89.5", "1e6", "-1000"]))).encode()
    if kind == "nesting":
        depth = int(rng.choice([50, 500, 5000]))
        return "toml:" + kind, (text + "\n[table]\nripple_ppm = " + "[" * depth + "]" * depth + "\n").encode()
    if kind == "syntax":
        return "toml:" + kind, text.replace("=", "", 1).encode()
    if kind == "duplicate":
        return "toml:" + kind, (text + "[site]\nlatitude_deg = 1\n").encode()
    if kind == "harmonic":
        order = rng.choice(["0", "-1", "1.5", "9" * 400, "100000"])
        return "toml:" + kind, (text + f"\n[[encoder.harmonics]]\norder = {order}\namplitude_arcsec = 1\n").encode()
    if kind == "bytes":
        return "toml:" + kind, b"\xff\xfe" + text.encode()
    return "toml:" + kind, b""


def mutate_json(text, rng):
    d = json.loads(text)
    kind = rng.choice(["truncate", "not_json", "nesting", "format", "version", "covariance_1x1",
                       "missing_key", "type", "nan", "big", "root", "names"])
    if kind == "truncate":
        return "json:" + kind, text[:int(rng.integers(len(text)))].encode()
    if kind == "not_json":
        return "json:" + kind, b"effects = hse\n"
    if kind == "nesting":
        depth = int(rng.choice([50, 5000, 100000]))
        return "json:" + kind, ("[" * depth + "]" * depth).encode()
    if kind == "format":
        d["format"] = "something else"
    elif kind == "version":
        d["version"] = int(rng.choice([0, 99]))
    elif kind == "covariance_1x1":
        d["covariance"] = [[1.0]]
    elif kind == "missing_key":
        d.pop(str(rng.choice(sorted(d))))
    elif kind == "type":
        key = str(rng.choice(sorted(d)))
        d[key] = str(rng.choice(["x", "1"]))
    elif kind == "nan":
        return "json:" + kind, text.replace('"chi2": ', '"chi2": NaN, "x": ', 1).encode()
    elif kind == "big":
        return "json:" + kind, re.sub(r'("value": )([-0-9.e+]+)', r"\g<1>1e999", text, count=1).encode()
    elif kind == "root":
        return "json:" + kind, b"[1, 2, 3]"
    elif kind == "names":
        d["names"] = list(reversed(d["names"]))
    return "json:" + kind, json.dumps(d).encode()


def tamper_json(text, rng):
    """(class, bytes) of a FIT.json whose numbers were edited so that they disagree (each
    must be refused: exit 2 naming the field; hse_opt/fit/file.py)."""
    d = json.loads(text)
    kind = rng.choice(["p_si", "value", "covariance", "std", "asymmetric", "correlation", "tilt_known",
                       "free", "input"])
    i = int(rng.integers(len(d["names"])))
    name = d["names"][i]
    if kind == "p_si":
        d["p_si"][i] = float(rng.choice([1e308, -1e308, 1e3, d["p_si"][i] * 2 + 1e-3]))
    elif kind == "value":
        d["parameters"][name]["value"] = float(d["parameters"][name]["value"] + rng.choice([1.0, 1e3, -1e6]))
    elif kind == "covariance":
        d["covariance"][i][i] = float(rng.choice([1e308, 4.0 * d["covariance"][i][i] + 1.0]))
    elif kind == "std":
        d["parameters"][name]["std"] = float(d["parameters"][name]["std"] * 2 + 1.0)
    elif kind == "asymmetric":
        j = (i + 1) % len(d["names"])
        d["covariance"][i][j] = float(d["covariance"][i][j] + 1.0 + abs(d["covariance"][i][j]))
    elif kind == "correlation":
        j = (i + 1) % len(d["names"])
        d["correlation"][i][j] = d["correlation"][j][i] = 0.5 + 0.4 * float(rng.random())
    elif kind == "tilt_known":
        d["tilt_known"] = str(rng.choice(["no", "false", "0"]))
    elif kind == "free":
        d["parameters"][name]["free"] = str(rng.choice(["yes", "1"]))
    else:
        row = str(rng.choice(["rate", "latitude", "duration"]))
        d["runs"]["inputs"][row][0] = float(rng.choice([-1e4, 1e308]))  # SI: beyond every physical range
    return "tamper:" + kind, json.dumps(d).encode()


#: hostile column names (hse_opt/names.py refuses them all)
HOSTILE_NAMES = ["t*/x", "<script>alert(1)</script>", "temp c", "k-1", "a.b", "x" * 65, "\u00e9t\u00e9"]


def hostile_header(text, rng):
    """(class, bytes) of a CSV whose extra column (or an existing one) has a hostile name."""
    rows = _csv_rows(text)
    name = str(rng.choice(HOSTILE_NAMES))
    quoted = '"' + name.replace('"', '""') + '"' if any(c in name for c in ',"') else name
    if rng.random() < 0.5:
        rows = [r + [quoted if k == 0 else "1.5"] for k, r in enumerate(rows)]
    else:
        rows[0][int(rng.integers(len(rows[0])))] = quoted
    return "names:header", _csv_text(rows).encode()


#: classes whose every case must be refused (exit 2): never an answer from edited numbers or names
MUST_REFUSE = ("tamper:", "names:")


# -- options --------------------------------------------------------------------------------
BAD_NUMBERS = ["-1", "0", "nan", "inf", "-inf", "1e9", "1e999", "abc", "", "1e-300", "9" * 400]


def option_case(rng):
    """(class, argv) of an option mutation; ``{...}`` names the files the fixture provides."""
    cases = [
        ("fit:--fix", ["fit", "{T1}", "--fix", str(rng.choice(["lambda2", "=1", "nope=1", "offset=abc",
                                                              "offset=nan", "lambda2*tilt_const=1e999"]))]),
        ("fit:--fix-all", ["fit", "{T1}", "--fix", "offset=0", "--fix", "lambda2*tilt_cos=0", "--fix",
                           "lambda2*tilt_sin=0", "--fix", "lambda2*tilt_const=0"]),
        ("fit:--bound", ["fit", "{T1}", *FIX, "--bound", str(rng.choice(["offset=1", "offset=5:1", "offset=a:b",
                                                                        "nope=0:1", "offset=nan:1"]))]),
        ("fit:--effects", ["fit", "{T1}", *FIX, "--effects", str(rng.choice(["nope", ",", "hse,hse", "covariate:",
                                                                            "covariate:nope", "warmup" * 50]))]),
        ("fit:--min-rate-dps", ["fit", "{T1}", *FIX, "--min-rate-dps", str(rng.choice(BAD_NUMBERS))]),
        ("compensate:--fit", ["compensate", "{T1}", "--fit", str(rng.choice(["{T1}", "/dev/null", "nofile.json",
                                                                            "{DIR}"])), "-o", "C.csv"]),
        ("simulate:--seed", ["simulate", "{PLAN}", "-o", "S.csv", "--seed", str(rng.choice(["-1", "abc", "1e3"]))]),
        ("simulate:--jobs", ["simulate", "{PLAN}", "-o", "S.csv", "--jobs", str(rng.choice(["0", "-2", "x"]))]),
        ("simulate:--truth", ["simulate", "{PLAN}", "-o", "S.csv", "--truth",
                              str(rng.choice(["/dev/zero", "nofile.toml", "{DIR}", "{PLAN}"]))]),
        ("design:--budget-h", ["design", "-o", "P2.csv", "--budget-h", str(rng.choice(BAD_NUMBERS))]),
        ("design:--rates", ["design", "-o", "P2.csv", "--rates", str(rng.choice(["60:20", "a:b", "0:10",
                                                                              "-5:5", "1e6:1e7", "nan:1"]))]),
        ("design:--latitude-deg", ["design", "--evaluate", "{PLAN}", "--latitude-deg",
                                   str(rng.choice(["90", "-91", "nan", "1e999"]))]),
        ("design:--criterion", ["design", "--evaluate", "{PLAN}", "--criterion", str(rng.choice(["X", "c:nope", "c:"]))]),
        ("design:--evaluate-o", ["design", "--evaluate", "{PLAN}", "-o", "P2.csv"]),
        ("diagnose:--alpha", ["diagnose", "{T1}", *FIX, "--alpha", str(rng.choice(["0", "1", "-1", "nan", "2"]))]),
        ("diagnose:--covariates", ["diagnose", "{T1}", *FIX, "--covariates", "nope"]),
        ("demo:--seed", ["demo", "--seed", str(rng.choice(["-1", "x", "1e3"])), "--out", "D"]),
        ("export:-o", ["export", "{FIT}", "-o", str(rng.choice(["{FIT}", "{T1}", "nodir/x", "/dev/null"]))]),
        ("align:logs", ["align", str(rng.choice(["{T1}", "nofile.npz", "{DIR}", "/dev/zero"])), "-o", "R.csv"]),
        ("calibrate:logs", ["calibrate", str(rng.choice(["{T1}", "nofile.npz", "{DIR}", "/dev/zero"])), "--out",
                            "CAL", "--no-progress"]),
        ("calibrate:numbers", ["calibrate", "{DIR}", "--out", str(rng.choice(["CAL", "{T1}", "{DIR}"])),
                               str(rng.choice(["--time-left-h", "--target-sigma", "--jobs", "--poll-s"])),
                               str(rng.choice(BAD_NUMBERS))]),
        ("any:-o", [str(rng.choice(["fit", "compensate", "simulate"])), "{IN}", "-o",
                    str(rng.choice(["{IN}", "{HARD}", "{SYM}", "nodir/x.csv", "{DIR}", "/dev/null", "", "x/"]))]),
    ]
    k = int(rng.integers(len(cases)))
    return cases[k]


# -- harness ---------------------------------------------------------------------------------
def snapshot(folder):
    return {str(p.relative_to(folder)): (hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir")
            for p in sorted(Path(folder).rglob("*")) if not p.is_symlink()}


def run_case(work, argv, outputs):
    """Run ``argv`` in ``work`` in-process and check every promise; returns the exit status."""
    before = snapshot(work)
    err, out = io.StringIO(), io.StringIO()
    cwd = os.getcwd()
    os.chdir(work)
    try:
        with redirect_stderr(err), redirect_stdout(out):
            code = main(argv)
    finally:
        os.chdir(cwd)
    text = err.getvalue()
    what = f"{argv}: exit {code}, stderr {text[-800:]!r}"
    assert "Traceback" not in text and "internal error" not in text, what
    assert code in (0, 2) or (code == 1 and re.search(r"status|did not converge", text)), what
    after = snapshot(work)
    assert not [p for p in after if TEMP_TAG in p], what
    for path, digest in before.items():  # inputs (every file that was there) unchanged
        if path not in outputs:
            assert after.get(path) == digest, f"{path} changed: {what}"
    if code != 0:
        assert after == before, f"partial output: {set(after) ^ set(before)}: {what}"
        lines = text.strip("\n").split("\n")
        # one line; align names each log it could not read, then says what it did
        assert len(lines) == 1 or argv[0] == "align", what
        assert all(line.startswith(f"hse-opt {argv[0]}") for line in lines), what
    else:
        assert all(o in after for o in outputs), what
    return code


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzzbase")
    (d / "T1.csv").write_bytes(Path(paper_table1_path()).read_bytes())
    rng = np.random.default_rng(1)
    sheet = ["run,rate_dps,azimuth_deg,heading_err_arcsec,latitude_deg,duration_s,t_start_s,temp_c"]
    for k in range(36):  # a real sheet's shape: four azimuths, three rates, three repeats, no sigma
        az, rate = (0, 90, 180, 270)[k // 9], (40, -40, 60)[(k // 3) % 3]
        sheet.append(f"{k + 1},{rate},{az},{rng.normal(0, 8):.2f},28.07,600,{(k + 1) * 700},{20 + k / 10:.1f}")
    (d / "SHEET.csv").write_text("\n".join(sheet) + "\n")
    (d / "PLAN.csv").write_text(PLAN)
    (d / "TRUTH.toml").write_text(TRUTH)
    (d / "PROJECT.toml").write_text(PROJECT)
    assert run_case(d, ["fit", "T1.csv", *FIX, "-o", "FIT.json"], {"FIT.json"}) == 0
    return d


@pytest.fixture
def work(base, tmp_path):
    for p in base.iterdir():
        (tmp_path / p.name).write_bytes(p.read_bytes())
    (tmp_path / "adir").mkdir()
    os.link(tmp_path / "T1.csv", tmp_path / "hard.csv")
    os.symlink("T1.csv", tmp_path / "sym.csv")
    return tmp_path


def _argv_for(kind, name):
    """The commands that read a mutated input file ``name``, and their outputs."""
    if kind == "csv-runs":
        return [(["fit", name, *FIX, "-o", "F2.json"], {"F2.json"}),
                (["compensate", name, "--fit", "FIT.json", "-o", "C.csv"], {"C.csv"}),
                (["fit", name, "--json"], set())]
    if kind == "csv-plan":
        return [(["simulate", name, "-o", "S.csv", "--no-progress", "--write-truth", "T2.toml"], {"S.csv", "T2.toml"}),
                (["design", "--evaluate", name, "--json"], set())]
    if kind == "toml":
        return [(["simulate", "PLAN.csv", "--truth", name, "-o", "S.csv", "--no-progress"], {"S.csv"})]
    if kind == "toml-project":
        return [(["config", "--config", name, "--json"], set()),
                (["fit", "T1.csv", *FIX, "--config", name, "-o", "F2.json"], {"F2.json"}),
                (["design", "--evaluate", "PLAN.csv", "--config", name, "--json"], set())]
    return [(["compensate", "T1.csv", "--fit", name, "-o", "C.csv"], {"C.csv"}),
            (["fit", "T1.csv", *FIX, "--prior", name], set()),
            (["export", name, "-o", "EXP"], {"EXP"}),
            (["design", "--evaluate", "PLAN.csv", "--prior", name], set())]


# (input kind, base file, mutation, cases per class in CI, seed)
FILE_CLASSES = [("csv-runs", "T1.csv", mutate_csv, 24, 11), ("csv-runs", "SHEET.csv", mutate_csv, 12, 12),
                ("csv-plan", "PLAN.csv", mutate_csv, 14, 13), ("toml", "TRUTH.toml", mutate_toml, 12, 14),
                ("toml-project", "PROJECT.toml", mutate_toml, 10, 17),
                ("json", "FIT.json", mutate_json, 14, 15), ("json", "FIT.json", tamper_json, 10, 18),
                ("csv-runs", "T1.csv", hostile_header, 6, 19)]
TALLY = Counter()


@pytest.mark.parametrize("kind, name, mutate, n, seed", FILE_CLASSES,
                         ids=[f"{k}-{n}" for k, n, *_ in FILE_CLASSES])
def test_malformed_files(work, kind, name, mutate, n, seed):
    rng = np.random.default_rng(seed)
    original = (work / name).read_text()
    for case in range(CASES or n):
        cls, data = mutate(original, rng)
        bad = f"bad_{case}{Path(name).suffix}"
        (work / bad).write_bytes(data)
        for argv, outputs in _argv_for(kind, bad)[int(rng.integers(len(_argv_for(kind, bad)))):][:1]:
            code = run_case(work, argv, outputs)
            TALLY[(cls, argv[0], code)] += 1
            assert code == 2 or not cls.startswith(MUST_REFUSE), f"{cls}: {argv} exit {code}"
            for o in outputs:  # the next case starts without this one's outputs
                p = work / o
                if p.is_dir():
                    import shutil
                    shutil.rmtree(p)
                elif p.exists():
                    p.unlink()
        (work / bad).unlink()


def test_malformed_options(work):
    rng = np.random.default_rng(16)
    names = {"{T1}": "T1.csv", "{PLAN}": "PLAN.csv", "{FIT}": "FIT.json", "{DIR}": "adir", "{HARD}": "hard.csv",
             "{SYM}": "sym.csv"}
    for case in range(CASES or 60):
        cls, argv = option_case(rng)
        names["{IN}"] = "PLAN.csv" if argv[0] == "simulate" else "T1.csv"
        extra = {"compensate": ["--fit", "FIT.json"], "fit": FIX}.get(argv[0], []) if cls == "any:-o" else []
        argv = [names.get(a, a) for a in argv] + extra
        outputs = {argv[i + 1] for i, a in enumerate(argv[:-1]) if a in ("-o", "--out", "--report")}
        code = run_case(work, argv, outputs)
        TALLY[(cls, argv[0], code)] += 1
        for o in outputs:
            p = work / o
            if p.is_file() and o not in ("T1.csv", "PLAN.csv", "FIT.json"):
                p.unlink()


def test_every_command_is_fuzzed():
    """The fuzz covers every registered command (a new command must be added here)."""
    fuzzed = {"fit", "compensate", "simulate", "design", "diagnose", "demo", "export", "align", "config",
              "calibrate"}
    assert set(COMMANDS) <= fuzzed, set(COMMANDS) - fuzzed


def teardown_module(module):
    if os.environ.get("HSE_FUZZ_CASES"):
        by_class = Counter()
        for (cls, cmd, code), k in sorted(TALLY.items()):
            by_class[(cls, code)] += k
        print("\nfuzz tally (class, exit status): count")
        for (cls, code), k in sorted(by_class.items()):
            print(f"  {cls:<28} {code}: {k}")
        print(f"  total {sum(TALLY.values())} commands")
