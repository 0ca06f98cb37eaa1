"""Hidden-effect campaigns from the numeric simulator (issue 6, item 7).

The truth is the paper-like default system (warm-up switched off) plus one effect the paper's
model lacks - every catalogue effect in turn, and a combination of two - switched on through
its twin's TRUTH keys (:mod:`hse_opt.validation.twins`); and a campaign with nothing hidden. The plan
(``diagnostic_plan``): 4 cold starts on 4 days at different lab temperatures (so temperature is
not a function of time since power-on), +-20/40/60 deg/s, 8 azimuths, the stand's tilt plus a
0.5-deg tilt fixture per day; 64 runs of 300 s, sampled at 100 Hz instead of the paper's
500 Hz (a third of the CPU; the effects' heading signatures agree to 0.003 arcsec and the
noise to 1 %). ``refine`` diagnoses the paper's model and adds the suggested effects until no test
rejects.

Noise level: the noise actually in the campaign - the campaign minus its noise-free twin, an
independent reference the diagnosis never sees. The simulator draws the same noise whatever
the truth (to 0.02 arcsec RMS; to 2.5 arcsec with the scale-factor nonlinearity, which moves
the RLG pulses' quantization), so one twin of the no-effect campaign serves all nine. Not the
filter's 1-sigma: the RMS of 64 runs scatters about it by 1/sqrt(2 x 64) = 8.8 %, so the
issue's 20 % would be 2.3 standard errors and the study would pass or fail by seed (the
filter's sigma is printed, and must agree within 4 standard errors). Against the realised
noise that scatter cancels: with the right effects added, the residual is the noise less its
projection on the k fitted directions (sqrt(1 - k/n) = 0.93-0.97) plus what no model term
describes of the simulated system (a few arcsec); measured 0.88-1.09 x level over 12 seeds.
1.2 x level is exceeded only when a systematic part of ~0.7 x level RMS is left unexplained.

Sizes: each hidden effect leaves, after the paper's model has absorbed what it can, about 1.6
noise sigmas RMS (printed: the signature's peak, and the paper model's RMS against the noise
level, >= 1.55 over 12 seeds), so that it is found with power ~1 and the RMS before adding it
exceeds 1.2 x level by > 4 standard errors of the noise-signature cross term.

Verdicts: each is a test at a family-wise level; at the default 0.05 all nine campaigns would
end adequate in only ~0.95^9 = 63 % of seeds. The study uses the Bonferroni level 1e-3 / 9 per
campaign, so that a correct diagnosis fails the study's verdicts with probability < 1e-3.

Criteria, in every campaign: the paper's model is flagged missing-effect, the hidden effect
ranks first, nothing is ambiguous and the RMS exceeds 1.2 x level (for the no-effect campaign:
adequate at once); after refining, exactly the hidden effects were added, the RMS is within
1.2 x level and no test rejects (the verdict adequate, or inconclusive when another effect
these runs would miss could still move a parameter: hse_opt.aliasing).

Seeds: the CI seed (6, the issue's number) was fixed before any trial. ``--seeds N`` runs
seeds 6 .. 5 + N and prints the pass count: 12/12 seeds passed (``--seeds 12``, 190 s CPU).

Run: python studies/diagnose_hidden_effects.py              (one seed, ~18 s CPU)
     python studies/diagnose_hidden_effects.py --seeds 12   (the robustness check)
"""
import argparse
import sys
import time

import numpy as np
from threadpoolctl import threadpool_limits

from hse_opt import units
from hse_opt.data import Runs
from hse_opt.diagnose import refine
from hse_opt.validation.synthetic import diagnostic_plan
from hse_opt.sim import TruthConfig, run_campaign
from hse_opt.validation import twins

SEED = 6
#: family-wise probability that a correct diagnosis fails the study's verdicts
STUDY_ALPHA = 1e-3
AMBIENT_C = (16.0, 24.0, 20.0, 28.0)
BASE = TruthConfig.default().updated({
    "timing": {"sample_period_ms": 10.0},
    "mount": {"warmup_xi_z_arcsec": 0.0}, "gyro": {"bias_warmup_dph": [0.0, 0.0, 0.0]},
    "thermal": {"swing_c": 1.5, "swing_period_s": 3600.0}})
#: size of each hidden effect (its parameters, display units); the simulator's truth follows
#: from its twin (hse_opt.validation.twins). Stand reading error 26 arcsec at 2 x azimuth,
#: encoder error 200 arcsec at the table angle, both at phase 30 deg.
SIZES = {
    "axis_bias": {"bias_z": 0.2},
    "sync_delay": {"delay": 125.0},
    "scale_nonlinearity": {"sf_nonlin": 0.175},
    "warmup": {"warmup_amp": 80.0, "warmup_tau": 600.0},
    "azimuth_harmonic2": {"az_c2": -26.0 * np.sin(np.pi / 6), "az_s2": -26.0 * np.cos(np.pi / 6)},
    "encoder_harmonic": {"enc_c1": 200.0 * np.sin(np.pi / 6), "enc_s1": 200.0 * np.cos(np.pi / 6),
                         "enc_c2": 0.0, "enc_s2": 0.0},
    "covariate:temp_c": {"k_temp_c": 4.0},
}
#: name -> truth changes: every effect the model shares with the simulator but the paper's
#: (hse_opt.validation.twins.effect_names), then sync delay and stand reading error together
HIDDEN = {name: twins.truth_changes(name, values)
          for name, values in twins.hidden(SIZES, pairs=[("sync_delay", "azimuth_harmonic2")]).items()}


def simulate(truth, seed, sessions=4, per_session=16):
    """The diagnostic plan on the simulator, each day at its own lab temperature."""
    plan = diagnostic_plan(sessions=sessions, runs_per_session=per_session)
    days = []
    for s in range(sessions):
        day = plan.subset(np.arange(s * per_session, (s + 1) * per_session))
        days.append(run_campaign(day, truth.updated({"thermal": {"ambient_c": AMBIENT_C[s % 4]}}),
                                 seed).to_columns())
    return Runs.from_columns({k: np.concatenate([d[k] for d in days]) for k in days[0]}, source="simulator")


def study(seed, alpha):
    """One seed: every campaign diagnosed and refined; returns the failed campaigns."""
    runs = simulate(BASE, seed)
    noise = runs.heading_err - simulate(BASE.noise_free(), seed).heading_err
    level = float(np.sqrt(np.mean(noise ** 2)) / units.ARCSEC)
    stated = float(np.sqrt(np.mean(runs.heading_std ** 2)) / units.ARCSEC)
    se = 1 / np.sqrt(2 * len(runs))
    print(f"\nseed {seed}: noise in the campaigns {level:.2f} arcsec RMS; the filter's own 1-sigma "
          f"{stated:.2f} ({(level / stated - 1) / se:+.1f} standard errors of a {len(runs)}-run RMS)")
    print(f"{'hidden':<30}{'peak/level':>11}{'1st candidate':>20}{'RMS/level before':>18}{'after':>7}"
          f"  verdict after, effects added")
    failed = []
    # the reference itself: the processor's sigma describes the noise the campaigns carry
    if abs(level / stated - 1) > 4 * se:
        failed.append("noise level against the filter's sigma")
    for hidden, change in [("none", {})] + list(HIDDEN.items()):
        data = runs if hidden == "none" else simulate(BASE.updated(change), seed)
        steps = refine(data, covariates=["temp_c"], alpha=alpha)
        first, last = steps[0], steps[-1]
        wanted = set() if hidden == "none" else set(hidden.split("+"))
        added = [e for e in last.effects if e != "hse"]
        top = first.candidates[0].effect if first.best is not None else "-"
        peak = np.max(np.abs(data.heading_err - runs.heading_err)) / units.ARCSEC / level
        before, after = first.rms_arcsec / level, last.rms_arcsec / level
        print(f"{hidden:<30}{peak:>11.1f}{top:>20}{before:>18.2f}{after:>7.2f}  {last.verdict}, "
              f"{', '.join(added) or 'none'}")
        found = (not wanted or (first.verdict == "missing-effect" and top in wanted and first.ambiguous == ()
                                and before > 1.2))
        if not (found and set(added) == wanted and after <= 1.2 and last.fits):
            failed.append(hidden)
    return failed


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=1, help=f"run seeds {SEED} .. {SEED} + N - 1 (default 1)")
    args = ap.parse_args(argv)
    t0 = time.process_time()
    alpha = STUDY_ALPHA / (len(HIDDEN) + 1)
    print(f"verdicts at the family-wise level {alpha:.2g} per campaign (Bonferroni: {STUDY_ALPHA:g} over "
          f"the {len(HIDDEN) + 1} campaigns of a seed)")
    failures = {seed: study(seed, alpha) for seed in range(SEED, SEED + args.seeds)}
    passed = [seed for seed, f in failures.items() if not f]
    print(f"\npassed {len(passed)}/{args.seeds} seeds ({time.process_time() - t0:.0f} s CPU)")
    for seed, f in failures.items():
        if f:
            print(f"  seed {seed}: failed {', '.join(f)}")
    assert len(passed) == args.seeds, f"not found, added and brought to the noise: {failures}"
    print("OK: every hidden effect found first, added, RMS within 20 % of the noise, no test rejecting")


if __name__ == "__main__":
    with threadpool_limits(limits=1, user_api="blas"):  # small matrices: threads would only spin
        sys.exit(main())
