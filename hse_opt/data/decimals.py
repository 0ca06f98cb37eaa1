"""File values as the exact decimals they are written as: file text <-> SI float64, exactly
(the "Numbers" section of :mod:`hse_opt.data`)."""
from __future__ import annotations

import decimal
import numbers

import numpy as np

_EXACT = decimal.Context(prec=80)  # wide enough that file-value * factor is exact


def _decimal(value):
    """One file value (str or real number) as an exact Decimal; ValueError if it is none."""
    if isinstance(value, str):
        text = value.strip()
        if not text:
            raise ValueError("is empty")
        if not text.isascii() or "_" in text:  # Decimal reads '١٢', '１２' and '1_000' as numbers: no file should
            raise ValueError(f"{value!r} is not a number (ASCII digits only, no '_')")
        try:
            return decimal.Decimal(text)
        except decimal.InvalidOperation:
            raise ValueError(f"{value!r} is not a number") from None
    if isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_)):
        return decimal.Decimal(int(value))
    if isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)):
        return decimal.Decimal(repr(float(value)))
    raise ValueError(f"{value!r} is not a number")


def _to_si(value, factor):
    """File value -> SI float: the exact product with ``factor``, rounded once."""
    try:
        x = float(_EXACT.multiply(_decimal(value), decimal.Decimal(factor)))
    except decimal.InvalidOperation:
        raise ValueError(f"{value!r} is not a number") from None
    except ArithmeticError:  # decimal.Overflow: 1e999999999
        raise ValueError(f"{value!r} is not finite") from None
    if not np.isfinite(x):
        raise ValueError(f"{value!r} is not finite")
    return x


def _to_text(x, factor):
    """SI float -> shortest decimal text in file units that :func:`_to_si` reads back exactly."""
    x = float(x)
    if x == 0:  # keep the sign of zero (Context.plus would turn -0 into 0)
        return "-0" if np.signbit(x) else "0"
    f = decimal.Decimal(factor)
    q = _EXACT.divide(decimal.Decimal(x), f)
    for digits in (15, 16, 17, 18):  # 18 digits always land inside the rounding interval
        r = decimal.Context(prec=digits).plus(q).normalize()
        if float(_EXACT.multiply(r, f)) == x:
            break
    return format(r, "f" if -7 <= r.adjusted() < 17 else "e")


def _to_run_id(value):
    d = _decimal(value)
    if not d.is_finite() or d.adjusted() > 18 or abs(d) >= 2**63 or d != d.to_integral_value():
        raise ValueError(f"{value!r} is not an integer in the int64 range")
    return int(d)


def _missing(value):
    """An empty cell: an empty or blank string, None or a float NaN (not the text 'nan')."""
    if value is None:
        return True
    if isinstance(value, str):
        return not value.strip()
    return isinstance(value, float) and value != value


def _heading_err_text(azimuth_deg, heading_deg):
    """``heading_deg - azimuth_deg`` in arcsec, wrapped to [-180, 180) deg, as exact decimal text
    (the values as the file writes them); a value that is not a number is returned as it is,
    for the common parse to name."""
    try:
        d = _EXACT.subtract(_decimal(heading_deg), _decimal(azimuth_deg))
    except (ValueError, decimal.InvalidOperation):
        return heading_deg
    if not d.is_finite():
        return heading_deg
    d = _EXACT.subtract(d, _EXACT.multiply(360, ((d + 180) / 360).to_integral_value(decimal.ROUND_FLOOR)))
    return str(_EXACT.multiply(d, 3600))


def _first_not_number(values):
    """Index of the first value that is not a finite number (an empty cell counts), or None."""
    for i, v in enumerate(values):
        try:
            if not _decimal(v).is_finite():
                return i
        except ValueError:
            return i
    return None
