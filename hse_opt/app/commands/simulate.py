"""``hse-opt simulate``: PLAN.csv (+ TRUTH.toml) -> RUNS.csv with the numeric simulator."""
import os
import sys

from . import add_dask_argument, dask_client, message
from .outputs import FILE

NAME = "simulate"
HELP = "simulate the alignments of a test plan (PLAN.csv -> RUNS.csv)"
DESCRIPTION = (
    "Simulate every planned alignment with the numeric simulator: raw 500 Hz gyro, "
    "accelerometer and encoder data of the true system (TRUTH.toml; default: the paper-like "
    "system) through the alignment processor. Writes RUNS.csv with the heading error, the "
    "alignment's own pitch, roll and 1-sigma, and the mean IMU temperature (temp_c). With "
    "--field, a field campaign: each stand position (the plan's position column, else one per "
    "azimuth, labelled P1, P2, ...) keeps its true heading to itself, and RUNS.csv carries the "
    "alignment's own heading_deg and the position instead of azimuth_deg and "
    "heading_err_arcsec (kept for the positions named in --surveyed). --raw-logs DIR also writes "
    "every run's raw log, for hse-opt align; --write-calibration CAL.toml the system's lab "
    "calibration for it (hse-opt align --calibration CAL.toml).")
INPUTS = ("plan", "truth")
# raw logs: a folder, any names
OUTPUTS = {"output": FILE, "write_truth": FILE, "write_calibration": FILE, "raw_logs": ()}
EXAMPLE = """examples:
  hse-opt simulate PLAN.csv -o RUNS.csv --seed 1 --jobs 2
  hse-opt simulate FIELD_PLAN.csv -o RUNS.csv --field --surveyed A --raw-logs logs/ --write-calibration CAL.toml
  hse-opt simulate PLAN.csv --truth TRUTH.toml -o RUNS.csv --dask tcp://scheduler:8786"""


def add_arguments(parser):
    parser.add_argument("plan", metavar="PLAN.csv", help="the test plan")
    parser.add_argument("--truth", metavar="TRUTH.toml",
                        help="the true system (default: the paper-like system)")
    parser.add_argument("-o", "--output", metavar="RUNS.csv", required=True, help="results to write")
    parser.add_argument("--seed", type=int, default=0, help="campaign seed, >= 0 (default 0)")
    parser.add_argument("--jobs", type=int, default=1, help="local worker processes (default 1)")
    add_dask_argument(parser)
    parser.add_argument("--write-truth", metavar="FILE",
                        help="also write the truth used, every key, to FILE (TOML)")
    parser.add_argument("--write-calibration", metavar="CAL.toml",
                        help="also write the simulated system's lab calibration (its calibrated K~_g and "
                             "C~_s^b, ideal accelerometers, pulse weights, noise, latitude; "
                             "docs/calibration.md) for hse-opt align --calibration, e.g. "
                             "--write-calibration CAL.toml")
    parser.add_argument("--field", action="store_true",
                        help="a field campaign: the positions' true headings are hidden from RUNS.csv")
    parser.add_argument("--surveyed", metavar="LABELS", default="",
                        help="with --field: comma-separated positions whose azimuth is known")
    parser.add_argument("--raw-logs", metavar="DIR",
                        help="also write each run's raw log to DIR/run_<id>.npz (DIR must exist)")
    parser.add_argument("--no-progress", dest="progress", action="store_false",
                        help="no progress bar on stderr")


def _io(action, what, fun, path, *args):
    """Read or write a file; a file that cannot be read or written is bad input (exit 2)."""
    try:
        return fun(*args, path) if args else fun(path)
    except OSError as err:
        raise ValueError(f"{path}: cannot {action} the {what}: {err.strerror or err}; allowed: "
                         f"{'a file you can read' if action == 'read' else 'a path you can write'}") from None


def run(args):
    from tqdm import tqdm

    from ...data import load_plan, save_runs
    from ...sim import TruthConfig, run_campaign

    if args.seed < 0:
        raise ValueError(f"--seed {args.seed} is not allowed; allowed: an integer >= 0")
    if args.jobs < 1:
        raise ValueError(f"--jobs {args.jobs} is not allowed; allowed: an integer >= 1")
    surveyed = [p.strip() for p in args.surveyed.split(",") if p.strip()]
    if surveyed and not args.field:
        raise ValueError("--surveyed: allowed only with --field")
    if args.raw_logs and not os.path.isdir(args.raw_logs):
        raise ValueError(f"--raw-logs {args.raw_logs}: the directory does not exist; allowed: an existing directory")
    truth = _io("read", "truth", TruthConfig.from_toml, args.truth) if args.truth else TruthConfig.default()
    plan = _io("read", "plan", load_plan, args.plan)
    # tqdm: on stderr, off with --no-progress and when stderr is not a terminal
    with dask_client(args.dask) as client, tqdm(total=len(plan), unit="run", desc="simulate", file=sys.stderr,
                                                disable=None if args.progress else True) as bar:
        runs = run_campaign(plan, truth, args.seed, jobs=args.jobs, client=client,
                            progress=lambda done, total: bar.update(done - bar.n),
                            field=args.field, surveyed=surveyed,
                            raw_logs=args.tx.path("raw_logs") if args.raw_logs else None)
    _io("write", "runs", save_runs, args.tx.path("output"), runs)
    if args.write_truth:
        _io("write", "truth", truth.to_toml, args.tx.path("write_truth"))
    if args.write_calibration:
        from ...align import save_calibration
        from ...sim import lab_calibration
        _io("write", "calibration", save_calibration, args.tx.path("write_calibration"), lab_calibration(truth))
    logs = f"; raw logs in {args.raw_logs}" if args.raw_logs else ""
    message(f"hse-opt simulate: {len(runs)} runs written to {args.output}{logs}")
    return 0
