"""Every code block in the README runs.

The blocks run top to bottom in one temporary working directory, as a reader would run them.
Each python block runs on its own, as if pasted alone into a new interpreter: a fresh
namespace (it imports and loads what it needs; files the blocks above wrote are there, as
in the reader's directory). Bash blocks run line by line with this interpreter's
``python`` and ``hse-opt`` first on the PATH. A bash line may end with ``# exit N`` to state the exit status it shows, or with
``# needs a C compiler`` (skipped when there is none). A C block whose first line is a
comment naming a file (``/* NAME.c: ...``) is written to that file in the shared directory,
for the bash lines that follow to compile and run. The quick-start block is what
``.ci/run`` runs on a fresh clone; a block preceded by ``<!-- not run: REASON -->`` is
skipped here (the reason says which test covers it).
"""
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from hse_opt.model import effects
from hse_opt.validation import twins

README = Path(__file__).resolve().parents[1] / "README.md"
_BLOCK = re.compile(r"(<!-- [^>]*-->\s*)?```(python|bash|c)\n(.*?)```", flags=re.S)
COMPILER = shutil.which("cc")


def _blocks():
    """``[(language, code)]`` of the blocks to run, in the README's order."""
    out = []
    for m in _BLOCK.finditer(README.read_text(encoding="utf-8")):
        marker = m.group(1) or ""
        if "quickstart" not in marker and "not run:" not in marker:
            out.append((m.group(2), m.group(3)))
    return out


@pytest.mark.slow
def test_readme_blocks_run_top_to_bottom(tmp_path, monkeypatch):
    blocks = _blocks()
    assert sum(lang == "python" for lang, _ in blocks) >= 4
    assert any(lang == "bash" and "hse-opt" in code for lang, code in blocks)
    shared = tmp_path
    monkeypatch.chdir(shared)
    bindir = Path(sys.executable).parent
    env = {**os.environ, "PATH": f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}"}
    # the README declares an effect: the catalogue and the twin map are as before afterwards
    saved = [(registry, dict(registry)) for registry in (effects.CATALOGUE, twins.TWINS)]
    try:
        for k, (lang, code) in enumerate(blocks):
            if lang == "python":  # on its own: a fresh namespace
                exec(compile(code, f"{README} (block {k})", "exec"), {"__name__": "__main__"})
                continue
            if lang == "c":
                name = re.match(r"/\*\s*(\w+\.c):", code)
                assert name, f"a C block must start with /* NAME.c: ...\n{code[:200]}"
                (shared / name.group(1)).write_text(code, encoding="utf-8")
                continue
            for line in (ln.strip() for ln in code.splitlines()):
                if not line or line.startswith("#") or (COMPILER is None and line.endswith("# needs a C compiler")):
                    continue
                m = re.search(r"#\s*exit\s+(\d+)\s*$", line)
                out = subprocess.run(["bash", "-c", line], cwd=shared, env=env, capture_output=True,
                                     text=True, timeout=300)
                assert out.returncode == (int(m.group(1)) if m else 0), f"{line}\n{out.stderr[-2000:]}"
    finally:
        for registry, before in saved:
            registry.clear()
            registry.update(before)


def test_quickstart_is_the_two_commands_ci_runs():
    m = re.search(r"<!-- quickstart -->\s*```bash\n(.*?)```\s*<!-- /quickstart -->",
                  README.read_text(encoding="utf-8"), flags=re.S)
    assert m and m.group(1).splitlines() == ["pip install . && hse-opt demo",
                                            "pip install -e '.[test]' && python -m pytest"]


def test_every_skipped_block_says_why():
    for m in _BLOCK.finditer(README.read_text(encoding="utf-8")):
        marker = m.group(1) or ""
        if "not run:" in marker:
            assert re.search(r"not run: \S.{8,}", marker), marker


def test_readme_quotes_what_fit_prints_for_table1(capsys):
    """The tutorial says what ``hse-opt fit table1.csv`` prints for the heading-sensitive
    sinusoid; the quote is the command's own line (it said 3.27 where the fit prints 3.28)."""
    from hse_opt.cli import main as cli
    from hse_opt.datasets import paper_table1_path

    quote = re.search(r'it prints "(amplitude [^"]+)"', README.read_text(encoding="utf-8")).group(1)
    assert cli(["fit", str(paper_table1_path())]) == 0
    out = capsys.readouterr().out
    assert f"sinusoid lambda2 * C23 (tilt unknown): {quote}" in out
