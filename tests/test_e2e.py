"""End to end, as a new user: a fresh virtual environment, ``pip install .`` as the README's
quick start says, ``hse-opt demo``, and the report's numbers against ``--json``.

Slow (about a minute: pip unpacks numpy, scipy, casadi, cvxpy and matplotlib, from its cache
when it has one); one such test only.
"""
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _tracked_files():
    """The repository's files as a fresh clone has them (git's view when available)."""
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True)
        return [REPO / p for p in out.stdout.decode().split("\0") if p]
    except (OSError, subprocess.CalledProcessError):
        skip = {".git", "build", "__pycache__", ".pytest_cache"}
        return [p for p in REPO.rglob("*") if p.is_file() and not skip & set(p.parts)
                and ".egg-info" not in str(p)]


def _cells(html, key):
    """The value cells of the table row(s) with ``data-key=key``."""
    rows = re.findall(rf'<tr data-key="{re.escape(key)}">(.*?)</tr>', html, flags=re.S)
    return [re.findall(r"<td>(.*?)</td>", r)[1:] for r in rows]


@pytest.mark.slow
def test_fresh_install_runs_the_demo_and_the_report_agrees_with_json(tmp_path):
    src = tmp_path / "src"
    for f in _tracked_files():
        if f.is_file():
            dest = src / f.relative_to(REPO)
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(f, dest)
    quick = re.search(r"<!-- quickstart -->\s*```bash\n(.*?)```", (src / "README.md").read_text(), re.S)
    assert quick and quick.group(1).splitlines()[0] == "pip install . && hse-opt demo"

    t0 = time.perf_counter()
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    bindir = venv / ("Scripts" if os.name == "nt" else "bin")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["PATH"] = f"{bindir}{os.pathsep}{env.get('PATH', '')}"
    pip = subprocess.run([str(bindir / "python"), "-m", "pip", "install", "-q", "."], cwd=src,
                         env=env, capture_output=True, text=True)
    assert pip.returncode == 0, pip.stderr[-3000:]
    t_install = time.perf_counter() - t0

    work = tmp_path / "user"
    work.mkdir()
    t0 = time.perf_counter()
    run = subprocess.run(["hse-opt", "demo", "--json", "--no-progress"], cwd=work, env=env,
                         capture_output=True, text=True, timeout=600)
    t_demo = time.perf_counter() - t0
    assert run.returncode == 0, run.stderr[-3000:]
    print(f"fresh venv + pip install: {t_install:.1f} s; hse-opt demo: {t_demo:.1f} s")
    data = json.loads(run.stdout)                          # stdout holds one JSON object only

    # the installed package ran, not the source tree
    where = subprocess.run([str(bindir / "python"), "-c", "import hse_opt; print(hse_opt.__file__)"],
                           cwd=work, env=env, capture_output=True, text=True, check=True).stdout
    assert str(venv) in where

    out = work / "hse_opt_demo"                            # the default --out
    report = out / "report.html"
    assert report.is_file() and report.stat().st_size > 50_000
    assert json.loads((out / "summary.json").read_text()) == data
    html = report.read_text(encoding="utf-8")
    n_img = html.count('<img class="plot" src="data:image/svg+xml;base64,')
    assert n_img >= 4

    # the numbers the report shows are the numbers --json printed
    rms = _cells(html, "rms_arcsec")
    chi2_red = _cells(html, "chi2_red")
    assert float(rms[0][0]) == pytest.approx(data["before"]["rms_arcsec"], rel=5e-4)
    assert float(chi2_red[0][0]) == pytest.approx(data["before"]["chi2_red"], rel=5e-4)
    assert int(_cells(html, "n_runs")[0][0]) == data["n_runs"]
    if data["after"] is not None:
        assert float(rms[-1][-1]) == pytest.approx(data["after"]["rms_arcsec"], rel=5e-4)
    assert f"{data['before']['rms_arcsec']:.1f} arcsec" in html       # the summary at the top
    assert data["hidden_effect"] in html
    # the diagnosis: every candidate's score p, Delta-BIC and RMS after, best first
    cands = data["diagnosis"]["candidates"]
    for c in cands:
        row = _cells(html, f"candidate:{c['effect']}")[0]
        if c["p_value"] is not None:
            assert float(row[1]) == pytest.approx(c["p_value"], rel=0.06)
            assert c["delta_bic"] is None or float(row[2]) == pytest.approx(c["delta_bic"], abs=0.06)
    # the next plan (the best one designed) against the paper's plan: sigma(lambda2) and ratio
    nxt = data["next_plan"]
    best = nxt["tilt_fixture"] or nxt["paper_limits"]
    sd, paper, ratio = (float(x) for x in _cells(html, "sigma:lambda2")[0][1:4])
    assert sd == pytest.approx(best["sigma_lambda2_arcsec"], rel=5e-3)
    assert paper == pytest.approx(nxt["paper_sigma_lambda2_arcsec"], rel=5e-3)
    assert 1 / ratio == pytest.approx(best["gain"], rel=5e-3)
