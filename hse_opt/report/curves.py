"""The fitted model drawn as curves on made-up runs, and what the calibration line's slope holds
(each effect's part)."""
from __future__ import annotations

import numpy as np

from .. import units
from ..data import Runs
from .rules import _groups


def _arcsec(x):
    return np.asarray(x, dtype=float) / units.ARCSEC


def _grid_runs(runs, mask, n, **columns):
    """``n`` made-up runs like ``runs[mask]``: every column at its median over the mask
    except those given (SI arrays of shape (n,)); for drawing the model as a curve."""
    def med(x):
        return None if x is None else np.full(n, np.median(np.asarray(x)[mask]))
    cols = {name: med(getattr(runs, name)) for name in
            ("rate", "azimuth", "latitude", "duration", "t_start", "pitch", "roll")}
    cols.update(columns)
    if runs.pitch is None:
        cols["pitch"] = cols["roll"] = None
    return Runs(run=np.arange(1, n + 1), heading_err=np.zeros(n), source="model curve",
                covariates={k: med(v) for k, v in runs.covariates.items()}, **cols)


def _curve(fit, runs, mask, **columns):
    """The fitted model's heading error (rad) and the part compensation removes (rad) on
    made-up runs (:func:`_grid_runs`)."""
    from ..fit.correction import compensation
    n = len(next(iter(columns.values())))
    grid = _grid_runs(runs, mask, n, **columns)
    h = fit.measurement.predict(fit.p, fit.measurement.inputs_from_runs(grid))
    return h, compensation(grid, fit)[0]


def _only(fit, effects):
    """The fit's SI parameter vector with the parameters of every effect outside ``effects``
    at their nominal (no-error) values (tilt coefficients ``name*tilt_...`` follow ``name``)."""
    mm = fit.measurement
    owner = {q.name: e.name for e in fit.model.effects for q in e.params}
    keep = np.array([owner.get(nm.split("*", 1)[0]) in effects for nm in mm.names])
    return np.where(keep, fit.p, mm.nominal)


def slope_parts(fit, runs):
    """The calibration line's slope at each stand azimuth of the runs and each effect's part.

    The slope is that of the fitted model between the smallest and largest bias rate, the
    other inputs at their medians over the runs at that azimuth; an effect's part is the
    slope of the model with only that effect's parameters as fitted (the others at their
    nominal values). For the paper's model the ``hse`` part is -K_HSE (our sign, Eq. 16).

    Returns
    -------
    dict or None
        ``azimuth_deg`` (m,), ``slope`` (m,) and ``parts`` (effect -> (m,)), arcsec per
        deg/s; None when the runs share one bias rate.
    """
    r1, r2 = float(np.min(runs.rate)), float(np.max(runs.rate))
    if np.unique(np.round(runs.rate / units.DEG_PER_S, 6)).size < 2:
        return None
    mm = fit.measurement
    labels, centres = _groups(np.mod(runs.azimuth, 2 * np.pi), 1 * units.DEG)
    grids = [_grid_runs(runs, labels == g, 2, rate=np.array([r1, r2]), azimuth=np.full(2, c))
             for g, c in enumerate(centres)]
    X = np.concatenate([mm.inputs_from_runs(gr) for gr in grids], axis=1)

    def slope(p):
        h = mm.predict(p, X).reshape(-1, 2)
        return (h[:, 1] - h[:, 0]) / units.ARCSEC / ((r2 - r1) / units.DEG_PER_S)
    return {"azimuth_deg": centres / units.DEG, "slope": slope(fit.p),
            "parts": {e: slope(_only(fit, {e})) for e in fit.model.effect_names}}


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def _slope_others(parts):
    """Effects beyond hse whose part of the slope exceeds 5 % of it (RMS over azimuths)."""
    return {e: v for e, v in parts["parts"].items() if e != "hse" and _rms(v) > 0.05 * _rms(parts["slope"])}


def slope_caption(parts):
    """The calibration line's caption: what its slope holds (:func:`slope_parts`)."""
    base = ("Heading error against bias rate at each stand azimuth (points: measured, 1-sigma bars; "
            "lines: the fitted model). The paper's Fig. 2: ")
    others = _slope_others(parts)
    if not others:
        return base + ("the slope is -K_HSE = -lambda2 C23 / (3 w_ie cos L) (our sign), so it changes "
                       "with azimuth as the tilt term C23 does.")
    shares = ", ".join(f"{e} {_rms(v):.3g}" for e, v in {"hse": parts["parts"]["hse"], **others}.items())
    return base + (f"here the slope is not K_HSE alone: effects beyond hse contribute to it. Of its "
                   f"RMS over the stand azimuths, {_rms(parts['slope']):.3g} arcsec per deg/s, the "
                   f"effects alone give: {shares} arcsec per deg/s. Dashed: the hse part alone, "
                   "-K_HSE = -lambda2 C23 / (3 w_ie cos L) (our sign).")
