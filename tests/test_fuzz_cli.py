"""Fuzz test of the command line: malformed CSV, TOML and JSON inputs and options for every
command, from a seeded generator (each case is reproducible from its seed).

Every case asserts what a user is promised: exit status 0 or 2 (1 only with a solver's
status), no traceback and no internal error, a failure in one line naming what is wrong (the
file, row, column or option) and what is allowed (warning lines may come before it), the
inputs unchanged (checksums) and no partial output (the folder listing is the same as before
when the command fails; every output is there, with no temporary file, when it succeeds).
And no malformed input is a wrong answer in disguise: where a mutated input is accepted
(exit 0), the answer is the clean input's within its stated uncertainty, or a note, check or
warning the clean input does not get says what is different.

What is fuzzed is one registry: :data:`INPUTS` (each input file, how it is mutated, and the
commands that read it) and :data:`OPTION_CASES` (malformed options). A new command, or a new
input file kind, is one entry there; :func:`test_every_command_is_fuzzed` derives the
commands covered from the registry.

``HSE_FUZZ_CASES=N`` runs N cases per class instead of the CI size (the report's counts come
from ``HSE_FUZZ_CASES=60``).
"""
import csv
import hashlib
import io
import json
import os
import re
import shutil
from collections import Counter
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
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


#: values a TOML key may be given instead of its own
BAD_TOML_VALUES = ['"x"', '""', "nan", "inf", "-inf", "-1", "0", "1e999", "9" * 400, "[]", "{}", "true",
                   '[1, "a"]', "[[1, 2], [3]]", "[1, 2, 3, 4]", '"../../etc/passwd"', "1e-300"]


def mutate_toml(text, rng):
    kind = rng.choice(["unknown_key", "type", "big_int", "big_float", "nan", "range", "nesting", "syntax",
                       "duplicate", "harmonic", "bytes", "empty", "value", "value", "value", "drop"])
    keys = [k for k, line in enumerate(text.split("\n")) if re.match(r"^\s*\w+\s*=", line)]
    if kind in ("value", "drop") and keys:  # any file's keys: a value replaced, or a key left out
        lines = text.split("\n")
        k = keys[int(rng.integers(len(keys)))]
        key = lines[k].split("=", 1)[0]
        lines[k] = f"{key}= {rng.choice(BAD_TOML_VALUES)}" if kind == "value" else ""
        return "toml:" + kind, "\n".join(lines).encode()
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


def _pick(*values):
    return lambda rng: str(rng.choice(list(values)))


#: (class, argv template): ``{...}`` names the files the fixture provides, a callable draws a value
OPTION_CASES = [
    ("fit:--fix", ["fit", "{T1}", "--fix", _pick("lambda2", "=1", "nope=1", "offset=abc", "offset=nan",
                                                 "lambda2*tilt_const=1e999")]),
    ("fit:--fix-all", ["fit", "{T1}", "--fix", "offset=0", "--fix", "lambda2*tilt_cos=0", "--fix",
                       "lambda2*tilt_sin=0", "--fix", "lambda2*tilt_const=0"]),
    ("fit:--bound", ["fit", "{T1}", *FIX, "--bound", _pick("offset=1", "offset=5:1", "offset=a:b", "nope=0:1",
                                                         "offset=nan:1")]),
    ("fit:--effects", ["fit", "{T1}", *FIX, "--effects", _pick("nope", ",", "hse,hse", "covariate:", "covariate:nope",
                                                             "warmup" * 50, "covariate:temp c")]),
    ("fit:--min-rate-dps", ["fit", "{T1}", *FIX, "--min-rate-dps", _pick(*BAD_NUMBERS)]),
    ("compensate:--fit", ["compensate", "{T1}", "--fit", _pick("{T1}", "/dev/null", "nofile.json", "{DIR}"),
                          "-o", "C.csv"]),
    ("simulate:--seed", ["simulate", "{PLAN}", "-o", "S.csv", "--seed", _pick("-1", "abc", "1e3")]),
    ("simulate:--jobs", ["simulate", "{PLAN}", "-o", "S.csv", "--jobs", _pick("0", "-2", "x")]),
    ("simulate:--truth", ["simulate", "{PLAN}", "-o", "S.csv", "--truth", _pick("/dev/zero", "nofile.toml", "{DIR}",
                                                                              "{PLAN}")]),
    ("simulate:--dask", ["simulate", "{PLAN}", "-o", "S.csv", "--dask", _pick("not an address", "", "tcp://:0")]),
    ("design:--budget-h", ["design", "-o", "P2.csv", "--budget-h", _pick(*BAD_NUMBERS)]),
    ("design:--rates", ["design", "-o", "P2.csv", "--rates", _pick("60:20", "a:b", "0:10", "-5:5", "1e6:1e7",
                                                                  "nan:1")]),
    ("design:--latitude-deg", ["design", "--evaluate", "{PLAN}", "--latitude-deg", _pick("90", "-91", "nan",
                                                                                         "1e999")]),
    ("design:--arw-dph-rthz", ["design", "--evaluate", "{PLAN}", "--arw-dph-rthz", _pick(*BAD_NUMBERS)]),
    ("design:--times", ["design", "--evaluate", "{PLAN}", _pick("--warmup-s", "--azimuth-change-s", "--floor-arcsec",
                                                                "--rate-change-s"), _pick("-1", "nan", "inf", "1e9")]),
    ("design:--criterion", ["design", "--evaluate", "{PLAN}", "--criterion", _pick("X", "c:nope", "c:")]),
    ("design:--evaluate-o", ["design", "--evaluate", "{PLAN}", "-o", "P2.csv"]),
    ("diagnose:--alpha", ["diagnose", "{T1}", *FIX, "--alpha", _pick("0", "1", "-1", "nan", "2")]),
    ("diagnose:--covariates", ["diagnose", "{T1}", *FIX, "--covariates", _pick("nope", "", ",")]),
    ("demo:--seed", ["demo", "--seed", _pick("-1", "x", "1e3"), "--out", "D"]),
    ("export:-o", ["export", "{FIT}", "-o", _pick("{FIT}", "{T1}", "nodir/x", "/dev/null")]),
    ("align:logs", ["align", _pick("{T1}", "nofile.npz", "{DIR}", "/dev/zero"), "-o", "R.csv"]),
    ("align:--mapping", ["align", "logs", "-o", "R.csv", "--mapping", _pick("nofile.toml", "{T1}", "{DIR}",
                                                                              "/dev/zero", "{TRUTH}")]),
    ("align:--latitude-deg", ["align", "logs", "-o", "R.csv", "--latitude-deg", _pick("90", "nan", "-1e9")]),
    ("config:--config", ["config", "--config", _pick("nofile.toml", "{DIR}", "{T1}", "/dev/zero")]),
    ("calibrate:logs", ["calibrate", _pick("{T1}", "nofile.npz", "{DIR}", "/dev/zero"), "--out", "CAL",
                        "--no-progress"]),
    ("calibrate:numbers", ["calibrate", "{DIR}", "--out", _pick("CAL", "{T1}", "{DIR}"),
                           _pick("--time-left-h", "--target-sigma", "--jobs", "--poll-s"), _pick(*BAD_NUMBERS)]),
    ("any:-o", [_pick("fit", "compensate", "simulate"), "{IN}", "-o",
                _pick("{IN}", "{HARD}", "{SYM}", "nodir/x.csv", "{DIR}", "/dev/null", "", "x/")]),
]


def option_case(rng):
    """(class, argv) of an option mutation; ``{...}`` names the files the fixture provides."""
    cls, template = OPTION_CASES[int(rng.integers(len(OPTION_CASES)))]
    return cls, [a(rng) if callable(a) else a for a in template]


# -- harness ---------------------------------------------------------------------------------
def snapshot(folder):
    return {str(p.relative_to(folder)): (hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir")
            for p in sorted(Path(folder).rglob("*")) if not p.is_symlink()}


#: an error line names a file (a path with a suffix, or a folder given), an option, or a
#: parameter; these are the words that do
_NAMES = re.compile(r"(\S+\.(csv|json|toml|npz|txt|dat)\b|(^|[\s(])--?[a-z]|\blogs?\b|parameters?\b|"
                    r"\bcolumn\b|\brow\b|\bline\b|/dev/|\badir\b|\bD\b|\bnodir\b|\bEXP\b|positions?\b)")


def run_case(work, argv, outputs):
    """Run ``argv`` in ``work`` in-process and check every promise; returns (exit status,
    stdout, stderr)."""
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
    lines = text.strip("\n").split("\n") if text.strip() else []
    assert all(line.startswith(f"hse-opt {argv[0]}") or line.startswith("  ") for line in lines), what
    if code != 0:
        assert after == before, f"partial output: {set(after) ^ set(before)}: {what}"
        # one error line after any warnings; align names each log it could not read, then says
        # what it did
        errors = [line for line in lines if ": warning: " not in line]
        assert len(errors) == 1 or argv[0] == "align", what
        if code == 2:
            assert all("allowed" in line for line in errors if "error:" in line), what
            assert all(_NAMES.search(line) for line in errors), what
    else:
        assert all(o in after for o in outputs), what
    return code, out.getvalue(), text


# -- what each input is, how it is mutated, which commands read it -------------------------------
@dataclass(frozen=True)
class Target:
    """A command that reads the mutated input ``{IN}``: its argv, its outputs and, for a
    command whose answer is comparable, how to read the answer (:data:`ANSWERS`)."""

    argv: tuple
    outputs: tuple = ()
    answer: str = ""


@dataclass(frozen=True)
class Input:
    """An input file of the fixture (:func:`base`), its mutation, the commands that read it,
    and the CI size and seed of its cases."""

    name: str
    mutate: object
    targets: tuple
    cases: int
    seed: int


def _fit_answer(out, stdout):
    """(value, std, notes) per parameter of a ``fit --json`` output."""
    d = json.loads(stdout)
    return ({k: (p["value"], p["std"]) for k, p in d["parameters"].items()},
            set(d["notes"]) | {json.dumps(c, sort_keys=True) for c in d.get("checks", []) + d.get("outliers", [])})


def _align_answer(out, stdout):
    """(heading, its sigma) per run of an ``align`` output, and the quality notes."""
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return ({r["run"]: (float(r["heading_deg"]) * 3600, float(r["heading_std_arcsec"])) for r in rows},
            {r.get("quality", "") for r in rows} - {"ok", ""})


#: how an answer is read: name -> function(output path, stdout) -> ({key: (value, sigma)}, notes)
ANSWERS = {"fit": _fit_answer, "align": _align_answer}

RUNS_TARGETS = (Target(("fit", "{IN}", *FIX, "-o", "F2.json"), ("F2.json",)),
                Target(("compensate", "{IN}", "--fit", "FIT.json", "-o", "C.csv"), ("C.csv",)),
                Target(("fit", "{IN}", *FIX, "--json"), answer="fit"),
                Target(("diagnose", "{IN}", *FIX, "--json")))
FIELD_TARGETS = (Target(("fit", "{IN}", "--json"), answer="fit"),
                 Target(("diagnose", "{IN}", "--json")),
                 Target(("compensate", "{IN}", "--fit", "FIELD_FIT.json", "-o", "C.csv"), ("C.csv",)))
FIT_TARGETS = (Target(("compensate", "T1.csv", "--fit", "{IN}", "-o", "C.csv"), ("C.csv",)),
               Target(("fit", "T1.csv", *FIX, "--prior", "{IN}")),
               Target(("export", "{IN}", "-o", "EXP"), ("EXP",)),
               Target(("design", "--evaluate", "PLAN.csv", "--prior", "{IN}")))

INPUTS = (
    Input("T1.csv", mutate_csv, RUNS_TARGETS, 30, 11),
    Input("SHEET.csv", mutate_csv, RUNS_TARGETS, 16, 12),
    Input("FIELD.csv", mutate_csv, FIELD_TARGETS, 24, 22),
    Input("PLAN.csv", mutate_csv, (Target(("simulate", "{IN}", "-o", "S.csv", "--no-progress", "--write-truth",
                                           "T2.toml"), ("S.csv", "T2.toml")),
                                   Target(("design", "--evaluate", "{IN}", "--json"))), 14, 13),
    Input("FIELD_PLAN.csv", mutate_csv, (Target(("simulate", "{IN}", "--field", "-o", "S.csv", "--no-progress"),
                                                ("S.csv",)),
                                         Target(("design", "--evaluate", "{IN}", "--field", "--json"))), 8, 23),
    Input("TRUTH.toml", mutate_toml, (Target(("simulate", "PLAN.csv", "--truth", "{IN}", "-o", "S.csv",
                                              "--no-progress"), ("S.csv",)),), 14, 14),
    Input("PROJECT.toml", mutate_toml, (Target(("config", "--config", "{IN}", "--json")),
                                        Target(("fit", "T1.csv", *FIX, "--config", "{IN}", "-o", "F2.json"),
                                               ("F2.json",)),
                                        Target(("design", "--evaluate", "PLAN.csv", "--config", "{IN}",
                                                "--json"))), 10, 17),
    Input("FIT.json", mutate_json, FIT_TARGETS, 14, 15),
    Input("FIT.json", tamper_json, FIT_TARGETS, 10, 18),
    Input("T1.csv", hostile_header, RUNS_TARGETS, 6, 19),
    Input("FIELD_FIT.json", mutate_json, (Target(("export", "{IN}", "-o", "EXP"), ("EXP",)),
                                          Target(("compensate", "FIELD.csv", "--fit", "{IN}", "-o", "C.csv"),
                                                 ("C.csv",))), 8, 20),
    Input("CAL.toml", mutate_toml, (Target(("align", "logs", "--calibration", "{IN}", "-o", "R.csv", "--no-progress"),
                                           ("R.csv",)),), 14, 24),
    Input("MAP.toml", mutate_toml, (Target(("align", "stand", "--mapping", "{IN}", "-o", "R.csv", "--no-progress"),
                                           ("R.csv",)),), 14, 25),
    Input("logs/run_1.csv", mutate_csv, (Target(("align", "logs", "-o", "R.csv", "--no-progress"), ("R.csv",),
                                                answer="align"),
                                         Target(("calibrate", "logs", "--out", "CAL", "--no-progress"), ("CAL",))),
          10, 21),
)
FIELD_PLAN = [("A", 37.0, 150, -400), ("B", 212.0, -300, 250)]


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
    # a field campaign (the README's two positions without a reference), its fit
    plan = ["run,rate_dps,azimuth_deg,t_start_s,duration_s,tilt_x_arcsec,tilt_y_arcsec,position"]
    for label, heading, tx, ty in FIELD_PLAN:
        for rate in (20, 60, -40, 20, 60, -40):
            plan.append(f"{len(plan)},{rate},{heading},{3600 + 360 * len(plan)},300,{tx},{ty},{label}")
    (d / "FIELD_PLAN.csv").write_text("\n".join(plan) + "\n")
    assert run_case(d, ["simulate", "FIELD_PLAN.csv", "--field", "-o", "FIELD.csv", "--seed", "3", "--no-progress"],
                    {"FIELD.csv"})[0] == 0
    assert run_case(d, ["fit", "T1.csv", *FIX, "-o", "FIT.json"], {"FIT.json"})[0] == 0
    assert run_case(d, ["fit", "FIELD.csv", "-o", "FIELD_FIT.json"], {"FIELD_FIT.json"})[0] == 0
    # a raw log as a CSV file (12 s at 500 Hz, two table turns), in a folder of its own
    from hse_opt import units
    from hse_opt.sim import RunSpec, TruthConfig, generate, save_rawlog
    log = generate(TruthConfig.default(), RunSpec(rate=60 * units.DEG_PER_S, azimuth=np.radians(33.0),
                                                  duration=12.0, t_start=600.0), np.random.default_rng(2))
    object.__setattr__(log, "meta", {"latitude_deg": 28.07, "azimuth_deg": 33.0, "run": 1, "t_start_s": 600.0})
    (d / "logs").mkdir()
    save_rawlog(log, d / "logs" / "run_1.csv")
    # the lab calibration file and a stand's own CSV with its mapping file (the second example)
    from hse_opt.align.mapping import example_mapping
    from hse_opt.datasets import __file__ as datasets
    (d / "CAL.toml").write_bytes((Path(datasets).parent / "calibration_example.toml").read_bytes())
    (d / "MAP.toml").write_bytes(Path(example_mapping("rate_stand")).read_bytes())
    (d / "stand").mkdir()
    from test_align_mapping import _rate_stand_csv   # the stand's format, written by that test's helper
    _rate_stand_csv(log, d / "stand" / "run_1.csv")
    return d


@pytest.fixture
def work(base, tmp_path):
    shutil.copytree(base, tmp_path, dirs_exist_ok=True)
    (tmp_path / "adir").mkdir()
    os.link(tmp_path / "T1.csv", tmp_path / "hard.csv")
    os.symlink("T1.csv", tmp_path / "sym.csv")
    return tmp_path


TALLY = Counter()
#: the clean input's answer per (input, target): computed once
_CLEAN = {}


def _remove(work, outputs):
    for o in outputs:  # the next case starts without this one's outputs
        p = work / o
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()


def _answer(work, target, stdout):
    out = next((work / o for o in target.outputs), None)
    return ANSWERS[target.answer](out, stdout)


def _unsaid(clean, mutated, stderr):
    """The parameters (or runs) whose answer moved beyond the stated uncertainty with no new
    note, check or warning to say so; [] when every difference is explained."""
    (v0, notes0), (v1, notes1) = clean, mutated
    number = re.compile(r"[-+]?\d[\d.e+-]*")
    new = {number.sub("#", n) for n in notes1} - {number.sub("#", n) for n in notes0}
    if new or ": warning: " in stderr:
        return []
    moved = []
    for key in v0.keys() & v1.keys():
        (a, sa), (b, sb) = v0[key], v1[key]
        if abs(b - a) > max(sa, sb, 1e-9 * max(abs(a), 1.0)):
            moved.append(f"{key}: {a:.6g} +- {sa:.3g} -> {b:.6g} +- {sb:.3g}")
    return moved


@pytest.mark.parametrize("spec", INPUTS, ids=[f"{i.name}-{i.seed}" for i in INPUTS])
def test_malformed_files(work, spec):
    rng = np.random.default_rng(spec.seed)
    path = work / spec.name
    original = path.read_text()
    for case in range(CASES or spec.cases):
        cls, data = spec.mutate(original, rng)
        target = spec.targets[int(rng.integers(len(spec.targets)))]
        if "/" in spec.name:  # a file inside a folder the command reads: mutated in place
            bad, restore = path, True
        else:
            bad, restore = work / f"bad_{case}{path.suffix}", False
        bad.write_bytes(data)
        argv = [str(bad.relative_to(work)) if a == "{IN}" else a for a in target.argv]
        try:
            code, stdout, stderr = run_case(work, argv, set(target.outputs))
            TALLY[(cls, argv[0], code)] += 1
            assert code == 2 or not cls.startswith(MUST_REFUSE), f"{cls}: {argv} exit {code}"
            if code == 0 and target.answer:
                key = (spec.name, target.argv)
                if key not in _CLEAN:
                    bad.write_text(original)
                    _remove(work, target.outputs)
                    c0, out0, _ = run_case(work, [str(path.relative_to(work)) if a == "{IN}" else a
                                                  for a in target.argv], set(target.outputs))
                    assert c0 == 0
                    _CLEAN[key] = _answer(work, target, out0)
                    _remove(work, target.outputs)
                    bad.write_bytes(data)
                    code, stdout, stderr = run_case(work, argv, set(target.outputs))
                moved = _unsaid(_CLEAN[key], _answer(work, target, stdout), stderr)
                assert not moved, f"{cls} {argv}: exit 0, the answer moved without a note: {moved}"
        finally:
            _remove(work, target.outputs)
            if restore:
                bad.write_text(original)
            else:
                bad.unlink()


def test_malformed_options(work):
    rng = np.random.default_rng(16)
    names = {"{T1}": "T1.csv", "{PLAN}": "PLAN.csv", "{FIT}": "FIT.json", "{DIR}": "adir", "{HARD}": "hard.csv",
             "{SYM}": "sym.csv", "{TRUTH}": "TRUTH.toml"}
    for case in range(CASES or 100):
        cls, argv = option_case(rng)
        names["{IN}"] = "PLAN.csv" if argv[0] == "simulate" else "T1.csv"
        extra = {"compensate": ["--fit", "FIT.json"], "fit": FIX}.get(argv[0], []) if cls == "any:-o" else []
        argv = [names.get(a, a) for a in argv] + extra
        outputs = {argv[i + 1] for i, a in enumerate(argv[:-1]) if a in ("-o", "--out", "--report")}
        code = run_case(work, argv, outputs)[0]
        TALLY[(cls, argv[0], code)] += 1
        for o in outputs:
            p = work / o
            if p.is_file() and o not in ("T1.csv", "PLAN.csv", "FIT.json"):
                p.unlink()


def test_every_command_is_fuzzed():
    """The registry covers every registered command: a new command is one entry in
    :data:`INPUTS` or :data:`OPTION_CASES`."""
    fuzzed = {t.argv[0] for i in INPUTS for t in i.targets}
    fuzzed |= {template[0] for _, template in OPTION_CASES if isinstance(template[0], str)}
    fuzzed |= {v for _, template in OPTION_CASES if callable(template[0])
               for v in ("fit", "compensate", "simulate")}
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
