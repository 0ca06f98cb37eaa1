"""The ``hse-opt`` command line.

Each command lives in :mod:`hse_opt.app.commands` (one module each). Exit status: 0 success,
2 bad input or data that cannot answer the question (one line on stderr naming what is wrong
and what is allowed), 1 anything else.
"""
import argparse
import contextlib
import importlib
import os
import sys
import warnings

from hse_opt.interrupts import Terminated, check as check_interrupt, handling as handling_signals

#: command modules, in the order ``--help`` lists them
COMMANDS = ("demo", "calibrate", "design", "simulate", "align", "fit", "compensate", "diagnose", "export",
            "config")


class _Parser(argparse.ArgumentParser):
    """Usage errors in one line (naming what is wrong) and exit status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {_usage_allowed(message)} (see '{self.prog} --help')\n")


def _usage_allowed(message):
    """argparse's usage error with what is allowed (the contract's "allowed: ..." part)."""
    import re
    if "allowed" in message:
        return message
    m = re.match(r"argument (\S+): invalid (int|float) value", message)
    if m:
        return f"{message}; allowed: {'an integer' if m.group(2) == 'int' else 'a number'}"
    m = re.match(r"argument (\S+): expected one argument", message)
    if m:
        opt = m.group(1).split("/")[-1]
        return (f"{message}; allowed: a value after {opt} (one that starts with '-' written as "
                f"{opt}=VALUE)")
    m = re.match(r"(argument \S+: invalid choice: \S+) \(choose from (.*)\)$", message)
    if m:
        return f"{m.group(1)}; allowed: {m.group(2)}"
    if message.startswith("the following arguments are required"):
        return f"{message}; allowed: the command's usage line"
    return f"{message}; allowed: the options and arguments of the command's --help"


def build_parser():
    parser = _Parser(
        prog="hse-opt",
        description="Calibration and compensation of the heading-sensitive error of a "
                    "constant-rate biased RLG system.")
    from hse_opt import __version__
    parser.add_argument("--version", action="version", version=f"hse-opt {__version__}")
    parser.add_argument("--config", metavar="PATH",
                        help="the project file (default: hse-opt.toml in the working folder, if any); "
                             "may stand anywhere on the line; see 'hse-opt config --help'")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    parser.commands = {}
    for name in COMMANDS:
        mod = importlib.import_module(f"hse_opt.app.commands.{name}")
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP),
                           epilog=mod.EXAMPLE, formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(p)
        p.set_defaults(run=mod.run, subparser=p)
        parser.commands[mod.NAME] = p
    return parser


def _with_project(parser, argv):
    """``argv`` without ``--config``; the project file's settings made the commands' defaults
    (:mod:`hse_opt.app.project`). Raises ValueError naming the file and key."""
    from hse_opt.app import project
    argv, path = project.pop_config(sys.argv[1:] if argv is None else argv)
    proj = project.find(path)
    for p in parser.commands.values():
        proj.apply(p)
        p.set_defaults(project=proj)
    return argv


def _from_project(text, args, argv):
    """A message about an option whose value the project file gave says so."""
    project = getattr(args, "project", None)
    for s in () if project is None else project.settings:
        given = any(a == s.option or a.startswith(s.option + "=") for a in argv or ())
        if not given and text.startswith(s.option):
            return f"{text} (from {s.source})"
    return text


@contextlib.contextmanager
def json_stdout():
    """While a ``--json`` command runs, file descriptor 1 goes to stderr (solvers written in
    C print there, past Python) and ``sys.stdout`` writes to the real stdout, which then
    carries the one JSON object only. A no-op when ``sys.stdout`` is not file descriptor 1
    (e.g. captured by a test)."""
    try:
        is_fd1 = sys.stdout.fileno() == 1
    except (AttributeError, OSError, ValueError):
        is_fd1 = False
    if not is_fd1:
        yield
        return
    sys.stdout.flush()
    real = os.dup(1)
    try:
        os.dup2(2, 1)
        with open(real, "w", closefd=False) as out, contextlib.redirect_stdout(out):
            yield
            out.flush()
    finally:
        os.dup2(real, 1)
        os.close(real)


def _message(err):
    """One line for a bad-input exception."""
    if isinstance(err, OSError):
        text = err.strerror or str(err)
        if err.filename is not None:
            text = f"{err.filename}: {text}"
        allowed = {FileNotFoundError: "an existing file", IsADirectoryError: "a file, not a folder",
                   NotADirectoryError: "a path whose folders exist",
                   PermissionError: "a file you can read (outputs: a folder you can write)"}
        if "allowed" not in text:
            text += f"; allowed: {allowed.get(type(err), 'a file this user can read')}"
    else:
        text = str(err)
    return " ".join(text.split())


@contextlib.contextmanager
def _warnings_in_one_line(command):
    """While a command runs, each warning is one line on stderr, ``hse-opt CMD: warning: ...``
    (the library warns, the command line prints); a data warning every time it is issued."""
    from hse_opt.data import DataWarning

    def show(message, category, filename, lineno, file=None, line=None):
        print(f"{command}: warning: {' '.join(str(message).split())}", file=sys.stderr)
    with warnings.catch_warnings():
        warnings.simplefilter("always", DataWarning)
        warnings.showwarning = show
        yield


def _main(argv):
    command, tx = "hse-opt", None
    try:
        with handling_signals():
            # the command named from the line before the parser is built (its imports take a
            # while): an interrupt then still says which command it stopped
            given = sys.argv[1:] if argv is None else list(argv)
            named = next((a for a in given if a in COMMANDS), None)
            command = "hse-opt" if named is None else f"hse-opt {named}"
            parser = build_parser()
            try:
                argv = _with_project(parser, given)
            except ValueError as err:
                print(f"{command}: error: {_message(err)}", file=sys.stderr)
                return 2
            args, extra = parser.parse_known_args(argv)
            command = f"hse-opt {args.command}"
            if extra:  # reported by the command's own parser, so the message names the command
                args.subparser.error(f"unrecognized arguments: {' '.join(extra)}")
            from hse_opt.app.commands.outputs import Transaction
            try:
                # every output checked before the command runs; all written together or none
                tx = Transaction.from_args(args, sys.modules[args.run.__module__], args.subparser)
                with tx.check() as args.tx, _warnings_in_one_line(command), \
                        json_stdout() if getattr(args, "json", False) else contextlib.nullcontext():
                    status = args.run(args)
                    check_interrupt()  # a signal a solver in C swallowed: no output is renamed into place
                    return status
            except (KeyboardInterrupt, Terminated, BrokenPipeError):
                raise
            except (ValueError, FileNotFoundError, IsADirectoryError, NotADirectoryError,
                    PermissionError) as err:
                check_interrupt()  # a failure that a swallowed interrupt caused is the interrupt
                # bad input: one line naming the file, row, column or parameter and what is allowed
                print(f"{command}: error: {_from_project(_message(err), args, argv)}", file=sys.stderr)
                return 2
            except Exception as err:  # noqa: BLE001 - the command line reports, never tracebacks
                check_interrupt()
                from hse_opt.fit.result import SolverError
                if isinstance(err, SolverError):  # a numerical failure: the status and what to try
                    print(f"{command}: error: {_message(err)}", file=sys.stderr)
                else:
                    print(f"{command}: internal error: {type(err).__name__}: {err}", file=sys.stderr)
                return 1
    except (KeyboardInterrupt, Terminated) as err:
        what = "interrupted" if isinstance(err, KeyboardInterrupt) else f"terminated (signal {err.signum})"
        written = "" if tx is None or not tx.outputs else \
            ("; the outputs were written" if tx.committed else "; no output was written")
        print(f"{command}: {what}{written}", file=sys.stderr)
        return 130 if isinstance(err, KeyboardInterrupt) else 128 + err.signum


#: the BLAS thread counts the command line sets to 1 for its own process when left unset
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _one_blas_thread():
    """The command line's BLAS on one thread: in a fresh process (numpy not loaded yet, so the
    library reads it as it loads), each of :data:`BLAS_THREAD_VARIABLES` the user left unset is
    set to 1. The tool's matrices are small, and OpenBLAS's second thread spins beside every
    product even under a thread limit set later: ``hse-opt align`` of 100 ten-minute logs with
    ``--jobs 2`` took 24.1 ms CPU a log with it, 19.4 without (78 -> 91 logs/s on 2 cores;
    ``hse-opt design`` and ``demo`` no slower). A variable given keeps its value."""
    if "numpy" not in sys.modules:
        for name in BLAS_THREAD_VARIABLES:
            os.environ.setdefault(name, "1")


def main(argv=None):
    _one_blas_thread()
    try:
        try:
            status = _main(argv)
        except SystemExit as done:  # argparse: --help, --version, usage errors
            status = done.code
        sys.stdout.flush()
    except BrokenPipeError:
        # the reader closed the pipe (``hse-opt ... | head``): nothing more to say and nowhere
        # to say it; stdout goes to devnull so the interpreter's last flush is quiet too
        with contextlib.suppress(OSError, ValueError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    return status


if __name__ == "__main__":
    _status = main()
    from hse_opt.interrupts import forget_escaped_interrupt
    forget_escaped_interrupt()     # python -m: the status chosen, not a kill by SIGINT on the way out
    sys.exit(_status)
