"""studies/paper_table1.py runs, ends in its assertions and prints its figures."""
import subprocess
import sys
from pathlib import Path


def test_paper_table1_study():
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run([sys.executable, str(root / "studies" / "paper_table1.py")],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "peak-to-peak before 40.50, after 28.50" in out.stdout
    assert "OK: Table 1 reproduced" in out.stdout
