"""The factors of a campaign: the run settings a residual can depend on, and which of them
a report may plot.

A factor is a run setting - bias rate, stand azimuth, time since power-on (or the run order
when the runs have no ``t_start_s``), alignment length, pitch and roll of the table base,
latitude - or a covariate column. Two rules keep plots and tests from overstating:

Resolution
    A factor counts as varying only when its values spread over more than its resolution
    (:data:`RESOLUTION`, in the factor's edge unit: what the stand, the leveling or the
    clock can tell apart). Below it the factor is *constant*: reports list it with its range
    instead of plotting residuals against noise (a leveled pitch that wanders by 0.15
    arcsec is the leveling's noise, not a setting). Covariates have no resolution unless the
    caller gives one (``resolution={"temp_c": 0.1}``): any spread counts.
Derived columns
    A column derived from the heading error is an outcome of the alignment, not a setting,
    and is never a factor (residuals against it correlate by construction). It is
    recognised by its name: every covariate whose name begins with ``heading`` (the
    contract's outcome columns are ``heading_err_arcsec``, ``heading_std_arcsec``,
    ``heading_deg``; Table 1's ``heading_err_compensated_arcsec`` and the
    ``heading_err_comp_arcsec``/``heading_comp_std_arcsec`` that ``hse-opt compensate``
    adds follow it), and every column the user names (``derived=``; ``--derived COLUMN`` on
    the command line). Name your own derived columns ``heading_...`` or pass them.
    Likewise the figures ``hse-opt align`` writes about a log's own sensors (its noise:
    ``gyro_arw_dph_rthz``, ``accel_vrw_ug_rthz``, ...; :data:`SENSOR_PREFIXES`) are outcomes
    of the log, not settings: every covariate whose name begins with ``gyro_`` or ``accel_``.
"""
from dataclasses import dataclass

import numpy as np

from . import units

__all__ = ["Factor", "Factors", "RESOLUTION", "DERIVED_PREFIX", "SENSOR_PREFIXES", "campaign_factors",
           "is_derived"]

#: resolution of each run setting, in the unit of its label (see the module docstring)
RESOLUTION = {
    "rate": 0.01,          # deg/s: the table rate is set and held to 1e-4 of 20-60 deg/s
    "azimuth": 0.01,       # deg: a stand azimuth reading
    "t_start": 1.0 / 3600,  # h: one second
    "order": 0.5,          # runs
    "duration": 1.0,       # s
    "pitch": 2.0,          # arcsec: the leveling's repeatability between alignments
    "roll": 2.0,           # arcsec
    "latitude": 1e-3,      # deg: about 100 m
}
#: a covariate whose name begins with this is derived from the heading error
DERIVED_PREFIX = "heading"
#: a covariate whose name begins with one of these is a figure of the log's own sensors
SENSOR_PREFIXES = ("gyro_", "accel_")


def is_derived(name, derived=()):
    """Whether column ``name`` is an outcome, not a setting: derived from the heading error or
    a figure of the log's sensors (module docstring)."""
    return name.startswith((DERIVED_PREFIX, *SENSOR_PREFIXES)) or name in set(derived)


@dataclass(frozen=True)
class Factor:
    """One factor: ``key`` (``rate``, ``covariate:temp_c``, ...), ``label`` with its unit,
    its ``values`` in that unit, shape (n,), and its ``resolution`` in that unit."""

    key: str
    label: str
    values: np.ndarray
    resolution: float
    period: float = None

    @property
    def spread(self):
        """Peak-to-peak of the values (the shorter way round for an angle)."""
        if not self.values.size:
            return 0.0
        if self.period is None:
            return float(np.ptp(self.values))
        half = 0.5 * self.period
        return float(min(np.ptp(np.mod(self.values, self.period)),
                         np.ptp(np.mod(self.values + half, self.period))))

    @property
    def varies(self):
        return self.spread > self.resolution

    def describe(self):
        """One line for a constant factor: its value or range and why it is constant."""
        lo, hi = float(np.min(self.values)), float(np.max(self.values))
        if self.spread == 0 or lo == hi:
            return f"{self.label}: {lo:.6g} in every run"
        return (f"{self.label}: {lo:.6g} to {hi:.6g} (spread {self.spread:.3g}, not beyond its "
                f"resolution {self.resolution:.3g})")


@dataclass(frozen=True)
class Factors:
    """A campaign's factors: ``varying`` (plotted and tested), ``constant`` (listed with
    their range) and ``derived`` (covariate names left out as outcomes of the alignment)."""

    varying: tuple
    constant: tuple
    derived: tuple

    def notes(self):
        """Sentences for a report: the constant factors and the derived columns left out."""
        out = []
        if self.constant:
            out.append("Constant over the runs (not plotted): " + "; ".join(f.describe() for f in self.constant)
                       + ".")
        sensors = [c for c in self.derived if c.startswith(SENSOR_PREFIXES)]
        heading = [c for c in self.derived if c not in sensors]
        if heading:
            out.append(f"Derived from the heading error, never a factor: {', '.join(heading)} "
                       f"(a column whose name begins with '{DERIVED_PREFIX}', or named as derived).")
        if sensors:
            out.append(f"Figures of each log's own sensors (hse-opt align: their noise), outcomes of the log, "
                       f"never a factor: {', '.join(sensors)} (a column whose name begins with "
                       f"{' or '.join(repr(p) for p in SENSOR_PREFIXES)}).")
        return out


def campaign_factors(runs, derived=(), resolution=None):
    """The :class:`Factors` of ``runs`` (a :class:`hse_opt.data.Runs`).

    Parameters
    ----------
    runs : hse_opt.data.Runs
    derived : sequence of str
        Covariate columns derived from the heading error (besides those named ``heading...``).
    resolution : mapping key -> float, optional
        Resolutions overriding :data:`RESOLUTION`, in the factor's edge unit (covariates by
        column name).
    """
    res = {**RESOLUTION, **(resolution or {})}
    n = len(runs)
    raw = [("rate", "bias rate [deg/s]", runs.rate / units.DEG_PER_S),
           ("azimuth", "stand azimuth [deg]", np.mod(runs.azimuth / units.DEG, 360.0))]
    if runs.t_start is not None:
        raw.append(("t_start", "time since power-on [h]", runs.t_start / units.HOUR))
    else:
        raw.append(("order", "run order (no t_start_s)", np.arange(1, n + 1, dtype=float)))
    raw.append(("duration", "alignment length [s]", np.asarray(runs.duration, float)))
    if runs.pitch is not None:
        raw.append(("pitch", "pitch of b0 [arcsec]", runs.pitch / units.ARCSEC))
        raw.append(("roll", "roll of b0 [arcsec]", runs.roll / units.ARCSEC))
    raw.append(("latitude", "latitude [deg]", runs.latitude / units.DEG))
    gone = []
    for name, values in runs.covariates.items():
        if is_derived(name, derived):
            gone.append(name)
        else:
            raw.append((f"covariate:{name}", name, np.asarray(values, float)))
    facs = [Factor(k, lab, v, float(res.get(k.split(":", 1)[-1], 0.0)), 360.0 if k == "azimuth" else None)
            for k, lab, v in raw]
    return Factors(tuple(f for f in facs if f.varies), tuple(f for f in facs if not f.varies), tuple(gone))
