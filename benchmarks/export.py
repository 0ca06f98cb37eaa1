"""Benchmark of ``hse-opt export`` and of the compiled compensation (issue 18).

For the paper's model and for one with every catalogue effect (and a covariate), fitted to a
simulated campaign of 240 runs (tilt known), and for the paper's Table 1 (tilt unknown): the wall time of ``hse-opt export FIT.json -o DIR`` as a user
runs it (a new process: interpreter start, imports, code generation, files written; target
<= 2 s) and of the export inside Python; then the generated C, compiled with ``cc -O2``,
called from a C driver over 1,024 operating points inside the validity range, 2,000,000
calls timed in process CPU time (``clock_gettime(CLOCK_PROCESS_CPUTIME_ID)``: fair on a
shared machine; target <= 100 ns per call). The export's times are its process's CPU time
(the target) and wall time.

Run: taskset -c 0 python benchmarks/export.py      (the script also pins itself to one core)
"""
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_export import EVERY_EFFECT, _campaign, _random_points  # noqa: E402

from hse_opt.export import export_calibration  # noqa: E402
from hse_opt.datasets import paper_table1  # noqa: E402
from hse_opt.fit import fit, save_fit  # noqa: E402

DRIVER = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <time.h>
#include "hse_compensation.h"
#include "points.h"
int main(void) {
  double c, s, sum = 0.0;
  long calls = 2000000, bad = 0;
  struct timespec t0, t1;
  for (int i = 0; i < N_POINTS; ++i) bad += hse_compensation(POINTS[i], &c, &s) != 0;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t0);
  for (long k = 0; k < calls; ++k) {
    hse_compensation(POINTS[k & (N_POINTS - 1)], &c, &s);
    sum += c + s;
  }
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t1);
  double ns = ((t1.tv_sec - t0.tv_sec) * 1e9 + (t1.tv_nsec - t0.tv_nsec)) / calls;
  printf("%.1f %ld %g\n", ns, bad, sum);
  return 0;
}
"""


def _children_cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def bench(label, calibration, rng, work):
    d = work / label
    d.mkdir()
    save_fit(calibration, d / "FIT.json")
    walls, cpus = [], []
    for k in range(3):
        t, c = time.perf_counter(), _children_cpu()
        subprocess.run([sys.executable, "-m", "hse_opt.cli", "export", str(d / "FIT.json"), "-o",
                        str(d / f"nav{k}")], check=True, capture_output=True)
        walls.append(time.perf_counter() - t)
        cpus.append(_children_cpu() - c)
    t = time.perf_counter()
    cal = export_calibration(calibration, d / "nav", source="FIT.json")
    inside = time.perf_counter() - t
    X = _random_points(cal, 1024, rng)
    rows = ",\n".join("{" + ", ".join(repr(float(v)) for v in col) + "}" for col in X.T)
    (d / "nav" / "points.h").write_text(f"#define N_POINTS 1024\nstatic const double POINTS[1024][{X.shape[0]}] = "
                                        f"{{\n{rows}}};\n")
    (d / "nav" / "driver.c").write_text(DRIVER)
    cc = shutil.which("cc") or shutil.which("gcc")
    subprocess.run([cc, "-std=c99", "-O2", "-o", str(d / "nav" / "bench"), str(d / "nav" / "driver.c"),
                    str(d / "nav" / "hse_compensation.c"), "-lm"], check=True)
    ns, bad, _ = subprocess.run([str(d / "nav" / "bench")], check=True, capture_output=True,
                                text=True).stdout.split()
    print(f"{label}: {len(calibration.model.effect_names)} effects, {X.shape[0]} inputs, "
          f"tilt {'known' if calibration.tilt_known else 'unknown'}\n"
          f"  hse-opt export (new process): CPU median {np.median(cpus):.2f} s (target <= 2 s: "
          f"{'met' if np.median(cpus) <= 2 else 'NOT met'}), wall median {np.median(walls):.2f} s; "
          f"inside Python {inside:.3f} s\n"
          f"  compiled compensation (cc -O2): {float(ns):.1f} ns per call (target <= 100 ns: "
          f"{'met' if float(ns) <= 100 else 'NOT met'}); status != 0 at {bad} of 1024 points inside the range")


def main():
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    rng = np.random.default_rng(18)
    with tempfile.TemporaryDirectory() as tmp:
        bench("paper-model", _campaign(["hse"], 240, rng)[1], rng, Path(tmp))
        bench("every-catalogue-effect", _campaign(EVERY_EFFECT, 240, rng)[1], rng, Path(tmp))
        bench("paper-table-1", fit(paper_table1(), fix={"lambda2*tilt_const": 0.0}), rng, Path(tmp))


if __name__ == "__main__":
    main()
