"""Degenerate noise (issue 14, item 5): heading errors without noise and identical replicates
get a clear note (fit) or a one-line error (diagnose, exit 2), never F = inf, a false alarm or
a solver failure. On the paper's Table 1 as a user has it (text-like position column, no
heading_std, replicates) and on generated campaigns, against independent references: the
parameter values the data were made from, and the diagnosis of the same runs without the
copies."""
import csv
import hashlib
import io
import json
import math
from contextlib import redirect_stderr, redirect_stdout

import numpy as np
import pytest

from hse_opt import units
from hse_opt.cli import main
from hse_opt.data import Runs, load_runs
from hse_opt.datasets import paper_table1_path
from hse_opt.diagnose import diagnose
from hse_opt.fit import fit
from hse_opt.fit.checks import check_lines
from hse_opt.model import as_model
from hse_opt.validation.synthetic import diagnostic_plan, model_runs

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")

BASE_TILT = (-120 * units.ARCSEC, -55 * units.ARCSEC)
#: Table 1 has no tilt columns: the paper's model with its tilt terms as free sinusoids
TABLE1_TRUTH = {"offset": 3.0, "lambda2*tilt_cos": 2.5, "lambda2*tilt_sin": -1.5}
FIX = ["--fix", "lambda2*tilt_const=0"]


def cli(argv):
    out, err = io.StringIO(), io.StringIO()
    with redirect_stderr(err), redirect_stdout(out):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def table1_with(tmp_path, name, heading_arcsec):
    """Table 1 with its heading_err_arcsec column replaced (every other column as published)."""
    with open(paper_table1_path(), newline="") as fh:
        rows = list(csv.DictReader(fh))
    path = tmp_path / name
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        for row, h in zip(rows, heading_arcsec):
            w.writerow({**row, "heading_err_arcsec": repr(float(h))})
    return path


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_table1_without_noise_fit_says_so_and_diagnose_exits_2(tmp_path):
    runs = load_runs(paper_table1_path())
    mm = as_model("hse").measurement(False)
    exact = mm.predict(mm.vector(TABLE1_TRUTH), mm.inputs_from_runs(runs)) / units.ARCSEC
    path = table1_with(tmp_path, "exact.csv", exact)
    before = digest(path)
    # without noise a setting's three runs are one measurement written three times (copies):
    # 4 measurements, so the fourth parameter is held at the value the data were made from
    f = fit(load_runs(path), fix={"lambda2*tilt_const": 0.0})
    for name, value in TABLE1_TRUTH.items():   # the values the data were made from
        assert f.value(name)[0] == pytest.approx(value, abs=1e-6)
    code, out, err = cli(["fit", path])
    assert code == 2 and "4 runs (the 12 rows hold 4 distinct measurements: the others are copies) cannot fit " \
        "4 free parameters" in err
    code, out, err = cli(["fit", path, *FIX])
    assert code == 0 and "the residuals are zero" in out and "no noise" in out and "8 of 12 rows are copies" in out
    code, out, err = cli(["diagnose", path, *FIX])
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and str(path) in err and "no noise" in err and "rounding" in err
    assert digest(path) == before


def test_table1_identical_replicates_no_infinite_f_and_no_false_alarm(tmp_path):
    with open(paper_table1_path(), newline="") as fh:
        rows = list(csv.DictReader(fh))
    first = {}
    copies = [first.setdefault((r["rate_dps"], r["azimuth_deg"]), float(r["heading_err_arcsec"])) for r in rows]
    assert len(first) == 4 and len(copies) == 12      # 4 settings, 3 runs each
    path = table1_with(tmp_path, "copies.csv", copies)
    code, out, _ = cli(["fit", path, *FIX])
    assert code == 0 and "8 of 12 rows are copies of another row" in out
    code, out, _ = cli(["diagnose", path, *FIX, "--json"])
    assert code == 0
    d = json.loads(out)
    # 4 settings, 3 parameters: no test is possible (before: F = inf and missing-effect)
    stats = [t["statistic"] for t in d["factors"]] + [c["statistic"] for c in d["candidates"]]
    assert all(s is None or math.isfinite(s) for s in stats)
    # nothing can be tested, so nothing is ruled out: inconclusive, never adequate
    assert d["verdict"] == "inconclusive" and d["n_tests"] == 0
    assert any("4 measurements once, not the 12 rows" in n for n in d["notes"])
    assert any("no test is possible" in n for n in d["notes"])


def test_copies_count_once():
    """Each run of a campaign written three times (no heading_std: one unknown sigma) is
    diagnosed as the campaign itself: the same F statistics and degrees of freedom for every
    factor of the settings and every candidate, not three times the evidence."""
    runs = model_runs(diagnostic_plan(), {"offset": 3.0, "lambda2": 4.2, "delay": 40.0},
                      np.random.default_rng(11), base_tilt=BASE_TILT).replace(heading_std=None)
    cols = {k: np.repeat(v, 3) for k, v in runs.to_columns().items()}
    tripled = Runs.from_columns({**cols, "run": np.arange(3 * len(runs))}, source="copies")
    once, thrice = diagnose(runs, refit=False), diagnose(tripled, refit=False)
    settings = ("azimuth", "bias rate", "rotation sense", "rate x azimuth", "tilt (C23)")
    a = {t.name: t for t in once.factors if t.name in settings}
    b = {t.name: t for t in thrice.factors if t.name in settings}
    assert set(a) == set(settings) and set(b) == set(settings)
    for name in settings:
        assert b[name].dof == a[name].dof
        assert b[name].statistic == pytest.approx(a[name].statistic, rel=1e-6)
    for c in once.candidates:
        c3 = thrice.candidate(c.effect)
        assert c3.dof == c.dof and (c.p_value is None or c3.p_value == pytest.approx(c.p_value, rel=1e-5))
    assert thrice.verdict == once.verdict
    assert thrice.lack_of_fit.p_value is None and "identical" in thrice.lack_of_fit.note


def test_copies_have_the_influence_of_their_setting():
    """A campaign with one run 40 arcsec off, each run written three times: every copy gets
    its setting's leverage (the copies' sum), Cook's distance and studentised residual, those
    of the campaign diagnosed once, and the outlier is the off run's three copies."""
    runs = model_runs(diagnostic_plan(), {"offset": 3.0, "lambda2": 4.2}, np.random.default_rng(5),
                      base_tilt=BASE_TILT).replace(heading_std=None)
    h = runs.heading_err.copy()
    h[9] += 40 * units.ARCSEC
    runs = runs.replace(heading_err=h)
    cols = {k: np.repeat(v, 3) for k, v in runs.to_columns().items()}
    tripled = Runs.from_columns({**cols, "run": np.arange(3 * len(runs))}, source="copies")
    once, thrice = diagnose(runs, refit=False), diagnose(tripled, refit=False)
    for name in ("leverage", "cooks", "studentized"):
        np.testing.assert_allclose(getattr(thrice, name), np.repeat(getattr(once, name), 3), rtol=1e-6)
    assert once.outliers == (int(runs.run[9]),)
    assert thrice.outliers == (27, 28, 29)
    assert sorted(thrice.influential) == sorted(3 * i + j for i in np.searchsorted(runs.run, once.influential)
                                               for j in range(3))


def test_noise_free_runs_with_the_smallest_allowed_sigma_fit_without_a_solver_failure():
    """heading_std 0.01 arcsec (the loaders' lower limit) on noise-free runs: the fit converges to
    the values the data were made from (before: Gauss-Newton gave up, its steps below rounding),
    says that the residuals are zero, and the diagnosis refuses with the runs' source named."""
    truth = {"offset": 3.0, "lambda2": 4.2, "delay": 70.0}
    runs = model_runs(diagnostic_plan(), truth, np.random.default_rng(0), base_tilt=BASE_TILT,
                      sigma=0.01 * units.ARCSEC)
    mm = as_model("hse,sync_delay").measurement(True)
    runs = runs.replace(heading_err=mm.predict(mm.vector(truth), mm.inputs_from_runs(runs)))   # no noise
    f = fit(runs, "hse,sync_delay")
    for name, value in truth.items():
        assert f.value(name)[0] == pytest.approx(value, abs=1e-5)
    assert any("residuals are zero" in line for line in check_lines(f, runs))
    with pytest.raises(ValueError, match=r"^measurement model: the residuals are zero .*no noise"):
        diagnose(runs, "hse,sync_delay")
