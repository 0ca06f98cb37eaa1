"""``hse-opt design``: the calibration test plan that calibrates best in the stand time."""
import numpy as np

from . import (add_input_checks, add_report_argument, input_checks, message, model_option, print_json,
               write_report)
from .outputs import FILE, REPORT

NAME = "design"
HELP = "optimise a calibration test plan (PLAN.csv), or evaluate one (--evaluate)"
DESCRIPTION = """\
Choose bias rates, rotation senses, stand azimuths, tilt-fixture settings and repeats that
minimise a criterion of the model's parameter covariance within a test-time budget, and write
them as PLAN.csv in execution order with start times (time since power-on). The default
criterion, protect (protect:lambda2), gives the smallest sigma of lambda2 (the paper's goal)
with every parameter identified and power >= 0.8 of the diagnosis against each catalogue effect
outside the model at the edge of its plausible range, where the budget allows; it names each
effect it cannot protect and why (needs a tilt fixture, needs time slots, no signature without
another effect, out of reach in the budget). Others by name: D (volume of the confidence
ellipsoid), A (sum of variances), E (worst direction), c:NAME (the variance of one parameter
alone, e.g. c:lambda2, which leaves rate-dependent effects unseen). Setups cost time: warm-up
before the first run, changing the azimuth, the rate or sense, the tilt fixture. The report
gives each parameter's predicted sigma, the efficiency against the approximate optimum, and the
bias a slow heading drift would cause. With --field (no heading reference) the plan is chosen
among positions x rate patterns x repeats by the same criterion: protect keeps power >= 0.8
against each effect some plan in the budget can show (a field plan cannot show an effect that
is constant at a position, e.g. axis_bias), c:lambda2 takes the smallest sigma alone. With
--evaluate an existing PLAN.csv is scored instead;
a plan that cannot identify the model stops (exit 2) naming the parameters. A conic solver that
ends inaccurate is backed by the even design and IPOPT from it (kept when the equivalence
theorem certifies it); a refinement IPOPT cannot finish keeps the grid plan (said in the
output); a convex program that still fails stops with one line naming the solver's status and
what to change: exit 2 when even every candidate run together barely separates some
parameters (named, condition number above 1e4), else exit 1."""
INPUTS = ("evaluate", "prior", "runs")
OUTPUTS = {"output": FILE, "report": REPORT}
EXAMPLE = """\
examples:
  hse-opt design --budget-h 4.5 --reverse -o PLAN.csv
  hse-opt design --budget-h 4.5 --effects axis_bias,sync_delay --criterion D --json -o PLAN.csv
  hse-opt design --budget-h 4.5 --reverse --max-tilt-arcsec 1800 --identify axis_bias,sync_delay -o PLAN.csv
  hse-opt design --evaluate PLAN.csv --effects axis_bias,sync_delay --json
  hse-opt design --field --budget-h 3 --azimuth-change-s 1800 -o FIELD_PLAN.csv
  hse-opt design --field --runs RUNS.csv --budget-h 2 --prior FIT.json -o NEXT_PLAN.csv   (the rest of a campaign)
  hse-opt design --budget-h 4.5 --reverse -o PLAN.csv --report design_report   (HTML report)"""


def add_arguments(parser):
    parser.add_argument("--evaluate", metavar="PLAN.csv", help="score this plan instead of designing one")
    add_input_checks(parser)
    parser.add_argument("-o", "--output", metavar="PLAN.csv", help="write the optimised plan here")
    parser.add_argument("--budget-h", type=float, default=5.0, metavar="H",
                        help="test time from power-on to the end of the last run, hours (default 5)")
    parser.add_argument("--max-runs", type=int, metavar="N", help="at most N alignments")
    parser.add_argument("--effects", metavar="a,b", default="", help="catalogue effects to add to 'hse'")
    parser.add_argument("--criterion", default="protect", metavar="protect|D|A|E|c:NAME",
                        help="optimality criterion (default protect: sigma(lambda2) with every parameter "
                             "identified and power >= 0.8 against the effects outside the model; "
                             "e.g. --criterion c:lambda2 for sigma(lambda2) alone)")
    parser.add_argument("--rates", default="20:60", metavar="LO:HI",
                        help="|bias rate| limits, deg/s (default 20:60)")
    parser.add_argument("--n-rates", type=int, default=5, metavar="N",
                        help="rate levels between the limits (default 5)")
    parser.add_argument("--reverse", action="store_true", help="allow both rotation senses")
    parser.add_argument("--negative", action="store_true", help="turn the negative sense when not --reverse")
    parser.add_argument("--azimuth-step-deg", type=float, default=15.0, metavar="DEG",
                        help="candidate stand azimuths every DEG degrees (default 15)")
    parser.add_argument("--max-tilt-arcsec", type=float, default=0.0, metavar="X",
                        help="tilt-fixture limit, arcsec (default 0: no fixture)")
    parser.add_argument("--durations-s", default="600", metavar="T1,T2",
                        help="allowed alignment durations, s (default 600)")
    parser.add_argument("--time-slots", type=int, default=1, metavar="N",
                        help="make time since power-on a factor with N slots (for warmup)")
    parser.add_argument("--latitude-deg", type=float, default=28.07, help="latitude, deg (default 28.07)")
    parser.add_argument("--stand-tilt-arcsec", default="-55,-120", metavar="X,Y",
                        help="tilt of the turntable base on the stand, roll x and pitch y, arcsec "
                             "(default -55,-120: the default simulated system)")
    parser.add_argument("--arw-dph-rthz", type=float, default=None, metavar="ARW",
                        help="gyro angle random walk for the heading noise model (default 0.012)")
    parser.add_argument("--floor-arcsec", type=float, default=0.0, metavar="S",
                        help="run-to-run heading scatter beyond the gyro noise, arcsec")
    parser.add_argument("--warmup-s", type=float, default=3600.0, help="warm-up before the first run, s")
    parser.add_argument("--azimuth-change-s", type=float, default=600.0, help="time to change the azimuth, s")
    parser.add_argument("--rate-change-s", type=float, default=60.0, help="time to change rate or sense, s")
    parser.add_argument("--tilt-change-s", type=float, default=1200.0, help="time to reset the tilt fixture, s")
    parser.add_argument("--run-overhead-s", type=float, default=0.0,
                        help="per alignment beyond its duration, s")
    parser.add_argument("--tilt-unknown", action="store_true",
                        help="the runs will not carry pitch/roll: tilt-coupled terms as free C23 coefficients")
    parser.add_argument("--identify", metavar="a,b", default=None,
                        help="effects (added to 'hse') the plan must also identify")
    parser.add_argument("--identify-efficiency", type=float, default=0.25, metavar="E",
                        help="their minimum D-efficiency (default 0.25)")
    parser.add_argument("--nominal", action="append", default=[], metavar="NAME=VALUE",
                        help="linearise at this parameter value, display units (repeatable)")
    parser.add_argument("--prior", metavar="FIT.json", help="an earlier calibration as prior information")
    parser.add_argument("--order", choices=("trend-robust", "min-setup"), default="trend-robust",
                        help="run order (default trend-robust)")
    parser.add_argument("--no-refine", dest="refine", action="store_false",
                        help="keep rates and azimuths on the candidate grid")
    parser.add_argument("--resolution-rate-dps", type=float, default=0.1, metavar="R",
                        help="the stand's rate step: the plan's rates are multiples of it (default 0.1)")
    parser.add_argument("--resolution-azimuth-deg", type=float, default=0.01, metavar="A",
                        help="the stand's azimuth step, deg (default 0.01)")
    parser.add_argument("--resolution-tilt-arcsec", type=float, default=1.0, metavar="T",
                        help="the tilt fixture's step, arcsec (default 1)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the run-order search (default 0)")
    parser.add_argument("--field", action="store_true",
                        help="a field campaign: no position has a heading reference (only differences "
                             "within a position count); with --evaluate, PLAN.csv's position column (else "
                             "its azimuths) gives the positions; without, the number of positions, rate "
                             "pattern and repeats with the smallest sigma of lambda2 in --budget-h, a move "
                             "between positions costing --azimuth-change-s, among the plans with power >= 0.8 "
                             "of the diagnosis against each effect outside the model that some plan in the "
                             "budget protects (the others named with the reason; --criterion c:lambda2: the "
                             "smallest sigma alone); e.g. hse-opt design --field --budget-h 3 -o FIELD_PLAN.csv")
    parser.add_argument("--runs", metavar="RUNS.csv",
                        help="with --field: the campaign's runs so far (with t_start_s, pitch/roll): plan the "
                             "rest for --budget-h, the time left after the last run, with these runs counted in "
                             "the information (their positions, measured tilts, times since power-on) and in "
                             "the protection (it moves to new positions when those so far cannot tell an effect "
                             "from lambda2); e.g. "
                             "hse-opt design --field --runs RUNS.csv --budget-h 2 -o NEXT_PLAN.csv")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    add_report_argument(parser)


def _pair(text, option, n=2, sep=","):
    parts = text.split(sep)
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"{option} {text!r}: allowed {n} numbers separated by '{sep}'") from None
    if len(values) != n or not all(np.isfinite(values)):
        raise ValueError(f"{option} {text!r}: allowed {n} finite numbers separated by '{sep}'")
    return values


def _stand(args):
    from ... import units
    from ...design import Stand
    from ...information import DEFAULT_ARW

    from ...ranges import check_option
    tilt = _pair(args.stand_tilt_arcsec, "--stand-tilt-arcsec")
    check_option("--latitude-deg", args.latitude_deg, "latitude_deg")
    for option in ("--arw-dph-rthz", "--floor-arcsec", "--warmup-s", "--azimuth-change-s", "--rate-change-s",
                   "--tilt-change-s", "--run-overhead-s"):
        value = getattr(args, option[2:].replace("-", "_"), None)
        if value is not None:
            check_option(option, value)
    arw = DEFAULT_ARW if args.arw_dph_rthz is None else args.arw_dph_rthz * units.DEG_PER_H
    return Stand(latitude=args.latitude_deg * units.DEG, tilt=tuple(v * units.ARCSEC for v in tilt), arw=arw,
                 floor=args.floor_arcsec * units.ARCSEC)


def _references(args, model, result, kw):
    """Plans whose sigmas say what the criterion gave up: the paper's plan and, for another
    criterion than D, the D-optimal plan for the same budget (None where one cannot be had)."""
    from ...design import DesignError, design, evaluate, paper_plan
    from ...information import UnidentifiableError

    out = []
    try:
        out.append(evaluate(paper_plan(costs=kw["costs"]), model, stand=kw["stand"], tilt_known=kw["tilt_known"],
                            nominal=kw["nominal"], prior=kw["prior"]))
    except UnidentifiableError:
        pass
    if result.criterion != "D":
        try:
            out.append(design(model, "D", **kw, prune=False, refine=False, resolution=None).evaluation)
        except (UnidentifiableError, DesignError):
            pass
    return out


def _numbers(text, option):
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"{option} {text!r}: allowed numbers separated by ','") from None
    if not all(np.isfinite(values)):
        raise ValueError(f"{option} {text!r}: allowed finite numbers separated by ','")
    return values


def _nominal(items):
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise ValueError(f"--nominal {item!r}: allowed form NAME=VALUE (display units)") from None
        if not sep or not name.strip():
            raise ValueError(f"--nominal {item!r}: allowed form NAME=VALUE (display units)")
    return out


def _expected(plan, model, stand, tilt_known, args):
    """What a campaign of ``plan`` could not rule out if the model is right (its alias budget);
    None when the plan's whole runs do not identify the model."""
    from ...information import UnidentifiableError
    from ...validation.expected import expected_budget
    try:
        return expected_budget(plan, model, stand=stand, tilt_known=tilt_known, values=_nominal(args.nominal))
    except UnidentifiableError:
        return None


def _expected_json(expected):
    if expected is None:
        return None
    return {**expected.to_dict(), "systematic": dict(zip(expected.names, expected.systematic.tolist()))}


def run(args):
    from ... import units
    from ...data import load_plan, save_plan
    from ...design import Costs, DesignSpace, Resolution, design, evaluate, plan_lines
    from ...design.evaluation import sacrificed
    from ...design.space import SAMPLE_PERIOD
    from ...validation.expected import describe_expected
    from ...fit.file import load_fit
    from ...information import UnidentifiableError

    model = model_option(args.effects)
    stand = _stand(args)
    prior = load_fit(args.prior) if args.prior else None
    tilt_known = not args.tilt_unknown
    costs = Costs(warmup=args.warmup_s, azimuth_change=args.azimuth_change_s, rate_change=args.rate_change_s,
                  tilt_change=args.tilt_change_s, run_overhead=args.run_overhead_s)

    def report(section, plan_title, **kw):
        """--report DIR: the section with the paper's plan evaluated the same way as baseline."""
        if not args.report:
            return
        from ... import report as rep
        from ...design import paper_plan
        try:
            base, note = evaluate(paper_plan(costs=costs), model, stand=stand, tilt_known=tilt_known,
                                  nominal=_nominal(args.nominal), prior=prior), None
        except UnidentifiableError as err:
            base, note = None, f"The paper's plan cannot identify {'+'.join(model.effect_names)}: {err}"
        write_report(args, [getattr(rep, section)(**kw, baseline=base, baseline_note=note)], plan_title)
    if args.evaluate:
        if args.output:
            raise ValueError("-o with --evaluate: an evaluation writes nothing; allowed: one of them")
        plan = load_plan(args.evaluate, **input_checks(args))
        try:
            ev = evaluate(plan, model, stand=stand, tilt_known=tilt_known,
                          criterion=args.criterion,
                          nominal=_nominal(args.nominal), prior=prior, field=args.field)
        except UnidentifiableError as err:
            raise UnidentifiableError(f"{args.evaluate}: {err}; allowed: a plan whose runs separate them",
                                      err.names, err.direction, err.condition) from None
        report("evaluation_section", f"hse-opt design --evaluate {args.evaluate}", evaluation=ev,
               plan=plan)
        if args.json:
            print_json({**ev.to_dict(), "source": args.evaluate})
        else:
            meaning = ""
            kind, _, name = ev.criterion.partition(":")
            if kind in ("c", "protect") and name in ev.names:
                # the loss of c:NAME and protect:NAME is the parameter's variance: said, with its sigma
                meaning = (f" (the variance of {name}, {ev.units[ev.names.index(name)]}^2: sigma "
                           f"{ev.std_of(name):.4g})")
            print(f"hse-opt design --evaluate {args.evaluate}: criterion {ev.criterion} = "
                  f"{ev.criterion_value:.6g}{meaning}")
            print("\n".join(ev.summary()))
            print("\n".join(plan_lines(plan)))
        return 0

    if not args.output:
        raise ValueError("-o PLAN.csv is required to design a plan; allowed: -o PLAN.csv, or --evaluate "
                         "PLAN.csv to score a plan")
    from ...ranges import RANGES
    budget = RANGES["--budget-h"]
    for opt, value, allowed, ok in (("--budget-h", args.budget_h, budget.allowed("H"), budget.contains),
                                    ("--max-tilt-arcsec", args.max_tilt_arcsec, ">= 0 arcsec", lambda v: v >= 0),
                                    ("--seed", args.seed, ">= 0", lambda v: v >= 0)):
        if not (np.isfinite(value) and ok(value)):
            raise ValueError(f"{opt} {value:g} is not allowed; allowed: {allowed}")
    if args.runs and not args.field:
        raise ValueError("--runs RUNS.csv continues a field campaign; allowed: with --field")
    if args.field:
        from ...design.field import continue_campaign, design_field
        from ...design.field_protection import field_criterion
        try:
            field_criterion(args.criterion)
        except ValueError as err:
            raise ValueError(f"--criterion {args.criterion}: {err}") from None
        duration = float(args.durations_s.split(",")[0])
        if args.runs:
            from ...data import load_runs
            runs = load_runs(args.runs, **input_checks(args))
            try:
                fd = continue_campaign(runs, model, args.budget_h * units.HOUR, criterion=args.criterion,
                                       prior=prior, costs=costs, stand=stand, duration=duration)
            except ValueError as err:
                raise ValueError(f"--runs {args.runs} with --budget-h {args.budget_h:g} (the time left): {err}") from None
        else:
            fd = design_field(args.budget_h * units.HOUR, model, criterion=args.criterion, costs=costs, stand=stand,
                              duration=duration, prior=prior)
        expected = _expected(fd.plan, model, stand, tilt_known, args)
        save_plan(fd.plan, args.tx.path("output"))
        message(f"hse-opt design: wrote {args.output} ({fd.plan.run.size} runs)")
        if args.report:
            from ... import report as rep
            title = "The rest of the field campaign" if fd.before is not None else "Field campaign plan"
            note = ("Field campaign: no position has a heading reference, so only the differences within a "
                    "position count; the paper's surveyed plan is no baseline for it."
                    + (f" The sigmas are those of the {fd.before.run.size} runs so far ({args.runs}) and the "
                       f"{fd.plan.run.size} new runs together." if fd.before is not None else "")
                    + (f" Prior information: {args.prior}." if args.prior else "") + " " + " ".join(fd.summary()))
            write_report(args, [rep.evaluation_section(fd.evaluation, fd.plan, None, title, note)],
                         f"hse-opt design --field {args.output}")
        summary = {**fd.to_dict(), "field": True, "n_runs": int(fd.plan.run.size),
                   **{k: v for k, v in fd.evaluation.to_dict().items() if k in ("total_time_h", "predicted_std")},
                   "runs_so_far": 0 if fd.before is None else int(fd.before.run.size),
                   "stay_at_last_position": bool(fd.stay), "prior": args.prior, "output": args.output,
                   "expected_alias_budget": _expected_json(expected)}
        if args.json:
            print_json(summary)
        else:
            so_far = "" if fd.before is None else (
                f" with the {fd.before.run.size} runs so far" + (" (staying at the last position first)"
                                                                 if fd.stay else ""))
            print(f"hse-opt design --field: {fd.positions} position(s) x rates {fd.pattern_dps} deg/s x "
                  f"{fd.repeats}{so_far}, sigma(lambda2) {fd.evaluation.std_of('lambda2'):.4g} arcsec, "
                  f"{summary['total_time_h']:.3f} h from power-on")
            print("\n".join(fd.summary()))
            if expected is not None:
                print("\n".join(describe_expected(expected)))
            print("\n".join(plan_lines(fd.plan)))
        return 0
    lo, hi = _pair(args.rates, "--rates", sep=":")
    if not 0 < lo <= hi:
        raise ValueError(f"--rates {args.rates}: allowed LO:HI in deg/s with 0 < LO <= HI")
    if hi > 400:  # the design space's limit (hse_opt.design.space)
        raise ValueError(f"--rates {args.rates}: {hi:g} deg/s is not allowed; allowed: LO:HI in deg/s with "
                         "HI <= 400 (a rate table's range)")
    if lo < args.min_rate_dps:
        raise ValueError(f"--rates {args.rates}: {lo:g} deg/s is inside the lock-in limit; allowed: LO >= "
                         f"{args.min_rate_dps:g} deg/s (--min-rate-dps)")
    durations = _numbers(args.durations_s, "--durations-s")
    shortest = 360.0 / lo + SAMPLE_PERIOD
    if min(durations) < shortest or max(durations) > 86400:
        raise ValueError(f"--durations-s {args.durations_s}: allowed {shortest:.6g} s (one table revolution at "
                         f"{lo:g} deg/s, the lowest rate, plus one sample) to 86400 s")
    resolution = Resolution(rate=args.resolution_rate_dps * units.DEG_PER_S,
                            azimuth=args.resolution_azimuth_deg * units.DEG,
                            tilt=args.resolution_tilt_arcsec * units.ARCSEC)
    space = DesignSpace(rates=(lo * units.DEG_PER_S, hi * units.DEG_PER_S), n_rates=args.n_rates,
                        reverse=args.reverse, sense=-1 if args.negative else 1,
                        azimuth_step=args.azimuth_step_deg * units.DEG,
                        max_tilt=args.max_tilt_arcsec * units.ARCSEC, durations=durations,
                        time_slots=args.time_slots, min_rate=args.min_rate_dps * units.DEG_PER_S)
    identify = None if args.identify is None else model_option(args.identify, "--identify")
    if args.max_tilt_arcsec > 0 and args.max_tilt_arcsec + max(abs(v) for v in stand.tilt) / units.ARCSEC > 3600:
        raise ValueError(f"--max-tilt-arcsec {args.max_tilt_arcsec:g} with --stand-tilt-arcsec "
                         f"{args.stand_tilt_arcsec}: allowed |fixture + stand tilt| <= 3600 arcsec in each axis")
    kw = dict(budget=args.budget_h * units.HOUR, space=space, stand=stand, costs=costs, max_runs=args.max_runs,
              tilt_known=tilt_known, nominal=_nominal(args.nominal), prior=prior)
    try:
        result = design(model, args.criterion, **kw, identify=identify, identify_efficiency=args.identify_efficiency,
                        refine=args.refine, order=args.order, rng=np.random.default_rng(args.seed),
                        resolution=resolution)
    except UnidentifiableError as err:
        raise UnidentifiableError(f"{err}; allowed: candidate runs that identify every parameter (--rates, "
                                  "--reverse, --azimuth-step-deg, --max-tilt-arcsec, --budget-h) or fewer effects",
                                  err.names, err.direction, err.condition) from None
    expected = _expected(result.plan, model, stand, tilt_known, args)
    save_plan(result.plan, args.tx.path("output"))
    message(f"hse-opt design: wrote {args.output} ({result.n_runs} runs)")
    report("design_section", f"hse-opt design {args.output}", result=result)
    given_up = sacrificed(result.evaluation, *_references(args, model, result, kw))
    if args.json:
        print_json({**result.to_dict(), "output": args.output,
                    "sacrificed": {n: {"std": s, "reference_std": r, "unit": u} for n, s, r, u in given_up},
                    "expected_alias_budget": _expected_json(expected)})
    else:
        print(f"hse-opt design: {'+'.join(model.effect_names)}, budget {args.budget_h:g} h")
        print("\n".join(result.summary()))
        if expected is not None:
            print("\n".join(describe_expected(expected)))
        if given_up:  # part of what the plan is, said before it: the trade the criterion made
            print(f"trade-off: criterion {result.criterion} buys its goal with "
                  + ", ".join(f"{n} (sigma {s:.3g} {u}, {s / r:.1f}x the {r:.3g} of the paper's plan or a "
                              f"D-optimal plan)" for n, s, r, u in given_up)
                  + "; to protect every parameter: --identify-efficiency 0.7 (the criterion with a "
                    "D-efficiency bound on the whole model) or --criterion D")
        print("\n".join(plan_lines(result.plan)))
    return 0
