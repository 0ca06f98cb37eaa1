"""``hse-opt align`` benchmark (issue 13, item 4): prints its figures.

1. The alignment of one 10-minute 500 Hz raw log (the paper-like default system, 40 deg/s),
   reading excluded (target <= 20 ms); its quality checks (``hse_opt.align.quality.assess``,
   with the block sums it shares with the Allan analysis: ``hse_opt.align.blocks.block_sums``)
   and Allan analysis (``hse_opt.align.noise.noise_from_log`` on those sums), as ``hse-opt
   align`` runs them (issue 25: together <= 50 % of the alignment; BLAS on one thread, as the
   command line loads it); the reading of its ``.npz`` file; and all three in ``hse-opt
   align``'s own order (read, checks and Allan analysis, align: the checks then run on the
   freshly read arrays, not after the alignment).
2. ``hse-opt align DIR -o RUNS.csv --jobs N`` on a directory of 100 such logs, end to end as
   a user runs it (a fresh process: start-up, reading, checks, alignment, RUNS.csv), in logs
   per second (target >= 40 with ``--jobs 2`` on the project's 2-core machine), with the
   filter tuned from the logs' own noise (the default: a first pass over the logs for their
   Allan figures) and by ``--truth``; also the CPU time of all its processes per log, which
   a busy machine does not inflate. The directory holds 10 distinct simulated logs, each
   written 10 times with its clock's epoch moved (100 files of 29 MB: a copy would be
   refused as the same log): every file is read, checked and aligned in full.

    python benchmarks/align.py               # 100 logs, --jobs 2
    python benchmarks/align.py --logs 20 --jobs 1
    python benchmarks/align.py --logs 0             # the single log only
    python benchmarks/align.py --logs 0 --scaling   # also logs of 1-20 minutes
    python benchmarks/align.py --logs 0 --parts     # also each compiled part against numpy's route

3. With ``--scaling``: align and checks + Allan (CPU, medians) on logs of 1, 2, 5, 10 and 20
   minutes, and a straight line through them: the fixed cost of each (independent of the log's
   length) and its cost per minute of log. The ratio of the per-minute costs is what the
   checks and the Allan analysis add to a long log's alignment, whatever their fixed cost.
4. With ``--parts``: each part the compiled kernels serve (``hse_opt/align/_kernels.c``), by
   numpy's route and compiled, right after an alignment as ``hse-opt align`` runs them
   (medians of the repeats, ms; needs the compiled part built).
"""
import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

from hse_opt.app.cli import _one_blas_thread

_one_blas_thread()          # BLAS as the command line runs it (one thread), before numpy loads it

import numpy as np  # noqa: E402

from hse_opt.align import _compiled, blocks, noise
from hse_opt.align.blocks import block_sums
from hse_opt.align.noise import noise_from_log
from hse_opt.align.quality import assess
from hse_opt.sim import (AlignConfig, RawLog, RunSpec, TruthConfig, align, align_config_from_truth, generate,
                         load_rawlog, save_rawlog, save_truth)
from hse_opt.units import DEG_PER_S


def one_log(repeats, path):
    truth = TruthConfig.default()
    log = generate(truth, RunSpec(rate=40 * DEG_PER_S, azimuth=0.3, duration=600.0, t_start=7200.0),
                   np.random.default_rng(0))
    cfg = align_config_from_truth(truth)

    def checks():                                     # as hse-opt align: one pass of block sums for both
        sums = block_sums(log)
        return assess(log, sums=sums), sums

    align(log, cfg)                                   # warm-up
    quality, sums = checks()
    noise_from_log(quality.log, sums=sums)
    ta, tq, tn, cpu = [], [], [], []
    for _ in range(repeats):                          # interleaved: a busy machine slows all three alike
        c0, t0 = time.process_time(), time.perf_counter()
        align(log, cfg)
        c1, t1 = time.process_time(), time.perf_counter()
        quality, sums = checks()
        c2, t2 = time.process_time(), time.perf_counter()
        noise_from_log(quality.log, sums=sums)
        c3, t3 = time.process_time(), time.perf_counter()
        ta.append(t1 - t0)
        tq.append(t2 - t1)
        tn.append(t3 - t2)
        cpu.append((c1 - c0, c2 - c1, c3 - c2))
    save_rawlog(log, path)
    load_rawlog(path)
    tr, tc, tl = [], [], []
    for _ in range(repeats):                          # in hse-opt align's order: read, checks + Allan, align
        t0 = time.perf_counter()
        read = load_rawlog(path)
        t1 = time.perf_counter()
        sums = block_sums(read)
        quality = assess(read, sums=sums)
        noise_from_log(quality.log, sums=sums)
        t2 = time.perf_counter()
        align(quality.log, cfg)
        t3 = time.perf_counter()
        tr.append(t1 - t0)
        tc.append(t2 - t1)
        tl.append(t3 - t2)
    print(f"one 10-minute 500 Hz log ({len(log)} samples, {repeats} repeats; median [min]; the raw-log path's "
          f"compiled part {'built' if _compiled.kernels is not None else 'not built: numpy route'}):")
    print(f"  align (reading excluded) : {1e3 * statistics.median(ta):6.1f} ms  [{1e3 * min(ta):.1f}]  "
          "(target <= 20 ms)")
    added = (statistics.median(tq) + statistics.median(tn)) / statistics.median(ta)
    added_min = (min(tq) + min(tn)) / min(ta)
    print(f"  quality checks           : {1e3 * statistics.median(tq):6.1f} ms  [{1e3 * min(tq):.1f}]")
    print(f"  Allan analysis (noise)   : {1e3 * statistics.median(tn):6.1f} ms  [{1e3 * min(tn):.1f}]")
    print(f"  checks + Allan / align   : {100 * added:6.0f} %  [{100 * added_min:.0f}]  (target <= 50 %)")
    ca, cq, cn = (statistics.median(c) for c in zip(*cpu))
    print(f"  CPU (process time, which a busy machine inflates less): align {1e3 * ca:.1f} ms, checks "
          f"{1e3 * cq:.1f} ms ({100 * cq / ca:.0f} %), Allan {1e3 * cn:.1f} ms ({100 * cn / ca:.0f} %)")
    print(f"  read .npz + checks       : {1e3 * statistics.median(tr):6.1f} ms  [{1e3 * min(tr):.1f}]")
    print(f"  in hse-opt align's order (read, checks + Allan, align): checks + Allan "
          f"{1e3 * statistics.median(tc):.1f} ms, align {1e3 * statistics.median(tl):.1f} ms: "
          f"{100 * statistics.median(tc) / statistics.median(tl):.0f} %  [{100 * min(tc) / min(tl):.0f}]")


def scaling(repeats):
    truth = TruthConfig.default()
    cfg = align_config_from_truth(truth)
    minutes = np.array([1.0, 2.0, 5.0, 10.0, 20.0])
    costs = []
    print(f"align and checks + Allan against the log's length (CPU, {repeats} repeats, medians):")
    for m in minutes:
        log = generate(truth, RunSpec(rate=40 * DEG_PER_S, azimuth=0.3, duration=60.0 * m, t_start=7200.0),
                       np.random.default_rng(0))
        align(log, cfg)
        ta, tc = [], []
        for _ in range(repeats + 1):
            c0 = time.process_time()
            align(log, cfg)
            c1 = time.process_time()
            sums = block_sums(log)
            noise_from_log(assess(log, sums=sums).log, sums=sums)
            c2 = time.process_time()
            ta.append(c1 - c0)
            tc.append(c2 - c1)
        a, c = statistics.median(ta[1:]), statistics.median(tc[1:])
        costs.append((a, c))
        print(f"  {m:4.0f} min: align {1e3 * a:6.2f} ms, checks + Allan {1e3 * c:6.2f} ms ({100 * c / a:.0f} %)")
    (sa, fa), (sc, fc) = (np.polyfit(minutes, col, 1) for col in np.transpose(costs))
    print(f"  straight lines: align {1e3 * fa:.2f} ms + {1e3 * sa:.3f} ms/min, checks + Allan {1e3 * fc:.2f} ms + "
          f"{1e3 * sc:.3f} ms/min: per minute of log they add {100 * sc / sa:.0f} % to the alignment")


def parts(repeats):
    from hse_opt.align import steps
    from hse_opt.align._quanta import Quanta
    if _compiled.kernels is None:
        print("the compiled part is not built: no parts to compare")
        return
    truth = TruthConfig.default()
    cfg = align_config_from_truth(truth)
    log = generate(truth, RunSpec(rate=40 * DEG_PER_S, azimuth=0.3, duration=600.0, t_start=7200.0),
                   np.random.default_rng(0))
    sums = block_sums(log)
    res = sums.residual
    beta = steps.shares(res)
    short, sizes = noise._log_sizes(res.blocks.shape[1], res.block)
    work = {"record's pass (block_sums)": lambda: block_sums(log),
            "deterministic fit (_fit_residual)": lambda: blocks._fit_residual(log, sums.block, sums.sums),
            "short Allan clusters": lambda: noise._short_allan(log, res, short),
            "Allan curve (allan_deviation)": lambda: noise.allan_deviation(res.blocks, res.tau0, sizes=sizes),
            "check 3b (step_statistic)": lambda: steps.step_statistic(log.t, log.encoder, log.gyro, res, beta, sums),
            "quanta (Quanta.of)": lambda: Quanta.of(log.encoder, log.gyro, log.accel)}
    built = _compiled.kernels
    print(f"each compiled part against numpy's route, right after align (CPU, {repeats} repeats, medians):")
    try:
        for name, f in work.items():
            times = {"numpy": [], "compiled": []}
            for _ in range(repeats):
                for route, kernels in (("compiled", built), ("numpy", None)):
                    align(log, cfg)
                    _compiled.kernels = kernels
                    c0 = time.process_time()
                    f()
                    times[route].append(time.process_time() - c0)
                    _compiled.kernels = built
            print(f"  {name:36s}: numpy {1e3 * statistics.median(times['numpy']):.3f} ms -> compiled "
                  f"{1e3 * statistics.median(times['compiled']):.3f} ms")
    finally:
        _compiled.kernels = built


def directory(n_logs, jobs, workdir):
    truth = TruthConfig.default()
    save_truth(truth, os.path.join(workdir, "TRUTH.toml"))
    logdir = os.path.join(workdir, "logs")
    os.makedirs(logdir)
    distinct = min(10, n_logs)
    sources = [generate(truth, RunSpec(rate=(20 + 20 * (k % 3)) * DEG_PER_S * (-1) ** k, azimuth=0.3,
                                       duration=600.0, t_start=7200.0 + 700 * k), np.random.default_rng(k))
               for k in range(distinct)]
    for i in range(n_logs):     # each file its own log (a copy is refused): the clock's epoch moved
        src = sources[i % distinct]
        save_rawlog(RawLog(src.t + 1000.0 * i, src.gyro, src.accel, src.encoder, src.meta),
                    os.path.join(logdir, f"log_{i:03d}.npz"))
    out = os.path.join(workdir, "RUNS.csv")
    print(f"hse-opt align on {n_logs} ten-minute logs, --jobs {jobs} (3 runs; best [median]; CPU of all "
          "processes per log, and the logs/s two such cores would give):")
    for label, extra in (("filter tuned from the logs (a first pass over 8)", []),
                         ("filter tuned by --truth (1 pass)", ["--truth", os.path.join(workdir, "TRUTH.toml")])):
        cmd = [sys.executable, "-m", "hse_opt.cli", "align", logdir, "-o", out, "--jobs", str(jobs), "--no-progress",
               *extra]
        subprocess.run(cmd, check=True, capture_output=True)          # warm the page cache
        times, cpu = [], []
        for _ in range(3):
            r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            times.append(time.perf_counter() - t0)
            r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu.append(r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime)
        best, per_log = min(times), min(cpu) / n_logs
        print(f"  {label}: {best:.2f} s [{statistics.median(times):.2f}] -> {n_logs / best:.1f} logs/s "
              f"[{n_logs / statistics.median(times):.1f}]; CPU {1e3 * per_log:.1f} ms/log -> "
              f"{2 / per_log:.0f} logs/s on 2 cores  (target >= 40 logs/s with --jobs 2)")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--logs", type=int, default=100, help="logs for part 2 (0: part 1 only)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--scaling", action="store_true", help="also the costs against the log's length (part 3)")
    ap.add_argument("--parts", action="store_true", help="also each compiled part against numpy's route (part 4)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as workdir:
        one_log(args.repeats, os.path.join(workdir, "one.npz"))
        if args.scaling:
            scaling(args.repeats)
        if args.parts:
            parts(args.repeats)
        if args.logs > 0:
            directory(args.logs, args.jobs, workdir)


if __name__ == "__main__":
    main()
