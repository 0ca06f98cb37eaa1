"""``hse-opt demo``: the whole method on an embedded default (see :mod:`hse_opt.app.demo`)."""
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
INPUTS = ()


def _files():
    from ..demo import OUTPUT_FILES
    return OUTPUT_FILES


OUTPUTS = {"out": _files}


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
            for old in bars.values():  # a new step: the earlier ones are done
                old.update(old.total - old.n)
                old.close()
            bar = bars[step] = tqdm(total=total, desc=step, unit="run" if total > 1 else "step",
                                    file=sys.stderr, leave=False, disable=None)
        bar.update(done - bar.n)

    def close():
        for bar in bars.values():
            bar.close()
    return progress, close


def summary_lines(result, out_dir):
    """The printed summary (a list of lines)."""
    r = result
    fb, fa, d, n = r.fit_before, r.fit_after, r.diagnosis, r.next_plan
    hours = float((r.plan.t_start[-1] + r.plan.duration[-1]) / 3600.0)
    hidden = ", ".join(f"{k} = {v:.4g} {r.hidden.units[k]}" for k, v in r.hidden.values.items())
    lines = [
        f"hse-opt demo, seed {r.seed}: a simulated campaign hides one effect the paper's model lacks",
        f"  campaign  {len(r.runs)} ten-minute alignments over {hours:.1f} h, noise "
        f"{r.noise_arcsec:.1f} arcsec each",
        f"  hidden    {r.hidden.name}: {hidden}",
        f"  paper fit RMS {fb.rms_arcsec:.1f} arcsec, reduced chi-square {fb.chi2_red:.2f}",
    ]
    if r.named is None:
        lines.append(f"  diagnose  {d.verdict}: no significant candidate (missed {r.hidden.name})")
    else:
        c = d.best
        lines.append(f"  diagnose  {d.verdict}; best candidate {r.named} (p {c.p_value:.2g}, "
                     f"Delta-BIC {c.delta_bic:.1f}): "
                     + ("the hidden effect" if r.found else f"NOT the hidden {r.hidden.name}"))
        if d.ambiguous:
            lines.append(f"            cannot be told apart here: {', '.join(d.ambiguous)}")
    if fa is not None:
        lines.append(f"  refit     {' + '.join(fa.model.effect_names)}: RMS {fb.rms_arcsec:.1f} -> "
                     f"{fa.rms_arcsec:.1f} arcsec, reduced chi-square {fa.chi2_red:.2f}, "
                     f"{r.diagnosis_after.verdict}")
        for name, value in r.hidden.values.items():
            if name in fa.names:
                v, sd = fa.value(name)
                lines.append(f"            {name} = {v:.4g} +- {sd:.2g} {r.hidden.units[name]} "
                             f"(hidden {value:.4g})")
    if n.best is None:
        lines.append(f"  next plan {'; '.join(n.notes)}")
    else:
        lines.append(f"  next plan sigma(lambda2) in the paper plan's {n.best.total_time / 3600:.1f} h:")
        if n.baseline is None:
            lines.append("            the paper's plan cannot identify this model")
        else:
            lines.append(f"            {n.baseline.std_of('lambda2'):#.3g} arcsec with the paper's plan")
        for d, which, label in ((n.level, "level", "the paper's limits"),
                                (n.design, "design", "a 0.5-deg tilt fixture")):
            if d is not None:
                gain = n.gain(which)
                lines.append(f"            {d.std_of('lambda2'):#.3g} arcsec optimised, {label}"
                             + ("" if gain is None else f" ({gain:.1f}x smaller)"))
            else:
                lines.append(f"            no design with {label} (the report says why)")
    data = "RUNS.csv, PLAN.csv, " + ("" if n.best is None else "NEXT_PLAN.csv, ")
    if r.session:
        lines.append("  live      a field session steered run by run (hse-opt calibrate --watch), one line per log:")
        lines += [f"            {ln}" for ln in r.session]
    lines.append(f"  report    {Path(out_dir) / 'report.html'} (data: {data}TRUTH.toml, summary.json)")
    return lines


def run(args):
    from ..demo import run_demo, write_outputs

    if args.seed < 0:
        raise ValueError(f"--seed {args.seed} is not allowed; allowed: an integer >= 0")
    out = Path(args.out)
    progress, close = _progress_bar(args.progress)
    try:
        result = run_demo(args.seed, progress=progress)
    finally:
        close()
    if args.progress:
        message("writing the report ...")
    data = write_outputs(result, args.tx.path("out"), shown=out)
    if args.json:
        print_json(data)
    else:
        print("\n".join(summary_lines(result, out)))
    if result.next_plan.best is None:
        message("hse-opt demo: error: the design step failed (see the summary); the other "
                f"results are in {out}")
        return 1
    return 0
