"""Error rates of the diagnosis, measured (issue 6, item 6).

Campaigns come from the measurement model itself plus seeded Gaussian noise (the runs' own
sigma, ``heading_sigma`` of a 300-s alignment: about 10.8 arcsec): the paper's model with
lambda2 = 4.2 arcsec and an offset, and - for the hidden-effect campaigns - one catalogue
effect (or two) at the size stated in the table this script prints. The temperature column
comes from the simulator's thermal model (``hse_opt.sim.truth.temperature``: warm-up rise,
a 1-h swing, and a different lab temperature on each of the four days).

The plan (``hse_opt.validation.synthetic.diagnostic_plan``): 4 cold starts, 16 back-to-back 300-s runs
each; +-20, +-40, +-60 deg/s; 8 azimuths; base tilt of the stand (-120, -55 arcsec) plus a
tilt fixture per day (none, 0.5 deg about x, about y, about both). In it every catalogue
effect has a signature of its own (the study checks that the full model is identifiable).

Measured, for the stated family-wise significance level alpha = 0.05 (Bonferroni over the
diagnosis' tests):

* false alarms: the fraction of no-effect campaigns whose verdict is ``missing-effect``
  (target <= 10 %); the verdict rests on the score tests alone, so these campaigns are
  diagnosed without refits;
* for each hidden effect: the fraction of seeds in which it ranks first among the candidates
  (target >= 90 %), the fraction with verdict ``missing-effect``, and (``--full``) after
  ``refine`` (adding the suggested effects until no test rejects) the fraction ending so
  with the hidden effect(s) in the model.

* held-back cases (issue 14, item 7), each with its right answer:

  - a 25-arcsec level shift after run 23, one run 200 arcsec off: verdict ``unexplained
    structure``;
  - a campaign without ``heading_std`` and no hidden effect: no test rejects (``adequate`` or
    ``inconclusive``);
  - a 150-us sync delay beside a recorded column that follows the rotation sense (a fan
    switched with the sense, with 2 % noise of its own): a truly ambiguous pair, both reported
    ambiguous. (The column's noise must not be the heading noise: drawn from the same
    generator seed, it was, and the column then explained the noise too -- sync_delay +
    column fitted to chi2 0.15 on 44 dof, and the column won by Delta-BIC 5-9 in most seeds:
    31 % "ambiguous" at ``--full`` came from that, not from the diagnosis.)
  - the issue's own pair: a 70-us sync delay on 48 runs, ``encoder_harmonic`` the rival. The
    study measures whether the data separate them: the chi2 (noise sigmas squared) that the
    rival's best fit leaves of the delay's noise-free signature. Above Delta-BIC 6 plus the
    rival's extra parameter's ln n the right answer is sync_delay first and not ambiguous
    with encoder_harmonic, else both ambiguous. On the measurement model the encoder's first
    harmonic reaches heading only through lambda2 and leaves chi2 ~48 of the delay's 49: the
    data separate them clearly.

Sizes are stated as the parameter value and as the effect's signature on the plan: its peak
in arcsec and noise sigmas, and the RMS (in sigmas) of the part the paper's model cannot
absorb (what the data can see: noncentrality = n x RMS^2).

Checks. At any size: the issue's targets on the point estimates (false alarms <= 10 %; each
hidden effect first, each held-back case right, in >= 90 % of the seeds -- at the CI size,
10 fixed seeds, that allows one miss), and one-sided binomial tests at the family-wise level
1e-3 (Bonferroni over the rates): the false-alarm count consistent with a rate <= alpha, each
right count with a rate >= 90 %. Measured with ``--full`` (CPU time on a shared machine):

    false alarms 1/200 = 0.5 % (95 % CI 0.0-2.8 %)
    every hidden effect (and the pair) ranks first in 100/100 seeds, verdict missing-effect in
    97-100 %, refined to adequate with the effect(s) in the model in 97-100 % (the pair 99 %;
    73 % before complementary effects stopped counting as ambiguous)
    held back: level shift 100/100, outlier 100/100, no heading_std 186/200 = 93 % adequate,
    sync delay beside the sense-following column 100/100 ambiguous (31 % before its noise
    had a stream of its own), 70-us delay against encoder_harmonic 100/100 sync_delay first
    and not ambiguous (the rival leaves chi2 48.5 of the delay's signature); 234 s CPU for
    the hidden effects, a few minutes in all

Run:  python studies/diagnose_error_rates.py            (CI size: 100 null, 10 seeds each; ~15 s CPU)
      python studies/diagnose_error_rates.py --full     (200 null campaigns, 100 seeds each)
"""
import argparse
import sys
import time

import numpy as np
from scipy import stats
from threadpoolctl import threadpool_limits

from hse_opt import units
from hse_opt.diagnose import ALPHA, diagnose, refine
from hse_opt.diagnose.candidates import AMBIGUOUS_DELTA_BIC
from hse_opt.fit import fit
from hse_opt.model import as_model
from hse_opt.model.inputs import RUN_FIELDS
from hse_opt.validation.synthetic import diagnostic_plan, model_runs
from hse_opt.information import analyse, fisher
from hse_opt.sim.truth import TruthConfig, temperature
from hse_opt.validation.twins import hidden

#: family-wise probability that a diagnosis meeting the targets fails the study's checks
CHECK_ALPHA = 1e-3
#: the paper's model as it holds in every campaign (display units)
BASE = {"offset": 3.0, "lambda2": 4.2}
#: base tilt of the stand (pitch, roll), rad
BASE_TILT = (-120 * units.ARCSEC, -55 * units.ARCSEC)
#: lab temperature on each day (session), degC
AMBIENT_C = (16.0, 24.0, 20.0, 28.0)
#: stated size of each hidden effect (display units)
SIZES = {
    "axis_bias": {"bias_z": 0.09},
    "sync_delay": {"delay": 60.0},
    "scale_nonlinearity": {"sf_nonlin": 0.08},
    "warmup": {"warmup_amp": 40.0, "warmup_tau": 600.0},
    "azimuth_harmonic2": {"az_c2": 12.0, "az_s2": 6.0},
    "encoder_harmonic": {"enc_c1": 320.0, "enc_s1": 240.0},
    "covariate:temp_c": {"k_temp_c": 2.0},
}
#: hidden effects: every effect of the catalogue but the paper's
#: (hse_opt.validation.twins.effect_names), then sync delay and stand reading error together
HIDDEN = hidden(SIZES, pairs=[("sync_delay", "azimuth_harmonic2")])


def campaign_temperature(plan, runs_per_session=16):
    """Window-mean IMU temperature of each run (degC) from the simulator's thermal model, with
    the lab temperature of its day and a 1.5-degC, 1-h swing."""
    base = TruthConfig.default().updated({"thermal": {"swing_c": 1.5, "swing_period_s": 3600.0}})
    day = np.arange(len(plan)) // runs_per_session
    t = plan.t_start[:, None] + np.linspace(0.0, 1.0, 201)[None, :] * plan.duration[:, None]
    out = np.empty(len(plan))
    for d in np.unique(day):
        th = base.updated({"thermal": {"ambient_c": AMBIENT_C[d % len(AMBIENT_C)]}}).thermal
        out[day == d] = temperature(th, t[day == d]).mean(axis=1)
    return out


def effects_of(name):
    return name.split("+")


def signature(plan, temp, name, values):
    """Peak (arcsec, sigmas) and RMS of the unabsorbable part (sigmas) of an effect on the plan."""
    model = ["hse"] + effects_of(name)
    runs = model_runs(plan, BASE, np.random.default_rng(0), model=model, base_tilt=BASE_TILT,
                      covariates={"temp_c": temp})
    mm = as_model(model).measurement(True)
    X = mm.inputs_from_runs(runs)
    s = mm.predict(mm.vector({**BASE, **values}), X) - mm.predict(mm.vector(BASE), X)
    sig = runs.heading_std
    m0 = as_model(["hse"]).measurement(True)
    A = m0.jacobian(m0.vector(BASE), X[:len(RUN_FIELDS)]) / sig[:, None]  # no covariates
    Q, _ = np.linalg.qr(A)
    w = s / sig
    w = w - Q @ (Q.T @ w)
    return np.abs(s).max() / units.ARCSEC, np.abs(s / sig).max(), float(np.sqrt(np.mean(w ** 2)))


def clopper_pearson(k, n, conf=0.95):
    lo = stats.beta.ppf((1 - conf) / 2, k, n - k + 1) if k > 0 else 0.0
    hi = stats.beta.ppf(1 - (1 - conf) / 2, k + 1, n - k) if k < n else 1.0
    return lo, hi


def _step(runs_for, plan, seed):       # +25 arcsec from run 24 on (a re-mount)
    runs = runs_for({}, seed, model=["hse"])
    return runs.replace(heading_err=runs.heading_err + 25 * units.ARCSEC * (np.arange(len(runs)) >= 24))


def _outlier(runs_for, plan, seed):    # one run 200 arcsec off
    runs = runs_for({}, seed, model=["hse"])
    h = runs.heading_err.copy()
    h[17] += 200 * units.ARCSEC
    return runs.replace(heading_err=h)


def _no_std(runs_for, plan, seed):     # Table-1-like: no heading_std, no hidden effect
    return runs_for({}, seed, model=["hse"]).replace(heading_std=None)


def _pair(runs_for, plan, seed):       # a recorded column that follows the rotation sense
    p2 = diagnostic_plan(sessions=2, runs_per_session=24, rates_dps=(40.0,))
    # the column's own noise: a stream of its own, not the heading noise's
    fan = (p2.rate > 0).astype(float) + np.random.default_rng([seed, 1]).normal(0, 0.02, len(p2))
    return model_runs(p2, {**BASE, "delay": 150.0}, np.random.default_rng(seed), base_tilt=BASE_TILT,
                      covariates={"fan": fan})


#: the issue's pair: a 70-us sync delay on 48 runs (three days: no tilt fixture, about x, about y)
RIVAL_PLAN = dict(sessions=3, runs_per_session=16)
RIVAL_TRUTH = {**BASE, "delay": 70.0}


def _rival(runs_for, plan, seed):
    return model_runs(diagnostic_plan(**RIVAL_PLAN), RIVAL_TRUTH, np.random.default_rng(seed),
                      base_tilt=BASE_TILT)


def rival_separation():
    """The chi2 (noise sigmas squared) that hse + encoder_harmonic fitted to the delay's noise-free
    runs leaves (hse + sync_delay leaves 0), and whether that separates them: more than Delta-BIC
    6 plus ln n for the rival's one extra free parameter (enc_c1, enc_s1 against delay)."""
    exact = model_runs(diagnostic_plan(**RIVAL_PLAN), RIVAL_TRUTH, np.random.default_rng(0),
                       base_tilt=BASE_TILT)
    mm = as_model(["hse", "sync_delay"]).measurement(True)
    exact = exact.replace(heading_err=mm.predict(mm.vector(RIVAL_TRUTH), mm.inputs_from_runs(exact)))
    # the 2nd harmonic has no heading signature: held at 0, as the diagnosis holds it
    chi2 = float(fit(exact, ["hse", "encoder_harmonic"], fix={"enc_c2": 0.0, "enc_s2": 0.0}).chi2)
    return chi2, chi2 > AMBIGUOUS_DELTA_BIC + np.log(len(exact))


def _rival_right(separated):
    def right(runs, alpha):
        d = diagnose(runs, alpha=alpha)
        if separated:
            return d.best is not None and d.best.effect == "sync_delay" and "encoder_harmonic" not in d.ambiguous
        return {"sync_delay", "encoder_harmonic"} <= set(d.ambiguous)
    return right


HELD_BACK = {
    "level shift of 25 arcsec after run 23": (
        _step, lambda r, a: diagnose(r, alpha=a, refit=False).verdict == "unexplained structure",
        "verdict unexplained structure"),
    "one run 200 arcsec off": (
        _outlier, lambda r, a: diagnose(r, alpha=a, refit=False).verdict == "unexplained structure",
        "verdict unexplained structure"),
    "no heading_std, no hidden effect": (  # a false-alarm case: as many campaigns as the null's
        _no_std, lambda r, a: diagnose(r, alpha=a, refit=False).fits, "no test rejects"),
    "sync delay beside a sense-following column": (
        _pair, lambda r, a: set(diagnose(r, alpha=a).ambiguous) == {"sync_delay", "covariate:fan"},
        "both reported ambiguous"),
}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--null", type=int, default=100, help="no-effect campaigns (default 100)")
    ap.add_argument("--seeds", type=int, default=10, help="seeds per hidden effect (default 10)")
    ap.add_argument("--full", action="store_true",
                    help="200 no-effect campaigns, 100 seeds per effect, refine every hidden-effect campaign")
    ap.add_argument("--alpha", type=float, default=ALPHA)
    args = ap.parse_args(argv)
    if args.full:
        args.null, args.seeds = 200, 100
    plan = diagnostic_plan()
    temp = campaign_temperature(plan)
    t_start = time.process_time()

    # the plan separates every catalogue effect: the full model is identifiable on it
    full = as_model(["hse"] + [e for e in HIDDEN if "+" not in e])
    mm = full.measurement(True)
    runs0 = model_runs(plan, BASE, np.random.default_rng(0), model=full, base_tilt=BASE_TILT,
                       covariates={"temp_c": temp})
    p = mm.vector({**BASE, "warmup_amp": 40.0, "warmup_tau": 600.0})
    keep = [n not in ("enc_c2", "enc_s2") for n in mm.names]  # no heading signature at all
    info = analyse(fisher(mm.jacobian(p, mm.inputs_from_runs(runs0))[:, keep], runs0.heading_std,
                          mm.scale[keep]), np.array(mm.names)[keep], np.array(mm.names)[keep])
    print(f"plan: {len(plan)} runs of {plan.duration[0]:g} s, sigma {runs0.heading_std[0] / units.ARCSEC:.2f} "
          f"arcsec; full catalogue model identifiable, condition number {info.condition:.3g}")
    print(f"significance: alpha = {args.alpha:g} family-wise (Bonferroni over the diagnosis' tests)")

    def runs_for(values, seed, model=None):
        return model_runs(plan, {**BASE, **values}, np.random.default_rng(seed), model=model,
                          base_tilt=BASE_TILT, covariates={"temp_c": temp})

    # false alarms (the verdict rests on the score tests alone: no refits needed)
    alarms = sum(not diagnose(runs_for({}, seed, model=["hse"]), alpha=args.alpha, refit=False).fits
                 for seed in range(args.null))
    lo, hi = clopper_pearson(alarms, args.null)
    fa = alarms / args.null
    print(f"\nno hidden effect: verdict missing-effect in {alarms}/{args.null} campaigns = {100 * fa:.1f} % "
          f"(95 % CI {100 * lo:.1f}-{100 * hi:.1f} %; target <= 10 %)")

    # hidden effects
    print(f"\n{'hidden effect':<30}{'size':<34}{'peak arcsec':>12}{'peak/sigma':>11}{'seen RMS/sigma':>15}"
          f"{'ranks 1st':>11}{'missing':>9}" + (f"{'refined ok':>11}" if args.full else ""))
    firsts = {}
    for name, values in HIDDEN.items():
        peak, peak_s, seen = signature(plan, temp, name, values)
        first = missing = fixed = 0
        for seed in range(args.seeds):
            runs = runs_for(values, 10_000 + seed, model=["hse"] + effects_of(name))
            steps = refine(runs, alpha=args.alpha) if args.full else (diagnose(runs, alpha=args.alpha),)
            d = steps[0]
            top = [c.effect for c in d.candidates[:len(effects_of(name))]]
            first += set(top) == set(effects_of(name))
            missing += d.verdict == "missing-effect"
            fixed += steps[-1].fits and set(effects_of(name)) <= set(steps[-1].effects)
        size = ", ".join(f"{k} = {v:g}" for k, v in values.items())
        firsts[name] = (first, args.seeds)
        print(f"{name:<30}{size:<34}{peak:>12.1f}{peak_s:>11.1f}{seen:>15.2f}"
              f"{100 * first / args.seeds:>10.0f}%{100 * missing / args.seeds:>8.0f}%"
              + (f"{100 * fixed / args.seeds:>10.0f}%" if args.full else ""))
    print(f"\n({args.seeds} seeds per effect; for the combination 'ranks 1st' means both effects are the "
          f"two best candidates; {time.process_time() - t_start:.0f} s CPU)")

    # held-back cases (issue 14): the right answer is an effect, an ambiguity or "unexplained
    # structure"; a campaign without heading_std must not raise a false alarm
    chi2_rival, separated = rival_separation()
    print(f"\nissue 14's pair: on the delay's noise-free runs encoder_harmonic leaves chi2 {chi2_rival:.1f} "
          f"(sync_delay 0): {'the data separate them' if separated else 'the data cannot separate them'}")
    held_back = {**HELD_BACK, "70-us sync delay, encoder harmonic rival": (
        _rival, _rival_right(separated),
        "sync_delay first, not ambiguous" if separated else "both reported ambiguous")}
    print(f"\n{'held-back case':<44}{'right answer':<34}{'right':>12}")
    for name, (make, right, what) in held_back.items():
        n = args.null if make is _no_std else args.seeds
        k = sum(right(make(runs_for, plan, 20_000 + seed), args.alpha) for seed in range(n))
        firsts[f"held back: {name}"] = (k, n)
        print(f"{name:<44}{what:<34}{k:>5}/{n:<3}{100 * k / n:>4.0f}%")

    # the rates against their targets: one-sided binomial tests at the family-wise level
    # CHECK_ALPHA (Bonferroni over the 1 + len(HIDDEN) rates), so that a diagnosis meeting the
    # targets fails this study with probability < CHECK_ALPHA at any size
    level = CHECK_ALPHA / (1 + len(firsts))
    p_fa = float(stats.binom.sf(alarms - 1, args.null, args.alpha))
    print(f"\nchecks (one-sided binomial, level {level:.2g} each): false-alarm rate <= alpha = "
          f"{args.alpha:g}: p = {p_fa:.3g}; ranks first >= 90 %: smallest p = "
          f"{min(stats.binom.cdf(k, n, 0.9) for k, n in firsts.values()):.3g}")
    assert p_fa >= level, f"false-alarm rate {fa:.2f} exceeds alpha = {args.alpha:g} (p = {p_fa:.2g})"
    for name, (k, n) in firsts.items():
        p_first = stats.binom.cdf(k, n, 0.9)
        assert p_first >= level, f"{name}: right in only {k}/{n} seeds (p = {p_first:.2g})"
    # the targets, on the point estimates (at the CI size too: fixed seeds)
    assert fa <= 0.10, f"false-alarm rate {fa:.2f} > 0.10"
    for name, (k, n) in firsts.items():
        assert k >= 0.9 * n, f"{name}: right in only {100 * k / n:.0f} % of seeds"
    print("OK: false-alarm rate <= 10 %, every hidden effect ranks first and every held-back case gets "
          "its right answer in >= 90 % of seeds")


if __name__ == "__main__":
    with threadpool_limits(limits=1, user_api="blas"):  # small matrices: threads would only spin
        sys.exit(main())
