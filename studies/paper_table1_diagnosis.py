"""The paper's Table 1 diagnosed (issue 6, item 8): what the paper's model misses there, what
adding the warm-up does, and what 12 runs without times or tilts can and cannot tell.

Table 1: 12 alignments of 10 min at +40 deg/s, 3 at each of 4 stand azimuths, the first
position right after a cold start. The table gives no start times (run order stands in:
back-to-back 600-s runs, an assumption), no pitch/roll (the heading-sensitive error is fitted
as a free azimuth sinusoid; its constant part cannot be told from the offset at one rate and is
held at 0, by name) and no sigmas (one sigma from the scatter within the 4 positions: pure
error, 8 degrees of freedom). The label ``position`` (the azimuth group) and the covariate
``heading_err_compensated_arcsec`` (the paper's own compensated output: using it would be
circular) are left out.

Run: python studies/paper_table1_diagnosis.py
"""
import numpy as np

from hse_opt import units
from hse_opt.datasets import paper_table1
from hse_opt.diagnose import compare, diagnose, discriminating_runs

runs = paper_table1().replace(position=None, heading_err_compensated_arcsec=None)
FIX = {"lambda2*tilt_const": 0.0}

d0 = diagnose(runs, fix=FIX)
print("\n".join(d0.summary()))

print("\nPer run (residual of the paper's model):")
print(f"  {'run':>3} {'az deg':>7} {'res arcsec':>10} {'std.':>6} {'stud.':>6} {'leverage':>8} {'Cook':>6}")
for i, r in enumerate(d0.fit.run):
    print(f"  {r:>3} {runs.azimuth[i] / units.DEG:>7.1f} {d0.residuals[i] / units.ARCSEC:>10.2f} "
          f"{d0.standardized[i]:>6.2f} {d0.studentized[i]:>6.2f} {d0.leverage[i]:>8.2f} {d0.cooks[i]:>6.3f}")
first = d0.residuals[0] / units.ARCSEC
pos1_rest = np.mean(d0.residuals[1:3]) / units.ARCSEC
print(f"  cold start: run 1 sits {first - pos1_rest:+.1f} arcsec from the other two runs of position 1")

# what adding the warm-up does (its time constant profiled over its bounds)
d1 = d0.add("warmup")
print()
print("\n".join(compare(d0, d1).summary()))
warm = d0.candidate("warmup")
tau = d1.fit.value("warmup_tau")[0]
amp, amp_sd = d1.fit.value("warmup_amp")

# with the time constant of the default simulated system (10 min) held, the amplitude and its
# significance are a plain linear question
d600 = diagnose(runs, ["hse", "warmup"], fix={**FIX, "warmup_tau": 600.0})
a600, s600 = d600.fit.value("warmup_amp")

# which runs would tell the two models apart
prop = discriminating_runs(runs, d0.fit, d1.fit, k=2)
print("\nRuns that would tell hse from hse+warmup apart (best first):")
for p in prop:
    print(f"  {p['rate_dps']:+.0f} deg/s, azimuth {p['azimuth_deg']:.0f} deg, t_start {p['t_start_s']:.0f} s: "
          f"{p['pred_a_arcsec']:.1f} vs {p['pred_b_arcsec']:.1f} arcsec ({p['separation']:.2f} sigma apart)")

untestable = [c.effect for c in d0.candidates if not c.testable]
print(f"""
What 12 runs without times or tilts can and cannot tell
  * The paper's model fits to {d0.rms_arcsec:.2f} arcsec RMS against a pure-error sigma of
    {d0.fit.sigma[0] / units.ARCSEC:.2f} arcsec; lack of fit p = {d0.lack_of_fit_p:.2f}: verdict {d0.verdict}.
  * The cold start shows as run 1, {first - pos1_rest:+.1f} arcsec from runs 2-3 of the same position
    (standardised {d0.standardized[0]:+.2f}): not an outlier at n = 12 (studentised {d0.studentized[0]:+.2f}).
  * Adding the warm-up explains exactly that run: the profile puts the time constant at {tau:.0f} s
    (its lower bound) and the amplitude at {amp:.0f} +- {amp_sd:.0f} arcsec, run 1 gets leverage
    {d1.leverage[0]:.2f} (the warm-up rests on it alone); RMS {d0.rms_arcsec:.2f} -> {d1.rms_arcsec:.2f}
    arcsec, but Delta-BIC {warm.delta_bic:+.2f} and score p = {warm.p_value:.2f}: the data do not
    ask for it.
  * With the time constant held at 600 s, the warm-up amplitude is {a600:.1f} +- {s600:.1f} arcsec
    ({abs(a600) / s600:.1f} sigma).
  * Not testable here (named, with reasons above): {', '.join(untestable)}. One rate and one sense
    confound sync delay with the offset and the tilt-coupled effects with the HSE sinusoid; no
    times turn the warm-up into a question about run order; four azimuths leave one azimuth
    degree of freedom beyond the model.
  * A cold start at another azimuth (or the opposite sense) would separate warm-up from the
    stand position: {prop[0]['separation']:.2f} sigma for one run, so a few such runs are needed.""")

# checks against independent hand computations
y = runs.heading_err / units.ARCSEC
pos = np.repeat(np.arange(4), 3)
means = np.array([y[pos == k].mean() for k in range(4)])
ss_pe = float(np.sum((y - means[pos]) ** 2))
assert abs(d0.fit.sigma[0] / units.ARCSEC - np.sqrt(ss_pe / 8)) < 1e-9       # pure error, 8 dof
rss = float(np.sum((d0.residuals / units.ARCSEC) ** 2))
F = ((rss - ss_pe) / 1) / (ss_pe / 8)                                      # textbook lack-of-fit F
assert abs(d0.lack_of_fit.statistic - F) < 1e-9 * F and d0.lack_of_fit.dof == (1, 8)
assert d0.fits and d0.lack_of_fit_p > 0.05
assert {"sync_delay", "axis_bias", "scale_nonlinearity", "azimuth_harmonic2"} <= set(untestable)
assert d0.candidate("warmup").testable and d1.rms_arcsec < d0.rms_arcsec
assert d1.leverage[0] > 0.99 and abs(d1.residuals[0]) < 1e-6 * units.ARCSEC  # warm-up = run 1
assert d0.residuals[0] > 0 and first - pos1_rest > 15                        # run 1 above its position
print("\nOK: Table 1 diagnosed; pure error and lack of fit equal the hand computation")
