"""A raw log's metadata keys and the values each allows (the raw-log quality check 5,
:func:`hse_opt.align.quality.check_metadata`; ``docs/rawlogs.md`` lists the keys), and the
encoder's resolution from them.

The keys the processor and RUNS.csv read must have their types: numbers finite, ``run`` an
integer, ``position`` a label; a wrong type refuses the log, naming the key and what is
allowed. Keys not listed are kept unchecked (the loader checks the pulse weights).
"""
from __future__ import annotations

import math
import numbers

__all__ = ["META_TYPES", "metadata_problems", "encoder_counts"]


def _number(v):
    if type(v) is float:                    # (the usual case, without the abstract class's check)
        return math.isfinite(v)
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(float(v))


#: metadata key -> (test, what is allowed)
META_TYPES = {
    "latitude_deg": (lambda v: _number(v) and abs(float(v)) < 89.0, "a number, |latitude| < 89 deg"),
    "rate_dps": (_number, "a finite number, deg/s"),
    "azimuth_deg": (_number, "a finite number, deg (leave the key out for an unsurveyed position)"),
    "t_start_s": (lambda v: _number(v) and float(v) >= 0.0, "a finite number >= 0, s"),
    "temp_c": (_number, "a finite number, degC"),
    "run": (lambda v: isinstance(v, numbers.Integral) and not isinstance(v, bool), "an integer"),
    "position": (lambda v: isinstance(v, str) and v.strip() != "" or
                 isinstance(v, numbers.Integral) and not isinstance(v, bool), "a text label or an integer"),
    "source": (lambda v: isinstance(v, str), "text"),
    "encoder_counts_per_rev": (lambda v: _number(v) and float(v) >= 1.0,
                               "a number >= 1, the encoder's counts per revolution"),
}


def metadata_problems(meta):
    """One text per metadata key of the wrong type or value: ``'key' = value; allowed: ...``.

    Parameters
    ----------
    meta : dict
        A raw log's metadata.

    Returns
    -------
    list of str
    """
    return [f"'{key}' = {meta[key]!r}; allowed: {allowed}" for key, (ok, allowed) in META_TYPES.items()
            if key in meta and meta[key] is not None and not ok(meta[key])]


def encoder_counts(meta, counts=None):
    """The encoder's counts per revolution: ``counts`` (the calibration file's) when given, else
    the metadata's ``encoder_counts_per_rev`` (a wrong type counts as none: it is a problem of
    :func:`metadata_problems` already).

    Returns
    -------
    counts : float or None
        None: not known.
    problem : str or None
        The two given and differing (by more than 1e-9 relative): the text naming both.
    """
    given = meta.get("encoder_counts_per_rev")
    given = float(given) if given is not None and META_TYPES["encoder_counts_per_rev"][0](given) else None
    if counts is not None and given is not None and abs(given - counts) > 1e-9 * counts:
        return counts, (f"'encoder_counts_per_rev' = {meta['encoder_counts_per_rev']!r} and the calibration's "
                        f"encoder.counts_per_rev = {counts:g} differ; allowed: one encoder resolution")
    return (counts if counts is not None else given), None
