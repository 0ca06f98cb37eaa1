import json
import subprocess
import sys

from hse_opt.cli import main


def test_demo_json_matches_the_paper(capsys):
    assert main(["demo", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert abs(out["k_hse_model_arcsec_per_radps"] - 17.4) < 0.01
    assert 25 < out["example_amplitude_model"] < 35


def test_console_script_help():
    out = subprocess.run([sys.executable, "-m", "hse_opt.cli", "demo", "--help"], capture_output=True,
                         text=True)
    assert out.returncode == 0 and "example: hse-opt demo" in out.stdout
    bad = subprocess.run([sys.executable, "-m", "hse_opt.cli", "frobnicate"], capture_output=True, text=True)
    assert bad.returncode == 2 and "invalid choice: 'frobnicate'" in bad.stderr
