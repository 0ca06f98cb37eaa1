"""Unit factors: the only home of non-SI constants in hse_opt.

Inside the library every angle is in rad, every rate in rad/s and every time in s.
Values in other units exist only at the edges (files, command line, reports) and are
converted with the factors below: ``rate = rate_dps * DEG_PER_S`` and
``rate_dps = rate / DEG_PER_S``.
"""
import math

#: one degree of arc, in rad
DEG = math.pi / 180.0
#: one minute of arc, in rad
ARCMIN = DEG / 60.0
#: one second of arc, in rad
ARCSEC = DEG / 3600.0
#: one milliradian, in rad
MRAD = 1e-3
#: one degree per second, in rad/s
DEG_PER_S = DEG
#: one degree per hour, in rad/s
DEG_PER_H = DEG / 3600.0
#: one microsecond, in s
MICROSECOND = 1e-6
#: one millisecond, in s
MILLISECOND = 1e-3
#: one minute, in s
MINUTE = 60.0
#: one hour, in s
HOUR = 3600.0
#: one part per million (dimensionless)
PPM = 1e-6

#: unit name -> factor to SI, for parameter records and reports
FACTORS = {
    "rad": 1.0,
    "deg": DEG,
    "arcmin": ARCMIN,
    "arcsec": ARCSEC,
    "mrad": MRAD,
    "rad/s": 1.0,
    "deg/s": DEG_PER_S,
    "deg/h": DEG_PER_H,
    "s": 1.0,
    "us": MICROSECOND,
    "ms": MILLISECOND,
    "min": MINUTE,
    "h": HOUR,
    "ppm": PPM,
    "ppm/(deg/s)": PPM / DEG_PER_S,
    "1": 1.0,
}


def to_si(value, unit):
    """Convert ``value`` given in ``unit`` (a key of :data:`FACTORS`) to SI."""
    return value * factor(unit)


def from_si(value, unit):
    """Convert an SI ``value`` to ``unit`` (a key of :data:`FACTORS`)."""
    return value / factor(unit)


def factor(unit):
    """The SI factor of ``unit``; ``arcsec/<u>`` and ``<u>*mrad`` forms are understood."""
    if unit in FACTORS:
        return FACTORS[unit]
    if "/" in unit:
        num, den = unit.split("/", 1)
        if num in FACTORS and den in FACTORS:
            return FACTORS[num] / FACTORS[den]
    if "*" in unit:
        a, b = unit.split("*", 1)
        if a in FACTORS and b in FACTORS:
            return FACTORS[a] * FACTORS[b]
    raise ValueError(f"unit {unit!r} is not known; allowed: {sorted(FACTORS)}, 'a/b' or 'a*b' of those")


# -- additions for the simulator (accelerometer units) ----------------------------------------
#: standard gravity g0 (unit of the "g"-based accelerometer specs, not the local gravity), m/s^2
STANDARD_GRAVITY = 9.80665
#: one micro-g, in m/s^2
MICRO_G = 1e-6 * STANDARD_GRAVITY
FACTORS.setdefault("ug", MICRO_G)
