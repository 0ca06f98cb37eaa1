"""One module per ``hse-opt`` command. Each defines ``NAME``, ``HELP``, ``EXAMPLE``,
``add_arguments(parser)`` and ``run(args) -> int``; :mod:`hse_opt.app.cli` registers them.

Commands print (the library never does); with ``--json`` stdout carries one JSON object and
nothing else, messages go to stderr.
"""
import contextlib
import json
import os
import sys


def print_json(obj):
    """Write one JSON object on stdout."""
    json.dump(obj, sys.stdout, indent=2, allow_nan=False)
    sys.stdout.write("\n")


def message(text):
    """A message for the user, on stderr."""
    print(text, file=sys.stderr)


def add_input_checks(parser):
    """The options of the RUNS/PLAN input checks (:mod:`hse_opt.data`)."""
    from ...data import DEFAULT_MIN_RATE_DPS
    parser.add_argument("--min-rate-dps", type=float, default=DEFAULT_MIN_RATE_DPS, metavar="R",
                        help=f"lock-in limit: smaller |rate_dps| is an error (default {DEFAULT_MIN_RATE_DPS:g})")
    parser.add_argument("--allow-small-azimuths", action="store_true",
                        help="accept azimuths that look like radians (a fine sweep in degrees)")


def input_checks(args):
    """Keyword arguments of :func:`hse_opt.data.load_runs` / ``load_plan`` from the options."""
    if not args.min_rate_dps >= 0:
        raise ValueError(f"--min-rate-dps {args.min_rate_dps:g} is not allowed; allowed: >= 0 deg/s (0 turns the "
                         "lock-in check off)")
    return dict(min_rate_dps=args.min_rate_dps, allow_small_azimuths=args.allow_small_azimuths)


def model_option(value, option="--effects"):
    """The model of an ``--effects`` option (:func:`hse_opt.model.as_model`; ``None`` or empty:
    the paper's); a bad effect or covariate name raises ValueError naming the option."""
    from ...model import as_model
    try:
        return as_model(value or None)
    except ValueError as err:
        raise ValueError(f"{option}: {err}") from None


def add_report_argument(parser):
    """The ``--report DIR`` option: an HTML report (``DIR/report.html``) of what the command did."""
    parser.add_argument("--report", metavar="DIR",
                        help="also write a self-contained HTML report to DIR/report.html")


def add_derived_argument(parser):
    """The ``--derived COLUMN`` option: a column derived from the heading error, never a
    factor of the report (:mod:`hse_opt.factors`)."""
    parser.add_argument("--derived", action="append", default=[], metavar="COLUMN",
                        help="a column derived from the heading error, never plotted as a factor "
                             "(columns named heading... are recognised anyway; repeatable)")


def write_report(args, sections, title):
    """Write the report when ``--report DIR`` was given (with the command's other outputs:
    :mod:`hse_opt.app.commands.outputs`); says where on stderr."""
    if getattr(args, "report", None):
        from ...report import REPORT_NAME
        from ...report import write_report as write
        write(args.tx.path("report"), sections, title)
        message(f"report: {os.path.join(args.report, REPORT_NAME)}")


def add_dask_argument(parser):
    """The ``--dask ADDRESS`` option: run the work on a Dask cluster's scheduler instead of local
    worker processes (the results are the same as with ``--jobs 1``)."""
    parser.add_argument("--dask", metavar="ADDRESS",
                        help="run on the Dask scheduler at ADDRESS (e.g. tcp://host:8786) instead of "
                             "local processes (needs the dask extra: pip install 'hse_opt[dask]')")


@contextlib.contextmanager
def dask_client(address):
    """A ``distributed.Client`` connected to ``address`` for the ``with`` block, or None when
    ``address`` is None; an address that does not connect is bad input naming ``--dask``."""
    if not address:
        yield None
        return
    try:
        from distributed import Client
    except ImportError:
        raise ValueError(f"--dask {address}: the dask extra is not installed; allowed: "
                         f"pip install 'hse_opt[dask]', or --jobs N without --dask") from None
    try:
        client = Client(address, timeout="10s")
    except (OSError, ValueError, TypeError) as err:
        raise ValueError(f"--dask {address}: cannot connect to a scheduler ({' '.join(str(err).split())}); "
                         f"allowed: a running scheduler's address, e.g. tcp://host:8786") from None
    try:
        yield client
    finally:
        client.close()
