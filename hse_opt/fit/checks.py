"""What a user should look at after a fit: runs far off the model (externally studentised
residuals, Bonferroni over the runs), a reduced chi-square far from 1 when sigma is known or
from pure error, degenerate noise (zero scatter) and a scatter no alignment gives (a unit
error).

Every ``hse-opt fit`` runs these checks, so they load no scipy.stats (a second of start-up):
the chi-square check uses the closed form :func:`~hse_opt.fit.result.chi2_sf`, and the
outlier test asks scipy for Student's t only when a run could be an outlier."""
import math

import numpy as np

from .. import units
from .result import chi2_isf, chi2_sf

#: family-wise level of the outlier test and two-sided level of the chi-square check
ALPHA = 0.01
#: a residual scatter below this (arcsec) is no noise at all
ZERO_SCATTER_ARCSEC = 1e-6


def studentized(result, runs):
    """Externally studentised residuals and leverages per run: ``t_i = u_i / sqrt(s_(i)^2
    (1 - h_i))`` with ``h_i`` the diagonal of the weighted hat matrix at the estimate and
    ``s_(i)^2`` the scale without run i (scale-free: the sigmas' ratios weight the runs)."""
    mm = result.measurement
    G = mm.jacobian(result.p, mm.inputs_from_runs(runs)) * mm.scale
    A = G[:, np.asarray(result.free, bool)] / np.asarray(result.sigma)[:, None]
    Q, R = np.linalg.qr(A)
    keep = np.abs(np.diag(R)) > 1e-12 * max(np.abs(np.diag(R)).max(), 1e-300) if R.size else np.zeros(0, bool)
    h = np.clip(np.sum(Q[:, keep] ** 2, axis=1), 0.0, 1.0)
    u = np.asarray(result.standardized, float)
    dof = int(result.dof)
    with np.errstate(divide="ignore", invalid="ignore"):
        s2_i = (float(u @ u) - u ** 2 / (1 - h)) / (dof - 1) if dof > 1 else np.full(u.size, np.nan)
        t = u / np.sqrt(s2_i * (1 - h))
    t[(1 - h) < 1e-9] = np.nan
    return t, h


def outliers(result, runs, alpha=ALPHA):
    """``[(run id, studentised residual)]`` rejecting at ``alpha`` (Bonferroni over the runs),
    largest first."""
    t, _ = studentized(result, runs)
    n, dof = t.size, int(result.dof)
    largest = float(np.max(np.nan_to_num(np.abs(t)), initial=0.0))
    # Student's t has the heavier tails (P(|T| > x) >= P(|Z| > x), Jensen: a Gaussian scale
    # mixture): when the largest residual passes the normal test, no run is an outlier
    if dof < 2 or n * math.erfc(largest / math.sqrt(2.0)) >= alpha:
        return []
    from scipy import stats
    with np.errstate(invalid="ignore"):
        p = n * 2 * stats.t.sf(np.abs(t), dof - 1)
    order = np.argsort(-np.nan_to_num(np.abs(t)))
    return [(int(result.run[i]), float(t[i])) for i in order if p[i] < alpha]


def zero_scatter(result):
    """The sentence saying that the fit's residuals are zero (below :data:`ZERO_SCATTER_ARCSEC`
    RMS: the model reproduces the data to rounding), or ""."""
    scatter = float(np.sqrt(np.mean(np.asarray(result.residuals) ** 2))) / units.ARCSEC
    if scatter >= ZERO_SCATTER_ARCSEC:
        return ""
    return (f"the residuals are zero ({scatter:.2g} arcsec RMS): the data carry no noise (generated, or "
            "copied values)")


#: a residual scatter this many times the default noise model's is no alignment noise
IMPLAUSIBLE_SCATTER = 100.0


def implausible_scatter(result, runs):
    """The sentence saying that the residual scatter is :data:`IMPLAUSIBLE_SCATTER` times or
    more what a gyrocompass alignment of these runs' lengths gives with the default gyro noise
    (:func:`hse_opt.information.heading_sigma`): heading errors in another unit (a column of
    milliarcseconds, say), or runs that did not align; or ""."""
    from ..information import heading_sigma
    scatter = float(np.sqrt(np.mean(np.asarray(result.residuals) ** 2)))
    expected = float(np.sqrt(np.mean(heading_sigma(runs.duration, runs.latitude) ** 2)))
    if scatter < IMPLAUSIBLE_SCATTER * expected:
        return ""
    return (f"the residual scatter {scatter / units.ARCSEC:.4g} arcsec RMS is {scatter / expected:.0f} times what "
            f"a gyrocompass alignment of these lengths gives with the default gyro noise "
            f"({expected / units.ARCSEC:.3g} arcsec): heading errors in another unit, or runs that did not align?")


def check_lines(result, runs):
    """Sentences for the fit's report (empty when nothing needs a look)."""
    out = []
    zero = zero_scatter(result)
    if zero:
        return [f"{zero}; sigmas, tests and uncertainties mean nothing here"]
    implausible = implausible_scatter(result, runs)
    if implausible:
        out.append(implausible)
    lof = result.lack_of_fit
    if lof is not None and lof.p_value < ALPHA:
        out.append(f"the replicate groups' means stray from the model more than the replicates scatter "
                   f"({lof.text()}): a missing effect (hse-opt diagnose), or replicates that are not "
                   "independent")
    if result.weighting == "heading_std" and result.dof > 0:
        p = chi2_sf(result.chi2_red * result.dof, result.dof)
        if not ALPHA / 2 <= p <= 1 - ALPHA / 2:
            lo, hi = (chi2_isf(q, result.dof) / result.dof for q in (1 - ALPHA / 2, ALPHA / 2))
            why = ("the scatter exceeds the sigmas: a missing effect or outliers (hse-opt diagnose), or "
                   "optimistic sigmas" if result.chi2_red > hi else "the scatter is below the sigmas: "
                   "pessimistic sigmas, or replicates that are not independent")
            out.append(f"chi2_red {result.chi2_red:.3g} is far from 1 (outside [{lo:.2g}, {hi:.2g}] at "
                       f"{ALPHA:g}): {why}")
    bad = outliers(result, runs)
    if bad:
        out.append("outliers (externally studentised residual, Bonferroni over the runs at "
                   f"{ALPHA:g}): " + ", ".join(f"run {r} ({t:+.3g})" for r, t in bad)
                   + ("" if result.downweighted else "; consider --robust (Huber loss) or check those runs"))
    return out
