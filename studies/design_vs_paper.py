"""The paper's test plan against optimised plans for the same stand time (issue 5, item 9).

The paper's plan: 3 alignments at each of 20, 40, 60 deg/s at one position, then 3 at 40 deg/s
at each of 4 stand azimuths (Table 1's), 21 ten-minute alignments. Optimised plans get the same
total time from power-on (same costs: 1 h warm-up, 10 min per azimuth change, 1 min per rate or
sense change, 20 min per tilt-fixture change) under three sets of limits:

  (a) rates 20-60 deg/s, one sense, the stand's own tilt;
  (b) both rotation senses;
  (c) a tilt fixture up to 0.5 deg as well;

each designed for the paper's model (hse: offset, lambda2; and required to identify the model
extended by axis_bias and sync_delay with a D-efficiency >= 0.5) and for the extended model
itself; criterion c:lambda2, the paper's goal.

Tilt mode: known in every case. The paper takes C23 from the alignment's own leveling (its
step 3), the simulated RUNS carry pitch/roll, and only then is lambda2 itself a parameter (with
the tilt unknown only lambda2*C23 coefficients are). The system is the simulator's default
(hse_opt/datasets/truth_default.toml): base tilt roll -55, pitch -120 arcsec (|C23| <= 132
arcsec), lambda2 = 4.2 arcsec, latitude 28.07 deg.

Where the paper's single position is not said, it is put where the base tilt gives the largest
|C23| (the paper's best case) and the 4 positions at Table 1's spacing from it; the plan with
Table 1's azimuths as given (position 1 at 0 deg, C23 = 55 arcsec) is reported too. The targets
compare against the best case.

Run: python studies/design_vs_paper.py [--reps N --jobs J]
With --reps N each plan is also simulated N times with the numeric simulator and fitted with
both models: the empirical sigma of lambda2 against the predicted one (within 15% asserted for
N >= 100). The default (0) gives the predictions only (the CI run; the Monte Carlo of the issue
note was run with --reps 200 --jobs 2).

Measured (--reps 200, seed 2013, 25 min on 2 cores): Monte Carlo sigma of lambda2 over the
predicted one 0.92-1.15 over the 13 plan/model pairs; against the prediction scaled by the
runs' own scatter (which is 2-6 % above the design's noise model) 0.90-1.09. A sigma from 200
replicates has a 5 % standard error; an earlier run in which two plans with the same run
structure shared their noise draws gave 1.17 on both at once, and 1.04 and 0.98 when re-run
with other draws (200 and 400 replicates).
"""
import argparse

import numpy as np

from hse_opt import units
from hse_opt.design import Costs, DesignSpace, Stand, design, evaluate, paper_plan, plan_lines
from hse_opt.information import UnidentifiableError
from hse_opt.sim import TruthConfig
from hse_opt.validation.monte_carlo import monte_carlo

PAPER, EXT = "hse", "hse,axis_bias,sync_delay"
TARGETS = {"a": 0.70, "b": 0.55, "c": 0.05}


def predicted(plan, model, stand):
    """(sigma of lambda2, max |correlation|) or (None, reason) when the plan cannot identify it."""
    try:
        ev = evaluate(plan, model, stand=stand)
    except UnidentifiableError as err:
        return None, f"unidentifiable: {', '.join(err.names)}"
    off = np.abs(ev.correlation[~np.eye(len(ev.names), dtype=bool)])
    return ev.std_of("lambda2"), float(off.max(initial=0.0))


def identifiable(sigma_corr):
    """In practice: the information is invertible and no two estimates correlate above 0.99."""
    sigma, corr = sigma_corr
    return sigma is not None and corr < 0.99


def main():
    parser = argparse.ArgumentParser(description="paper plan vs optimised plans")
    parser.add_argument("--reps", type=int, default=0, help="Monte Carlo replicates per plan (0: none)")
    parser.add_argument("--jobs", type=int, default=1, help="simulator worker processes")
    parser.add_argument("--seed", type=int, default=2013)
    args = parser.parse_args()

    truth = TruthConfig.default()
    stand = Stand(latitude=truth.site.latitude, tilt=tuple(truth.stand.mount_tilt), arw=truth.gyro.arw)
    costs = Costs()
    roll, pitch = stand.tilt
    psi = np.linspace(0, 2 * np.pi, 36001)
    best = float(psi[np.argmax(np.abs(-roll * np.cos(psi) + pitch * np.sin(psi)))])
    paper = paper_plan(best, costs)
    table1 = paper_plan(0.0, costs)
    budget = float(paper.t_start[-1] + paper.duration[-1])
    print(f"system: base tilt roll {roll / units.ARCSEC:g}, pitch {pitch / units.ARCSEC:g} arcsec; "
          f"largest |C23| at azimuth {np.degrees(best):.1f} deg")
    print(f"same test time for every plan: {budget / units.HOUR:.3f} h from power-on "
          f"({paper.run.size} x 10 min alignments in the paper's plan)\n")

    ref, _ = predicted(paper, PAPER, stand)
    plans = {"paper (best case)": (paper, None), "paper (Table 1 azimuths)": (table1, None)}
    spaces = {"a": DesignSpace(), "b": DesignSpace(reverse=True),
              "c": DesignSpace(reverse=True, max_tilt=0.5 * units.DEG)}
    results = {}
    for key, space in spaces.items():
        for label, model, kw in (("paper model", PAPER, dict(identify=EXT, identify_efficiency=0.5)),
                                 ("extended model", EXT, {})):
            r = design(model, "c:lambda2", budget=budget, space=space, stand=stand, costs=costs, **kw)
            results[(key, label)] = r
            plans[f"({key}) for the {label}"] = (r.plan, r)

    header = (f"{'plan':<34}{'runs':>5}{'time h':>8}{'sigma(l2) hse':>15}{'ratio':>8}"
              f"{'sigma(l2) ext':>15}{'ratio':>8}{'max|corr| ext':>15}{'eff':>8}{'round':>8}")
    print("predicted sigma of lambda2 (arcsec); ratio against the paper's plan with the paper's model")
    print(header)
    rows = {}
    for name, (plan, r) in plans.items():
        s_p, _ = predicted(plan, PAPER, stand)
        s_e, c_e = predicted(plan, EXT, stand)
        rows[name] = (s_p, s_e, c_e)
        ext = f"{s_e:>15.4g}{s_e / ref:>8.3f}{c_e:>15.5f}" if s_e is not None else f"{c_e:>38}"
        eff = f"{r.efficiency:>8.4f}{r.rounding_efficiency:>8.4f}" if r is not None else ""
        print(f"{name:<34}{plan.run.size:>5}{(plan.t_start[-1] + plan.duration[-1]) / units.HOUR:>8.3f}"
              f"{s_p:>15.4g}{s_p / ref:>8.3f}{ext}{eff}")

    print("\nthe optimised plans (runs in order):")
    for (key, label), r in results.items():
        print(f"  ({key}) for the {label}: setups {r.setup_time / units.HOUR:.2f} h; drift bias of lambda2 "
              f"{r.evaluation.drift_bias[r.evaluation.names.index('lambda2')]:+.3g} arcsec per arcsec/h; "
              f"refinement {r.refinement}")
        print("\n".join("  " + line for line in plan_lines(r.plan)))

    if args.reps:
        print(f"\nMonte Carlo: {args.reps} simulated campaigns of each plan, each fitted with both models "
              "(empirical vs predicted sigma of lambda2, arcsec; 'noise' = the simulated alignments' own "
              "heading scatter over the noise model's; 'mean' = mean estimate, truth 4.2)")
        print(f"{'plan':<34}{'model':>9}{'predicted':>11}{'empirical':>11}{'ratio':>8}{'noise':>8}"
              f"{'emp/(pred*noise)':>18}{'mean':>9}")
        checks = []
        for k, (name, (plan, _)) in enumerate(plans.items()):
            if name == "paper (Table 1 azimuths)":
                continue
            models = [m for m, s in ((PAPER, rows[name][0]), (EXT, rows[name][1]))
                      if s is not None and (m == PAPER or identifiable(rows[name][1:]))]
            # each plan its own noise (plans with the same run structure would share draws)
            mcs = monte_carlo(plan, models, args.reps, truth=truth, seed=args.seed + k,
                              jobs=args.jobs, progress=True)
            for m, mc in zip(models, mcs):
                i = mc.names.index("lambda2")
                prop = mc.empirical_std[i] / mc.propagated_std[i]
                checks.append((name, m, mc.ratio[i], prop))
                print(f"{name:<34}{'hse' if m == PAPER else 'ext':>9}{mc.predicted_std[i]:>11.4g}"
                      f"{mc.empirical_std[i]:>11.4g}{mc.ratio[i]:>8.3f}{mc.run_scatter_ratio:>8.3f}"
                      f"{prop:>18.3f}{mc.mean[i]:>9.4g}")
        print(f"(a sigma from {args.reps} replicates has a standard error of "
              f"{100 / np.sqrt(2 * (args.reps - 1)):.1f}%)")
        if args.reps >= 100:
            worst = max(checks, key=lambda c: abs(c[3] - 1))
            assert abs(worst[3] - 1) < 0.15, f"Monte Carlo off the propagated prediction: {worst}"

    # ---- the targets
    print()
    for key, target in TARGETS.items():
        s = rows[f"({key}) for the paper model"][0]
        print(f"({key}) sigma(lambda2) {s:.4g} arcsec = {s / ref:.3f} x the paper plan's {ref:.4g} "
              f"(target <= {target})")
        assert s / ref <= target, f"case ({key}) misses its target"
        s_ext = rows[f"({key}) for the extended model"][1]
        print(f"    with the extended model: {s_ext:.4g} arcsec = {s_ext / ref:.3f} x")
    print("the paper's plan and the extended model: "
          + "; ".join(f"{n}: sigma(lambda2) {rows[n][1]:.4g} arcsec, max |corr| {rows[n][2]:.6f}"
                      if rows[n][1] is not None else f"{n}: {rows[n][2]}"
                      for n in ("paper (best case)", "paper (Table 1 azimuths)")))
    for n in ("paper (best case)", "paper (Table 1 azimuths)"):
        assert not identifiable(rows[n][1:]), f"{n} should not identify the extended model"
    for name, (plan, r) in plans.items():
        if r is not None:
            assert identifiable(rows[name][1:]), f"{name} does not identify the extended model"
            assert r.total_time <= budget + 1e-6
            assert r.approximate.certified_efficiency > 0.999
    print("OK: the optimised plans meet the targets and all identify the extended model; "
          "the paper's plan cannot")


if __name__ == "__main__":
    main()
