"""``hse-opt align`` benchmark (issue 13, item 4): prints its figures.

1. The alignment of one 10-minute 500 Hz raw log (the paper-like default system, 40 deg/s),
   reading excluded (target <= 20 ms); its quality checks (``hse_opt.align.quality.assess``)
   and Allan analysis (``hse_opt.align.noise.noise_from_log``), which ``hse-opt align`` adds
   (issue 25: together <= 50 % of the alignment); the reading of its ``.npz`` file.
2. ``hse-opt align DIR -o RUNS.csv --jobs N`` on a directory of 100 such logs, end to end as
   a user runs it (a fresh process: start-up, reading, checks, alignment, RUNS.csv), in logs
   per second (target >= 40 with ``--jobs 2`` on the project's 2-core machine). The
   directory holds 10 distinct simulated logs, each hard-linked 10 times under its own name
   (100 files, 10 x 29 MB on disk): every file is read, checked and aligned in full.

    python benchmarks/align.py               # 100 logs, --jobs 2
    python benchmarks/align.py --logs 20 --jobs 1
"""
import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from hse_opt.align.noise import noise_from_log
from hse_opt.align.quality import assess
from hse_opt.sim import (AlignConfig, RunSpec, TruthConfig, align, align_config_from_truth, generate, load_rawlog,
                         save_rawlog)
from hse_opt.units import DEG_PER_S


def one_log(repeats, path):
    truth = TruthConfig.default()
    log = generate(truth, RunSpec(rate=40 * DEG_PER_S, azimuth=0.3, duration=600.0, t_start=7200.0),
                   np.random.default_rng(0))
    cfg = align_config_from_truth(truth)
    align(log, cfg)                                   # warm-up
    assess(log)
    noise_from_log(log)
    ta, tq, tn = [], [], []
    for _ in range(repeats):                          # interleaved: a busy machine slows all three alike
        t0 = time.perf_counter()
        align(log, cfg)
        t1 = time.perf_counter()
        assess(log)
        t2 = time.perf_counter()
        noise_from_log(log)
        t3 = time.perf_counter()
        ta.append(t1 - t0)
        tq.append(t2 - t1)
        tn.append(t3 - t2)
    save_rawlog(log, path)
    load_rawlog(path)
    tr = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        load_rawlog(path)
        tr.append(time.perf_counter() - t0)
    print(f"one 10-minute 500 Hz log ({len(log)} samples, {repeats} repeats; median [min]):")
    print(f"  align (reading excluded) : {1e3 * statistics.median(ta):6.1f} ms  [{1e3 * min(ta):.1f}]  "
          "(target <= 20 ms)")
    added = (statistics.median(tq) + statistics.median(tn)) / statistics.median(ta)
    added_min = (min(tq) + min(tn)) / min(ta)
    print(f"  quality checks           : {1e3 * statistics.median(tq):6.1f} ms  [{1e3 * min(tq):.1f}]")
    print(f"  Allan analysis (noise)   : {1e3 * statistics.median(tn):6.1f} ms  [{1e3 * min(tn):.1f}]")
    print(f"  checks + Allan / align   : {100 * added:6.0f} %  [{100 * added_min:.0f}]  (target <= 50 %)")
    print(f"  read .npz + checks       : {1e3 * statistics.median(tr):6.1f} ms  [{1e3 * min(tr):.1f}]")


def directory(n_logs, jobs, workdir):
    truth = TruthConfig.default()
    logdir = os.path.join(workdir, "logs")
    os.makedirs(logdir)
    distinct = min(10, n_logs)
    for k in range(distinct):
        log = generate(truth, RunSpec(rate=(20 + 20 * (k % 3)) * DEG_PER_S * (-1) ** k, azimuth=0.3,
                                      duration=600.0, t_start=7200.0 + 700 * k), np.random.default_rng(k))
        save_rawlog(log, os.path.join(workdir, f"src{k}.npz"))
    for i in range(n_logs):
        os.link(os.path.join(workdir, f"src{i % distinct}.npz"), os.path.join(logdir, f"log_{i:03d}.npz"))
    out = os.path.join(workdir, "RUNS.csv")
    cmd = [sys.executable, "-m", "hse_opt.cli", "align", logdir, "-o", out, "--jobs", str(jobs), "--no-progress"]
    subprocess.run(cmd, check=True, capture_output=True)          # warm the page cache
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True)
        times.append(time.perf_counter() - t0)
    best = min(times)
    print(f"hse-opt align on {n_logs} ten-minute logs, --jobs {jobs} (3 runs; best [median]):")
    print(f"  {best:.2f} s [{statistics.median(times):.2f}] -> {n_logs / best:.1f} logs/s "
          f"[{n_logs / statistics.median(times):.1f}]  (target >= 40 logs/s with --jobs 2)")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--logs", type=int, default=100)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as workdir:
        one_log(args.repeats, os.path.join(workdir, "one.npz"))
        directory(args.logs, args.jobs, workdir)


if __name__ == "__main__":
    main()
