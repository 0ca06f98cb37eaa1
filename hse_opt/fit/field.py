"""Field campaigns: what a fit says at each stand position (the paper's Fig. 2 and K_HSE).

Planning such a campaign (how many positions, which rates and senses, how many repeats, or
the rest of one under way) is :mod:`hse_opt.design.field`.

In the field (no heading reference; :mod:`hse_opt.data`, "Field campaigns") the fit sees
only differences between the runs at each position, and the paper reads its calibration off
one line per position: heading against bias rate, normalised to the line's value at
0 deg/s (its Fig. 2), whose slope is K_HSE (Eqs. 15-16). :func:`position_lines` gives that
line for every position of a fitted campaign, from the fitted model and its covariance:

* the slope is the model's d(heading error)/d(Omega) at the position's mean run inputs (its
  C23 from the alignments' own leveling and headings), taken by least squares over rates
  spanning the position's, so it is exact for the paper's model (linear in Omega) and the
  best line for any other;
* ``K_HSE = -slope`` (the paper's sign, true - estimated per rad/s) with its 1-sigma from the
  fit's covariance; K_HSE differs between positions through C23 while lambda2 is one;
* the intercept is the weighted mean of ``heading_err - slope * Omega`` over the position's
  runs: the points minus it are the paper's normalised headings.
"""
from dataclasses import dataclass

import numpy as np

from .. import units

__all__ = ["PositionLine", "position_lines", "position_summary"]


@dataclass(frozen=True, eq=False)
class PositionLine:
    """One position's heading against the bias rate (SI unless the name says otherwise).

    Attributes
    ----------
    label : str
        The position (``'(surveyed)'`` for runs with a stand reference but no ``position``).
    surveyed : bool
        Whether the position has a heading reference.
    run : numpy.ndarray of int64, shape (m,)
    rate : numpy.ndarray, shape (m,)
        The runs' bias rates, rad/s.
    heading : numpy.ndarray, shape (m,)
        Heading error minus the intercept (normalised to the line at 0 deg/s), rad.
    sigma : numpy.ndarray, shape (m,)
        The runs' heading sigmas of the fit, rad.
    intercept : float
        The line at 0 deg/s in the position's own reference, rad.
    slope, slope_std : float
        d(heading error)/d(Omega) of the fitted model at the position and its 1-sigma, s.
    c23 : float or None
        Mean C23 = -gamma cos(psi) + theta sin(psi) of the position's runs, rad (None
        without pitch/roll).
    """

    label: str
    surveyed: bool
    run: np.ndarray
    rate: np.ndarray
    heading: np.ndarray
    sigma: np.ndarray
    intercept: float
    slope: float
    slope_std: float
    c23: float | None

    @property
    def k_hse_arcsec_per_radps(self):
        """K_HSE = -slope in the paper's unit and sign (section 3: 17.4 arcsec/(rad/s))."""
        return -self.slope / units.ARCSEC

    @property
    def k_hse_std_arcsec_per_radps(self):
        return self.slope_std / units.ARCSEC

    def to_dict(self):
        """Plain data in display units (``hse-opt fit --json``, key ``positions``)."""
        return {"position": self.label, "surveyed": self.surveyed, "n_runs": int(self.run.size),
                "rates_dps": sorted(set(np.round(self.rate / units.DEG_PER_S, 1).tolist())),  # 0.1 deg/s: encoder rates
                "k_hse_arcsec_per_radps": self.k_hse_arcsec_per_radps,
                "k_hse_std_arcsec_per_radps": self.k_hse_std_arcsec_per_radps,
                "c23_arcsec": None if self.c23 is None else self.c23 / units.ARCSEC}

    def line(self, rate):
        """The fitted line at ``rate`` (rad/s) and its 1-sigma band, normalised like
        :attr:`heading`: ``(slope * rate, slope_std * |rate|)``, rad."""
        rate = np.asarray(rate, dtype=float)
        return self.slope * rate, self.slope_std * np.abs(rate)


def _mean_inputs(runs, rows):
    """The position's mean run inputs, as arguments of ``MeasurementModel.inputs``."""
    mean = lambda a: None if a is None else float(np.mean(a[rows]))  # noqa: E731
    az = float(np.angle(np.mean(np.exp(1j * runs.azimuth[rows]))))
    cov = {k: float(np.mean(v[rows])) for k, v in runs.covariates.items()}
    return dict(azimuth=az, latitude=mean(runs.latitude), duration=mean(runs.duration),
                t_start=mean(runs.t_start), pitch=mean(runs.pitch), roll=mean(runs.roll), covariates=cov)


def position_lines(fit_result, runs):
    """The paper's Fig. 2 line for every position of a fitted campaign.

    Parameters
    ----------
    fit_result : hse_opt.fit.FitResult
        A fit of ``runs``.
    runs : hse_opt.data.Runs
        The fitted runs. Positions are the unsurveyed ones (:meth:`Runs.reference_groups`),
        then the surveyed runs grouped by ``position`` label (or all in one, ``'(surveyed)'``).

    Returns
    -------
    tuple of PositionLine
    """
    if len(runs) != len(fit_result.run) or not np.array_equal(np.asarray(runs.run), fit_result.run):
        raise ValueError(f"{runs.source}: the runs are not the fitted ones (run ids differ)")
    group, labels = runs.reference_groups()
    groups = [(lab, False, group == k) for k, lab in enumerate(labels)]
    surveyed = group < 0
    if surveyed.any():
        names = runs.position if runs.position is not None else np.full(len(runs), "(surveyed)")
        for lab in dict.fromkeys(names[surveyed].tolist()):
            groups.append((lab, True, surveyed & (names == lab)))
    mm = fit_result.measurement
    cov = np.asarray(fit_result.covariance) * np.outer(mm.scale, mm.scale)   # SI
    y, sigma = np.asarray(runs.heading_err), np.asarray(fit_result.sigma)
    out = []
    for label, known, rows in groups:
        rate = runs.rate[rows]
        top = max(np.max(np.abs(rate)), 5 * units.DEG_PER_S)
        grid = np.concatenate([np.linspace(-top, -top / 8, 4), np.linspace(top / 8, top, 4)])
        X = mm.inputs(grid, **_mean_inputs(runs, rows))
        h = mm.predict(fit_result.p, X)
        J = mm.jacobian(fit_result.p, X)
        A = np.column_stack([np.ones_like(grid), grid])
        slope = np.linalg.lstsq(A, h, rcond=None)[0][1]
        g = np.linalg.lstsq(A, J, rcond=None)[0][1]
        w = 1.0 / sigma[rows] ** 2
        intercept = float(np.sum(w * (y[rows] - slope * rate)) / np.sum(w))
        c23 = None
        if runs.pitch is not None:
            psi = runs.azimuth[rows]
            c23 = float(np.mean(-runs.roll[rows] * np.cos(psi) + runs.pitch[rows] * np.sin(psi)))
        out.append(PositionLine(label=str(label), surveyed=known, run=np.asarray(runs.run)[rows], rate=rate,
                                heading=y[rows] - intercept, sigma=sigma[rows], intercept=intercept,
                                slope=float(slope), slope_std=float(np.sqrt(max(g @ cov @ g, 0.0))), c23=c23))
    return tuple(out)


def position_summary(fit_result, runs):
    """Lines of text: K_HSE at each position of a campaign with unsurveyed positions."""
    out = ["  K_HSE per position (the slope of heading against bias rate within the position, the "
           "paper's Fig. 2 and sign):"]
    for ln in position_lines(fit_result, runs):
        d = ln.to_dict()
        c23 = "" if ln.c23 is None else f", C23 {d['c23_arcsec']:.0f} arcsec"
        rates = ", ".join(f"{r:g}" for r in d["rates_dps"])
        out.append(f"    {ln.label}{' (surveyed)' if ln.surveyed else ''}: {d['k_hse_arcsec_per_radps']:.4g} "
                   f"+- {d['k_hse_std_arcsec_per_radps']:.2g} arcsec/(rad/s){c23}; {d['n_runs']} runs at "
                   f"{rates} deg/s")
    return out
