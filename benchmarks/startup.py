"""Start-up benchmark (issue 19, items 3 and 4): whole-process times of short commands, and
the first call in a new process against the same call repeated (compile cache).

Part 1, whole processes (wall and CPU of the child, median of ``--repeats`` after one
warm-up run that also fills the compile cache and Python's bytecode cache, as an installed
package has it: the children write their ``.pyc`` files to a temporary folder
(``PYTHONPYCACHEPREFIX``) even where ``PYTHONDONTWRITEBYTECODE`` is set, which would make
every process compile the package's sources again, ~0.07 s):

- ``python -c pass`` (the interpreter alone), ``import hse_opt.sim`` (the simulator, which
  loads neither CasADi nor cvxpy), ``hse-opt --help``, ``hse-opt fit`` of 100 runs
  (targets: <= 0.5 s each on a warm cache).

Part 2, in a new process (cache warm): the first ``fit`` and ``diagnose`` of 10,000 runs, and
the second call of each in the same process (target: first <= 2x second), wall time and the
CPU time of the process (the compiler, when it runs, is another process: wall time counts it).
``--cold`` also runs part 2 with the cache off (``HSE_OPT_NO_CACHE=1``: everything compiled
anew).

    taskset -c 0 python benchmarks/startup.py
    taskset -c 0 python benchmarks/startup.py --repeats 11 --cold
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

#: part 2's child: builds the runs, times two calls of fit and of diagnose, prints JSON
CHILD = """
import json, sys, time
import numpy as np
t0 = time.perf_counter()
import numpy.random  # numpy loads it lazily; the model's tilt-coupling check would pay it
import hse_opt
from hse_opt.data import load_runs
fit, diagnose = hse_opt.fit, hse_opt.diagnose
runs = load_runs(sys.argv[1])
out = {"imports + load": time.perf_counter() - t0}
for label, call in (("fit", lambda: fit(runs)), ("diagnose", lambda: diagnose(runs))):
    times = []
    for _ in range(2):
        t, c = time.perf_counter(), time.process_time()
        call()
        times.append((time.perf_counter() - t, time.process_time() - c))
    out[label] = times
print(json.dumps(out))
"""


def write_runs(path, n, rng):
    """A RUNS.csv of ``n`` runs: the paper's model at typical values plus 8-arcsec noise."""
    from hse_opt import units
    from hse_opt.data import Runs, save_runs
    from hse_opt.model import paper_model

    mm = paper_model().measurement(tilt_known=False)
    rate = rng.choice([-40.0, 40.0], n)
    azimuth = rng.choice(np.arange(0.0, 360.0, 45.0), n)
    X = mm.inputs(rate * units.DEG_PER_S, azimuth * units.DEG, 28.07 * units.DEG, 600.0,
                  t_start=3600.0 + 650.0 * np.arange(n))
    err = mm.predict(mm.vector({"offset": -3.0, "lambda2*tilt_cos": 2.0, "lambda2*tilt_sin": -1.0}), X) / units.ARCSEC + rng.normal(0, 8.0, n)
    save_runs(Runs.from_columns({"run": np.arange(1, n + 1), "rate_dps": rate, "azimuth_deg": azimuth,
                                 "duration_s": np.full(n, 600.0), "latitude_deg": np.full(n, 28.07),
                                 "heading_err_arcsec": err, "heading_std_arcsec": np.full(n, 8.0)}),
              path)


def whole_process(cmd, repeats, env):
    """Median and min of wall and child CPU seconds over ``repeats`` runs after one warm-up."""
    walls, cpus = [], []
    for i in range(repeats + 1):
        before = os.times()
        t = time.perf_counter()
        subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        wall = time.perf_counter() - t
        after = os.times()
        if i:
            walls.append(wall)
            cpus.append(after.children_user - before.children_user + after.children_system
                        - before.children_system)
    return statistics.median(walls), min(walls), statistics.median(cpus)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--cold", action="store_true", help="also part 2 with the compile cache off")
    a = p.parse_args(argv)
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        env = {**{k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"},
               "PYTHONPYCACHEPREFIX": str(Path(tmp) / "pycache"),
               "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
        small, large = Path(tmp) / "runs100.csv", Path(tmp) / "runs10000.csv"
        write_runs(small, 100, rng)
        write_runs(large, 10_000, rng)
        py = [sys.executable]
        cli = py + ["-m", "hse_opt.cli"]
        print(f"whole process, median [min] of {a.repeats} after a warm-up (wall; CPU median):")
        for label, cmd in (("python -c pass", py + ["-c", "pass"]),
                           ("import hse_opt.sim", py + ["-c", "import hse_opt.sim"]),
                           ("hse-opt --help", cli + ["--help"]),
                           ("hse-opt fit (100 runs)", cli + ["fit", str(small)])):
            med, best, cpu = whole_process(cmd, a.repeats, env)
            print(f"  {label:24s} {med:6.3f} s [{best:.3f}]; CPU {cpu:.3f} s   (target <= 0.5 s)"
                  if "hse-opt" in label else f"  {label:24s} {med:6.3f} s [{best:.3f}]; CPU {cpu:.3f} s")
        for cache in (("warm", {}),) + ((("off", {"HSE_OPT_NO_CACHE": "1"}),) if a.cold else ()):
            res = json.loads(subprocess.run(py + ["-c", CHILD, str(large)], env={**env, **cache[1]}, check=True,
                                            capture_output=True, text=True).stdout)
            print(f"new process, compile cache {cache[0]}, 10,000 runs (imports + load "
                  f"{res['imports + load']:.2f} s):")
            for label in ("fit", "diagnose"):
                (first, first_cpu), (second, second_cpu) = res[label]
                print(f"  {label:9s} first {first:6.3f} s, second {second:6.3f} s: first/second "
                      f"{first / second:.2f} (CPU of this process {first_cpu:.3f} / {second_cpu:.3f} s: "
                      f"{first_cpu / second_cpu:.2f})" + ("   (target <= 2)" if cache[0] == "warm" else ""))


if __name__ == "__main__":
    main()
