"""The project's own docs (``docs/``): what the code cites exists in the repository, and the
format contract names the columns the loaders read."""
import re
from pathlib import Path

from hse_opt.data import Plan, Runs

ROOT = Path(__file__).resolve().parents[1]
SOURCES = [p for d in ("hse_opt", "tests", "studies", "benchmarks") for p in (ROOT / d).rglob("*.py")]


def test_code_cites_the_repositorys_docs_only():
    outside = re.compile(r"\b(DESIGN|PHYSICS)\.md\b")
    cited = set()
    for path in SOURCES + [ROOT / "README.md"]:
        text = path.read_text(encoding="utf-8")
        assert not outside.search(text), f"{path.relative_to(ROOT)} cites a file outside the repository"
        cited |= set(re.findall(r"docs/[\w.-]+\.md", text))
    assert {"docs/conventions.md", "docs/formats.md", "docs/architecture.md"} <= cited
    for doc in cited:
        assert (ROOT / doc).is_file(), doc


def _table_columns(section):
    """Backticked first cells of the markdown table under ``section`` in docs/formats.md."""
    text = (ROOT / "docs" / "formats.md").read_text(encoding="utf-8")
    block = text[text.index(section):]
    rows = re.findall(r"^\| (.+?) \|", block.split("\n\n", 2)[1], flags=re.M)
    return {c for row in rows for c in re.findall(r"`(\w+)`", row)}


def test_formats_doc_names_every_column_the_loaders_read():
    documented = _table_columns("`RUNS.csv` - one row per alignment result")
    assert documented == {c.name for c in Runs._COLUMNS} | {"position"}
    text = (ROOT / "docs" / "formats.md").read_text(encoding="utf-8")
    plan = text[text.index("`PLAN.csv` - one row per planned alignment"):].split("\n\n", 1)[0]
    for col in Plan._COLUMNS:
        assert re.search(rf"\b{col.name}\b", plan), col.name


def test_readme_names_the_oldest_stack_that_pyproject_pins():
    """``.ci/oldest`` runs the suite with exactly pyproject's lower bounds; the README names them."""
    deps = re.search(r"dependencies = \[(.*?)\]", (ROOT / "pyproject.toml").read_text(), re.S).group(1)
    readme = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    for name in ("numpy", "scipy", "casadi", "cvxpy"):
        low = re.search(rf'"{name}>=([0-9.]+)"', deps).group(1)
        assert f"{name} {low}" in readme, f"README does not name {name} {low}, the lower bound"
