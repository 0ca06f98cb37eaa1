import json
import os
import subprocess
import sys


def test_console_script_help():
    out = subprocess.run([sys.executable, "-m", "hse_opt.cli", "demo", "--help"], capture_output=True,
                         text=True)
    assert out.returncode == 0 and "example: hse-opt demo" in out.stdout
    bad = subprocess.run([sys.executable, "-m", "hse_opt.cli", "frobnicate"], capture_output=True, text=True)
    assert bad.returncode == 2 and "invalid choice: 'frobnicate'" in bad.stderr


def _blas_threads(env_extra):
    """numpy's BLAS thread count in a fresh process whose command line set its BLAS up
    (threadpoolctl reads it from the loaded library)."""
    code = ("import os, json, sys; from hse_opt.app.cli import _one_blas_thread; _one_blas_thread(); "
            "import numpy; from threadpoolctl import threadpool_info; "
            "print(json.dumps([[i['internal_api'], i['num_threads']] for i in threadpool_info() "
            "if i['user_api'] == 'blas'] + [os.environ.get('OPENBLAS_NUM_THREADS')]))")
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")}
    env.update(env_extra)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    return json.loads(out)


def test_the_command_line_runs_blas_on_one_thread_unless_told_otherwise():
    """A fresh hse-opt process loads numpy's BLAS with one thread (its second only spins beside
    the tool's small products); a thread count the user gives is kept."""
    *libs, var = _blas_threads({})
    assert var == "1" and libs and all(n == 1 for _, n in libs), libs
    *libs, var = _blas_threads({"OPENBLAS_NUM_THREADS": "2"})
    assert var == "2" and any(api == "openblas" and n == 2 for api, n in libs), libs


def test_the_blas_threads_of_a_process_that_has_numpy_are_left_alone(monkeypatch):
    import numpy  # noqa: F401  (loaded: the library has read its threads already)
    from hse_opt.app.cli import _one_blas_thread
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    _one_blas_thread()
    assert "OPENBLAS_NUM_THREADS" not in os.environ
