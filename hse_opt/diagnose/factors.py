"""The factors the runs vary (bias rate, sense, azimuth, tilt, time, duration, latitude,
covariates), each with its library of functions, and one F test of the residual per factor."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import units
from .statistics import Test

#: time constants (s) of the warm-up-like functions in the factor library
_TAUS = (600.0, 3600.0)


@dataclass(frozen=True)
class Column:
    """One factor as a column (for plots) and the library of its functions."""

    factor: str
    label: str
    values: np.ndarray
    functions: tuple   # (name, values (n,), unit, text template)


def factor_columns(runs, covariates=None, tilt_known=True):
    """Every factor that varies over the runs, with its library of functions."""
    n = len(runs)
    rate = np.asarray(runs.rate, float)
    rate_dps = rate / units.DEG_PER_S
    psi = np.asarray(runs.azimuth, float)
    dur = np.asarray(runs.duration, float)
    t0 = (np.asarray(runs.t_start, float) if runs.t_start is not None
          else np.concatenate([[0.0], np.cumsum(dur[:-1])]))
    sense = np.sign(rate)
    cols = []
    if np.ptp(rate_dps) > 1e-9:
        fns = [("rate", rate_dps, "deg/s", "residual changes linearly with the signed bias rate "
                "(it reverses with the rotation sense): {c} arcsec per deg/s"),
               ("|rate|", np.abs(rate_dps), "deg/s", "residual grows with |bias rate|, the same for "
                "both senses: {c} arcsec per deg/s"),
               ("rate x |rate|", rate_dps * np.abs(rate_dps), "(deg/s)^2", "residual grows with "
                "rate x |rate| (a scale-factor nonlinearity signature): {c} arcsec per (deg/s)^2")]
        cols.append(Column("bias rate", "bias rate [deg/s]", rate_dps, tuple(fns)))
    if np.any(sense > 0) and np.any(sense < 0):
        cols.append(Column("rotation sense", "rotation sense", sense, (
            ("sense", sense, "1", "residual changes sign with the rotation sense: +-{c} arcsec"),
            ("sense x cos(azimuth)", sense * np.cos(psi), "1", "residual follows sense x cos(azimuth): "
             "amplitude {c} arcsec"),
            ("sense x sin(azimuth)", sense * np.sin(psi), "1", "residual follows sense x sin(azimuth): "
             "amplitude {c} arcsec"))))
    az_deg = np.mod(psi / units.DEG, 360.0)
    n_az = np.unique(np.round(az_deg, 3)).size
    if n_az >= 2:
        fns = []
        for h in range(1, max(1, min(3, n_az // 2)) + 1):  # resolvable harmonics only
            for name, fn in (("cos", np.cos), ("sin", np.sin)):
                fns.append((f"{name}({h} x azimuth)" if h > 1 else f"{name}(azimuth)", fn(h * psi), "1",
                            f"residual follows {name}({h} x azimuth): amplitude {{c}} arcsec"
                            if h > 1 else f"residual follows {name}(azimuth): amplitude {{c}} arcsec"))
        cols.append(Column("azimuth", "stand azimuth [deg]", az_deg, tuple(fns)))
        if np.ptp(rate_dps) > 1e-9:
            cols.append(Column("rate x azimuth", "rate x azimuth", rate_dps, (
                ("rate x cos(azimuth)", rate_dps * np.cos(psi), "deg/s", "residual follows rate x "
                 "cos(azimuth), a heading-sensitive error through a tilt: {c} arcsec per deg/s"),
                ("rate x sin(azimuth)", rate_dps * np.sin(psi), "deg/s", "residual follows rate x "
                 "sin(azimuth), a heading-sensitive error through a tilt: {c} arcsec per deg/s"))))
    if tilt_known and runs.pitch is not None:
        c23 = (np.asarray(runs.pitch) * np.sin(psi) - np.asarray(runs.roll) * np.cos(psi)) / units.MRAD
        if np.ptp(c23) > 1e-6:
            cols.append(Column("tilt (C23)", "C23 [mrad]", c23, (
                ("C23", c23, "mrad", "residual follows the east tilt C23 of the rotation axis: {c} "
                 "arcsec per mrad (an error along the axis, e.g. an axis gyro bias)"),
                ("rate x C23", rate_dps * c23, "deg/s mrad", "residual follows rate x C23: {c} arcsec "
                 "per deg/s per mrad (a heading-sensitive error, lambda2-like)"),
                ("rate x |rate| x C23", rate_dps * np.abs(rate_dps) * c23, "(deg/s)^2 mrad",
                 "residual follows rate x |rate| x C23: {c} arcsec per (deg/s)^2 per mrad "
                 "(a scale-factor nonlinearity through the tilt)"))))
    time_name = "time since power-on" if runs.t_start is not None else "run order (time unknown)"
    if np.ptp(t0) > 0:
        fns = []
        for tau in _TAUS:
            fns.append((f"exp(-t/{tau:g} s)", tau / dur * (np.exp(-t0 / tau) - np.exp(-(t0 + dur) / tau)),
                        "1", f"residual decays with {time_name} (time constant about {tau:g} s): {{c}} "
                        "arcsec at power-on"))
        fns.append(("t", (t0 + dur / 2) / units.HOUR, "h",
                    f"residual drifts linearly with {time_name}: {{c}} arcsec per hour"))
        cols.append(Column(time_name, f"{time_name} [h]", t0 / units.HOUR, tuple(fns)))
    if runs.t_start is not None and n > 2:
        order = np.arange(n, dtype=float)
        cols.append(Column("run order", "run order", order, (
            ("run order", order, "run", "residual drifts with run order: {c} arcsec per run"),
            ("(run order)^2", (order - order.mean()) ** 2, "run^2", "residual bends with run order: "
             "{c} arcsec per run^2"))))
    if np.ptp(dur) > 1e-9:
        cols.append(Column("duration", "alignment length [s]", dur, (
            ("1/sqrt(duration)", 1.0 / np.sqrt(dur), "s^-1/2", "residual follows 1/sqrt(alignment "
             "length): {c} arcsec sqrt(s)"),
            ("duration", dur / units.MINUTE, "min", "residual changes with alignment length: {c} "
             "arcsec per minute"))))
    lat = np.asarray(runs.latitude, float)
    if np.ptp(lat) > 1e-9:
        cols.append(Column("latitude", "latitude [deg]", lat / units.DEG, (
            ("1/cos(latitude)", 1.0 / np.cos(lat), "1", "residual follows 1/cos(latitude) (a "
             "horizontal-rate error read as heading): {c} arcsec"),
            ("tan(latitude)", np.tan(lat), "1", "residual follows tan(latitude): {c} arcsec"))))
    for name in (runs.covariates if covariates is None else covariates):
        v = np.asarray(runs.covariates[name], float)
        if np.ptp(v) > 0:
            c = v - v.mean()
            cols.append(Column(f"covariate {name}", name, v, (
                (name, c, f"{name} unit", f"residual follows {name} linearly: {{c}} arcsec per unit "
                 "(add covariate:" + name + ")"),
                (f"{name}^2", c ** 2 - np.mean(c ** 2), f"({name} unit)^2", f"residual bends with "
                 f"{name}: {{c}} arcsec per unit^2 (a nonlinear dependence on {name})"))))
    return cols


def factor_tests(null, runs, covariates, tilt_known):
    """One F test per factor, and the whole function library (for the sparse regression)."""
    cols = factor_columns(runs, covariates, tilt_known)
    tests, library = [], []
    for col in cols:
        Z = np.column_stack([fv for _, fv, _, _ in col.functions]) / null.sigma[:, None]
        U = null.basis(Z)
        F, dof, p, logp = null.score(U)
        best, best_s = "", -1.0
        for (name, fv, unit, text) in col.functions:
            u = null.basis(fv / null.sigma)
            library.append((col.factor, name, fv, unit, text, u))
            s = float(np.sum((u.T @ null.r) ** 2)) if u.shape[1] else 0.0
            if s > best_s:
                best, best_s = name, s
        desc = "residual against " + ", ".join(name for name, *_ in col.functions)
        if p is None:
            note = ("every function of it is in the model's span" if U.shape[1] == 0
                    else "too few runs for the test")
            if U.shape[1] == 0 and null.positions and np.all(null.within_share(Z) < 1e-6):
                note = ("constant within each position without a heading reference (its unknown "
                        "heading absorbs it)")
            tests.append(Test(col.factor, desc, None, dof, None, None, "", note))
        else:
            tests.append(Test(col.factor, desc, F, dof, p, logp, best))
    for factor, why in _untested_factors(runs, tilt_known, cols):
        tests.append(Test(factor, "", None, (), None, None, "", why))
    return tests, library


def _untested_factors(runs, tilt_known, cols):
    present = {c.factor for c in cols}
    out = []
    if "bias rate" not in present:
        out.append(("bias rate", f"every run is at {runs.rate[0] / units.DEG_PER_S:.4g} deg/s"))
    if "rotation sense" not in present:
        out.append(("rotation sense", "every run turns the same sense"))
    if "azimuth" not in present:
        out.append(("azimuth", "every run is at one azimuth"))
    if "tilt (C23)" not in present:
        out.append(("tilt (C23)", "no pitch_arcsec/roll_arcsec: tilt-coupled terms are free azimuth "
                    "sinusoids in the model" if runs.pitch is None or not tilt_known
                    else "C23 does not vary over the runs"))
    if not any(c.factor.startswith(("time", "run order (")) for c in cols):
        out.append(("time since power-on", "every run starts at the same time since power-on"))
    if "duration" not in present:
        out.append(("duration", f"every run lasts {runs.duration[0]:.4g} s"))
    return out
