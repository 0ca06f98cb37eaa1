"""``hse-opt simulate``: PLAN.csv (+ TRUTH.toml) -> RUNS.csv with the numeric simulator."""
import sys

from . import message

NAME = "simulate"
HELP = "simulate the alignments of a test plan (PLAN.csv -> RUNS.csv)"
DESCRIPTION = (
    "Simulate every planned alignment with the numeric simulator: raw 500 Hz gyro, "
    "accelerometer and encoder data of the true system (TRUTH.toml; default: the paper-like "
    "system) through the alignment processor. Writes RUNS.csv with the heading error, the "
    "alignment's own pitch, roll and 1-sigma, and the mean IMU temperature (temp_c).")
EXAMPLE = """examples:
  hse-opt simulate PLAN.csv -o RUNS.csv --seed 1 --jobs 2
  hse-opt simulate PLAN.csv --truth TRUTH.toml -o RUNS.csv --dask tcp://scheduler:8786"""


def add_arguments(parser):
    parser.add_argument("plan", metavar="PLAN.csv", help="the test plan")
    parser.add_argument("--truth", metavar="TRUTH.toml",
                        help="the true system (default: the paper-like system)")
    parser.add_argument("-o", "--output", metavar="RUNS.csv", required=True, help="results to write")
    parser.add_argument("--seed", type=int, default=0, help="campaign seed, >= 0 (default 0)")
    parser.add_argument("--jobs", type=int, default=1, help="local worker processes (default 1)")
    parser.add_argument("--dask", metavar="ADDRESS",
                        help="run on the Dask scheduler at ADDRESS (e.g. tcp://host:8786) instead")
    parser.add_argument("--write-truth", metavar="FILE",
                        help="also write the truth used, every key, to FILE (TOML)")
    parser.add_argument("--no-progress", dest="progress", action="store_false",
                        help="no progress bar on stderr")


def _io(action, what, fun, path, *args):
    """Read or write a file; a file that cannot be read or written is bad input (exit 2)."""
    try:
        return fun(*args, path) if args else fun(path)
    except OSError as err:
        raise ValueError(f"{path}: cannot {action} the {what}: {err.strerror or err}") from None


def run(args):
    from tqdm import tqdm

    from ..data import load_plan, save_runs
    from ..sim import TruthConfig, run_campaign

    truth = _io("read", "truth", TruthConfig.from_toml, args.truth) if args.truth else TruthConfig.default()
    plan = _io("read", "plan", load_plan, args.plan)
    client = None
    if args.dask:
        from distributed import Client
        try:
            client = Client(args.dask)
        except OSError as err:
            raise ValueError(f"--dask {args.dask}: cannot connect to the scheduler: {err}") from None
    # tqdm: on stderr, off with --no-progress and when stderr is not a terminal
    with tqdm(total=len(plan), unit="run", desc="simulate", file=sys.stderr,
              disable=None if args.progress else True) as bar:
        try:
            runs = run_campaign(plan, truth, args.seed, jobs=args.jobs, client=client,
                                progress=lambda done, total: bar.update(done - bar.n))
        finally:
            if client is not None:
                client.close()
    _io("write", "runs", save_runs, args.output, runs)
    if args.write_truth:
        _io("write", "truth", truth.to_toml, args.write_truth)
    message(f"hse-opt simulate: {len(runs)} runs written to {args.output}")
    return 0
