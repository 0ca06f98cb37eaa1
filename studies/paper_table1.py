"""The paper's Table 1 (multi-position check at 40 deg/s): what it shows, and how firmly.

Reproduces the peak-to-peak values (40.50 and 28.50 arcsec) and the per-position means; fits
the heading-sensitive sinusoid (tilt not given: the free azimuth sinusoid of lambda2 * C23)
before and after the paper's compensation, with confidence intervals; reads the C23 each
run's compensation implies; and repeats every conclusion without the cold-start position 1.

Run: python studies/paper_table1.py
"""
import numpy as np
from scipy import stats

from hse_opt import units
from hse_opt.datasets import paper_table1
from hse_opt.fit import fit, pure_error
from hse_opt.frames import EARTH_RATE

runs = paper_table1()
position = runs.position.astype(int)
BEFORE = runs.heading_err / units.ARCSEC
AFTER = runs.covariates["heading_err_compensated_arcsec"]
LAT = runs.latitude[0]
LAMBDA1 = 40 * units.DEG_PER_S - EARTH_RATE * np.sin(LAT)
#: heading error (estimated - true, arcsec) per arcsec*mrad of lambda2 * C23 at 40 deg/s (Eq. 14)
PER_UNIT = -LAMBDA1 * units.ARCSEC * units.MRAD / (3 * EARTH_RATE * np.cos(LAT)) / units.ARCSEC
LAMBDA2_PAPER = 4.2  # arcsec, section 3


def sinusoid(y_arcsec, keep):
    """Fit offset + HSE sinusoid over azimuth to the runs ``keep``; return a dict (arcsec)."""
    sub = runs.replace(heading_err=np.asarray(y_arcsec) * units.ARCSEC).subset(keep)
    # a single rate and sense cannot separate the constant part of lambda2 * C23 from the
    # offset (the fit says so and proposes the other sense); it is held at 0 and absorbed
    f = fit(sub, fix={"lambda2*tilt_const": 0.0})
    idx = [f.names.index("lambda2*tilt_cos"), f.names.index("lambda2*tilt_sin")]
    coef = f.values[idx] * PER_UNIT  # heading sinusoid: a cos(psi) + b sin(psi), arcsec
    cov = f.covariance[np.ix_(idx, idx)] * PER_UNIT ** 2
    dof = pure_error(sub)[1]  # sigma is from pure error: t and F with its dof
    chi = float(coef @ np.linalg.solve(cov, coef))
    radius = np.sqrt(2 * stats.f.ppf(0.95, 2, dof) * np.max(np.linalg.eigvalsh(cov)))
    amp = float(np.hypot(*coef))
    return {"fit": f, "coef": coef, "std": np.sqrt(np.diag(cov)), "amp": amp,
            "amp_ci": (max(0.0, amp - radius), amp + radius), "p": float(stats.f.sf(chi / 2, 2, dof)),
            "t": stats.t.ppf(0.975, dof), "dof": dof, "sigma": f.sigma[0] / units.ARCSEC,
            "lambda2_tilt": float(np.hypot(*f.values[idx])),
            "lambda2_tilt_std": float(np.sqrt(np.max(np.linalg.eigvalsh(f.covariance[np.ix_(idx, idx)]))))}


def noise_range_quantile(n, q, rng, samples=200_000):
    """Quantile ``q`` of the range of ``n`` unit-normal samples (Monte Carlo)."""
    z = rng.standard_normal((samples, n))
    return float(np.quantile(np.ptp(z, axis=1), q))


rng = np.random.default_rng(20130401)
everything = np.ones(len(runs), bool)
warm = position > 1

print("Paper Table 1: 12 alignments, 40 deg/s, 3 at each of 4 stand azimuths (arcsec)")
ptp_before, ptp_after = np.ptp(BEFORE), np.ptp(AFTER)
print(f"  peak-to-peak before {ptp_before:.2f}, after {ptp_after:.2f} (paper: 40.50, 28.50)")
print("  position  azimuth   mean before  mean after   scatter before  after")
means = {}
for k in range(1, 5):
    m = position == k
    means[k] = (BEFORE[m].mean(), AFTER[m].mean())
    print(f"  {k:8d}  {np.rad2deg(runs.azimuth[m][0]):7.2f}   {means[k][0]:11.2f}  {means[k][1]:10.2f}"
          f"   {BEFORE[m].std(ddof=1):14.2f}  {AFTER[m].std(ddof=1):5.2f}")

results = {}
for label, keep in (("all positions", everything), ("without position 1 (cold start)", warm)):
    b, a = sinusoid(BEFORE, keep), sinusoid(AFTER, keep)
    results[label] = (b, a)
    n = int(keep.sum())
    print(f"\nHSE sinusoid a cos(psi) + b sin(psi), {label} ({n} runs; sigma from pure error, "
          f"{b['dof']} dof; 95% intervals):")
    for name, r in (("before", b), ("after ", a)):
        (ca, cb), (sa, sb) = r["coef"], r["std"]
        print(f"  {name}: a = {ca:6.2f} +- {r['t'] * sa:5.2f}, b = {cb:6.2f} +- {r['t'] * sb:5.2f}; "
              f"amplitude {r['amp']:5.2f} [{r['amp_ci'][0]:.2f}, {r['amp_ci'][1]:.2f}]; "
              f"F-test of no sinusoid p = {r['p']:.3f}; run sigma {r['sigma']:.2f}")
    q95 = noise_range_quantile(n, 0.95, rng)
    print(f"  peak-to-peak before {np.ptp(BEFORE[keep]):.2f}, after {np.ptp(AFTER[keep]):.2f}; noise alone "
          f"at the after-sigma gives up to {q95 * a['sigma']:.1f} (95% of {n}-run samples)")

# the C23 each run's compensation implies: correction = before - after = PER_UNIT * lambda2 C23
c23 = (BEFORE - AFTER) / (PER_UNIT * LAMBDA2_PAPER) * units.MRAD / units.ARCSEC  # arcsec
A = np.column_stack([np.ones(12), np.cos(runs.azimuth), np.sin(runs.azimuth)])
(c0, ca, cb), *_ = np.linalg.lstsq(A, c23, rcond=None)
tilt_mrad = np.hypot(ca, cb) * units.ARCSEC / units.MRAD
within = np.sqrt(sum(((c23[position == k] - c23[position == k].mean()) ** 2).sum() for k in range(1, 5)) / 8)
print("\nC23 implied by the paper's compensation (lambda2 = 4.2 arcsec), arcsec, per run:")
print("  " + " ".join(f"{v:7.1f}" for v in c23))
print(f"  sinusoid over azimuth: {c0:.1f} + {ca:.1f} cos(psi) + {cb:.1f} sin(psi): stand tilt "
      f"{tilt_mrad:.3f} mrad; scatter within a position {within:.1f} arcsec (each run used its own "
      "leveling)")
# positions 2-4 after compensation: their means agree far more closely than their runs' scatter
# allows if the compensation were independent of these runs
m_after = np.array([means[k][1] for k in (2, 3, 4)])
se = results["without position 1 (cold start)"][1]["sigma"] / np.sqrt(3)
chi_means = float(np.sum((m_after - m_after.mean()) ** 2) / se ** 2)
p_coincide = float(stats.chi2.cdf(chi_means, 2))
print(f"\nCompensated means of positions 2-4: {', '.join(f'{m:.2f}' for m in m_after)} arcsec, spread "
      f"{np.ptp(m_after):.2f} against a standard error of {se:.1f} per mean: chance of agreeing this "
      f"closely p = {p_coincide:.1e}")
b_all = results["all positions"][0]
lam2 = b_all["lambda2_tilt"] / tilt_mrad
lam2_std = b_all["lambda2_tilt_std"] / tilt_mrad
print(f"  lambda2 from the uncompensated sinusoid and that tilt: {lam2:.2f} +- {lam2_std:.2f} arcsec "
      f"(paper: {LAMBDA2_PAPER})")
print("\nWhat the data say:")
print("  - the peak-to-peak values and means are the table's; the 'after' 28.50 is what 12 runs of "
      "noise alone give")
print(f"  - with all positions the sinusoid before compensation is significant (p = {b_all['p']:.3f}) and "
      f"gone after it (p = {results['all positions'][1]['p']:.2f})")
bw, aw = results["without position 1 (cold start)"]
print(f"  - without the cold-start position it is no longer significant at 5% (p = {bw['p']:.3f}): part of "
      "the evidence is the warm-up; with 3 positions the compensated means fit exactly (no test left)")
print(f"  - positions 2-4 agree after compensation to {np.ptp(m_after):.2f} arcsec, closer than chance allows "
      f"(p = {p_coincide:.0e}): the compensation looks tuned on these runs, so Table 1 'after' "
      "is not an independent check of it")
print("  - one rate, one sense: K_HSE and lambda2 cannot be estimated from Table 1 alone")

# -- assertions ----------------------------------------------------------------------------------
assert abs(ptp_before - 40.50) < 1e-9 and abs(ptp_after - 28.50) < 1e-9
hand = {1: (-9.973333, -6.22), 2: (10.593333, 2.046667), 3: (6.393333, 2.146667), 4: (-7.006667, 2.013333)}
for k, (mb, ma) in hand.items():
    assert abs(means[k][0] - mb) < 1e-5 and abs(means[k][1] - ma) < 1e-5, k
# the symbolic model's free-tilt sinusoid is numpy's [1, cos, sin] regression
coef_np = np.linalg.lstsq(A, BEFORE, rcond=None)[0]
assert np.allclose(b_all["coef"], coef_np[1:], rtol=1e-3), (b_all["coef"], coef_np)
# conclusions, and how the cold start changes them
assert b_all["p"] < 0.05 and results["all positions"][1]["p"] > 0.2
assert bw["p"] > 0.05
assert aw["amp"] < 0.5 and aw["amp_ci"][1] > 5  # 3 means, 3 parameters: an exact fit, no test
assert p_coincide < 0.01
assert ptp_after < noise_range_quantile(12, 0.95, rng) * results["all positions"][1]["sigma"]
assert abs(lam2 - LAMBDA2_PAPER) < 2 * lam2_std
print("\nOK: Table 1 reproduced; conclusions checked")
