"""The on-disk cache of compiled CasADi Functions (hse_opt.compile_cache): a cached library
gives the numbers of CasADi's virtual machine (the uncompiled Function, an independent
evaluator), is compiled once per machine and once per process, is safe when processes start
together, can be disabled, and never writes into the working folder."""
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from hse_opt import compile_cache
from hse_opt.model import Model

ROOT = Path(__file__).resolve().parents[1]

#: a child process: compiles the mapped Jacobian of a model, prints where it came from and
#: its values at fixed inputs
CHILD = textwrap.dedent("""
    import sys
    import numpy as np
    from hse_opt import compile_cache
    if "no-compiler" in sys.argv:
        def refuse(*args, **kwargs):
            raise OSError("compiler refused by the test")
        compile_cache.subprocess.run = refuse
    from hse_opt.model import Model
    mm = Model(["hse", "axis_bias", "warmup"]).measurement()
    f = mm.J.map("J_map", "serial", 64, [0], [])
    g = compile_cache.compiled(f)
    X = np.zeros((mm.n_x, 64))
    X[0] = np.linspace(-0.8, 0.8, 64)
    X[1] = np.linspace(0, 6, 64)
    X[4] = 0.5
    X[5] = np.linspace(0, 7000, 64)
    X[6] = 600.0
    print(g.class_name(), repr(np.array(g(mm.nominal * 1.1 + 1e-6, X)).ravel().tolist()))
""")


def _run_child(cache, cwd, extra_env=None, wait=True, no_compiler=False):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "HSE_OPT_CACHE_DIR": str(cache)}
    env.pop("HSE_OPT_NO_CACHE", None)
    env.update(extra_env or {})
    proc = subprocess.Popen([sys.executable, "-c", CHILD, *(["no-compiler"] if no_compiler else [])],
                            cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    if not wait:
        return proc
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    kind, values = out.split(" ", 1)
    return kind, np.array(eval(values))  # noqa: S307 - our own child's repr of a list of floats


def _libraries(cache):
    return sorted((Path(cache) / "casadi").glob("*.so"))


def _inputs(mm, n, rng):
    from hse_opt.model.inputs import RUN_FIELDS, RunInputs
    X = np.zeros((mm.n_x, n))
    v = RunInputs(X)
    v.rate = rng.choice([-1, 1], n) * rng.uniform(0.2, 1.2, n)
    v.azimuth = rng.uniform(0, 2 * np.pi, n)
    v.pitch, v.roll = rng.uniform(-1e-3, 1e-3, (2, n))
    v.latitude = rng.uniform(-1, 1, n)
    v.t_start = rng.uniform(0, 7200, n)
    v.duration = 600.0
    X[len(RUN_FIELDS):] = rng.normal(25, 2, (mm.n_x - len(RUN_FIELDS), n))  # covariates
    return X


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """An empty cache folder of this test's own, and an empty in-process memory."""
    folder = tmp_path / "cache"
    monkeypatch.setenv("HSE_OPT_CACHE_DIR", str(folder))
    monkeypatch.delenv("HSE_OPT_NO_CACHE", raising=False)
    monkeypatch.setattr(compile_cache, "_loaded", {})
    return folder


def test_cached_library_gives_the_virtual_machines_numbers(cache, rng):
    """Whole catalogue, heading and Jacobian: the library compiled now and the one loaded from
    disk by a fresh memory evaluate as CasADi's VM does on the uncompiled Function."""
    mm = Model(["hse", "axis_bias", "sync_delay", "scale_nonlinearity", "warmup", "azimuth_harmonic2",
                "encoder_harmonic", "covariate:temp_c"]).measurement()
    X = _inputs(mm, 32, rng)
    p = mm.nominal + rng.normal(0, 1e-6, mm.nominal.size)
    for fun in (mm.h, mm.J):
        f = fun.map(f"{fun.name()}_map", "serial", 32, [0], [])
        reference = np.array(f(p, X))
        first = compile_cache.compiled(f)
        assert first.class_name() == "External"
        compile_cache._loaded.clear()
        again = compile_cache.compiled(f)  # from the disk
        assert again is not first
        for g in (first, again):
            np.testing.assert_allclose(np.array(g(p, X)), reference, rtol=1e-13, atol=1e-20)
    assert len(_libraries(cache)) == 2
    assert not list((cache / "casadi").glob(".build-*"))


def test_compiled_once_per_process_and_found_by_a_new_one(cache, tmp_path, monkeypatch):
    """The same Function asked for twice (two evaluators of one model, as design builds) runs
    the compiler once; a new process loads the library without compiling (a compiler that
    fails would give the uncompiled Function back)."""
    calls = []
    run = subprocess.run
    monkeypatch.setattr(compile_cache.subprocess, "run", lambda *a, **k: calls.append(a) or run(*a, **k))
    mm = Model(["hse"]).measurement()
    a = compile_cache.compiled(mm.h.map("h_map", "serial", 16, [0], []))
    b = compile_cache.compiled(mm.h.map("h_map", "serial", 16, [0], []))
    assert a is b and len(calls) == 1
    compile_cache.compiled(mm.h.map("h_map", "serial", 8, [0], []))  # another chunk: another key
    assert len(calls) == 2 and len(_libraries(cache)) == 2

    first_kind, first = _run_child(cache, tmp_path)
    assert first_kind == "External"
    stamp = {p: p.stat().st_mtime_ns for p in _libraries(cache)}
    kind, values = _run_child(cache, tmp_path, no_compiler=True)
    assert kind == "External"  # loaded: compiling would have failed and given the VM Function
    assert {p: p.stat().st_mtime_ns for p in _libraries(cache)} == stamp
    np.testing.assert_array_equal(values, first)


def test_processes_that_start_together_share_one_whole_library(cache, tmp_path):
    """Three processes compile the same Function into an empty cache at once: each gets a
    working library with the same numbers, one library is left and no build folder."""
    procs = [_run_child(cache, tmp_path, wait=False) for _ in range(3)]
    results = []
    for proc in procs:
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
        assert "RuntimeWarning" not in err, err
        kind, values = out.split(" ", 1)
        results.append((kind, np.array(eval(values))))  # noqa: S307
    assert [k for k, _ in results] == ["External"] * 3
    for _, values in results[1:]:
        np.testing.assert_array_equal(values, results[0][1])
    assert len(_libraries(cache)) == 1
    assert not list((cache / "casadi").glob(".build-*"))
    assert not list(tmp_path.glob("*.[co]")) and not list(tmp_path.glob("*.so"))


def test_no_cache_variable_compiles_without_writing_the_cache(cache, tmp_path):
    kind, values = _run_child(cache, tmp_path, {"HSE_OPT_NO_CACHE": "1"})
    assert kind == "External"
    assert not cache.exists()
    kind0, values0 = _run_child(cache, tmp_path, {"HSE_OPT_NO_CACHE": "0"})  # "0": cache on
    assert kind0 == "External" and len(_libraries(cache)) == 1
    np.testing.assert_array_equal(values, values0)


def test_killed_compile_leaves_nothing_in_the_working_folder(cache, tmp_path):
    """A process killed while it compiles leaves its build folder inside the cache only (the
    working folder stays empty); the next compile removes it once it is stale."""
    work = tmp_path / "work"
    work.mkdir()
    proc = _run_child(cache, work, wait=False)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not list((cache / "casadi").glob(".build-*/*")):
        time.sleep(0.002)
    os.killpg(proc.pid, signal.SIGKILL)  # the process and its compiler, as a terminal's kill does
    proc.communicate()
    assert list(work.iterdir()) == []
    for left in (cache / "casadi").glob(".build-*"):  # age it past the stale limit
        old = time.time() - 2 * compile_cache._STALE_S
        os.utime(left, (old, old))
    _run_child(cache, work)
    assert not list((cache / "casadi").glob(".build-*"))
    assert list(work.iterdir()) == []


def test_cache_folder_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("HSE_OPT_CACHE_DIR", str(tmp_path / "here"))
    assert compile_cache.cache_dir() == tmp_path / "here"
    monkeypatch.delenv("HSE_OPT_CACHE_DIR")
    if sys.platform.startswith("linux"):
        monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
        assert compile_cache.cache_dir() == tmp_path / "xdg" / "hse_opt"
    for value, on in (("", True), ("0", True), ("1", False), ("yes", False)):
        monkeypatch.setenv("HSE_OPT_NO_CACHE", value)
        assert compile_cache.enabled() is on


def test_batch_evaluator_compiled_path_matches_the_virtual_machine(cache, rng):
    """Batches of every size through the compiled chunk (padded last chunk) and through the
    VM give the same numbers, numeric and inside a CasADi graph."""
    mm = Model(["hse", "sync_delay"]).measurement()
    p = mm.nominal + rng.normal(0, 1e-6, mm.nominal.size)
    for n in (1, 255, 256, 257, 1000):
        X = _inputs(mm, n, rng)
        vm = mm.jacobian(p, X, jit=False)
        np.testing.assert_allclose(mm.jacobian(p, X, jit=True), vm, rtol=1e-13, atol=1e-20)
        P, XS = ca.MX.sym("p", p.size), ca.MX.sym("X", *X.shape)
        h = mm.predict_graph(P, XS, jit=True)
        graph = ca.Function("g", [P, XS], [h, ca.gradient(ca.sumsqr(h), P)])  # solvers differentiate it
        value, grad = graph(p, X)
        np.testing.assert_allclose(np.array(value).ravel(), mm.predict(p, X, jit=False), rtol=1e-13, atol=1e-20)
        np.testing.assert_allclose(np.array(grad).ravel(), 2 * vm.T @ mm.predict(p, X, jit=False),
                                   rtol=1e-10, atol=1e-30)


def test_bounded_fit_of_many_runs_goes_through_ipopt(cache, rng):
    """A binding bound on 1,500 runs (the size rule compiles the numeric batches) sends the fit
    through IPOPT, whose problem CasADi differentiates; the bound holds and the other
    parameters are the bounded least-squares optimum (equality-constrained refit)."""
    import hse_opt
    from hse_opt.data import Runs
    from hse_opt.units import ARCSEC, DEG

    n = 1500
    rate = rng.choice([-60.0, -20.0, 20.0, 60.0], n)
    azimuth = rng.choice(np.arange(0.0, 360.0, 45.0), n)
    pitch, roll = rng.uniform(-400, 400, (2, n))  # arcsec
    mm = Model(["hse"]).measurement()
    X = mm.inputs(rate * DEG, azimuth * DEG, 0.49, 600.0, pitch=pitch * ARCSEC, roll=roll * ARCSEC)
    err = mm.predict(mm.vector(offset=-3.0, lambda2=4.0), X) / ARCSEC + rng.normal(0, 2.0, n)
    runs = Runs.from_columns({"run": np.arange(1, n + 1), "rate_dps": rate, "azimuth_deg": azimuth,
                              "duration_s": np.full(n, 600.0), "latitude_deg": np.full(n, np.degrees(0.49)),
                              "pitch_arcsec": pitch, "roll_arcsec": roll,
                              "heading_err_arcsec": err, "heading_std_arcsec": np.full(n, 2.0)})
    bounded = hse_opt.fit(runs, Model(["hse"]), bounds={"offset": (-2.0, None)})
    fixed = hse_opt.fit(runs, Model(["hse"]), fix={"offset": -2.0})
    values = {k: v["value"] for k, v in bounded.to_dict()["parameters"].items()}
    assert bounded.method == "ipopt" and "offset" in bounded.binding
    assert values["offset"] == pytest.approx(-2.0, abs=1e-9)
    assert values["lambda2"] == pytest.approx(fixed.to_dict()["parameters"]["lambda2"]["value"], rel=1e-6)
