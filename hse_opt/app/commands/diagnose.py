"""``hse-opt diagnose``: compare a model with measured runs and find the missing effect."""
import os

from . import add_derived_argument, add_input_checks, input_checks, message, model_option, print_json
from .outputs import REPORT

NAME = "diagnose"
HELP = "compare a model with measured runs: where it fails, which effect is missing"
DESCRIPTION = """\
Fit the model to RUNS.csv and compare it with the measurements: residuals and influence per
run, goodness of fit (chi-square with the runs' own sigmas; pure-error lack of fit when
settings are replicated), residual structure against every factor, every catalogue effect not
in the model ranked by a score test, Delta-BIC and the residual RMS after refitting, the
unexplained structure in words (level shifts and outliers in run order too), and the verdict
(adequate, missing-effect, unexplained structure, or inconclusive: no test rejects, but an
effect the test would miss here (power < 0.8 at its plausible size) could move a calibrated
parameter by more than its sigma, or the BIC strongly favours a candidate the test cannot
confirm - the notes name them and the runs that would resolve them). Candidates are compared on one likelihood
scale, the base model's noise model. --refine adds the best significant effect and diagnoses
again until the verdict is adequate; it stops, adding nothing, when the best candidates are
ambiguous, the structure follows no catalogue effect, or the verdict is inconclusive."""
INPUTS = ("runs",)
OUTPUTS = {"report": REPORT}
EXAMPLE = """examples:
  hse-opt diagnose RUNS.csv
  hse-opt diagnose RUNS.csv --effects hse,warmup --json
  hse-opt diagnose RUNS.csv --refine
  hse-opt diagnose paper.csv --fix lambda2*tilt_const=0 --covariates none"""


def add_arguments(parser):
    parser.add_argument("runs", metavar="RUNS.csv", help="alignment results (columns: docs/formats.md)")
    add_input_checks(parser)
    parser.add_argument("--effects", default="hse", help="effects of the model (default: hse, the paper's)")
    parser.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                        help="hold a parameter at a value in its display unit (repeatable)")
    parser.add_argument("--covariates", metavar="A,B",
                        help="covariate columns to test (default: every extra numeric column; 'none')")
    parser.add_argument("--alpha", type=float, default=None,
                        help="family-wise significance level of the verdict (default 0.05)")
    parser.add_argument("--refine", action="store_true",
                        help="add the best significant effect and diagnose again, until adequate")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    parser.add_argument("--report", metavar="DIR", help="write the HTML report into DIR")
    add_derived_argument(parser)


def parse_fix(items):
    """``["NAME=VALUE", ...]`` -> {name: float}; ValueError naming the bad item."""
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            if not sep or not name.strip():
                raise ValueError
            out[name.strip()] = float(value)
        except ValueError:
            raise ValueError(f"--fix {item!r}; allowed: NAME=VALUE with a number in the parameter's "
                             "display unit, e.g. --fix lambda2=4.2") from None
    return out


def run(args):
    from ...data import load_runs
    from ...diagnose import ALPHA, compare, diagnose, refine

    try:
        runs = load_runs(args.runs, **input_checks(args))
    except OSError as err:
        raise ValueError(f"{args.runs}: cannot read the file ({err.strerror or err}); allowed: a RUNS.csv "
                         "you can read") from None
    covariates = None
    if args.derived:  # the user's own derived columns are never factors or candidates
        from ...factors import is_derived
        covariates = [c for c in runs.covariates if not is_derived(c, args.derived)]
    if args.covariates is not None:
        covariates = [] if args.covariates.strip().lower() == "none" else \
            [c.strip() for c in args.covariates.split(",") if c.strip()]
    if args.alpha is not None and not 0.0 < args.alpha < 1.0:
        raise ValueError(f"--alpha {args.alpha:g} is not allowed; allowed: a significance level in (0, 1), "
                         "e.g. 0.05")
    kw = dict(fix=parse_fix(args.fix), covariates=covariates,
              alpha=ALPHA if args.alpha is None else args.alpha)
    model = model_option(args.effects)
    steps = refine(runs, model, **kw) if args.refine else (diagnose(runs, model, **kw),)
    stopped = _stopped(steps[-1]) if args.refine else None
    if stopped:
        message(f"--refine stopped: {stopped}")
    if args.report:
        status = write_report(steps, args.tx.path("report"), args.runs, args.derived, args.report)
        if status:
            return status
    if args.json:
        out = steps[-1].to_dict()
        if args.refine:
            out["added"] = [e for e in steps[-1].effects if e not in steps[0].effects]
            out["stopped"] = stopped
            out["steps"] = [{"effects": list(s.effects), "rms_arcsec": s.rms_arcsec,
                             "chi2_red": float(s.chi2_red), "lack_of_fit_p": s.lack_of_fit_p,
                             "verdict": s.verdict} for s in steps]
        print_json(out)
        return 0
    print("\n".join(steps[0].summary()))
    if len(steps) > 1:
        print()
        print("\n".join(compare(steps[0], steps[-1]).summary()))
        print()
        print("\n".join(steps[-1].summary()))
    return 0


def _stopped(last):
    """Why --refine stopped short of an adequate model without adding the best candidate, or
    None."""
    if len(last.ambiguous) > 1:
        return (f"{', '.join(last.ambiguous)} are ambiguous (Delta-BIC within 6 or equally adequate): "
                "none added; make the proposed runs to tell them apart")
    if last.verdict == "unexplained structure":
        return "the strongest structure follows no catalogue effect (see the notes): none added"
    if last.verdict == "inconclusive":
        return ("inconclusive: the model fits, but these runs cannot rule out what would move it (see the "
                "notes: the effects, and the runs that would resolve them)")
    return None


def write_report(steps, directory, source="", derived=(), shown=None):
    """The HTML report of the diagnosis steps (:mod:`hse_opt.report`): the first diagnosis,
    each added effect's before/after, and the last diagnosis; returns the exit status."""
    from ... import report
    from ...diagnose import compare
    sections = [report.diagnosis_section(steps[0], derived=derived)]
    if len(steps) > 1:
        sections += [report.comparison_section(compare(a, b), derived=derived) for a, b in zip(steps, steps[1:])]
        sections.append(report.diagnosis_section(steps[-1], derived=derived))
    path = report.write_report(directory, sections, title=f"hse-opt diagnose {source}".rstrip())
    message(f"report: {path if shown is None else os.path.join(shown, report.REPORT_NAME)}")
    return 0
