"""Every code block in the README runs.

Python blocks run in order in one namespace (the tutorial builds on itself), in a temporary
working directory. Bash blocks run line by line in another temporary directory, in order,
with this interpreter's ``python`` and ``hse-opt`` first on the PATH; a line may end with
``# exit N`` to state the exit status it shows. The quick-start block is what ``.ci/run``
runs on a fresh clone; a block preceded by ``<!-- not run: REASON -->`` is skipped here
(the reason says which test covers it).
"""
import os
import re
import subprocess
import sys
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"
_BLOCK = re.compile(r"(<!-- [^>]*-->\s*)?```(python|bash)\n(.*?)```", flags=re.S)


def _blocks(lang):
    out = []
    for m in _BLOCK.finditer(README.read_text(encoding="utf-8")):
        marker = m.group(1) or ""
        if m.group(2) == lang and "quickstart" not in marker and "not run:" not in marker:
            out.append(m.group(3))
    return out


def test_readme_python_blocks_run(tmp_path, monkeypatch):
    blocks = _blocks("python")
    assert len(blocks) >= 4
    monkeypatch.chdir(tmp_path)
    namespace = {}
    for code in blocks:
        exec(compile(code, str(README), "exec"), namespace)


def test_readme_bash_blocks_run(tmp_path):
    lines = [ln.strip() for block in _blocks("bash") for ln in block.splitlines()]
    lines = [ln for ln in lines if ln and not ln.startswith("#")]
    assert any(ln.startswith("hse-opt") for ln in lines)
    bindir = Path(sys.executable).parent
    env = {**os.environ, "PATH": f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}"}
    for line in lines:
        m = re.search(r"#\s*exit\s+(\d+)\s*$", line)
        expect = int(m.group(1)) if m else 0
        out = subprocess.run(["bash", "-c", line], cwd=tmp_path, env=env, capture_output=True,
                             text=True, timeout=300)
        assert out.returncode == expect, f"{line}\n{out.stderr[-2000:]}"


def test_quickstart_is_the_two_commands_ci_runs():
    m = re.search(r"<!-- quickstart -->\s*```bash\n(.*?)```\s*<!-- /quickstart -->",
                  README.read_text(encoding="utf-8"), flags=re.S)
    assert m and m.group(1).splitlines() == ["pip install . && hse-opt demo",
                                            "pip install '.[test]' && python -m pytest"]


def test_every_skipped_block_says_why():
    for m in _BLOCK.finditer(README.read_text(encoding="utf-8")):
        marker = m.group(1) or ""
        if "not run:" in marker:
            assert re.search(r"not run: \S.{8,}", marker), marker
