"""Plans a stand can run: the final settings rounded to the stand's resolution, re-certified,
and written as the decimals an operator types (``60.0`` deg/s, ``314.94`` deg, no ``-3.3e-13``).
"""
from __future__ import annotations

from decimal import Decimal

import numpy as np

from .. import units
from ..data import Plan
from .problem import mean_loss


def _steps(x, step):
    """Nearest whole number of ``step`` (int array)."""
    return np.rint(np.asarray(x, float) / step).astype(np.int64)


def _text(k, step_unit):
    """``k`` steps of ``step_unit`` (a float in file units) as exact decimal text."""
    q = Decimal(f"{step_unit:.12g}")
    return [format((Decimal(int(v)) * q).normalize(), "f") for v in k]


def snap(settings, space, resolution):
    """Settings rounded to ``resolution``: rates to the nearest step inside the rate limits,
    azimuths to the nearest step in [0, 360) deg, tilts towards zero (inside the fixture's
    limit). Returns ``(settings, steps)``, the latter the whole steps per factor."""
    lo, hi = space.rates
    r = resolution.rate
    k_rate = _steps(settings.rate, r)
    mag, sign = np.abs(k_rate), np.where(settings.rate < 0, -1, 1)
    k_lo, k_hi = int(np.ceil(lo / r - 1e-9)), int(np.floor(hi / r + 1e-9))
    if k_lo > k_hi:
        raise ValueError(f"rate resolution {r / units.DEG_PER_S:g} deg/s: no step inside the rate limits "
                         f"{lo / units.DEG_PER_S:g}-{hi / units.DEG_PER_S:g} deg/s; allowed: a finer resolution")
    k_rate = sign * np.clip(mag, k_lo, k_hi)
    n_az = _steps(2 * np.pi, resolution.azimuth)
    k_az = np.mod(_steps(np.mod(settings.azimuth, 2 * np.pi), resolution.azimuth), n_az)
    k_tx = np.trunc(np.asarray(settings.tilt_x) / resolution.tilt + 1e-9 * np.sign(settings.tilt_x)).astype(np.int64)
    k_ty = np.trunc(np.asarray(settings.tilt_y) / resolution.tilt + 1e-9 * np.sign(settings.tilt_y)).astype(np.int64)
    new = settings.replace(rate=k_rate * r, azimuth=k_az * resolution.azimuth, tilt_x=k_tx * resolution.tilt + 0.0,
                           tilt_y=k_ty * resolution.tilt + 0.0)
    return new, (k_rate, k_az, k_tx, k_ty)


def to_resolution(prob, exact, stand, mm, space, resolution):
    """Round ``exact``'s settings (in place) and re-evaluate its loss and guards there. When
    the nearest steps put a guard below its bound (or below where it was), the other neighbour
    of one rate or azimuth at a time is taken, the change that raises the worst guard most,
    until every guard holds (at most once per value). Returns the guards that still fail."""
    floors = [min(g.bound, g.level(exact.counts)) for g in exact.guards]

    def at(settings):
        X = settings.inputs(mm, stand)
        sigma = stand.sigma(settings.duration)
        guards = tuple(g.at(g.spec.numeric(X, sigma)) for g in exact.guards)
        margin = min([g.level(exact.counts) - f for g, f in zip(guards, floors)], default=0.0)
        return settings, X, sigma, guards, margin

    best = at(snap(exact.settings, space, resolution)[0])
    tried = set()
    while best[4] < -1e-9:
        trials = []
        for field, step in (("rate", resolution.rate), ("azimuth", resolution.azimuth)):
            old = getattr(exact.settings, field)
            cur = getattr(best[0], field)
            for value in np.unique(cur):
                if (field, value) in tried:
                    continue
                sel = cur == value
                other = value + step * np.sign(old[sel][0] - value) if old[sel][0] != value else value + step
                if field == "rate" and not space.rates[0] - 1e-12 <= abs(other) <= space.rates[1] + 1e-12:
                    continue
                moved = np.where(sel, other, cur)
                trials.append(((field, value), at(best[0].replace(**{field: moved}))))
        if not trials:
            break
        key, trial = max(trials, key=lambda t: t[1][4])
        tried.add(key)
        if trial[4] <= best[4]:
            break
        best = trial
    settings, X, sigma, guards, margin = best
    exact.rows = prob.spec.numeric(X, sigma)
    exact.loss = mean_loss(prob.criterion, exact.rows, prob.spec, exact.counts)
    exact.guards, exact.settings = guards, settings
    return [g for g, f in zip(guards, floors) if g.level(exact.counts) < f - 1e-9]


def stand_plan(settings, t_start, space, resolution, fixture):
    """The plan of these ordered settings as a loader reads it (the decimals of the
    resolution's steps; :meth:`hse_opt.data.Plan.from_columns` checks it like a file)."""
    n = settings.rate.size
    cols = {"run": np.arange(1, n + 1), "t_start_s": [repr(float(t)) for t in t_start],
            "duration_s": [repr(float(d)) for d in settings.duration]}
    if resolution is None:
        cols.update(rate_dps=[repr(float(v)) for v in settings.rate / units.DEG_PER_S],
                    azimuth_deg=[repr(float(v)) for v in np.mod(settings.azimuth, 2 * np.pi) / units.DEG])
        tilts = [[repr(float(v) + 0.0) for v in x / units.ARCSEC] for x in (settings.tilt_x, settings.tilt_y)]
    else:
        _, (k_rate, k_az, k_tx, k_ty) = snap(settings, space, resolution)
        cols.update(rate_dps=_text(k_rate, resolution.rate / units.DEG_PER_S),
                    azimuth_deg=_text(k_az, resolution.azimuth / units.DEG))
        tilts = [_text(k, resolution.tilt / units.ARCSEC) for k in (k_tx, k_ty)]
    if fixture:
        cols.update(tilt_x_arcsec=tilts[0], tilt_y_arcsec=tilts[1])
    return Plan.from_columns(cols, "the designed plan", min_rate_dps=space.min_rate / units.DEG_PER_S)
