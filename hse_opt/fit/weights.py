"""The weights of a fit: each run's heading sigma (the runs' own, the pure error of replicate
groups, or one to be estimated from the residuals; :mod:`hse_opt.fit`) and the robust
(Huber) weights and scale."""
from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np

from .. import units
from ..data.runs import COPY_TOL_ARCSEC
from ..information import heading_sigma
from ..model.inputs import RUN_FIELDS, RunInputs

#: the fewest replicate degrees of freedom whose pure error is used as the runs' sigma
#: (docs/weights.md): ``s^2 / sigma^2`` is ``chi2_nu / nu``, so with ``nu``
#: = 2 one sheet in ten gets ``s < sigma / 3`` and the fit's chi-square and standard errors are
#: off by that factor; from 8 the one-sided 97.5 % bound of ``sigma / s`` is below 2 (1.92).
#: Fewer: the pooled residual variance (``n - k`` >= ``nu`` degrees of freedom) is the sigma.
PURE_ERROR_MIN_DOF = 8

#: Huber's threshold in sigmas (95 % efficiency for Gaussian data)
HUBER_C = 1.345


#: rates within this share of each other are one setting: a rate measured from the encoder
#: (``hse-opt align``) differs from run to run by the table's ripple and the encoder's
#: quantization, 1e-5 - 1e-4 of it; the heading error follows the rate, so 1e-3 of it moves
#: a 10-arcsec HSE by 0.01 arcsec
RATE_RTOL = 1e-3


def _clusters(x, tol):
    """Labels of ``x`` (n,) grouped where sorted neighbours are within ``tol`` (n,) of each
    other (so measured values of one setting group, and no rounding boundary splits them)."""
    order = np.argsort(x, kind="stable")
    xs = np.asarray(x, float)[order]
    labels = np.empty(x.size, dtype=np.int64)
    labels[order] = np.concatenate([[0], np.cumsum(np.diff(xs) > tol[order][1:])]) if x.size else []
    return labels


def replicate_groups(runs, mm=None, tilt_tol=10 * units.ARCSEC):
    """Replicate groups: runs with the same settings share a label. Returns ``(labels, n_groups)``.

    Settings are the rate (within :data:`RATE_RTOL` of it: a measured rate), azimuth (for an
    unsurveyed position: the position), duration and latitude, the tilt (pitch and roll
    within ``tilt_tol`` of a neighbour's: measured tilts carry noise) and -- for a measurement model ``mm``
    whose heading depends on them (a warm-up, a covariate effect) -- time since power-on and
    the covariate columns: runs the model tells apart are not replicates, or their modelled
    differences would count as noise. Without ``mm`` the tilt counts when the runs have it."""
    # an unsurveyed position's runs carry their own headings as azimuths: the position is the setting
    group, _ = runs.reference_groups()
    azimuth = np.where(group < 0, np.mod(runs.azimuth, 2 * np.pi), 10.0 + group)
    rate = np.asarray(runs.rate, float)
    cols = [_clusters(rate, RATE_RTOL * np.abs(rate) + 1e-9)]
    cols += [np.round(np.asarray(a, float) / 1e-9) for a in (azimuth, runs.duration, runs.latitude)]
    if runs.pitch is not None and (mm is None or mm.tilt_known):
        cols += [_clusters(np.asarray(a, float), np.full(len(a), tilt_tol)) for a in (runs.pitch, runs.roll)]
    if mm is not None:
        X = mm.inputs_from_runs(runs)
        used = _inputs_used(mm)
        extra = [RunInputs.INDEX["t_start"], *range(len(RUN_FIELDS), mm.n_x)]  # time, covariates
        cols += [X[i] for i in extra if used[i]]
    _, labels = np.unique(np.column_stack(cols), axis=0, return_inverse=True)
    labels = labels.ravel()
    return labels, int(labels.max()) + 1 if labels.size else 0


@lru_cache(maxsize=64)
def _inputs_used(mm):
    """Whether the model's heading depends on each run input (from the expression graph)."""
    p, x = ca.SX.sym("p", len(mm.names)), ca.SX.sym("x", mm.n_x)
    sp = ca.jacobian(mm.h(p, x), x).sparsity()
    used = np.zeros(mm.n_x, dtype=bool)
    used[np.asarray(sp.get_col(), dtype=int)] = True
    return used


def multiplicity(runs):
    """``(count (n,), note or None)``: how many rows carry each row's measurement
    (:meth:`hse_opt.data.Runs.copies`: rows written twice), and the note that says which rows
    are copies; ``count`` is all ones without copies."""
    copies = getattr(runs, "copies", None)
    if copies is None:
        return np.ones(len(runs)), None
    labels, m = copies()
    n = labels.size
    if m == n:
        return np.ones(n), None
    count = np.bincount(labels, minlength=m)[labels].astype(float)
    first = np.unique(labels, return_index=True)[1][labels]   # each row's first row
    again = np.flatnonzero(first != np.arange(n))
    pairs = [f"{runs.run[i]} = {runs.run[first[i]]}" for i in again[:6]]
    shown = ", ".join(pairs) + (f", ... ({again.size} in all)" if again.size > 6 else "")
    return count, (f"{n - m} of {n} rows are copies of another row (run {shown}: the same settings and "
                   "heading to the last bit, written twice rather than measured again): each of the "
                   f"{m} measurements counted once, its weight shared among its copies")


def pure_error(runs, mm=None):
    """``(sigma, dof)`` from the scatter within replicate groups (rad), or ``(None, dof)``;
    copies of one measurement (:func:`multiplicity`) count once."""
    copies = getattr(runs, "copies", None)
    if copies is not None:
        labels, m = copies()
        if m < labels.size:
            runs = runs.subset(np.unique(labels, return_index=True)[1])
    labels, g = replicate_groups(runs, mm)
    dof = runs.rate.size - g
    if dof < 2:
        return None, dof
    y = runs.heading_err
    mean = np.bincount(labels, y, g) / np.bincount(labels, minlength=g)
    return float(np.sqrt(np.sum((y - mean[labels]) ** 2) / dof)), dof


#: replicates whose scatter is below this (arcsec) are copies, not measurements
IDENTICAL_ARCSEC = COPY_TOL_ARCSEC


def run_sigma(runs, robust=False, mm=None):
    """``(sigma (n,) rad, weighting, notes)`` by the rules of the module docstring (replicates
    as :func:`replicate_groups` of the measurement model ``mm``); where sigma is estimated
    later from the residuals, the default noise model's (:func:`heading_sigma`). Copies of one
    measurement (:func:`multiplicity`: ``c`` rows) each get ``sqrt(c)`` times its sigma, so
    that together they weigh as the one measurement they are."""
    count, note = multiplicity(runs)
    sigma, weighting, notes = _run_sigma(runs, robust, mm)
    return sigma * np.sqrt(count), weighting, notes + ([note] if note else [])


def _run_sigma(runs, robust, mm):
    n = len(runs)
    reference = getattr(runs, "azimuth_std", None)
    if runs.heading_std is not None:
        return _with_reference(np.asarray(runs.heading_std, dtype=float), reference, "heading_std")
    # to be estimated from the residuals: start from the default noise model
    guess = np.full(n, float(np.sqrt(np.mean(heading_sigma(runs.duration, runs.latitude) ** 2))))
    skipped = [] if reference is None else [
        "azimuth_std_arcsec not added to the sigma: the scale estimated from the residuals already "
        "holds the reference's scatter"]
    if robust:
        return guess, "robust-scale", skipped
    s_pe, dof_pe = pure_error(runs, mm)
    if s_pe is not None and s_pe <= IDENTICAL_ARCSEC * units.ARCSEC:
        return guess, "residual", [
            f"the replicates are identical (pure-error scatter {s_pe / units.ARCSEC:.2g} arcsec from {dof_pe} "
            "degrees of freedom): no pure-error sigma; check that the repeated runs were really measured again"]
    if s_pe is not None and dof_pe >= PURE_ERROR_MIN_DOF:
        sigma, weighting, notes = _with_reference(np.full(n, s_pe), reference, "pure-error")
        return sigma, weighting, [
            f"sigma {s_pe / units.ARCSEC:.3g} arcsec from {dof_pe} replicate degrees of freedom "
            f"(pure error)"] + notes
    if dof_pe >= 1:
        skipped = [f"{dof_pe} replicate degree{'s' if dof_pe > 1 else ''} of freedom: too few for a "
                   f"pure-error sigma (at least {PURE_ERROR_MIN_DOF}), sigma from the residuals; the "
                   "replicates test the fit (lack of fit)"] + skipped
    return guess, "residual", skipped


@dataclass(frozen=True)
class LackOfFit:
    """The pure-error lack-of-fit F test: the scatter of the replicate groups' means about the
    model against the scatter within the groups.

    Attributes
    ----------
    statistic : float
        ``F = (SS_lof / dof[0]) / (SS_pe / dof[1])``.
    dof : tuple of int
        ``(groups - k, measurements - groups)``: lack of fit, pure error.
    p_value : float
        P(F(dof) > statistic).
    groups : int
        Replicate groups (:func:`replicate_groups`).
    """

    statistic: float
    dof: tuple
    p_value: float
    groups: int

    def text(self):
        """``'lack of fit F(18, 2) = 0.61, p = 0.78 (20 replicate groups)'``."""
        return (f"lack of fit F({self.dof[0]}, {self.dof[1]}) = {self.statistic:.4g}, p = {self.p_value:.3g} "
                f"({self.groups} replicate groups)")

    def to_dict(self):
        return {"statistic": float(self.statistic), "dof": [int(d) for d in self.dof], "p_value": float(self.p_value), "groups": int(self.groups)}


def lack_of_fit_test(residuals, sigma, labels, n_groups, n_meas, k):
    """The pure-error lack-of-fit F test of a weighted fit (:class:`LackOfFit`), or None when
    the runs have no replicate, too few groups for it, or replicates that agree exactly. One rule for :func:`~hse_opt.fit.fit`
    and ``hse-opt diagnose``: the pure-error sum of squares is the weighted scatter within the
    replicate groups (``labels`` (n,), ``n_groups`` of them), ``dof = n_meas - n_groups``
    whatever the model; the lack of fit is the rest of the weighted residual sum of squares,
    ``n_groups - k`` degrees of freedom.

    Parameters
    ----------
    residuals, sigma : numpy.ndarray, shape (n,)
        The fit's residuals and each run's sigma (rad; the weights are ``1 / sigma^2``, copies
        of one measurement sharing its weight).
    labels : numpy.ndarray of int, shape (n,)
    n_groups, n_meas, k : int
        Replicate groups, measurements (rows less copies) and fitted directions (free parameters
        less active constraints, plus the positions' unknown headings).
    """
    from .result import f_sf
    dof_pe, dof_lof = n_meas - n_groups, n_groups - k
    if dof_pe < 1 or dof_lof < 1:
        return None
    res, w = np.asarray(residuals, float), 1.0 / np.asarray(sigma, float) ** 2
    mean = np.bincount(labels, w * res, n_groups) / np.bincount(labels, w, n_groups)
    ss_pe = float(np.sum(w * (res - mean[labels]) ** 2))
    ss_lof = max(float(np.sum(w * res ** 2)) - ss_pe, 0.0)
    if ss_pe <= 1e-20 * (ss_pe + ss_lof):
        return None                  # replicates that agree to the last bits: copies, no test
    F = (ss_lof / dof_lof) / (ss_pe / dof_pe)
    return LackOfFit(float(F), (int(dof_lof), int(dof_pe)), f_sf(F, dof_lof, dof_pe), int(n_groups))


def _with_reference(sigma, reference, weighting):
    """The runs' sigma with the stand reference's own 1-sigma (``azimuth_std_arcsec``) added in
    quadrature: a heading error is the alignment's heading minus the reference, so both
    errors are in it (independent, one draw per run)."""
    if reference is None:
        return sigma, weighting, []
    return np.hypot(sigma, reference), weighting, [
        "sigma of each run: its own and the stand reference's (azimuth_std_arcsec) in quadrature"]


def huber_weights(u, c):
    """Huber weights ``min(1, c/|u|)`` of standardised residuals ``u``."""
    a = np.abs(u)
    return np.where(a <= c, 1.0, c / np.maximum(a, 1e-300))


def mad_scale(res):
    """Robust sigma of the residuals: the median absolute deviation scaled to a Gaussian's
    sigma (``1.4826 MAD``, :func:`scipy.stats.median_abs_deviation`)."""
    from scipy.stats import median_abs_deviation  # robust fits only: scipy.stats loads slowly
    return float(median_abs_deviation(res, scale="normal"))
