"""``hse-opt demo``: the whole method on an embedded default (see :mod:`hse_opt.demo`)."""
import sys
from pathlib import Path

from . import message, print_json

NAME = "demo"
HELP = "the whole method on a simulated campaign with a hidden effect"
DESCRIPTION = (
    "Simulate a calibration campaign of a paper-like system whose truth hides one physical "
    "effect the paper's model lacks (picked by --seed), fit the paper's model, diagnose, add "
    "the effect the diagnosis names, refit, and design an optimised next plan. Prints a "
    "summary and writes an HTML report with the data to --out.")
EXAMPLE = ("example: hse-opt demo --seed 3 --out ./hse_opt_demo\n"
           "         hse-opt demo --json > demo.json")
DEFAULT_OUT = "hse_opt_demo"


def add_arguments(parser):
    parser.add_argument("--out", metavar="DIR", default=DEFAULT_OUT,
                        help=f"directory for report.html and the data (default ./{DEFAULT_OUT})")
    parser.add_argument("--seed", type=int, default=0,
                        help="picks the hidden effect and seeds the noise (integer >= 0, default 0)")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    parser.add_argument("--no-progress", dest="progress", action="store_false",
                        help="no progress bar on stderr")


def _progress_bar(enabled):
    """A ``progress(step, done, total)`` callback drawing tqdm bars on stderr, and a closer."""
    if not enabled:
        return None, lambda: None
    from tqdm import tqdm
    bars = {}

    def progress(step, done, total):
        bar = bars.get(step)
        if bar is None:
            bar = bars[step] = tqdm(total=total, desc=step, unit="run", file=sys.stderr,
                                    leave=False, disable=None)
        bar.update(done - bar.n)

    def close():
        for bar in bars.values():
            bar.close()
    return progress, close


def summary_lines(result, out_dir):
    """The printed summary (a list of lines)."""
    from ..demo import next_plan_text
    r = result
    fb, fa = r.fit_before, r.fit_after
    plan = r.plan
    hours = float((plan.t_start[-1] + plan.duration[-1]) / 3600.0)
    lines = [
        f"hse-opt demo, seed {r.seed}: a simulated campaign whose truth hides one effect "
        "the paper's model lacks",
        f"  campaign  {len(r.runs)} alignments of 10 min over {hours:.1f} h (20/40/60 deg/s x 6 "
        f"azimuths, half on a 0.5-deg tilt fixture); noise {r.noise_arcsec:.1f} arcsec per alignment",
        f"  hidden    {r.hidden.describe()}",
        f"  paper fit {'+'.join(fb.model.effect_names)}: RMS {fb.rms_arcsec:.1f} arcsec, "
        f"reduced chi-square {fb.chi2_red:.2f}",
    ]
    d = r.diagnosis
    if r.named is None:
        lines.append(f"  diagnose  verdict {d.verdict}: no significant candidate "
                     f"(the hidden effect {r.hidden.name} was not found)")
    else:
        c = d.best
        lines.append(f"  diagnose  verdict {d.verdict}; names {r.named} (score p {c.p_value:.2g}, "
                     f"Delta-BIC {c.delta_bic:.1f}): "
                     + ("the hidden effect" if r.found else f"NOT the hidden {r.hidden.name}"))
        if d.ambiguous:
            lines.append(f"            ambiguous here: {', '.join(d.ambiguous)}")
    if fa is not None:
        lines.append(f"  refit     {'+'.join(fa.model.effect_names)}: RMS {fb.rms_arcsec:.1f} -> "
                     f"{fa.rms_arcsec:.1f} arcsec, reduced chi-square {fa.chi2_red:.2f}, "
                     f"verdict {r.diagnosis_after.verdict}")
        for name in r.hidden.values:
            if name in fa.names:
                v, s = fa.value(name)
                lines.append(f"            {name} = {v:.4g} +- {s:.2g} {r.hidden.units[name]} "
                             f"(hidden: {r.hidden.values[name]:.4g})")
    lines.append("  design    " + next_plan_text(r.next_plan))
    lines.append(f"  report    {Path(out_dir) / 'report.html'}")
    return lines


def run(args):
    from ..demo import run_demo, write_outputs

    if args.seed < 0:
        raise ValueError(f"--seed {args.seed} is not allowed: an integer >= 0")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {args.out}: is a file; allowed: a directory (created when missing)")
    progress, close = _progress_bar(args.progress)
    try:
        result = run_demo(args.seed, progress=progress)
    finally:
        close()
    if args.progress:
        message("writing the report ...")
    data = write_outputs(result, out)
    if args.json:
        print_json(data)
    else:
        print("\n".join(summary_lines(result, out)))
    if result.next_plan.design is None:
        message("hse-opt demo: error: the design step failed (see the summary); the other "
                f"results are in {out}")
        return 1
    return 0
