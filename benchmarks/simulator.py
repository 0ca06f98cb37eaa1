"""Simulator benchmark (issue 3, item 7): prints its figures.

1-minute runs one after the other (first, in a fresh process); one 10-minute run at 500 Hz
(the paper-like default system, 40 deg/s): time to generate the raw data, time to align it,
peak memory; generate + align of a 10-minute and a 1-minute run
against the time of drawing their Gaussian noise in float64 (``rng.standard_normal``), side by
side (issue 19: <= 1.5x and <= 2x); then runs per second of a 1,000-run campaign with
``--jobs`` local processes.

    python benchmarks/simulator.py            # full: 1,000-run campaign with --jobs 2
    python benchmarks/simulator.py --runs 100 --jobs 2

Anchors measured on this class of machine (issue 3): pyins 1.0.1 takes 5.4 s to generate a
10-minute 500 Hz turntable record and 12 s more for a 1 Hz EKF; gnss-ins-sim 15 s to
generate one. Targets: generate + align <= 100 ms (stretch 50 ms), peak memory <= 150 MB.
"""
import argparse
import os
import resource
import statistics
import time
import tracemalloc

import numpy as np

from hse_opt.sim import (AlignConfig, RunSpec, TruthConfig, align, align_config_from_truth, generate,
                         run_campaign)
from hse_opt.units import DEG_PER_S


def _rss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def one_run(repeats):
    truth = TruthConfig.default()
    run = RunSpec(rate=40 * DEG_PER_S, azimuth=0.3, duration=600.0, t_start=7200.0)
    cfg = align_config_from_truth(truth)
    rng = np.random.default_rng(0)
    rss_before = _rss_mb()
    log = generate(truth, run, rng)                       # warm-up (imports, caches)
    align(log, cfg)
    del log
    tg, ta, cpu = [], [], []
    for _ in range(repeats):
        c0 = time.process_time()
        t0 = time.perf_counter()
        log = generate(truth, run, rng)
        t1 = time.perf_counter()
        align(log, cfg)
        t2 = time.perf_counter()
        cpu.append(time.process_time() - c0)
        tg.append(t1 - t0)
        ta.append(t2 - t1)
        del log
    tracemalloc.start()
    log = generate(truth, run, rng)
    align(log, cfg)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    n = len(log)
    print(f"one 10-minute 500 Hz run ({n} samples, {repeats} repeats; median [min]):")
    print(f"  generate raw data : {1e3 * statistics.median(tg):6.1f} ms  [{1e3 * min(tg):.1f}]")
    print(f"  align             : {1e3 * statistics.median(ta):6.1f} ms  [{1e3 * min(ta):.1f}]")
    tot = [a + b for a, b in zip(tg, ta)]
    print(f"  generate + align  : {1e3 * statistics.median(tot):6.1f} ms  [{1e3 * min(tot):.1f}]"
          "   (target <= 100 ms, stretch 50 ms)")
    print(f"  the same, CPU time: {1e3 * statistics.median(cpu):6.1f} ms  [{1e3 * min(cpu):.1f}]"
          f"   (this process only; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")
    print(f"  peak memory       : {peak / 2**20:6.1f} MB allocated by generate + align (tracemalloc); "
          f"process max RSS {_rss_mb():.0f} MB incl. numpy/scipy/casadi imports "
          f"({rss_before:.0f} MB before the first run)   (target <= 150 MB)")


def short_runs(repeats):
    """generate and align of 1-minute runs one after the other (a campaign of short runs), first
    thing in the process: their working arrays are allocated and freed on every run, so this
    is where fresh memory pages would cost (see ``hse_opt.sim.imu._Workspace``)."""
    truth = TruthConfig.default()
    cfg = align_config_from_truth(truth)
    rng = np.random.default_rng(0)
    run = RunSpec(rate=40 * DEG_PER_S, azimuth=0.3, duration=60.0, t_start=7200.0)
    align(generate(truth, run, rng), cfg)
    tg, ta = [], []
    for _ in range(repeats):
        c0 = time.process_time()
        log = generate(truth, run, rng)
        c1 = time.process_time()
        align(log, cfg)
        tg.append(c1 - c0)
        ta.append(time.process_time() - c1)
    print(f"1-minute runs in a loop ({repeats}, CPU, median): generate {1e3 * statistics.median(tg):.2f} ms, "
          f"align {1e3 * statistics.median(ta):.2f} ms")


def noise_count(truth, n):
    """Gaussian draws of one run of ``n`` samples: 3 per sample for the gyros' angle random
    walk, 3 for the accelerometers' white noise, 1 for the table's jitter (when present)."""
    return n * (3 * bool(truth.gyro.arw) + 3 * bool(truth.accel.vrw) + bool(truth.table.jitter))


def floor_ratio(repeats):
    """generate + align against the float64 noise-draw floor, side by side in this process:
    each repeat times one run and then ``rng.standard_normal`` of the run's noise count
    (float64, numpy's ziggurat) in CPU time of this process, and the ratio is taken pair by
    pair (a drifting or shared machine moves both)."""
    truth = TruthConfig.default()
    cfg = align_config_from_truth(truth)
    rng = np.random.default_rng(0)
    print("generate + align / float64 noise-draw floor (median of per-repeat ratios [min]):")
    for duration, target, reps in ((600.0, 1.5, repeats), (60.0, 2.0, 10 * repeats)):
        run = RunSpec(rate=40 * DEG_PER_S, azimuth=0.3, duration=duration, t_start=7200.0)
        k = noise_count(truth, int(round(duration / truth.timing.sample_period)))
        align(generate(truth, run, rng), cfg)
        rng.standard_normal(k)
        ratios, sims, floors = [], [], []
        for _ in range(reps):
            t0 = time.process_time()
            align(generate(truth, run, rng), cfg)
            t1 = time.process_time()
            rng.standard_normal(k)
            t2 = time.process_time()
            ratios.append((t1 - t0) / (t2 - t1))
            sims.append(t1 - t0)
            floors.append(t2 - t1)
        print(f"  {duration / 60:4.0f}-minute run: {statistics.median(ratios):5.2f} [{min(ratios):.2f}]"
              f"   (target <= {target}; CPU: generate + align {1e3 * statistics.median(sims):.2f} ms, "
              f"floor {1e3 * statistics.median(floors):.2f} ms for {k} draws)")


def campaign(runs, jobs):
    truth = TruthConfig.default()
    plan = [{"run": i, "rate_dps": 40.0 * (1 if i % 2 else -1), "azimuth_deg": 90.0 * (i % 4),
             "t_start_s": 3600.0 + 650.0 * i, "duration_s": 600.0} for i in range(runs)]
    t0 = time.perf_counter()
    result = run_campaign(plan, truth, seed=1, jobs=jobs)
    el = time.perf_counter() - t0
    assert len(result) == runs
    print(f"campaign: {runs} ten-minute runs with --jobs {jobs}: {el:.1f} s, "
          f"{runs / el:.1f} runs/s ({1e3 * el / runs:.0f} ms per run)")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--repeats", type=int, default=10)
    p.add_argument("--runs", type=int, default=1000)
    p.add_argument("--jobs", type=int, default=2)
    a = p.parse_args(argv)
    short_runs(10 * a.repeats)
    one_run(a.repeats)
    floor_ratio(a.repeats)
    if a.runs:
        campaign(a.runs, a.jobs)


if __name__ == "__main__":
    main()
