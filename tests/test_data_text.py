"""Inputs users have (issue 18, item 3): text columns of a results sheet kept as metadata and
passed through to every output table; the stand reference's own 1-sigma
(``azimuth_std_arcsec``) in the weights."""
import csv

import numpy as np
import pytest

from hse_opt import units
from hse_opt.cli import main as cli
from hse_opt.data import Plan, load_plan, load_runs, save_runs
from hse_opt.datasets import paper_table1
from hse_opt.fit import fit

SHEET = """run,date,operator,rate_dps,azimuth_deg,heading_err_arcsec,latitude_deg,duration_s,serial,remark
1,2013-05-02,Yu,40,0,-3.5,28.07,600,RLG-0042,
2,2013-05-02,Yu,40,0,1.5,28.07,600,RLG-0042,cold start
3,2013-05-02,Wu,40,90,12.0,28.07,600,RLG-0042,
4,2013-05-02,Wu,40,90,8.5,28.07,600,RLG-0042,"after lunch, 1 h"
5,2013-05-03,Cao,40,180,3.0,28.07,600,RLG-0042,
6,2013-05-03,Cao,40,180,6.0,28.07,600,RLG-0042,
7,2013-05-03,Liu,40,270,-9.5,28.07,600,RLG-0042,
8,2013-05-03,Liu,40,270,-6.0,28.07,600,RLG-0042,
"""


def _rows(path):
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def test_text_columns_are_metadata_passed_through(tmp_path):
    """A results sheet: dates, operators, a serial number, free remarks (one with a comma and
    most empty), no heading_std, replicates. Loads, fits, and compensate's output table carries
    the text columns as written."""
    src = tmp_path / "SHEET.csv"
    src.write_text(SHEET, encoding="utf-8")
    before = src.read_bytes()
    runs = load_runs(src)
    assert sorted(runs.metadata) == ["date", "operator", "remark", "serial"] and not runs.covariates
    assert runs.metadata["remark"].tolist()[1:4] == ["cold start", "", "after lunch, 1 h"]
    assert any("column 'operator' is text (row 1: 'Yu' is not a number)" in n for n in runs.notes)
    # the first cell that is text, not the first cell, empty (new-user trial: "row 1: '' is not a number")
    assert any("column 'remark' is text (row 2: 'cold start' is not a number)" in n for n in runs.notes)
    assert cli(["fit", str(src), "--fix", "lambda2*tilt_const=0", "-o", str(tmp_path / "FIT.json")]) == 0
    assert cli(["compensate", str(src), "--fit", str(tmp_path / "FIT.json"), "-o", str(tmp_path / "OUT.csv")]) == 0
    assert src.read_bytes() == before                          # the input is never modified
    sheet, out = _rows(src), _rows(tmp_path / "OUT.csv")
    for name in ("date", "operator", "serial", "remark"):
        assert [r[name] for r in out] == [r[name] for r in sheet]
    # subsets keep them row by row; 4 replicate degrees of freedom are too few for a pure-error
    # sigma (fewer than 8): the sigma comes from the residuals, and the replicates test the fit
    assert load_runs(tmp_path / "OUT.csv").subset([3, 0]).metadata["operator"].tolist() == ["Wu", "Yu"]
    f = fit(runs, fix={"lambda2*tilt_const": 0.0})
    assert f.weighting == "residual" and f.lack_of_fit.dof == (1, 4)


def test_plan_text_columns_reach_the_simulated_runs(tmp_path):
    from hse_opt.sim import TruthConfig, run_campaign
    plan = Plan.from_columns({"run": [1, 2], "rate_dps": [40, -40], "azimuth_deg": [0, 90],
                              "t_start_s": [0, 700], "duration_s": [120, 120], "fixture": ["A", "B-2"]})
    runs = run_campaign(plan, TruthConfig.default(), seed=1)
    assert runs.metadata["fixture"].tolist() == ["A", "B-2"]
    save_runs(runs, tmp_path / "RUNS.csv")
    assert [r["fixture"] for r in _rows(tmp_path / "RUNS.csv")] == ["A", "B-2"]
    (tmp_path / "PLAN.csv").write_text("run,rate_dps,azimuth_deg,t_start_s,duration_s,fixture\n"
                                       "1,40,0,0,600,x y\n2,40,90,700,600,z\n")
    assert load_plan(tmp_path / "PLAN.csv").metadata["fixture"].tolist() == ["x y", "z"]


def test_reference_sigma_enters_the_weights():
    """sigma of a run = sqrt(heading_std^2 + azimuth_std^2): the fit of runs with both equals
    the fit of the same runs with heading_std set to that sum (definition), and differs from
    ignoring the reference."""
    runs = paper_table1()
    n = len(runs)
    own = np.full(n, 7.9) * units.ARCSEC
    ref = np.where(np.arange(n) < 6, 2.0, 12.0) * units.ARCSEC     # one half of the stand read worse
    both = fit(runs.replace(heading_std=own, azimuth_std=ref), fix={"lambda2*tilt_const": 0.0})
    summed = fit(runs.replace(heading_std=np.hypot(own, ref)), fix={"lambda2*tilt_const": 0.0})
    alone = fit(runs.replace(heading_std=own), fix={"lambda2*tilt_const": 0.0})
    assert np.allclose(both.sigma, np.hypot(own, ref))
    assert np.allclose(both.values, summed.values, rtol=1e-9, atol=1e-12)
    assert np.allclose(both.std, summed.std, rtol=1e-9)
    assert not np.allclose(both.values, alone.values, rtol=1e-3)
    assert any("azimuth_std_arcsec" in n for n in both.notes)
    # in the file: a column of its own, read and written in arcsec
    assert "azimuth_std_arcsec" in runs.replace(azimuth_std=ref).to_columns()


def test_reference_sigma_from_the_file_and_pure_error(tmp_path):
    src = tmp_path / "SHEET.csv"
    lines = SHEET.splitlines()
    # most of the sheet measured twice more (18 replicate degrees of freedom: a pure-error sigma)
    again = [ln.split(",") for ln in lines[1:] if '"' not in ln]
    more = [",".join([str(8 * k + int(c[0]))] + c[1:5] + [f"{float(c[5]) + (-1) ** k * 0.5 * k:g}"] + c[6:])
            for k in (1, 2) for c in again]
    src.write_text("\n".join([lines[0] + ",azimuth_std_arcsec"] + [ln + ",3" for ln in lines[1:] + more]) + "\n")
    runs = load_runs(src)
    assert runs.azimuth_std == pytest.approx(np.full(len(runs), 3 * units.ARCSEC)) and len(runs) == 22
    f = fit(runs, fix={"lambda2*tilt_const": 0.0})
    plain = fit(runs.replace(azimuth_std=None), fix={"lambda2*tilt_const": 0.0})
    assert f.weighting == plain.weighting == "pure-error"
    assert f.sigma == pytest.approx(np.hypot(plain.sigma, 3 * units.ARCSEC))
