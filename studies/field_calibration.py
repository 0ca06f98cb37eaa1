"""On-line calibration without a reference (issue 13, item 6): simulated field campaigns.

The paper's central use: the system stands at positions whose true headings nobody knows,
aligns there at several bias rates, and lambda2 (K_HSE) comes from the heading differences
within each position. Each campaign here: the paper-like default system
(hse_opt/datasets/truth_default.toml, lambda2 = 4.2 arcsec), positions at random headings,
each with its own base tilt (a new placement: up to 300 arcsec about each axis, on top of the
system's own), at each position the rates +20, +60 and -40 deg/s (both senses: the sense
change separates the rate-odd HSE from the rate-even effects), run back to back from 1 h
after power-on. ``hse-opt simulate --field`` writes such campaigns: RUNS.csv with the
alignment's own heading and the position label, the true headings hidden. The fit sees only
the differences within each position (each position's unknown heading eliminated exactly),
with the alignments' own 1-sigma as weights.

(a) lambda2 recovered with an honest sigma: the z-scores (estimate - 4.2) / sigma over the
    campaigns have an RMS in [0.85, 1.15] and a mean within 3 standard errors of 0.
(b) A hidden effect found and removed as in surveyed campaigns: a 125-us time offset between
    gyro and encoder sampling (sync_delay: a heading error proportional to the bias rate, like
    the HSE, but the same at every position, where the HSE follows each position's C23), in
    field campaigns of 3 positions, each rate twice, 300-s alignments sampled at 100 Hz. The
    diagnosis sees only the differences within positions: it flags the paper's model
    (missing-effect) with sync_delay first or named among the effects these runs cannot tell
    apart (the encoder's first harmonic acts through lambda2 the same way here; the diagnosis
    then picks neither and proposes the runs that would, and the study adds sync_delay as
    those runs would decide); after adding it no test rejects (adequate or inconclusive) and the residual RMS is
    within 1.3 x the alignments' own 1-sigma. Candidates whose signature is constant at a position
    (axis_bias, the stand's azimuth errors) are reported as not testable, never as missing.

(c) The optimised field plan against the paper's single-position plan in the same time: the
    paper's step 1 (3 alignments at each of 20, 40, 60 deg/s, 10 min each, one position)
    against :func:`hse_opt.design.field.design_field` (how many positions, which rates and senses,
    how many repeats; a move between positions costs 30 min, a rate or sense change 1 min,
    1 h of warm-up) for the same time from power-on, both at the heading where the system's
    base tilt gives the largest |C23| (the paper's best case). Predicted sigma(lambda2) with
    every position's heading unknown, and a Monte Carlo of both plans through the simulator
    (field campaigns, 100-Hz sampling) and the field fit: the optimised plan's sigma is
    smaller, predicted and simulated.

Run: python studies/field_calibration.py [--campaigns N] [--duration S] [--positions P] [--jobs J]
                                         [--hidden-seeds K]
CI size (asserted by tests/test_field_study.py): (a) 100 campaigns of 2 positions, 120-s
alignments; (b) 2 seeds; (c) 20 Monte Carlo campaigns per plan (~1 min CPU in all).

Measured (this machine, 2026-11; --hidden-seeds 3 --reps 30, the rest at CI size):
(a) z-RMS 1.009 +- 0.071, mean z -0.11 +- 0.10 over 100 campaigns (lambda2 mean 3.97 arcsec,
    true 4.2; the fit's sigma ranges widely with each position's C23, median 2.9 arcsec).
(b) 3/3 seeds: the paper's model flagged; sync_delay first in 2, the encoder harmonic first in
    1, the two named as indistinguishable in 2 of the 3 (both are rate-odd and the same at
    every position here; in seed 1 sync_delay leads alone); with sync_delay added adequate,
    RMS 19.5-22.9 -> 6.1-10.8 arcsec against the filter's 1-sigma 11.8 (the 100-Hz
    processor's sigma is conservative); axis_bias, azimuth_harmonic2, mount_xi and the tilt
    covariates not testable in every seed.
(c) 2.53 h: the paper's plan 9 runs, sigma(lambda2) predicted 2.69, Monte Carlo 2.81 arcsec;
    optimised (moving costs more than it gains here: one position, +60/-60 deg/s x 4) 8 runs,
    0.78 / 0.79 arcsec; ratio 0.29 predicted, 0.28 Monte Carlo.
Full (the README's figures): --campaigns 200 --positions 3 --duration 600 --jobs 2.
"""
import argparse
import math
import time

import numpy as np

from hse_opt import units
from hse_opt.design import Costs, Stand, evaluate
from hse_opt.diagnose import refine
from hse_opt.design.field import design_field, field_plan as plan_of
from hse_opt.fit import fit
from hse_opt.sim import TruthConfig, run_campaign

RATES_DPS = (20.0, 60.0, -40.0)
LAMBDA2_TRUE = 4.2  # arcsec: eps_arcsec of the default truth, 1.6 + 1.2 + 1.4


def field_plan(rng, positions, duration, repeats=1, t0=3600.0, move=600.0):
    """One field campaign: positions at random headings and tilts, RATES_DPS at each (``repeats``
    rounds), from ``t0`` after power-on, ``move`` seconds between positions."""
    rows, t = [], t0
    for k in range(positions):
        heading = float(rng.uniform(0.0, 360.0))
        tilt = rng.uniform(-300.0, 300.0, 2)
        for rate in RATES_DPS * repeats:
            rows.append({"run": len(rows) + 1, "rate_dps": rate, "azimuth_deg": round(heading, 6),
                         "t_start_s": t, "duration_s": duration, "tilt_x_arcsec": round(float(tilt[0]), 3),
                         "tilt_y_arcsec": round(float(tilt[1]), 3), "position": f"P{k + 1}"})
            t += duration + 60.0
        t += move                       # moving to the next position
    return rows


def hidden_effect(seeds, seed0, jobs):
    """(b): a gyro/encoder time offset hidden in field campaigns, found by the diagnosis."""
    truth = TruthConfig.default().updated({"timing": {"sample_period_ms": 10.0},
                                           "encoder": {"sync_delay_us": 125.0}})
    print("(b) hidden sync_delay (125 us) in field campaigns (3 positions, each rate twice, 300 s):")
    for s in range(seeds):
        rng = np.random.default_rng(seed0 + 1000 + s)
        runs = run_campaign(field_plan(rng, 3, 300.0, repeats=2), truth, seed=seed0 + 1000 + s, jobs=jobs,
                            field=True)
        steps = refine(runs)
        first = steps[0]
        best = first.best.effect if first.best else None
        added = [d.best.effect for d in steps[:-1]]
        last = steps[-1]
        by_hand = ""
        if not added and "sync_delay" in first.ambiguous:
            # the diagnosis will not pick between indistinguishable effects (it proposes the runs
            # that would); add the hidden one, as those runs would decide
            last, added, by_hand = first.add("sync_delay"), ["sync_delay"], " (by hand: ambiguous)"
        untestable = [c.effect for c in first.candidates if not c.testable]
        level = float(np.sqrt(np.mean(runs.heading_std ** 2)) / units.ARCSEC)
        print(f"    seed {s}: paper model {first.verdict}, RMS {first.rms_arcsec:.1f} arcsec; first {best}"
              f"{' (ambiguous: ' + ', '.join(first.ambiguous) + ')' if first.ambiguous else ''}; added "
              f"{', '.join(added)}{by_hand}: {last.verdict}, RMS {last.rms_arcsec:.1f} arcsec (filter "
              f"1-sigma {level:.1f}); not testable here: {', '.join(untestable)}")
        assert first.verdict == "missing-effect", first.summary()
        assert best == "sync_delay" or "sync_delay" in first.ambiguous, first.summary()
        assert last.fits and len(added) == 1, last.summary()
        assert last.rms_arcsec <= 1.3 * level, (last.rms_arcsec, level)
        assert "axis_bias" in untestable and "azimuth_harmonic2" in untestable, untestable


def plans_compared(reps, seed0, jobs):
    """(c): the paper's single-position plan against the optimised field plan, same time."""
    truth = TruthConfig.default().updated({"timing": {"sample_period_ms": 10.0}})
    stand = Stand()
    costs = Costs(azimuth_change=1800.0)
    gamma, theta = stand.tilt                     # x roll, y pitch of the base, rad
    heading = float(np.arctan2(theta, -gamma))    # largest |C23| = |-gamma cos psi + theta sin psi|
    paper = plan_of([(20.0,) * 3 + (40.0,) * 3 + (60.0,) * 3], [1], [heading], costs)
    budget = float(np.max(paper.t_start + paper.duration))
    ev_paper = evaluate(paper, stand=stand, field=True)
    best = design_field(budget, costs=costs, stand=stand, heading0=heading)
    print(f"(c) {budget / units.HOUR:.2f} h from power-on, moves 30 min, heading {np.degrees(heading):.1f} deg "
          f"(|C23| {np.hypot(gamma, theta) / units.ARCSEC:.0f} arcsec), {len(best.tried)} field plans tried:")
    rows = []
    for name, plan, ev in (("paper, one position", paper, ev_paper), (
            f"optimised: {best.positions} position(s) x {best.pattern_dps} deg/s x {best.repeats}",
            best.plan, best.evaluation)):
        est = []
        for r in range(reps):
            runs = run_campaign(plan, truth, seed=seed0 + 5000 + r, jobs=jobs, field=True)
            f = fit(runs)
            est.append(f.values[f.names.index("lambda2")])
        mc = float(np.std(est, ddof=1)) if reps > 1 else float("nan")
        rows.append((ev.std_of("lambda2"), mc))
        print(f"    {name:<48} {plan.run.size:>2} runs: sigma(lambda2) predicted {ev.std_of('lambda2'):.3f}, "
              f"Monte Carlo {mc:.3f} arcsec ({reps} campaigns)")
    (p_pred, p_mc), (o_pred, o_mc) = rows
    print(f"    optimised / paper: predicted {o_pred / p_pred:.2f}, Monte Carlo {o_mc / p_mc:.2f}")
    assert o_pred < 0.7 * p_pred, (o_pred, p_pred)
    if reps >= 20:
        assert o_mc < p_mc, (o_mc, p_mc)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--campaigns", type=int, default=100)
    p.add_argument("--positions", type=int, default=2)
    p.add_argument("--duration", type=float, default=120.0)
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--seed", type=int, default=2013)
    p.add_argument("--hidden-seeds", type=int, default=2)
    p.add_argument("--reps", type=int, default=20, help="Monte Carlo campaigns per plan in (c)")
    args = p.parse_args()
    truth = TruthConfig.default()
    assert math.isclose(sum(truth.gyro.eps) / units.ARCSEC, LAMBDA2_TRUE, abs_tol=1e-9)
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    z, est, std = [], [], []
    for c in range(args.campaigns):
        runs = run_campaign(field_plan(rng, args.positions, args.duration), truth, seed=args.seed + c,
                            jobs=args.jobs, field=True)
        assert runs.azimuth is not None and not runs.surveyed.any()      # no reference anywhere
        f = fit(runs)
        i = f.names.index("lambda2")
        est.append(f.values[i])
        std.append(f.std[i])
        z.append((f.values[i] - LAMBDA2_TRUE) / f.std[i])
    z, est, std = map(np.array, (z, est, std))
    n = z.size
    rms = float(np.sqrt(np.mean(z ** 2)))
    print(f"(a) {n} field campaigns ({args.positions} positions x {len(RATES_DPS)} rates, "
          f"{args.duration:g}-s alignments, no reference), {time.perf_counter() - t0:.0f} s:")
    print(f"    lambda2 mean {est.mean():.3f} arcsec (true {LAMBDA2_TRUE}), scatter {est.std(ddof=1):.3f}, "
          f"fit's sigma (median) {np.median(std):.3f}")
    print(f"    z-scores: RMS {rms:.3f} (+- {rms / math.sqrt(2 * n):.3f}), mean {z.mean():+.3f} "
          f"(+- {1 / math.sqrt(n):.3f})")
    assert 0.85 <= rms <= 1.15, rms
    assert abs(z.mean()) <= 3 / math.sqrt(n), z.mean()
    hidden_effect(args.hidden_seeds, args.seed, args.jobs)
    plans_compared(args.reps, args.seed, args.jobs)
    print("\nOK: lambda2 recovered without a reference, with an honest sigma; the hidden effect "
          "found and removed from the differences within positions; the optimised field plan beats "
          "the paper's single-position plan in the same time")


if __name__ == "__main__":
    main()
