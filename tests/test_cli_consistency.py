"""The command line is consistent: every command has ``--help`` with an example, usage errors
are one line with exit status 2, and every command that reports numbers has ``--json``."""
import re
import subprocess
import sys

import pytest

from hse_opt.cli import COMMANDS

#: commands whose output is numbers (the rest write files)
REPORT_NUMBERS = {"demo", "fit", "design", "diagnose"}


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "hse_opt.cli", *args], capture_output=True,
                          text=True, timeout=120)


def test_top_level_help_lists_every_command():
    out = _cli("--help")
    assert out.returncode == 0
    for name in COMMANDS:
        assert re.search(rf"^\s+{name}\s+\S", out.stdout, flags=re.M), name


@pytest.mark.parametrize("name", COMMANDS)
def test_every_command_has_help_with_an_example(name):
    out = _cli(name, "--help")
    assert out.returncode == 0 and out.stderr == ""
    m = re.search(r"^examples?:", out.stdout, flags=re.M)
    assert m and re.search(rf"\bhse-opt {name}\b", out.stdout[m.end():])
    if name in REPORT_NUMBERS:
        assert "--json" in out.stdout


@pytest.mark.parametrize("name", COMMANDS)
def test_usage_errors_are_one_line_with_status_2(name):
    out = _cli(name, "--no-such-option")
    assert out.returncode == 2 and out.stdout == ""
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith(f"hse-opt {name}: error: ")
    assert lines[0].endswith(f"(see 'hse-opt {name} --help')")


def test_json_stdout_keeps_stray_output_off_stdout():
    """Output written straight to file descriptor 1 (as C solvers do) goes to stderr while a
    --json command runs; stdout holds the JSON object only."""
    code = ("import os; from hse_opt.cli import json_stdout; from hse_opt.commands import print_json\n"
            "with json_stdout():\n"
            "    os.write(1, b'ERROR: could not determine problem status.\\n')\n"
            "    print_json({'a': 1})\n"
            "print('after')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0
    assert out.stdout == '{\n  "a": 1\n}\nafter\n'
    assert "could not determine problem status" in out.stderr


@pytest.mark.parametrize("args, names", [
    (["fit", "no_such_file.csv"], "no_such_file.csv"),
    (["diagnose", "no_such_file.csv"], "no_such_file.csv"),
    (["compensate", "RUNS.csv", "--fit", "no_such_fit.json", "-o", "O.csv"], "no_such_fit.json"),
    (["simulate", "no_such_plan.csv", "-o", "R.csv"], "no_such_plan.csv"),
    (["design", "--evaluate", "no_such_plan.csv"], "no_such_plan.csv"),
    (["fit", "RUNS.csv", "--effects", "no_such_effect"], "no_such_effect"),
    (["fit", "RUNS.csv", "--bound", "lambda2=1"], "--bound"),
    (["design", "--budget-h", "-1", "-o", "P.csv"], "--budget-h -1"),
    (["design", "--max-tilt-arcsec", "-5", "-o", "P.csv"], "--max-tilt-arcsec -5"),
    (["design", "--seed", "-1", "-o", "P.csv"], "--seed -1"),
    (["demo", "--seed", "-1"], "--seed -1"),
])
def test_bad_input_is_one_line_naming_it_with_status_2(tmp_path, args, names):
    from hse_opt.datasets import paper_table1_path
    (tmp_path / "RUNS.csv").write_bytes(paper_table1_path().read_bytes())
    out = subprocess.run([sys.executable, "-m", "hse_opt.cli", *args], capture_output=True, text=True,
                         timeout=120, cwd=tmp_path)
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 2 and out.stdout == "" and len(lines) == 1, out.stderr
    assert lines[0].startswith(f"hse-opt {args[0]}: error: ") and names in lines[0], lines[0]
