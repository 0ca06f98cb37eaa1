import subprocess
import sys


def test_console_script_help():
    out = subprocess.run([sys.executable, "-m", "hse_opt.cli", "demo", "--help"], capture_output=True,
                         text=True)
    assert out.returncode == 0 and "example: hse-opt demo" in out.stdout
    bad = subprocess.run([sys.executable, "-m", "hse_opt.cli", "frobnicate"], capture_output=True, text=True)
    assert bad.returncode == 2 and "invalid choice: 'frobnicate'" in bad.stderr
