"""The field-calibration study runs at its CI size and passes its own assertions (issue 13,
item 6: lambda2 recovered without a reference, z-RMS in [0.85, 1.15] over 100 simulated
field campaigns); a RuntimeWarning in it is an error."""
import subprocess
import sys
from pathlib import Path

import pytest

STUDY = Path(__file__).resolve().parents[1] / "studies" / "field_calibration.py"


@pytest.mark.slow
def test_field_calibration_study():
    out = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", str(STUDY)],
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    assert "\nOK:" in out.stdout and "z-scores: RMS" in out.stdout
