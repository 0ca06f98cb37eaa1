"""Physical ranges of the quantities users give (file columns and options), each with its reason.

One table (:data:`RANGES`), in the user's units (the column or option name carries the unit);
the loaders (:mod:`hse_opt.data`) and the commands check every value against it and name the
reason in the message. A value outside is bad input (exit 2), never clamped. The limits are
wide: they catch wrong units and typing errors, not unusual but real systems.

Size limits (:data:`MAX_FILE_BYTES`, :data:`MAX_ROWS`, :data:`MAX_COLUMNS`, :data:`MAX_NESTING`)
bound what a command reads before it allocates anything.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Range", "RANGES", "MAX_FILE_BYTES", "MAX_ROWS", "MAX_COLUMNS", "MAX_NESTING", "MAX_RATE_DPS",
           "MAX_BUDGET_H", "check_option"]


@dataclass(frozen=True)
class Range:
    """``lo <= value <= hi`` in the unit of the name; ``reason`` says why (printed)."""

    lo: float
    hi: float
    reason: str

    def contains(self, x):
        """Elementwise: finite and inside (numpy arrays or floats, in the named unit)."""
        x = np.asarray(x, dtype=float)
        return np.isfinite(x) & (x >= self.lo) & (x <= self.hi)

    def allowed(self, name):
        """``'-89 <= latitude_deg <= 89 (why)'``."""
        return f"{self.lo:g} <= {name} <= {self.hi:g} ({self.reason})"


#: the largest |table rate|, deg/s
MAX_RATE_DPS = 1000.0
#: the largest design budget, hours
MAX_BUDGET_H = 1000.0

#: name (file column or option, with its unit) -> Range
RANGES = {
    "latitude_deg": Range(-89.0, 89.0, "the gyrocompass finds north from the horizontal Earth rate, "
                                       "w_ie cos(latitude), which vanishes at the poles"),
    "rate_dps": Range(-MAX_RATE_DPS, MAX_RATE_DPS, "a single-axis rate table and the gyros' input range "
                                                   "(RLG systems: +-400 to +-1000 deg/s; the paper uses "
                                                   "20-60); more is a unit error"),
    "azimuth_deg": Range(-720.0, 720.0, "a stand azimuth in degrees; larger numbers are no azimuth"),
    "heading_deg": Range(-720.0, 720.0, "a heading in degrees; larger numbers are no heading"),
    "heading_err_arcsec": Range(-648000.0, 648000.0, "a heading error within +-180 deg"),
    "duration_s": Range(0.0, 86400.0, "an alignment of at most a day; the loaders also ask for at least "
                                      "one table revolution, 360/|rate_dps| s"),
    "t_start_s": Range(0.0, 1e7, "time since power-on (at most ~4 months); a larger value looks like a "
                                 "clock time"),
    "pitch_arcsec": Range(-7200.0, 7200.0, "the tilt of the table base is small (the model is first "
                                           "order in it); larger values are a unit error"),
    "roll_arcsec": Range(-7200.0, 7200.0, "the tilt of the table base is small (the model is first order "
                                          "in it); larger values are a unit error"),
    "heading_std_arcsec": Range(0.01, 36000.0, "an alignment's own 1-sigma: no gyrocompass is better than "
                                               "0.01 arcsec (smaller values look like degrees: 7.9 arcsec "
                                               "is 0.0022 deg)"),
    "tilt_x_arcsec": Range(-3600.0, 3600.0, "a tilt fixture's setting within 1 deg (the model is first "
                                            "order in the tilt)"),
    "tilt_y_arcsec": Range(-3600.0, 3600.0, "a tilt fixture's setting within 1 deg (the model is first "
                                            "order in the tilt)"),
    "--budget-h": Range(1e-3, MAX_BUDGET_H, "stand time of a calibration campaign: at most ~6 weeks"),
    "--arw-dph-rthz": Range(1e-4, 10.0, "the gyros' angle random walk in deg/h/sqrt(Hz): an RLG's is "
                                        "0.001-0.1, the default system's 0.012; 0 would give the headings no "
                                        "noise and the design nothing to weigh"),
    "--floor-arcsec": Range(0.0, 3600.0, "run-to-run heading scatter beyond the gyro noise, arcsec"),
    **{f"--{what}-s": Range(0.0, 7 * 86400.0, "a time on the stand in s, at most a week")
       for what in ("warmup", "azimuth-change", "rate-change", "tilt-change", "run-overhead")},
}

#: pitch/roll columns whose every |value| is below this (and the largest at least
#: :data:`SMALL_TILT_FLOOR_ARCSEC`) may be radians or degrees: few stands are level to 0.05
#: arcsec (accelerometer biases of micro-g alone tilt the leveling by arcseconds), but a level
#: base does give such values, so they are a warning (:attr:`hse_opt.data.Runs.warnings`)
SMALL_TILT_ARCSEC = 0.05
SMALL_TILT_FLOOR_ARCSEC = 1e-4

#: the largest input file read, bytes (a RUNS.csv of 100,000 runs is ~20 MB)
MAX_FILE_BYTES = 64 * 2**20
#: the most data rows of a RUNS/PLAN table
MAX_ROWS = 100_000
#: the most columns of a RUNS/PLAN table
MAX_COLUMNS = 1000
#: the deepest nesting of a JSON/TOML input (FIT.json needs 4, TRUTH.toml 3)
MAX_NESTING = 20


def check_option(option, value, key=None):
    """``value`` (a float in the option's unit) against ``RANGES[key or option]``; ValueError
    naming the option and what is allowed."""
    r = RANGES[key or option]
    if not bool(r.contains(value)):
        raise ValueError(f"{option} {value:g} is not allowed; allowed: {r.allowed(key or option.lstrip('-'))}")
    return value
