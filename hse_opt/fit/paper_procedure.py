"""The paper's calibration procedure (section 2, steps 1-3) and its Eq. 14 compensation.

1. At one stand position, several alignments at each bias rate; average the heading error
   per rate.
2. Least-squares line through (Omega, mean heading error): its slope is K_HSE (Eqs. 15-16).
3. lambda2 = 3 w_ie cos L K_HSE / C23, with C23 = -gamma cos psi + theta sin psi from the
   alignments' own leveling (or given).

Later alignments, at any position or latitude, are compensated with Eq. 14 and their own C23.
Everything here is the paper's closed form (:mod:`hse_opt.model.closed_form`), independent
of the symbolic model that :func:`hse_opt.fit.fit` uses; with the paper's model the two agree
(``tests/test_fit.py``).

Signs: ``heading_err`` is estimated - true (the project's); K_HSE keeps the paper's sign
(true - estimated per rad/s), so the line's slope in our sign is ``-K_HSE``.
"""
from dataclasses import dataclass

import numpy as np

from .. import units
from .correction import COMPENSATED_COLUMN, COMPENSATION_STD_COLUMN
from .weights import run_sigma
from ..model import closed_form as cf

__all__ = ["PaperCalibration", "paper_procedure", "compensate_eq14", "POSITION_TOLERANCE"]

#: runs whose stand azimuths agree within this (rad) are one position
POSITION_TOLERANCE = 0.1 * units.DEG


@dataclass(frozen=True)
class PaperCalibration:
    """Result of the paper's procedure (SI unless the name says otherwise).

    Attributes
    ----------
    rate : numpy.ndarray, shape (m,)
        The distinct bias rates, rad/s, ascending.
    mean_heading_err : numpy.ndarray, shape (m,)
        Step 1: mean heading error per rate (estimated - true), rad.
    count : numpy.ndarray of int, shape (m,)
    k_hse, k_hse_std : float
        Step 2: K_HSE and its 1-sigma, s (rad of heading per rad/s; the paper's sign).
    intercept : float
        Heading error of the line at zero rate (estimated - true), rad.
    c23 : float or None
        East tilt of the rotation axis used in step 3, rad.
    lambda2, lambda2_std : float or None
        Step 3: lambda2 and its 1-sigma (C23 taken as exact), rad.
    latitude : float
        rad.
    sigma : float
        Heading sigma of one run used for the standard errors, rad.
    weighting : str
        Where ``sigma`` comes from (as :attr:`hse_opt.fit.FitResult.weighting`).
    dof : int
        Degrees of freedom of the line fit over the runs (n - 2).
    """

    rate: np.ndarray
    mean_heading_err: np.ndarray
    count: np.ndarray
    k_hse: float
    k_hse_std: float
    intercept: float
    c23: float
    lambda2: float
    lambda2_std: float
    latitude: float
    sigma: float
    weighting: str
    dof: int

    @property
    def k_hse_arcsec_per_radps(self):
        """K_HSE in arcsec/(rad/s), the paper's unit (section 3: 17.4)."""
        return self.k_hse / units.ARCSEC

    @property
    def lambda2_arcsec(self):
        return None if self.lambda2 is None else self.lambda2 / units.ARCSEC

    def compensate(self, runs):
        """Eq. 14 compensation of ``runs`` with this lambda2 (see :func:`compensate_eq14`)."""
        if self.lambda2 is None:
            raise ValueError("no lambda2: the calibration runs had no pitch/roll and no c23 was given")
        return compensate_eq14(runs, self.lambda2, self.lambda2_std)

    def to_dict(self):
        """JSON form, display units."""
        opt = lambda x, f=units.ARCSEC: None if x is None else float(x / f)  # noqa: E731
        return {
            "rates_dps": (self.rate / units.DEG_PER_S).tolist(),
            "mean_heading_err_arcsec": (self.mean_heading_err / units.ARCSEC).tolist(),
            "count": self.count.tolist(),
            "k_hse_arcsec_per_radps": self.k_hse_arcsec_per_radps,
            "k_hse_std_arcsec_per_radps": self.k_hse_std / units.ARCSEC,
            "intercept_arcsec": self.intercept / units.ARCSEC, "c23_arcsec": opt(self.c23),
            "lambda2_arcsec": opt(self.lambda2), "lambda2_std_arcsec": opt(self.lambda2_std),
            "latitude_deg": self.latitude / units.DEG, "sigma_arcsec": self.sigma / units.ARCSEC,
            "weighting": self.weighting, "dof": self.dof,
        }


def paper_procedure(runs, c23=None):
    """Steps 1-3 of the paper on single-position, multi-rate runs.

    Parameters
    ----------
    runs : hse_opt.data.Runs
        Alignments at one stand position (azimuths within :data:`POSITION_TOLERANCE`), one
        latitude and at least two bias rates.
    c23 : float, optional
        East tilt of the rotation axis C23, rad. Default: the mean over the runs of
        ``-roll cos(azimuth) + pitch sin(azimuth)`` from their leveling; without pitch/roll and
        without ``c23`` only K_HSE is estimated.

    Returns
    -------
    PaperCalibration
    """
    az = np.asarray(runs.azimuth, dtype=float)
    spread = np.ptp(np.angle(np.exp(1j * (az - az[0]))))
    if spread > POSITION_TOLERANCE:
        raise ValueError(f"{runs.source}: the paper's steps 1-3 use one stand position; these runs "
                         f"span {spread / units.DEG:.3g} deg of azimuth (allowed: "
                         f"{POSITION_TOLERANCE / units.DEG:g} deg): pass the single-position runs")
    lat = np.asarray(runs.latitude, dtype=float)
    if np.ptp(lat) > 1e-9:
        raise ValueError(f"{runs.source}: the runs are at several latitudes; allowed: one site")
    rate = np.asarray(runs.rate, dtype=float)
    key = np.round(rate / (1e-6 * units.DEG_PER_S)).astype(np.int64)
    keys, labels = np.unique(key, return_inverse=True)
    if keys.size < 2:
        raise ValueError(f"{runs.source}: every run is at {rate[0] / units.DEG_PER_S:g} deg/s; the "
                         "paper's step 2 needs at least two bias rates")
    n = rate.size
    if n < 3:
        raise ValueError(f"{runs.source}: {n} runs leave no degree of freedom for the line")
    sigma_run, weighting, _ = run_sigma(runs)
    wt = 1.0 / sigma_run ** 2
    y = np.asarray(runs.heading_err, dtype=float)
    # step 1: mean heading error per rate
    W = np.bincount(labels, wt)
    count = np.bincount(labels)
    mean = np.bincount(labels, wt * y) / W
    omega = np.bincount(labels, wt * rate) / W
    # step 2: least-squares line through the means, each weighted by its runs (with equal
    # repeats this is the paper's plain line, and it equals the line through every run)
    om_bar = np.sum(W * omega) / W.sum()
    sxx = np.sum(W * (omega - om_bar) ** 2)
    slope = np.sum(W * (omega - om_bar) * (mean - np.sum(W * mean) / W.sum())) / sxx
    intercept = np.sum(W * mean) / W.sum() - slope * om_bar
    res = y - intercept - slope * rate
    dof = n - 2
    if weighting == "residual":  # the weights were a guess: rescale them to the residuals'
        s = float(np.sqrt(np.sum(res ** 2) / dof))
        sxx = sxx * (sigma_run[0] / s) ** 2
        sigma_run = np.full(n, s)
    slope_std = float(1.0 / np.sqrt(sxx))
    k = -slope  # the paper's sign
    L = float(lat[0])
    # step 3
    if c23 is None and runs.pitch is not None:
        c23 = float(np.mean(cf.c23(az, runs.pitch, runs.roll)))
    lambda2 = lambda2_std = None
    if c23 is not None:
        if c23 == 0:
            raise ValueError("C23 = 0: a level axis has no heading-sensitive error; lambda2 cannot be "
                             "found from K_HSE")
        lambda2 = float(cf.lambda2_from_k_hse(k, c23, L))
        lambda2_std = float(abs(cf.lambda2_from_k_hse(slope_std, c23, L)))
    order = np.argsort(omega)
    return PaperCalibration(
        rate=omega[order], mean_heading_err=mean[order], count=count[order], k_hse=float(k),
        k_hse_std=slope_std, intercept=float(intercept), c23=c23, lambda2=lambda2,
        lambda2_std=lambda2_std, latitude=L, sigma=float(np.sqrt(np.mean(sigma_run ** 2))),
        weighting=weighting, dof=dof)


def compensate_eq14(runs, lambda2, lambda2_std=0.0):
    """Compensate ``runs`` with the paper's Eq. 14 and each run's own C23.

    Parameters
    ----------
    runs : hse_opt.data.Runs
        With pitch/roll (C23 from leveling); any position, rate or latitude.
    lambda2, lambda2_std : float
        rad.

    Returns
    -------
    Runs
        With ``heading_err_comp_arcsec`` (heading error minus Eq. 14's, project sign) and
        ``heading_comp_std_arcsec`` (the compensation's 1-sigma from ``lambda2_std``).
    """
    if runs.pitch is None:
        raise ValueError(f"{runs.source}: Eq. 14 needs each run's C23: give pitch_arcsec and roll_arcsec")
    for col in (COMPENSATED_COLUMN, COMPENSATION_STD_COLUMN):
        if col in runs.covariates:
            raise ValueError(f"{runs.source}, column '{col}': already present; allowed: runs without it")
    per_unit = cf.heading_error_eq14(runs.rate, runs.latitude, 1.0, runs.azimuth, runs.pitch, runs.roll)
    corr = per_unit * lambda2  # Eq. 14 is linear in lambda2
    std = np.abs(per_unit) * lambda2_std
    return runs.replace(**{COMPENSATED_COLUMN: (runs.heading_err - corr) / units.ARCSEC,
                           COMPENSATION_STD_COLUMN: std / units.ARCSEC})
