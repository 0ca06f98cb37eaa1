"""``hse-opt calibrate`` benchmark (issue 26): prints its figures.

A simulated campaign of ten-minute 500 Hz raw logs (the paper-like default system with a
300-us encoder sync delay; 5 stand positions, rates 20/40/60/-40/-60 deg/s, twice; each
log distinct), its lab calibration file as ``hse-opt simulate --write-calibration`` writes it.

1. Reading: every log read and checked by :func:`hse_opt.align.load_rawlog`, in one
   process, page cache warm (the reference of the target).
2. ``hse-opt calibrate LOGS --out DIR --jobs J`` end to end in a fresh process (start-up,
   alignment, fit, diagnosis, risk, export, plan, report): target <= 2 x (1) + 15 s.
3. One update's computation in-process, the other logs' alignments cached (wall and CPU).
4. ``--watch``: with all but the last log in the folder, the time from the last log's
   appearance (a hard link: complete at once) to its line on stdout, and to the rewritten
   ``summary.json`` (the report's plots included); the line's time includes the stability
   rule's wait of one to two poll intervals (``--poll-s``). Target: one update <= 2 s.

    python benchmarks/calibrate.py                 # 50 logs, --jobs 2
    python benchmarks/calibrate.py --logs 10 --jobs 1
"""
import argparse
import os
import selectors
import subprocess
import sys
import tempfile
import time

import numpy as np


def make_logs(n_logs, workdir):
    from hse_opt.align import save_calibration
    from hse_opt.data import Plan
    from hse_opt.sim import TruthConfig, run_campaign
    from hse_opt.sim.campaign import lab_calibration

    truth = TruthConfig.default().updated({"encoder": {"sync_delay_us": 300.0}})
    rates = (20.0, 40.0, 60.0, -40.0, -60.0)
    rows = [(rates[k % 5], 72.0 * ((k // 5) % 5)) for k in range(n_logs)]
    rate, az = zip(*rows)
    plan = Plan.from_columns({"run": np.arange(1, n_logs + 1), "rate_dps": rate, "azimuth_deg": az,
                              "t_start_s": 3600.0 + 700.0 * np.arange(n_logs), "duration_s": np.full(n_logs, 600.0)},
                             source="benchmark plan")
    logs = os.path.join(workdir, "logs")
    os.makedirs(logs)
    run_campaign(plan, truth, 1, jobs=2, raw_logs=logs)
    cal = os.path.join(workdir, "CALIBRATION.toml")
    save_calibration(lab_calibration(truth), cal)
    return logs, cal


def read_time(logs):
    from hse_opt.align import load_rawlog
    paths = sorted(os.path.join(logs, f) for f in os.listdir(logs))
    for p in paths:                      # warm the page cache
        load_rawlog(p)
    t0 = time.perf_counter()
    for p in paths:
        load_rawlog(p)
    return time.perf_counter() - t0, len(paths)


def whole(logs, cal, jobs, workdir):
    out = os.path.join(workdir, "session")
    cmd = [sys.executable, "-m", "hse_opt.cli", "calibrate", logs, "--out", out, "--jobs", str(jobs),
           "--calibration", cal, "--no-progress"]
    import resource
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"calibrate failed: {done.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return seconds, cpu, done.stdout.splitlines()[0]


def watch(logs, cal, jobs, workdir, poll):
    names = sorted(os.listdir(logs), key=lambda f: int(f.split("_")[1].split(".")[0]))
    folder = os.path.join(workdir, "watched")
    os.makedirs(folder)
    for f in names[:-1]:
        os.link(os.path.join(logs, f), os.path.join(folder, f))
    out = os.path.join(workdir, "watch_out")
    proc = subprocess.Popen([sys.executable, "-m", "hse_opt.cli", "calibrate", folder, "--out", out, "--watch",
                             "--jobs", str(jobs), "--calibration", cal, "--poll-s", str(poll)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    try:
        if not sel.select(600):
            raise SystemExit("no first line from --watch")
        proc.stdout.readline()
        summary = os.path.join(out, "summary.json")
        while not os.path.exists(summary):
            time.sleep(0.01)
        stamp = os.stat(summary).st_mtime_ns
        time.sleep(2 * poll)
        t0 = time.perf_counter()
        os.link(os.path.join(logs, names[-1]), os.path.join(folder, names[-1]))
        if not sel.select(120):
            raise SystemExit("no line after the new log")
        line = proc.stdout.readline()
        t_line = time.perf_counter() - t0
        while os.stat(summary).st_mtime_ns == stamp:
            time.sleep(0.01)
        t_report = time.perf_counter() - t0
    finally:
        proc.terminate()
        proc.communicate(timeout=60)
    return t_line, t_report, line.strip()


def update_compute(logs, cal):
    """One update's computation in-process (no poll wait, no start-up): the session on all
    logs after it has seen all but the last (their alignments cached), wall and CPU time."""
    from hse_opt.align import load_calibration
    from hse_opt.app.session import calibrate
    names = sorted(os.listdir(logs), key=lambda f: int(f.split("_")[1].split(".")[0]))
    paths = [os.path.join(logs, f) for f in names]
    lab = load_calibration(cal)
    kw = dict(config=lab.align_config(), align_kw={"pulse_weights": lab.pulse_weights}, cache={})
    calibrate(paths[:-1], **kw)
    w0, c0 = time.perf_counter(), time.process_time()
    result = calibrate(paths, **kw)
    return time.perf_counter() - w0, time.process_time() - c0, result.seconds


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--logs", type=int, default=50)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--poll-s", type=float, default=0.5)
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as workdir:
        t0 = time.perf_counter()
        logs, cal = make_logs(args.logs, workdir)
        print(f"{args.logs} ten-minute 500 Hz logs simulated in {time.perf_counter() - t0:.1f} s")
        read, n = read_time(logs)
        print(f"1. reading the {n} logs (load_rawlog, one process, warm cache): {read:.2f} s "
              f"({1e3 * read / n:.1f} ms per log)")
        seconds, cpu, first = whole(logs, cal, args.jobs, workdir)
        target = 2 * read + 15
        print(f"2. hse-opt calibrate --jobs {args.jobs}, fresh process: {seconds:.2f} s wall, {cpu:.2f} s CPU in all "
              f"its processes (target <= 2 x {read:.2f} + 15 = {target:.1f} s) {'ok' if seconds <= target else 'OVER'}")
        print(f"   {first}")
        wall, cpu, steps = update_compute(logs, cal)
        print(f"3. one update's computation in-process (log {args.logs} new, the others cached): {wall:.2f} s wall, "
              f"{cpu:.2f} s CPU (" + ", ".join(f"{k} {v:.2f} s" for k, v in steps.items()) + ")")
        t_line, t_report, line = watch(logs, cal, args.jobs, workdir, args.poll_s)
        print(f"4. --watch --poll-s {args.poll_s:g}, log {args.logs} arriving: its line after {t_line:.2f} s "
              f"(target <= 2 s) {'ok' if t_line <= 2 else 'OVER'}; the report rewritten after {t_report:.2f} s")
        print(f"   {line}")


if __name__ == "__main__":
    main()
