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
