"""``hse-opt --version`` and output into a closed pipe (``hse-opt ... | head``): the command
ends quietly (nothing on stderr) with exit status 0."""
import os
import subprocess
import sys

import pytest

from hse_opt import __version__
from hse_opt.datasets import paper_table1_path


def _run(args, stdout):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    return subprocess.run([sys.executable, "-m", "hse_opt.cli", *args], stdout=stdout,
                          stderr=subprocess.PIPE, text=True, env=env, timeout=120)


def test_version():
    out = _run(["--version"], subprocess.PIPE)
    assert out.returncode == 0 and out.stdout.strip() == f"hse-opt {__version__}"


@pytest.mark.parametrize("args", [
    ["--help"],
    ["fit", "--help"],
    ["fit", str(paper_table1_path()), "--fix", "lambda2*tilt_const=0"],
    ["fit", str(paper_table1_path()), "--fix", "lambda2*tilt_const=0", "--json"],
])
def test_closed_pipe_ends_quietly(args):
    r, w = os.pipe()
    os.close(r)                  # the reader is gone before the first byte: every write fails
    try:
        out = _run(args, w)
    finally:
        os.close(w)
    # quiet: no error, no traceback (the fit's own warnings, e.g. its systematic risks, may stand)
    assert out.returncode == 0 and all(": warning: " in ln for ln in out.stderr.splitlines()), out.stderr
    # and the same command into an open pipe prints (so the quiet end is not silence always)
    assert _run(args, subprocess.PIPE).stdout.strip()
