"""``hse-opt fit``: calibrate a model on alignment results (RUNS.csv)."""

import numpy as np

from . import (add_derived_argument, add_input_checks, add_report_argument, input_checks, message,
               model_option, print_json, write_report)
from .outputs import FILE, REPORT

NAME = "fit"
HELP = "calibrate a model on alignment results (RUNS.csv) by weighted least squares"
DESCRIPTION = """\
Fit the measurement model (the paper's 'hse' plus the effects named) to RUNS.csv by weighted
least squares and print the parameters with their units and standard errors, the fit
statistics, bounds that bind and strong correlations. Weights come from heading_std_arcsec,
else from the scatter of replicated runs (pure error) when they give at least 8 degrees of
freedom, else from the residuals (docs/weights.md: why 8); replicated runs also test the fit
(the lack-of-fit F test, the same in hse-opt diagnose). Runs without
pitch/roll get the tilt-coupled terms as free azimuth sinusoids (names like
lambda2*tilt_cos). When the runs cannot separate two parameters the command stops (exit 2),
names them and proposes runs that would; when they are only nearly inseparable (|r| > 0.99 or
a sigma inflated more than 10-fold) it warns on stderr, names the group and lists it under
'confounded' in --json. Every catalogue effect not in the model is put at the edge of its
plausible range: an effect the diagnosis would not detect here (power < 0.8) that would move a
parameter by more than its 1-sigma is a systematic risk, said in words and given per parameter
as 'systematic' and 'systematic_by' (docs/formats.md: what a campaign cannot rule out)."""
INPUTS = ("runs", "prior")
OUTPUTS = {"output": FILE, "report": REPORT}
EXAMPLE = """\
examples:
  hse-opt fit RUNS.csv --effects sync_delay,warmup -o FIT.json
  hse-opt fit paper_table1.csv --fix 'lambda2*tilt_const=0' --json
  hse-opt fit RUNS.csv --bound warmup_tau=60:7200 --robust
  hse-opt fit NEW_RUNS.csv --prior FIT.json -o FIT2.json      (on-line update)
  hse-opt fit RUNS.csv --report fit_report                     (HTML: fit_report/report.html)"""


def add_arguments(parser):
    parser.add_argument("runs", metavar="RUNS.csv", help="alignment results (columns: docs/formats.md)")
    add_input_checks(parser)
    parser.add_argument("--effects", metavar="a,b", default="",
                        help="catalogue effects to add to 'hse' (e.g. sync_delay,warmup,covariate:temp_c)")
    parser.add_argument("--bound", action="append", default=[], metavar="NAME=LO:HI",
                        help="bound a parameter, display units; either side may be empty (repeatable)")
    parser.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                        help="hold a parameter at a value, display units (repeatable)")
    parser.add_argument("--prior", metavar="FIT.json", help="a previous calibration as Gaussian prior")
    parser.add_argument("--robust", action="store_true",
                        help="Huber loss: down-weight outlying runs (they are named)")
    parser.add_argument("--ignore-tilt", action="store_true",
                        help="fit tilt-coupled terms as free azimuth sinusoids even if pitch/roll are given")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    parser.add_argument("-o", "--output", metavar="FIT.json", help="write the calibration (for compensate)")
    add_report_argument(parser)
    add_derived_argument(parser)


def _assignments(items, option):
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise ValueError(f"{option} {item!r}: allowed form NAME=VALUE")
        out[name] = value.strip()
    return out


def _number(text, option, name):
    try:
        x = float(text)
    except ValueError:
        raise ValueError(f"{option} {name}={text!r}: {text!r} is not a number; allowed: a number in the "
                         "parameter's unit") from None
    if not np.isfinite(x):
        raise ValueError(f"{option} {name}={text!r}: allowed: a finite number")
    return x


def parse_bounds(items):
    """``["lambda2=0:10", "delay=:500"]`` -> ``{"lambda2": (0.0, 10.0), "delay": (None, 500.0)}``."""
    out = {}
    for name, text in _assignments(items, "--bound").items():
        lo, sep, hi = text.partition(":")
        if not sep:
            raise ValueError(f"--bound {name}={text!r}: allowed form NAME=LO:HI (either side may be empty)")
        out[name] = tuple(None if not s.strip() else _number(s, "--bound", name) for s in (lo, hi))
    return out


def parse_fix(items):
    """``["lambda2*tilt_const=0"]`` -> ``{"lambda2*tilt_const": 0.0}``."""
    return {name: _number(v, "--fix", name) for name, v in _assignments(items, "--fix").items()}


def run(args):
    from ...data import load_runs
    from ...fit import fit
    from ...fit.checks import check_lines, outliers
    from ...fit.file import load_fit, save_fit
    from ...information import UnidentifiableError

    runs = load_runs(args.runs, **input_checks(args))
    model = model_option(args.effects)
    prior = load_fit(args.prior) if args.prior else None
    try:
        result = fit(runs, model, fix=parse_fix(args.fix), bounds=parse_bounds(args.bound),
                     prior=prior, robust=args.robust, tilt_known=False if args.ignore_tilt else None)
    except UnidentifiableError as err:
        raise UnidentifiableError(f"{args.runs}: {err}; allowed: runs that separate them, or one of them held "
                                  "with --fix NAME=VALUE",
                                  err.names, err.direction, err.condition) from None
    from ...aliasing import alias_budget
    budget = alias_budget(result, runs)
    result = result.with_budget(budget)
    for g in result.confounded:
        message(f"hse-opt fit: warning: {args.runs}: {g.text()}")
    for line in budget.sentences(result.values):
        message(f"hse-opt fit: warning: {args.runs}: systematic risk: {line}")
    if args.output:
        save_fit(result, args.tx.path("output"))
        message(f"hse-opt fit: wrote {args.output}")
    if args.report:
        from ...report import fit_section
        write_report(args, [fit_section(result, runs, derived=args.derived)], f"hse-opt fit {args.runs}")
    field = runs.surveyed is not None   # positions without a reference: K_HSE per position
    if args.json:
        extra = {}
        if field:
            from ...fit.field import position_lines
            extra["positions"] = [ln.to_dict() for ln in position_lines(result, runs)]
        print_json({**result.to_dict(), **extra, "source": args.runs, "alias_budget": budget.to_dict(),
                    "outliers": [{"run": r, "studentized": t} for r, t in outliers(result, runs)],
                    "checks": check_lines(result, runs)})
    else:
        lines = result.summary()
        lines = [f"hse-opt fit: {args.runs}: {lines[0]}", *lines[1:]]
        checks = check_lines(result, runs)
        if checks:
            lines += ["  look at:"] + [f"    - {c}" for c in checks]
        if field:
            from ...fit.field import position_summary
            lines += position_summary(result, runs)
        print("\n".join(lines))
    return 0
