"""The diagnosis studies run and pass their own assertions (issue 6, items 6-8), at their CI
size (``--full`` in the error-rate study, ``--seeds N`` in the hidden-effect study for the
documented figures); a RuntimeWarning in them is an error."""
import subprocess
import sys
from pathlib import Path

import pytest

STUDIES = Path(__file__).resolve().parents[1] / "studies"


@pytest.mark.parametrize("script", [
    "paper_table1_diagnosis.py",
    pytest.param("diagnose_error_rates.py", marks=pytest.mark.slow),
    pytest.param("diagnose_hidden_effects.py", marks=pytest.mark.slow),
])
def test_study(script):
    out = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", str(STUDIES / script)],
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    assert "\nOK:" in out.stdout
