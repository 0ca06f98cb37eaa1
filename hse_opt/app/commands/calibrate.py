"""``hse-opt calibrate``: the whole field session in one command (see :mod:`hse_opt.app.session`)."""
import contextlib
import json
import os
import sys

from . import add_dask_argument, dask_client, message, print_json

NAME = "calibrate"
HELP = "the field session in one command: raw logs in; calibration, evidence, C and the next plan out"
DESCRIPTION = """\
Align every raw log (a folder, or files), recognise the campaign (surveyed: every log has a
stand reading azimuth_deg; field: none has; mixed), fit the paper's model plus --effects,
diagnose and add the effects the runs show (diagnose --refine), export the final calibration
for the navigation computer (C, calibration.json, test vectors and a C test driver in
DIR/nav), plan the rest of the campaign for the time left (as design --field --runs plans
it: the smallest sigma of lambda2 with power >= 0.8 of the diagnosis against each effect
outside the model the time left can show, counting the runs so far), and write ONE report
DIR/report.html - the verdict first: usable, or not yet and why - with DIR/summary.json (what
--json prints), DIR/RUNS.csv, DIR/FIT.json, DIR/nav/ and DIR/NEXT_PLAN.csv, all together or
none. The first line printed is the verdict. Exit status 0 whenever the report was written
(the verdict is in it), 2 for bad input (no log could be aligned, a bad option).

--watch: the live session. After the logs already in the folder, wait for new ones; after
each, print one line (lambda2 so far with its total uncertainty, the verdict, the next
alignment to run) as soon as it is known, then rewrite DIR's files (each update whole; the
report's plots take a few seconds more). A log is read once its size
and modification time (and its .json sidecar's) are unchanged over one poll interval
(--poll-s): a log still being written is never read half; names starting with '.' are
ignored (write under such a name and rename, or just write). Stops with exit 0 when the
verdict is usable with lambda2's total sigma <= --target-sigma (arcsec of lambda2) or when
--time-left-h has passed; Ctrl-C stops it with exit 130, the report of the last update
complete in DIR (SIGTERM: 143, the same)."""
INPUTS = ("logs", "calibration", "truth", "mapping")


def _files():
    from ..session import OUTPUT_FILES
    return OUTPUT_FILES


OUTPUTS = {"out": _files}
EXAMPLE = """\
examples:
  hse-opt calibrate logs/ --out session
  hse-opt calibrate logs/ --out session --effects sync_delay --time-left-h 3 --jobs 2 --json
  hse-opt calibrate logs/ --out session --watch --target-sigma 1.5 --time-left-h 6"""


def add_arguments(parser):
    from ..session import DEFAULT_TIME_LEFT_H, POLL_S
    parser.add_argument("logs", nargs="+", metavar="LOGS",
                        help="a folder of raw logs (.npz, .csv: hse_opt/align/rawlog.py), or log files")
    parser.add_argument("--out", metavar="DIR", required=True,
                        help="folder for report.html, summary.json, RUNS.csv, FIT.json, nav/, NEXT_PLAN.csv "
                             "(created when missing)")
    from .align import add_processor_arguments
    add_processor_arguments(parser)
    parser.add_argument("--effects", metavar="a,b", default="",
                        help="effects to model besides 'hse' from the start (the diagnosis may add more), "
                             "e.g. --effects sync_delay,warmup")
    parser.add_argument("--time-left-h", type=float, default=DEFAULT_TIME_LEFT_H, metavar="H",
                        help=f"stand time left for the rest of the campaign, h (default {DEFAULT_TIME_LEFT_H:g}); "
                             "with --watch also when the session stops")
    parser.add_argument("--target-sigma", type=float, default=None, metavar="ARCSEC",
                        help="target total 1-sigma of lambda2, arcsec: the verdict is 'not yet' above it; "
                             "--watch stops once it is reached, e.g. --target-sigma 1.5")
    parser.add_argument("--jobs", type=int, default=1, help="local worker processes for the alignment (default 1)")
    add_dask_argument(parser)
    parser.add_argument("--watch", action="store_true",
                        help="the live session: wait for new logs in the folder, one line and a new report "
                             "after each (see above)")
    parser.add_argument("--poll-s", type=float, default=POLL_S, metavar="S",
                        help=f"--watch: poll interval, s (default {POLL_S:g}; 0.05 to 60)")
    parser.add_argument("--json", action="store_true",
                        help="print summary.json's object on stdout (with --watch: one compact object per "
                             "line and update)")
    parser.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar on stderr")


def _effects(text):
    from ...model import as_model
    names = [e.strip() for e in text.split(",") if e.strip() and e.strip() != "hse"]
    try:
        as_model(["hse", *names])
    except ValueError as err:
        raise ValueError(f"--effects {text}: {err}") from None
    return names


def _check(args):
    import math
    if args.jobs < 1:
        raise ValueError(f"--jobs {args.jobs}: allowed: an integer >= 1")
    if not (math.isfinite(args.time_left_h) and args.time_left_h >= 0):
        raise ValueError(f"--time-left-h {args.time_left_h:g}: allowed: hours >= 0")
    if args.target_sigma is not None and not (math.isfinite(args.target_sigma) and args.target_sigma > 0):
        raise ValueError(f"--target-sigma {args.target_sigma:g}: allowed: arcsec of lambda2 > 0")
    if not (0.05 <= args.poll_s <= 60):
        raise ValueError(f"--poll-s {args.poll_s:g}: allowed: 0.05 to 60 s")
    out = os.path.realpath(args.out)
    for item in args.logs:
        if os.path.isdir(item) and os.path.realpath(item) == out:
            raise ValueError(f"--out {args.out}: is the log folder {item}; allowed: another folder")
    if args.watch and not (len(args.logs) == 1 and os.path.isdir(args.logs[0])):
        raise ValueError(f"--watch with {' '.join(args.logs)}: allowed: one folder of logs (the one they "
                         "arrive in)")


def run(args):
    from ..session import calibrate, write_outputs
    from .align import assumption, processor
    from .demo import _progress_bar

    _check(args)
    config, align_kw, suffixes = processor(args)
    assumed = assumption(args)
    kw = dict(config=config, align_kw=align_kw, suffixes=suffixes, effects=_effects(args.effects),
              jobs=args.jobs, notes=(assumed,) if assumed else ())
    if args.watch:
        with dask_client(args.dask) as client:
            return _watch(args, {**kw, "client": client})
    progress, close = _progress_bar(args.progress)
    try:
        with dask_client(args.dask) as client:
            result = calibrate(args.logs, **kw, client=client, time_left_h=args.time_left_h,
                               target_sigma=args.target_sigma, progress=progress)
    finally:
        close()
    for err in result.errors:
        message(f"hse-opt calibrate: bad log left out: {' '.join(err.split())}")
    if assumed:                 # once the logs are read (bad input stays one line)
        message(f"hse-opt calibrate: note: {assumed}")
    data = write_outputs(result, args.tx.path("out"), shown=args.out)
    if args.json:
        print_json(data)
    else:
        from ...report.session import summary_lines
        lines = summary_lines(result)
        print(f"hse-opt calibrate: {lines[0]}")
        print("\n".join(f"  {ln}" for ln in lines[1:]))
        print(f"  report: {data['report']}")
    return 0


@contextlib.contextmanager
def _signals_deferred():
    """Ctrl-C and SIGTERM wait until the block is done (the report being rewritten is finished
    first), then act as they would have (main thread only)."""
    import signal
    import threading
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got = []
    names = [n for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n)]
    old = {n: signal.signal(getattr(signal, n), lambda signum, frame: got.append(signum)) for n in names}
    try:
        yield
    finally:
        for n, handler in old.items():
            signal.signal(getattr(signal, n), handler)
        for signum in got[:1]:
            signal.raise_signal(signum)


def _watch(args, kw):
    """The live session: after each update the line first (the next alignment as soon as it is
    known), then DIR rewritten, Ctrl-C deferred until it is whole."""
    from ..cli import Terminated
    from ..session import OUTPUT_FILES, summary, watch, write_outputs
    from .outputs import Transaction

    written = None
    try:
        for result in watch(args.logs[0], poll=args.poll_s, time_left_h=args.time_left_h,
                            target_sigma=args.target_sigma, **kw):
            with _signals_deferred():
                if args.json:
                    sys.stdout.write(json.dumps(summary(result, args.out), allow_nan=False) + "\n")
                else:
                    sys.stdout.write(result.line() + "\n")
                sys.stdout.flush()
                with Transaction([("LOGS", p) for p in result.logs],
                                 [("out", "--out", args.out, OUTPUT_FILES)]) as tx:
                    write_outputs(result, tx.path("out"), shown=args.out)
                if written is None and kw.get("notes"):
                    message(f"hse-opt calibrate --watch: note: {kw['notes'][0]}")
                written = result
    except (KeyboardInterrupt, Terminated) as err:
        what = "interrupted" if isinstance(err, KeyboardInterrupt) else f"terminated (signal {err.signum})"
        done = ("no log was processed: no report written" if written is None else
                f"the report in {args.out} is complete for the {len(written.logs)} logs read "
                f"(verdict: {written.verdict})")
        message(f"hse-opt calibrate --watch: {what}; {done}")
        return 130 if isinstance(err, KeyboardInterrupt) else 128 + err.signum
    if written is None:
        message(f"hse-opt calibrate --watch: the {args.time_left_h:g} h are over and no log could be aligned; "
                "no report written")
        return 2
    total = written.target()[3]
    why = ("the target is reached" if args.target_sigma is not None and written.verdict == "usable"
           and total is not None and total <= args.target_sigma else f"the {args.time_left_h:g} h are over")
    message(f"hse-opt calibrate --watch: stopped: {why}; report: {os.path.join(args.out, 'report.html')}")
    return 0
