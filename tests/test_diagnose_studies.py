"""The diagnosis studies run and pass their own assertions (issue 6, items 6-8)."""
import subprocess
import sys
from pathlib import Path

import pytest

STUDIES = Path(__file__).resolve().parents[1] / "studies"


@pytest.mark.parametrize("script", [
    "paper_table1_diagnosis.py",
    pytest.param("diagnose_error_rates.py", marks=pytest.mark.slow),
    # strict=False: the study's pass/fail is fragile at any seed (a 15 % noise tolerance is
    # ~1.7 standard errors at 64 runs, and 9 campaigns each take p < 0.05 decisions): it passes
    # or fails by seed on the simulator's current default system. Open in issue 6 (make the
    # criteria robust: several seeds, tolerances from the sampling error).
    pytest.param("diagnose_hidden_effects.py", marks=[
        pytest.mark.slow,
        pytest.mark.xfail(reason="hidden-effect study criteria are seed-fragile (see comment); "
                                 "issue 6 item 7 open", strict=False)]),
])
def test_study(script):
    out = subprocess.run([sys.executable, str(STUDIES / script)], capture_output=True, text=True,
                         timeout=900)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    assert "\nOK:" in out.stdout
