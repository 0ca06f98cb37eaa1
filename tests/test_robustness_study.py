"""The robustness study (issue 24 item 7) runs at its CI size and meets its target: natural
campaigns with each catalogue effect hidden at a plausible size end confidently wrong
(adequate, the true lambda2 outside value +- (2 sigma + systematic)) in <= 5 % of cases."""
import re
import subprocess
import sys
from pathlib import Path

STUDY = Path(__file__).resolve().parents[1] / "studies" / "robustness.py"


def test_robustness_study_meets_its_target_at_ci_size():
    out = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", str(STUDY), "--campaigns", "4"],
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    m = re.search(r"in all: (\d+) campaigns; confidently wrong before (\d+) .*after (\d+) ", out.stdout)
    n, before, after = map(int, m.groups())
    assert n == 56 and after <= 0.05 * n
    # every hidden effect and the no-effect baseline, both kinds, each with its tally
    assert len(re.findall(r"^  (stand|field) ", out.stdout, flags=re.M)) == 14
