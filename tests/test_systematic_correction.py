"""The correction's systematic bound: the fit's per-parameter ``systematic_by`` (what the
campaign could not rule out, :mod:`hse_opt.aliasing`) carried through the correction's
gradient - ``max_e sum_j |dcorr/dp_j| S[j, e]`` - in Python (``systematic_at``, compensate's
``heading_comp_sys_arcsec``) and in the exported C (``hse_compensation_systematic``). Checked
against central finite differences of the correction itself, and the C against Python at
random points."""
import dataclasses
import json

import numpy as np
import pytest

from hse_opt import units
from hse_opt.cli import main as cli
from hse_opt.data import load_runs, save_runs
from hse_opt.fit import fit, save_fit
from hse_opt.fit.correction import compensation_at, compensation_point, systematic_at

from test_domain import _runs
from test_export import COMPILER, _compile_strict, needs_cc

#: a budget written by hand: effect -> shift of each parameter (display units)
BY = {"lambda2": {"sync_delay": 6.0, "warmup": 2.5}, "delay": {"sync_delay": 0.0, "warmup": 40.0}}


def _calibration(rng):
    runs = _runs(rng, effects=("hse", "sync_delay"), truth={"offset": 3.0, "lambda2": 4.2, "delay": 300.0},
                 c23_arcsec=(-600.0, 200.0, 900.0))
    f = fit(runs, "hse,sync_delay")
    by = tuple(dict(BY.get(nm, {})) for nm in f.names)
    sys = np.array([max(d.values(), default=0.0) for d in by])
    return runs, dataclasses.replace(f, systematic=sys, systematic_by=by)


def _by_differences(f, X):
    """The bound from central differences of the correction in each parameter (display
    units, step 1e-3 of a unit; the correction is linear in lambda2, nearly so in delay)."""
    use, _ = compensation_point(f)
    grads = {}
    for nm in BY:
        i = f.names.index(nm)
        h = 1e-3
        plus, minus = f.p.copy(), f.p.copy()
        plus[i] += h * f.measurement.scale[i]
        minus[i] -= h * f.measurement.scale[i]
        cp = compensation_at(X, dataclasses.replace(f, p=plus))[0]
        cm = compensation_at(X, dataclasses.replace(f, p=minus))[0]
        grads[nm] = (cp - cm) / (2 * h)
    effects = ("sync_delay", "warmup")
    return np.max([sum(np.abs(grads[nm]) * BY[nm][e] for nm in BY) for e in effects], axis=0)


def test_systematic_bound_by_finite_differences(rng):
    runs, f = _calibration(rng)
    X = f.measurement.inputs_from_runs(runs)
    got = systematic_at(X, f)
    want = _by_differences(f, X)
    assert got == pytest.approx(want, rel=1e-5)
    assert got.min() > 1.0 * units.ARCSEC   # a bound that matters here (a check that can fail)
    # without a budget in the fit: 0
    assert np.all(systematic_at(X, dataclasses.replace(f, systematic=None, systematic_by=())) == 0)


@needs_cc
def test_c_systematic_equals_python_and_compensate(tmp_path, rng, monkeypatch):
    """FIT.json carries the budget; compensate's column and the C's second entry point give
    the same bound as systematic_at (1e-9 arcsec); the status of both entry points agrees."""
    import ctypes
    import subprocess

    monkeypatch.chdir(tmp_path)
    runs, f = _calibration(rng)
    save_fit(f, tmp_path / "FIT.json")
    assert json.loads((tmp_path / "FIT.json").read_text())["parameters"]["lambda2"]["systematic_by"] == BY["lambda2"]
    assert cli(["export", str(tmp_path / "FIT.json"), "-o", str(tmp_path / "nav")]) == 0
    _compile_strict(tmp_path / "nav")          # -Wall -Wextra -Werror with the bound's fabs and fmax too
    lib = tmp_path / "libhse.so"
    subprocess.run([COMPILER, "-std=c99", "-O2", "-shared", "-fPIC", "-o", str(lib),
                    str(tmp_path / "nav" / "hse_compensation.c"), "-lm"], check=True)
    so = ctypes.CDLL(str(lib))
    main_, sys_ = so.hse_compensation, so.hse_compensation_systematic
    ptr = ctypes.POINTER(ctypes.c_double)
    main_.argtypes, sys_.argtypes = [ptr] * 3, [ptr] * 2
    X = np.ascontiguousarray(f.measurement.inputs_from_runs(runs).T)
    c, s, ss = ctypes.c_double(), ctypes.c_double(), ctypes.c_double()
    got = np.empty(len(X))
    for k, row in enumerate(X):
        st = main_(row.ctypes.data_as(ptr), ctypes.byref(c), ctypes.byref(s))
        assert sys_(row.ctypes.data_as(ptr), ctypes.byref(ss)) == st == 0
        got[k] = ss.value
    want = systematic_at(X.T, f)
    assert np.abs(got - want).max() / units.ARCSEC < 1e-9
    save_runs(runs, tmp_path / "RUNS.csv")
    assert cli(["compensate", str(tmp_path / "RUNS.csv"), "--fit", str(tmp_path / "FIT.json"),
                "-o", str(tmp_path / "OUT.csv")]) == 0
    column = load_runs(tmp_path / "OUT.csv").covariates["heading_comp_sys_arcsec"]
    assert np.abs(column - want / units.ARCSEC).max() < 1e-9
