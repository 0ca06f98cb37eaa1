"""``hse-opt compensate``: remove the calibrated error from alignment results."""
import textwrap

import numpy as np

from . import add_input_checks, input_checks, message, print_json
from .outputs import FILE

#: what ``heading_err_comp_arcsec`` is at a row without ``azimuth_deg`` (an unsurveyed field
#: position): not a heading error, as no reference exists (the help, the summary and --json say it)
UNSURVEYED_COMPENSATED = ("the compensated heading (heading_comp_deg) less the position's stand-in "
                          "reference, the mean of its uncompensated headings (heading_deg), in arcsec: not an "
                          "error against any reference (the position has none); only its differences within a "
                          "position mean anything (its position mean is minus the position's mean correction)")

NAME = "compensate"
HELP = "compensate alignments with a calibration (FIT.json from hse-opt fit -o)"
DESCRIPTION = textwrap.fill(
    "Subtract the heading error the calibration predicts for each run (every system effect: the "
    "stand's own errors - the offset of its zero mark and its reading errors - are left alone) and "
    "write RUNS.csv with more columns: heading_err_comp_arcsec, the compensated heading error at a "
    "row with azimuth_deg; at a row without it (an unsurveyed field position) "
    f"{UNSURVEYED_COMPENSATED}; heading_comp_deg (rows with heading_deg), the compensated heading; "
    "heading_comp_std_arcsec, the compensation's 1-sigma from the calibration's covariance; "
    "heading_comp_sys_arcsec, its systematic bound (the largest shift one effect the calibration "
    "campaign could not rule out would cause: FIT.json's systematic_by through the correction); and "
    "comp_status, 0 for a run inside the calibration's validity domain, else the exported C's status "
    "bitmask (|rate| or sense, C23 = -roll cos(heading) + pitch sin(heading), time or covariates "
    "outside what the calibration runs covered; hse_opt/fit/domain.py): such rows are also named on "
    "stderr.", 95) + """
A calibration fitted with known tilt uses each run's pitch/roll (the paper's Eq. 14); one
fitted without tilt holds for the stand it was fitted on."""
INPUTS = ("runs", "fit")
OUTPUTS = {"output": FILE}
EXAMPLE = """\
example:
  hse-opt fit CAL_RUNS.csv -o FIT.json && hse-opt compensate RUNS.csv --fit FIT.json -o OUT.csv"""


def add_arguments(parser):
    parser.add_argument("runs", metavar="RUNS.csv", help="alignment results to compensate")
    add_input_checks(parser)
    parser.add_argument("--fit", required=True, metavar="FIT.json", help="calibration from hse-opt fit -o")
    parser.add_argument("-o", "--output", required=True, metavar="OUT.csv", help="compensated runs")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def _stats(x):
    return {"rms_arcsec": float(np.sqrt(np.mean(x ** 2))), "ptp_arcsec": float(np.ptp(x)),
            "std_arcsec": float(np.std(x, ddof=1)) if x.size > 1 else None}


def _systematic_text(calibration, summary):
    """The systematic bound as words: its size, or that there is none, or that none was computed."""
    if calibration.systematic is None:
        return ("systematic bound: not computed (this FIT.json carries no systematic budget: "
                "hse-opt fit writes one)")
    if summary["comp_sys_max_arcsec"] == 0:
        return ("systematic bound: none (no effect the calibration campaign could not rule out "
                "moves the correction)")
    return (f"systematic bound (what the calibration campaign could not rule out): up to "
            f"{summary['comp_sys_max_arcsec']:.3g} arcsec")


def run(args):
    from ... import units
    from ...data import load_runs, save_runs
    from ...fit.correction import (COMPENSATED_COLUMN, COMPENSATION_STD_COLUMN, COMPENSATION_SYS_COLUMN,
                                   DOMAIN_STATUS_COLUMN, compensate,
                                   compensated_parameters, domain_status)
    from ...fit.file import load_fit

    calibration = load_fit(args.fit)
    runs = load_runs(args.runs, **input_checks(args))
    out = compensate(runs, calibration)
    save_runs(out, args.tx.path("output"))
    message(f"hse-opt compensate: wrote {args.output}")
    status, reasons = domain_status(runs, calibration)
    outside = np.flatnonzero(status != 0)
    if outside.size:
        shown = ", ".join(f"run {runs.run[i]} ({reasons[i]})" for i in outside[:3])
        message(f"hse-opt compensate: {outside.size} of {len(runs)} runs outside the calibration's validity "
                f"domain, flagged in {DOMAIN_STATUS_COLUMN} (their correction is an extrapolation the "
                f"calibration cannot vouch for): {shown}{', ...' if outside.size > 3 else ''}")
    before = runs.heading_err / units.ARCSEC
    after = np.array(out.covariates[COMPENSATED_COLUMN])
    group, positions = runs.reference_groups()
    for k in range(len(positions)):   # an unsurveyed position: its scatter about its own mean
        after[group == k] -= after[group == k].mean()
    # what the numbers are: a heading error needs a reference; without one, only each
    # position's scatter about its own (unknown) mean heading is known
    surveyed = np.ones(len(runs), bool) if runs.surveyed is None else np.asarray(runs.surveyed)
    parts = {}
    if surveyed.any():
        parts["surveyed"] = {"n_runs": int(surveyed.sum()), "measure": "heading error (against the stand azimuth)",
                             "before": _stats(before[surveyed]), "after": _stats(after[surveyed])}
    if not surveyed.all():
        parts["unsurveyed"] = {"n_runs": int((~surveyed).sum()), "positions": list(positions),
                               "measure": "heading scatter about each position's mean heading (no reference: "
                                          "each position's own heading error is unknown): before, heading_deg "
                                          "about the position's mean; after, heading_comp_deg about its mean",
                               "column": f"{COMPENSATED_COLUMN}: {UNSURVEYED_COMPENSATED}",
                               "before": _stats(before[~surveyed]), "after": _stats(after[~surveyed])}
    summary = {"n_runs": len(runs), "fit": args.fit, "output": args.output,
               "parameters": list(compensated_parameters(calibration)),
               "before": _stats(before), "after": _stats(after), **parts,
               "comp_std_mean_arcsec": float(np.mean(out.covariates[COMPENSATION_STD_COLUMN])),
               "comp_sys_max_arcsec": float(np.max(out.covariates[COMPENSATION_SYS_COLUMN])),
               "outside_domain": [int(runs.run[i]) for i in outside]}
    if args.json:
        print_json(summary)
    else:
        print(f"hse-opt compensate: {args.runs}: {len(runs)} runs with {args.fit} "
              f"({', '.join(summary['parameters'])})")
        for key, what in (("surveyed", "heading error"), ("unsurveyed", "heading scatter about each position's mean")):
            if key not in parts:
                continue
            b, a = parts[key]["before"], parts[key]["after"]
            where = "" if len(parts) == 1 else f" ({parts[key]['n_runs']} {key} runs)"
            print(f"  {what}{where}: RMS {b['rms_arcsec']:.4g} -> {a['rms_arcsec']:.4g} arcsec, "
                  f"peak-to-peak {b['ptp_arcsec']:.4g} -> {a['ptp_arcsec']:.4g} arcsec")
        print(f"  compensation 1-sigma (calibration uncertainty): mean "
              f"{summary['comp_std_mean_arcsec']:.3g} arcsec; {_systematic_text(calibration, summary)}")
        if positions:
            print(f"  positions without a heading reference ({', '.join(positions)}): their true heading "
                  "errors are unknown; the scatter shows how consistent each position's headings became")
            print(f"  {COMPENSATED_COLUMN} at their rows: {UNSURVEYED_COMPENSATED}")
    return 0
