"""The runs that would tell two fitted models apart (a T-optimal discrimination design)."""
from __future__ import annotations

import numpy as np

from .. import units
from ..data import Runs


def discriminating_runs(runs, fit_a, fit_b, k=3):
    """The runs that would best tell two fitted models apart: a T-optimal discrimination
    design (:class:`hse_opt.design.LackOfFit`, :func:`hse_opt.design.approximate_design`)
    over candidate runs (both senses at the smallest and largest |rate|, azimuths every
    45 deg, a cold start, mid and late times since power-on, the observed tilts and the
    extremes of each covariate), added to the runs already made: the runs, in proportions,
    on which model ``b`` -- refitted to everything -- would fit data from model ``a`` worst.

    Parameters
    ----------
    runs : hse_opt.data.Runs
        The runs both models were fitted to.
    fit_a, fit_b : FitResult
    k : int
        At most this many runs (the design's support, largest share first).

    Returns
    -------
    list of dict
        ``rate_dps, azimuth_deg, t_start_s, duration_s`` (``pitch_arcsec, roll_arcsec`` when the
        tilt is known; covariates by name), ``pred_a_arcsec``, ``pred_b_arcsec``, ``share``
        (the design's fraction of new runs there) and ``separation`` (the difference of the
        predictions in sigmas of run noise and both fits' prediction uncertainty). Empty when
        the design's convex program has no solution (e.g. a field campaign whose positions'
        unknown headings leave the lack of fit unbounded on the candidates): no proposal
        rather than a made-up one; the diagnosis still names the pair.
    """
    from ..design import DesignError, LackOfFit, approximate_design

    grid = _candidate_grid(runs, fit_a, fit_b)
    sigma_run = float(np.median(fit_a.sigma))

    def rows(r):  # [J_b, h_a - h_b] / sigma over the runs r, and the variance of h_a - h_b
        preds, var = [], np.zeros(len(r))
        for f in (fit_a, fit_b):
            mm = f.measurement
            X = mm.inputs_from_runs(r)
            preds.append(mm.predict(f.p, X))
            G = mm.jacobian(f.p, X) * mm.scale  # per display unit
            var += np.einsum("ij,jk,ik->i", G, f.covariance, G)
        mm = fit_b.measurement
        Jb = (mm.jacobian(fit_b.p, mm.inputs_from_runs(r)) * mm.scale)[:, np.asarray(fit_b.free, bool)]
        return np.column_stack([Jb, preds[0] - preds[1]]) / sigma_run, preds, var

    A, preds, var = rows(grid)
    A0 = rows(runs)[0]
    try:
        design = approximate_design(A, LackOfFit(), prior=A0.T @ A0)
    except DesignError:
        return []
    sep = np.abs(preds[0] - preds[1]) / np.sqrt(sigma_run ** 2 + var)
    support = design.support[np.argsort(-design.runs[design.support], kind="stable")]
    out = []
    for i in support[:k]:
        row = {"rate_dps": float(grid.rate[i] / units.DEG_PER_S),
               "azimuth_deg": float(np.mod(grid.azimuth[i] / units.DEG, 360.0)),
               "t_start_s": float(grid.t_start[i]), "duration_s": float(grid.duration[i])}
        if grid.pitch is not None:
            row["pitch_arcsec"] = float(grid.pitch[i] / units.ARCSEC)
            row["roll_arcsec"] = float(grid.roll[i] / units.ARCSEC)
        row.update({c: float(v[i]) for c, v in grid.covariates.items()})
        row.update(pred_a_arcsec=float(preds[0][i] / units.ARCSEC),
                   pred_b_arcsec=float(preds[1][i] / units.ARCSEC),
                   share=float(design.runs[i] / design.runs.sum()), separation=float(sep[i]))
        out.append(row)
    return out



def _candidate_grid(runs, *fits):
    r = np.abs(np.asarray(runs.rate, float))
    rates = np.unique(np.concatenate([[r.min(), r.max()], [-r.min(), -r.max()]]))
    az = np.deg2rad(np.arange(0.0, 360.0, 45.0))
    dur = float(np.max(runs.duration))
    t_obs = (np.asarray(runs.t_start, float) if runs.t_start is not None
             else np.concatenate([[0.0], np.cumsum(np.asarray(runs.duration)[:-1])]))
    times = np.unique([0.0, float(np.median(t_obs)), float(np.max(t_obs))])
    tilts = [(None, None)]
    if runs.pitch is not None:
        q = np.round(np.column_stack([runs.pitch, runs.roll]) / (60 * units.ARCSEC))
        _, first = np.unique(q, axis=0, return_index=True)
        tilts = [(float(runs.pitch[i]), float(runs.roll[i])) for i in sorted(first)[:4]]
    used = []
    for f in fits:
        used += [c for c in f.model.covariates if c not in used]
    cov_levels = [[]]
    for c in used[:2]:
        v = np.asarray(runs.covariates[c], float)
        cov_levels = [lv + [(c, x)] for lv in cov_levels for x in (v.min(), v.max())]
    rows = []
    for rate in rates:
        for a in az:
            for t in times:
                for tilt in tilts:
                    for lv in cov_levels:
                        rows.append((rate, a, t, tilt, dict(lv)))
    m = len(rows)
    cov = {c: np.array([row[4].get(c, float(np.mean(runs.covariates[c]))) for row in rows]) for c in used}
    pitch = None if runs.pitch is None else np.array([row[3][0] for row in rows])
    roll = None if runs.pitch is None else np.array([row[3][1] for row in rows])
    return Runs(run=np.arange(m), rate=np.array([row[0] for row in rows]), azimuth=np.array([row[1] for row in rows]),
                heading_err=np.zeros(m), latitude=np.full(m, float(np.mean(runs.latitude))),
                duration=np.full(m, dur), t_start=np.array([row[2] for row in rows]), pitch=pitch, roll=roll,
                covariates=cov, source="candidate runs")
