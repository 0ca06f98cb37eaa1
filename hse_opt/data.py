"""PLAN and RUNS tables: load, validate and save (the data-format contract).

Both files are CSV with one header row and units in the column names (``docs/formats.md``,
the contract). In memory a table is a frozen dataclass of read-only float64 arrays in SI units
(rad, rad/s, s); the run id is int64. Every extra numeric column is kept as a covariate, in
the file's own unit and under its own name (``temp_c``). An extra column with a cell that is
not a finite number (a date, an operator, a serial number, an empty cell) is text: kept as
metadata (:attr:`Runs.metadata`, strings), passed through to every table written from it
(``hse-opt compensate``, ``hse-opt simulate``) and never an error; :attr:`Runs.notes` names
the first cell that made it text.

``RUNS.csv`` (:class:`Runs`): ``run, rate_dps, azimuth_deg, heading_err_arcsec,
latitude_deg, duration_s`` and optionally ``t_start_s``, ``pitch_arcsec`` with
``roll_arcsec``, ``heading_std_arcsec``, ``azimuth_std_arcsec`` (the stand reference's own
1-sigma; the fit adds it to each run's sigma in quadrature, :mod:`hse_opt.fit.weights`),
``heading_deg`` and ``position`` (field campaigns, below: then ``azimuth_deg`` and
``heading_err_arcsec`` may be empty or absent).

Field campaigns (positions without a heading reference)
-------------------------------------------------------
In the field nobody knows the true heading of the stand: the system aligns at a position
several times (rates, senses, repeats) and the calibration comes from the heading
*differences* between those runs (the paper's on-line calibration). ``RUNS.csv`` then carries:

``position``
    Optional text label (any text: ``A``, ``pier 3``, ``1``). Rows with one label share one
    stand position, i.e. one true heading. Kept as text (:attr:`Runs.position`), never a
    covariate.
``heading_deg``
    The alignment's own heading estimate, deg. It replaces ``heading_err_arcsec`` where no
    reference exists, and it is what the tools use for the heading in C23 at such a
    position (an arcminute is plenty there: see below).
``azimuth_deg``, ``heading_err_arcsec``
    Required only where a reference exists. With ``heading_deg`` present, a row whose
    ``azimuth_deg`` cell is empty (or a file without that column) belongs to an
    *unsurveyed* position; its ``heading_err_arcsec`` cell must be empty too. A surveyed
    row with ``heading_deg`` and an empty ``heading_err_arcsec`` gets ``heading_deg -
    azimuth_deg`` (exact decimals). Mixed campaigns -- some positions surveyed, some not --
    are allowed; a position is surveyed in all its rows or in none.

Without a ``position`` column, all unsurveyed rows are one position (the paper's
single-position procedure; :attr:`Runs.notes` says so), and a heading more than
:data:`MAX_POSITION_SPREAD_DEG` from its position's mean heading is an error (one position
is one stand heading: it catches a forgotten ``position`` column).

In memory (:class:`Runs`) an unsurveyed row has ``surveyed = False``, ``azimuth`` = the
position's mean heading (the system's own headings averaged: one true heading per position)
and ``heading_err`` = its heading minus that mean: the heading error up to one unknown
constant per position. :meth:`Runs.reference_groups` tells which
rows share which constant. What this data can estimate:

* Surveyed rows share the one unknown constant of the stand reading (``offset``), as
  before; each unsurveyed position adds one nuisance constant (its unknown true heading
  plus the offset), which the fit eliminates exactly and never reports.
* Within an unsurveyed position only *contrasts* count: everything that is constant at the
  position (the offset, the stand's azimuth errors, a tilt-coupled term at a single rate) is
  absorbed by its constant. lambda2 (K_HSE) is seen through the heading change with the
  bias rate Omega, so a position must be visited at two or more different rates (or both
  senses) to contribute; a position with one rate only carries no information on it.
  Time-dependent effects (warm-up) are seen through the time between its runs.
* Why the own heading is good enough in C23 = -gamma cos(psi) + theta sin(psi): an error
  d psi in psi changes C23 by at most |tilt| d psi. With a tilt of 1e-3 rad (the paper's
  worked example) and a heading off by 1 arcmin (an alignment is good to arcseconds, a
  position's unknown heading error by the HSE itself to tens of arcseconds), C23 changes
  by 3e-7 rad, a relative 3e-4 of C23 and ~0.01 arcsec of heading error at 40 deg/s.

``PLAN.csv`` (:class:`Plan`): ``run, rate_dps, azimuth_deg, t_start_s, duration_s`` and
optionally ``tilt_x_arcsec`` with ``tilt_y_arcsec``, and ``position`` (a text label).

Checks
------
Every construction checks the structure: equal 1-D lengths, finite values, unique integer
run ids, ``|latitude| <= 90 deg``, ``duration > 0``, ``t_start >= 0``, ``heading_std > 0``
and paired columns given together. Reading a table from columns or a file
(:meth:`Runs.from_columns`, :func:`load_runs`, ...) also checks two things that concern the
file rather than the physics:

* Lock-in. A constant-rate biased RLG system needs the table rate well outside the gyros'
  lock-in zone: each skewed gyro sees only ``|Omega| cos(54.74 deg) = |Omega|/sqrt(3)``, RLG
  lock-in thresholds are of the order of 0.01-0.5 deg/s, and the scale factor is nonlinear
  up to several times the threshold. ``|rate_dps| < min_rate_dps`` is therefore an error;
  the default :data:`DEFAULT_MIN_RATE_DPS` = 5 deg/s leaves each gyro about 2.9 deg/s, at
  least six times a large lock-in threshold (the paper uses 20-60 deg/s). It also catches a
  rate written in rad/s (40 deg/s is 0.70 rad/s). Pass ``min_rate_dps=0`` to turn it off.
* Azimuths in radians. ``azimuth_deg`` is taken to hold radians when it has at least two
  distinct values, all of them within +-2 pi, spread over at least 1 (57 deg if radians, a
  multi-position test; 1 deg if degrees, one stand position with reading jitter) and not
  all whole numbers (0, 90, 180 deg written as radians are not). Degrees inside +-6.28 deg
  with such a spread are a fine azimuth sweep; ``allow_small_azimuths=True`` accepts them.
  Azimuths outside [0, 360) deg are kept as given.

Every failure is a :class:`DataError` (a ``ValueError``) whose message names the file, the
1-based data row with its line in the file, the column, and what is allowed.

Numbers
-------
A file value is read as the decimal number it is written as (a float given to
:meth:`Runs.from_columns` as its shortest repr), multiplied exactly by the unit factor of
:mod:`hse_opt.units` and rounded once to float64. On saving, each SI value is written as
the shortest decimal (at most 18 significant digits) that reads back to exactly the same
float64, so ``load -> save -> load`` and ``save -> load`` are exact and a saved
``91.8795`` stays ``91.8795``. Files are written whole: a temporary file in the target's
directory, flushed and fsynced, then ``os.replace``; on any error the target is untouched.
Input files are only read.
"""
from __future__ import annotations

import contextlib
import csv
import dataclasses
import decimal
import io
import numbers
import os
import re
import secrets
from dataclasses import dataclass, field
from typing import ClassVar, Mapping, NamedTuple

import numpy as np

from .ranges import (MAX_COLUMNS, MAX_FILE_BYTES, MAX_ROWS, RANGES, SMALL_TILT_ARCSEC,
                     SMALL_TILT_FLOOR_ARCSEC)
from .units import ARCSEC, DEG, DEG_PER_S

__all__ = ["DataError", "Runs", "Plan", "load_runs", "load_plan", "save_runs", "save_plan",
           "DEFAULT_MIN_RATE_DPS", "write_text_atomic"]

#: default lock-in limit of the table rate, deg/s (see the module docstring)
DEFAULT_MIN_RATE_DPS = 5.0
#: largest distance of an unsurveyed row's heading from its position's mean heading, deg
MAX_POSITION_SPREAD_DEG = 2.0

_EXACT = decimal.Context(prec=80)  # wide enough that file-value * factor is exact


class DataError(ValueError):
    """Invalid PLAN/RUNS data; the message names file, row (with line), column and what is allowed.

    Attributes ``source``, ``problem``, ``row`` (1-based data row or None), ``line`` (line in
    the file or None) and ``column`` (name or None) carry the parts of the message.
    """

    def __init__(self, source, problem, row=None, line=None, column=None):
        self.source, self.problem, self.row, self.line, self.column = source, problem, row, line, column
        where = [str(source)]
        if row is not None:
            where.append(f"row {row}" + (f" (line {line})" if line is not None else ""))
        elif line is not None:
            where.append(f"line {line}")
        if column is not None:
            where.append(f"column '{column}'")
        super().__init__(", ".join(where) + ": " + problem)

    def __reduce__(self):
        return type(self), (self.source, self.problem, self.row, self.line, self.column)


class _Col(NamedTuple):
    name: str        # column name in the file, with its unit
    attr: str        # SI attribute
    factor: float    # SI value of one file unit; 0 marks the integer run id
    required: bool


def _decimal(value):
    """One file value (str or real number) as an exact Decimal; ValueError if it is none."""
    if isinstance(value, str):
        text = value.strip()
        if not text:
            raise ValueError("is empty")
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


def _wrap(angle):
    """Angle (rad) wrapped to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def _labels(values, src):
    """Position labels from file text or in-memory values (text or integers) -> array of str."""
    out = []
    for i, v in enumerate(values):
        text = str(v).strip() if isinstance(v, (str, numbers.Integral)) and not isinstance(v, bool) else None
        if not text:
            raise DataError(src, f"label {v!r} is not allowed; allowed: a non-empty text label",
                            row=i + 1, column="position")
        out.append(text)
    return np.array(out, dtype=str)


def _looks_like_radians(azimuth_deg):
    u = np.unique(azimuth_deg)
    return bool(u.size >= 2 and np.all(np.abs(u) <= 2 * np.pi + 1e-9) and np.ptp(u) >= 1.0
                and np.any(np.abs(u - np.round(u)) > 1e-9))


def _first_not_number(values):
    """Index of the first value that is not a finite number (an empty cell counts), or None."""
    for i, v in enumerate(values):
        try:
            if not _decimal(v).is_finite():
                return i
        except ValueError:
            return i
    return None


def _sequence(values, source, name):
    if isinstance(values, np.ndarray):
        if values.ndim != 1:
            raise DataError(source, f"has shape {values.shape}; allowed: a 1-D sequence", column=name)
        return values.tolist()
    if isinstance(values, (str, bytes)) or not hasattr(values, "__len__"):
        raise DataError(source, f"is a {type(values).__name__}; allowed: a 1-D sequence of numbers",
                        column=name)
    return list(values)


class _Table:
    """Shared behaviour of :class:`Runs` and :class:`Plan` (schema in ``_COLUMNS``)."""

    _COLUMNS: ClassVar[tuple[_Col, ...]]
    _PAIRS: ClassVar[tuple[tuple[str, str], ...]]
    _RULES: ClassVar[tuple[tuple[str, object, str], ...]]
    _NOTES: ClassVar[dict[str, str]] = {}
    _ROW_FIELDS: ClassVar[tuple[str, ...]] = ()   # row-wise attributes outside _COLUMNS
    _TEXT: ClassVar[tuple[str, ...]] = ()         # contract columns that hold text

    # -- construction and structural checks -----------------------------------------------
    def __post_init__(self):
        set_ = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731
        set_("source", str(self.source))
        src, n, first = self.source, None, self._COLUMNS[0].name
        for col in self._COLUMNS:
            value = getattr(self, col.attr)
            if value is None:
                if col.required:
                    raise DataError(src, "is required; allowed: a 1-D array", column=col.name)
                continue
            arr = self._array(value, col.name, n, first, integer=col.factor == 0)
            n = arr.size if n is None else n
            set_(col.attr, arr)
        for a, b in self._PAIRS:
            if (getattr(self, a) is None) != (getattr(self, b) is None):
                given, missing = (a, b) if getattr(self, b) is None else (b, a)
                raise DataError(src, f"is given without '{self._col(missing).name}'; allowed: both or "
                                     "neither", column=self._col(given).name)
        if not isinstance(self.covariates, Mapping):
            raise TypeError("covariates must be a mapping name -> 1-D array")
        covariates = {}
        for name, value in self.covariates.items():
            self._check_covariate_name(name, src)
            covariates[name] = self._array(value, name, n, first)
        set_("covariates", covariates)
        if not isinstance(self.metadata, Mapping):
            raise TypeError("metadata must be a mapping name -> 1-D sequence of text")
        metadata = {}
        for name, value in self.metadata.items():
            self._check_covariate_name(name, src)
            if name in covariates:
                raise DataError(src, "is both a covariate and a text column; allowed: one of them", column=name)
            text = np.array(["" if v is None else str(v) for v in _sequence(value, src, name)], dtype=str)
            if text.shape != (n,):
                raise DataError(src, f"has shape {text.shape}; allowed: ({n},) like '{first}'", column=name)
            text.setflags(write=False)
            metadata[name] = text
        set_("metadata", metadata)
        if getattr(self, "position", None) is not None:
            pos = np.array(self.position, dtype=object)
            if pos.shape != (n,):
                raise DataError(src, f"has shape {pos.shape}; allowed: ({n},) like '{first}'", column="position")
            for i, v in enumerate(pos.tolist()):
                if not isinstance(v, str) or not v.strip() or v != v.strip():
                    raise DataError(src, f"label {v!r} is not allowed; allowed: a non-empty text label "
                                         "without surrounding spaces", row=i + 1, column="position")
            pos = pos.astype(str)
            pos.setflags(write=False)
            set_("position", pos)
        seen = {}
        for i, r in enumerate(self.run.tolist()):
            if r in seen:
                raise DataError(src, f"run id {r} repeats row {seen[r] + 1}; allowed: unique integer ids",
                                row=i + 1, column="run")
            seen[r] = i
        for attr, ok, allowed in self._RULES:
            x = getattr(self, attr)
            if x is not None and not np.all(good := ok(x)):
                col, i = self._col(attr), int(np.argmin(good))
                raise DataError(src, f"value {_to_text(x[i], col.factor)} is not allowed; allowed: "
                                     f"{allowed}", row=i + 1, column=col.name)

    def _array(self, value, name, n, first, integer=False):
        src = self.source
        arr = np.array(value)  # a copy: the table owns its arrays
        if arr.ndim != 1 or (n is not None and arr.size != n):
            expected = "1-D" if n is None else f"({n},) like '{first}'"
            raise DataError(src, f"has shape {arr.shape}; allowed: {expected}", column=name)
        if arr.dtype.kind not in "iuf":
            raise DataError(src, f"has dtype {arr.dtype}; allowed: numbers", column=name)
        if integer:
            bad = np.zeros(arr.size, bool)
            if arr.dtype.kind == "f":
                bad = ~np.isfinite(arr) | (arr != np.round(arr))
            if bad.any():
                i = int(np.argmax(bad))
                raise DataError(src, f"value {float(arr[i])!r} is not an integer; allowed: integer ids",
                                row=i + 1, column=name)
            arr = arr.astype(np.int64)
        else:
            arr = arr.astype(np.float64, copy=False)
            if not np.all(finite := np.isfinite(arr)):
                i = int(np.argmin(finite))
                raise DataError(src, f"value {float(arr[i])!r} is not finite; allowed: a finite number",
                                row=i + 1, column=name)
        arr.setflags(write=False)
        return arr

    @classmethod
    def _col(cls, attr):
        return next(c for c in cls._COLUMNS if c.attr == attr)

    @classmethod
    def _check_covariate_name(cls, name, src, line=None):
        if not isinstance(name, str) or not name.strip() or name != name.strip():
            raise DataError(src, f"covariate name {name!r} is not allowed; allowed: a non-empty name "
                                 "without surrounding spaces", line=line)
        known = {c.name for c in cls._COLUMNS}
        stems = {f.name: None for f in dataclasses.fields(cls)} | {c.attr: c.name for c in cls._COLUMNS}
        if name in known or name in stems:
            hint = f" (it looks like '{stems[name]}' without its unit)" if stems.get(name) else ""
            raise DataError(src, f"name clashes with a contract column or attribute{hint}; allowed: "
                                 "another name for a covariate", line=line, column=name)

    # -- edge constructor ------------------------------------------------------------------
    @classmethod
    def from_columns(cls, columns, source="<memory>", *, min_rate_dps=DEFAULT_MIN_RATE_DPS,
                     allow_small_azimuths=False):
        """Build and validate a table from columns in file units, exactly like the loader.

        Parameters
        ----------
        columns : Mapping[str, array-like]
            Column name (with its unit, as in the file) -> 1-D values: numbers or numeric text.
            Contract columns are converted to SI; every other column becomes a covariate.
        source : str
            Name used in error messages.
        min_rate_dps : float
            Lock-in limit, deg/s: ``|rate_dps|`` below it is an error (0 turns the check off).
        allow_small_azimuths : bool
            Accept ``azimuth_deg`` values that look like radians (see the module docstring).

        Raises
        ------
        DataError
            With file, row, column and what is allowed.
        """
        return cls._build(columns, str(source), None, min_rate_dps, allow_small_azimuths)

    @classmethod
    def _build(cls, columns, src, lines, min_rate_dps, allow_small_azimuths, header_line=None):
        """from_columns with ``lines[k]``, the file line of data row k + 1, added to row errors."""
        if not (min_rate_dps >= 0):
            raise ValueError(f"min_rate_dps = {min_rate_dps!r}; allowed: >= 0 (deg/s)")
        try:
            return cls._parse(columns, src, min_rate_dps, allow_small_azimuths, header_line)
        except DataError as e:
            if lines is None or e.row is None:
                raise
            raise DataError(e.source, e.problem, e.row, lines[e.row - 1], e.column) from None

    @classmethod
    def _parse(cls, columns, src, min_rate_dps, allow_small_azimuths, header_line):
        if "position" in columns and "position" in cls._TEXT:
            columns = dict(columns)
            labels = _labels(_sequence(columns.pop("position"), src, "position"), src)
            table = cls._parse(columns, src, min_rate_dps, allow_small_azimuths, header_line)
            return dataclasses.replace(table, position=labels)
        names = list(columns)
        for col in cls._COLUMNS:
            if col.required and col.name not in names:
                stem = col.name.rsplit("_", 1)[0] if col.factor else col.name
                like = [n for n in names if isinstance(n, str) and n.startswith(stem)]
                hint = f" (found {', '.join(map(repr, like))}: give it in the unit named)" if like else ""
                need = ", ".join(c.name for c in cls._COLUMNS if c.required)
                raise DataError(src, f"required column is missing{hint}; allowed: a header with {need}",
                                line=header_line, column=col.name)
        values = {name: _sequence(columns[name], src, name) for name in names}
        n = len(values["run"])
        for name, seq in values.items():
            if len(seq) != n:
                raise DataError(src, f"has {len(seq)} values but 'run' has {n}; allowed: equal lengths",
                                column=name)
        if n == 0:
            raise DataError(src, "no data rows; allowed: at least one row below the header", line=header_line)
        by_name = {c.name: c for c in cls._COLUMNS}
        attrs, covariates, metadata = {}, {}, {}
        for name, seq in values.items():
            col = by_name.get(name)
            if col is None:
                cls._check_covariate_name(name, src, header_line)
                if _first_not_number(seq) is not None:  # text: metadata, passed through
                    metadata[name] = ["" if v is None else str(v) for v in seq]
                    continue
                factor = 1.0
                allowed = "a finite number (a column outside the contract is a numeric covariate)"
            else:
                factor, allowed = col.factor, "an integer run id" if col.factor == 0 else "a finite number"
            out = []
            for i, v in enumerate(seq):
                try:
                    out.append(_to_run_id(v) if factor == 0 else _to_si(v, factor))
                except ValueError as e:
                    raise DataError(src, f"value {e}; allowed: {allowed}", row=i + 1, column=name) from None
            if col is None:
                covariates[name] = out
            else:
                attrs[col.attr] = out
        limit = min_rate_dps * DEG_PER_S
        for i, rate in enumerate(attrs["rate"]):
            if abs(rate) < limit:
                raise DataError(src, f"value {values['rate_dps'][i]!r} is inside the lock-in limit; "
                                     f"allowed: |rate_dps| >= {min_rate_dps:g} deg/s (min_rate_dps, or "
                                     "--min-rate-dps, sets the limit; a rate in rad/s also lands here)",
                                row=i + 1, column="rate_dps")
        with np.errstate(over="ignore"):  # 1e308 rad is no azimuth either: the ranges say so below
            azimuth_deg = np.array(attrs["azimuth"]) / DEG
        if not allow_small_azimuths and _looks_like_radians(azimuth_deg):
            raise DataError(src, f"the values of rows 1-{n} look like radians (all within +-2 pi, spread "
                                 "over at least 1, not whole numbers); allowed: degrees, or "
                                 "allow_small_azimuths=True (--allow-small-azimuths) for a fine azimuth "
                                 "sweep in degrees",
                            column="azimuth_deg")
        table = cls(**attrs, covariates=covariates, metadata=metadata, source=src)  # the structure first
        table._check_ranges(values)
        return table

    def _check_ranges(self, values):
        """The physical ranges of :data:`hse_opt.ranges.RANGES` (file units), a duration of at
        least one table revolution, and pitch/roll that do not look like radians or degrees;
        ``values`` are the columns as given (for the message)."""
        src = self.source
        for col in self._COLUMNS:
            r, x = RANGES.get(col.name), getattr(self, col.attr)
            if r is None or x is None:
                continue
            bad = ~((x >= _to_si(r.lo, col.factor)) & (x <= _to_si(r.hi, col.factor)))
            if bad.any():
                i = int(np.argmax(bad))
                raise DataError(src, f"value {values[col.name][i]!r} is out of range; allowed: "
                                     f"{r.allowed(col.name)}", row=i + 1, column=col.name)
        with np.errstate(divide="ignore"):
            turn = 2 * np.pi / np.abs(self.rate)
        if np.any(short := (self.duration < turn) & (self.rate != 0)):  # rate 0: min_rate_dps=0
            i = int(np.argmax(short))
            raise DataError(src, f"value {values['duration_s'][i]!r} is shorter than one table revolution; "
                                 f"allowed: duration_s >= 360/|rate_dps| = {turn[i]:.4g} s (the model averages "
                                 "the heading error over whole revolutions)", row=i + 1, column="duration_s")
        if getattr(self, "pitch", None) is not None:
            tilt = np.abs(np.concatenate([self.pitch, self.roll])) / ARCSEC
            if np.all(tilt < SMALL_TILT_ARCSEC) and tilt.max() >= SMALL_TILT_FLOOR_ARCSEC:
                raise DataError(src, f"all values are below {SMALL_TILT_ARCSEC:g} arcsec: they look like "
                                     "radians or degrees; allowed: arcsec (no stand is level to "
                                     f"{SMALL_TILT_ARCSEC:g} arcsec: 1e-3 rad is 206 arcsec)",
                                column="pitch_arcsec")

    # -- helpers ---------------------------------------------------------------------------
    def __len__(self):
        return int(self.run.size)

    @property
    def notes(self):
        """tuple of str: what the tools should tell the user about missing optional columns and
        columns kept as text."""
        out = tuple(note for attr, note in self._NOTES.items() if getattr(self, attr) is None)
        for name, text in self.metadata.items():
            cells = text.tolist()
            i = _first_not_number(cells)
            out += (f"column '{name}' is text (row {i + 1}: {cells[i]!r} is not a number): kept as "
                    "metadata and passed through to output tables, not a covariate",)
        return out

    def subset(self, index):
        """The rows selected by a boolean mask of shape (n,) or by integer indices, as a new table."""
        idx = np.asarray(index)
        if idx.size == 0:
            idx = idx.astype(np.int64)
        if idx.ndim != 1 or idx.dtype.kind not in "biu" or (idx.dtype.kind == "b" and idx.size != len(self)):
            raise ValueError(f"index of shape {idx.shape} and dtype {idx.dtype}; allowed: a boolean mask "
                             f"of shape ({len(self)},) or 1-D integer indices")
        take = {a: getattr(self, a)[idx] for a in (*(c.attr for c in self._COLUMNS), *self._ROW_FIELDS)
                if getattr(self, a) is not None}
        return dataclasses.replace(self, **take, covariates={k: v[idx] for k, v in self.covariates.items()},
                                   metadata={k: v[idx] for k, v in self.metadata.items()})

    def replace(self, **changes):
        """A new, validated table with some attributes (SI) or covariates (file unit) replaced.

        Keywords that name a dataclass field replace it (``heading_err=...`` in rad); any other
        keyword sets the covariate of that name, or removes it when the value is None.
        """
        fields = {f.name for f in dataclasses.fields(self)}
        covariates = dict(changes.pop("covariates", self.covariates))
        for name in [k for k in changes if k not in fields]:
            value = changes.pop(name)
            if value is None:
                if name not in covariates:
                    raise KeyError(f"no covariate {name!r} to remove; covariates: {sorted(covariates)}")
                del covariates[name]
            else:
                covariates[name] = value
        return dataclasses.replace(self, **changes, covariates=covariates)

    def _text_columns(self):
        cols = {}
        for c in self._COLUMNS:
            x = getattr(self, c.attr)
            if x is not None:
                cols[c.name] = ([str(v) for v in x.tolist()] if c.factor == 0
                                else [_to_text(v, c.factor) for v in x])
        if getattr(self, "position", None) is not None:
            cols["position"] = self.position.tolist()
        for name, x in self.covariates.items():
            cols[name] = [_to_text(v, 1.0) for v in x]
        for name, x in self.metadata.items():
            cols[name] = x.tolist()
        return cols

    def to_columns(self):
        """dict[str, numpy.ndarray]: the table in file units, contract columns first, then covariates.

        Values are the nearest float64 of the decimals :func:`save_runs` / :func:`save_plan`
        write. A float64 in file units cannot always hold an SI float64 exactly, so
        ``from_columns(t.to_columns())`` may differ from ``t`` in the last bit; files round-trip
        exactly.
        """
        return {name: (np.array(col) if name in self._TEXT or name in self.metadata else np.array(
                       [v if v != "" else "nan" for v in col], np.int64 if name == "run" else np.float64))
                for name, col in self._text_columns().items()}


_RUN, _RATE, _AZIMUTH = _Col("run", "run", 0, True), _Col("rate_dps", "rate", DEG_PER_S, True), \
    _Col("azimuth_deg", "azimuth", DEG, True)
_DURATION, _T_START = _Col("duration_s", "duration", 1.0, True), _Col("t_start_s", "t_start", 1.0, True)
_POSITIVE_DURATION = ("duration", lambda x: x > 0, "duration_s > 0")
_NONNEGATIVE_T_START = ("t_start", lambda x: x >= 0, "t_start_s >= 0 (time since power-on)")


@dataclass(frozen=True, eq=False)
class Runs(_Table):
    """Alignment results (``RUNS.csv``), one row per run in execution order; SI inside.

    Attributes
    ----------
    run : numpy.ndarray of int64, shape (n,)
        Unique run ids.
    rate : numpy.ndarray, shape (n,)
        Signed table bias rate Omega, rad/s.
    azimuth : numpy.ndarray, shape (n,)
        Test-stand azimuth (the heading reference, up to one unknown constant), rad.
    heading_err : numpy.ndarray, shape (n,)
        Alignment heading minus stand azimuth (estimated minus true), rad.
    latitude : numpy.ndarray, shape (n,)
        Latitude, rad.
    duration : numpy.ndarray, shape (n,)
        Alignment length, s.
    t_start : numpy.ndarray, shape (n,), or None
        Time since power-on at the start of the alignment, s.
    pitch, roll : numpy.ndarray, shape (n,), or None
        theta and gamma of b0 from the alignment's own leveling, rad (both or neither).
    heading_std : numpy.ndarray, shape (n,), or None
        The alignment's own 1-sigma heading uncertainty, rad.
    heading : numpy.ndarray, shape (n,), or None
        The alignment's own heading estimate, rad (``heading_deg``).
    position : numpy.ndarray of str, shape (n,), or None
        Stand-position labels (``position``); rows with one label share one true heading.
    surveyed : numpy.ndarray of bool, shape (n,), or None
        False for rows without a heading reference (an unsurveyed position: ``azimuth_deg``
        empty or absent, ``heading_deg`` given). In those rows ``azimuth`` is the position's
        mean heading (the system's own) and ``heading_err`` the heading minus it, known
        up to the position's unknown constant (see "Field campaigns" in the module
        docstring). None: every row is surveyed.
    azimuth_std : numpy.ndarray, shape (n,), or None
        The stand reference's own 1-sigma (``azimuth_std_arcsec``), rad.
    covariates : dict[str, numpy.ndarray]
        Other numeric columns, shape (n,), in the file's unit, under the file's name.
    metadata : dict[str, numpy.ndarray of str]
        Text columns (date, operator, serial number), shape (n,), as written: passed through.
    source : str
        The file the table came from, or ``'<memory>'``.

    Arrays are read-only copies. Direct construction checks the structure only; the lock-in
    and radians checks belong to :meth:`from_columns` and :func:`load_runs`.
    """

    run: np.ndarray
    rate: np.ndarray
    azimuth: np.ndarray
    heading_err: np.ndarray
    latitude: np.ndarray
    duration: np.ndarray
    t_start: np.ndarray | None = None
    pitch: np.ndarray | None = None
    roll: np.ndarray | None = None
    heading_std: np.ndarray | None = None
    heading: np.ndarray | None = None
    position: np.ndarray | None = None
    surveyed: np.ndarray | None = None
    azimuth_std: np.ndarray | None = None
    covariates: dict = field(default_factory=dict)
    metadata: dict = field(default_factory=dict)
    source: str = "<memory>"

    _COLUMNS = (_RUN, _RATE, _AZIMUTH, _Col("heading_err_arcsec", "heading_err", ARCSEC, True),
                _Col("latitude_deg", "latitude", DEG, True), _DURATION, _T_START._replace(required=False),
                _Col("pitch_arcsec", "pitch", ARCSEC, False), _Col("roll_arcsec", "roll", ARCSEC, False),
                _Col("heading_std_arcsec", "heading_std", ARCSEC, False),
                _Col("heading_deg", "heading", DEG, False),
                _Col("azimuth_std_arcsec", "azimuth_std", ARCSEC, False))
    _ROW_FIELDS = ("position", "surveyed")
    _TEXT = ("position",)
    _PAIRS = (("pitch", "roll"),)
    _RULES = (("latitude", lambda x: np.abs(x) <= 90 * DEG, "|latitude_deg| <= 90"), _POSITIVE_DURATION,
              _NONNEGATIVE_T_START, ("heading_std", lambda x: x > 0, "heading_std_arcsec > 0"),
              ("azimuth_std", lambda x: x >= 0, "azimuth_std_arcsec >= 0"))
    _NOTES = {
        "t_start": "no t_start_s column: run order stands in for time since power-on",
        "pitch": "no pitch_arcsec/roll_arcsec columns: tilt-coupled terms are fitted as azimuth "
                 "sinusoids with free coefficients",
        "heading_std": "no heading_std_arcsec column: all runs get equal weight",
    }

    # -- field campaigns: positions without a heading reference ----------------------------
    def __post_init__(self):
        super().__post_init__()
        n, src = len(self), self.source
        if self.surveyed is not None:
            sv = np.array(self.surveyed)
            if sv.shape != (n,) or sv.dtype != bool:
                raise TypeError(f"surveyed must be a boolean array of shape ({n},)")
            if sv.all():
                sv = None
            else:
                sv.setflags(write=False)
                if self.heading is None:
                    raise DataError(src, "is required for rows without a heading reference; allowed: the "
                                         "alignment's own heading in every row without azimuth_deg",
                                    column="heading_deg")
            object.__setattr__(self, "surveyed", sv)
        if self.surveyed is not None and self.position is not None:
            for label in np.unique(self.position):
                rows = self.position == label
                if self.surveyed[rows].any() and not self.surveyed[rows].all():
                    first = self.surveyed[np.argmax(rows)]
                    i = int(np.argmax(rows & (self.surveyed != first)))
                    raise DataError(src, f"position {label!r} has rows with and without azimuth_deg; "
                                         "allowed: a position is surveyed (azimuth_deg in every row) or "
                                         "not (azimuth_deg empty in every row)", row=i + 1, column="azimuth_deg")

    def reference_groups(self):
        """Which rows share which unknown heading constant.

        Returns
        -------
        index : numpy.ndarray of int64, shape (n,)
            -1 for rows with a heading reference (``azimuth_deg``; they share the one unknown
            constant of the stand reading), ``k >= 0`` for rows of the k-th position without
            a reference (its true heading is unknown: one nuisance constant each).
        labels : tuple of str
            The label of each unsurveyed position, in order of first appearance (``'field'``
            when there is no ``position`` column: all unsurveyed rows are one position).
        """
        index = np.full(len(self), -1, dtype=np.int64)
        if self.surveyed is None:
            return index, ()
        free = ~self.surveyed
        names = self.position[free] if self.position is not None else np.full(int(free.sum()), "field")
        labels = tuple(dict.fromkeys(names.tolist()))
        index[free] = [labels.index(v) for v in names.tolist()]
        return index, labels

    @property
    def notes(self):
        notes = super().notes
        if self.surveyed is not None and self.position is None:
            notes += (f"no position column: the {int((~self.surveyed).sum())} rows without azimuth_deg "
                      "are taken as one stand position",)
        return notes

    def _text_columns(self):
        cols = super()._text_columns()
        if self.surveyed is not None:
            out = {}
            for name, col in cols.items():
                if name in ("azimuth_deg", "heading_err_arcsec"):
                    if not self.surveyed.any():
                        continue
                    col = [v if ok else "" for v, ok in zip(col, self.surveyed.tolist())]
                out[name] = col
            cols = out
        return cols

    @classmethod
    def _parse(cls, columns, src, min_rate_dps, allow_small_azimuths, header_line):
        """The field-campaign columns (``position``, ``heading_deg``, empty ``azimuth_deg``),
        then the common parse (see the module docstring, "Field campaigns")."""
        columns = dict(columns)
        if "heading_deg" not in columns or "run" not in columns:  # the common parse names the missing column
            return super()._parse(columns, src, min_rate_dps, allow_small_azimuths, header_line)
        n = len(_sequence(columns["run"], src, "run"))
        heading = _sequence(columns["heading_deg"], src, "heading_deg")
        seqs = {}
        for name in ("azimuth_deg", "heading_err_arcsec"):
            seqs[name] = _sequence(columns[name], src, name) if name in columns else [None] * n
            if len(seqs[name]) != n:
                raise DataError(src, f"has {len(seqs[name])} values but 'run' has {n}; allowed: equal "
                                     "lengths", column=name)
        if len(heading) != n:
            raise DataError(src, f"has {len(heading)} values but 'run' has {n}; allowed: equal lengths",
                            column="heading_deg")
        surveyed = np.array([not _missing(v) for v in seqs["azimuth_deg"]], dtype=bool)
        err_missing = np.array([_missing(v) for v in seqs["heading_err_arcsec"]], dtype=bool)
        for i in np.flatnonzero(~surveyed & ~err_missing):
            raise DataError(src, "is given where azimuth_deg is empty; allowed: heading_err_arcsec only "
                                 "with the stand azimuth it refers to", row=int(i) + 1, column="heading_err_arcsec")
        # the common parse on stand-ins: the own heading for a missing azimuth, 0 for a missing error
        columns["azimuth_deg"] = [a if ok else h for a, h, ok in zip(seqs["azimuth_deg"], heading, surveyed)]
        columns["heading_err_arcsec"] = [_heading_err_text(a, h) if ok else 0 if miss else e for a, h, e, ok, miss
                                         in zip(seqs["azimuth_deg"], heading, seqs["heading_err_arcsec"],
                                                surveyed, err_missing)]
        runs = super()._parse(columns, src, min_rate_dps, True, header_line)
        for name, x in (("azimuth_deg", runs.azimuth[surveyed]), ("heading_deg", runs.heading)):
            if not allow_small_azimuths and _looks_like_radians(x / DEG):
                raise DataError(src, "the values look like radians (all within +-2 pi, spread over at least "
                                     "1, not whole numbers); allowed: degrees, or allow_small_azimuths=True "
                                     "(--allow-small-azimuths) for a fine sweep in degrees", column=name)
        heading_err, azimuth = np.array(runs.heading_err), np.array(runs.azimuth)
        labels = runs.position
        groups = labels if labels is not None else np.full(n, "field")
        for label in np.unique(groups[~surveyed]):
            rows = np.flatnonzero((groups == label) & ~surveyed)
            h = runs.heading[rows]
            ref = np.angle(np.mean(np.exp(1j * h)))
            dev = _wrap(h - ref)
            k = int(np.argmax(np.abs(dev)))
            if abs(dev[k]) > MAX_POSITION_SPREAD_DEG * DEG:
                what = f"position {label!r}" if labels is not None else "the rows without azimuth_deg (one position: no position column)"
                raise DataError(src, f"heading {_to_text(runs.heading[rows[k]], DEG)} deg is "
                                     f"{abs(dev[k]) / DEG:.3g} deg from the mean heading of {what}; allowed: "
                                     f"within {MAX_POSITION_SPREAD_DEG:g} deg (one position is one stand heading: "
                                     "a position column separates positions)", row=int(rows[k]) + 1,
                                column="heading_deg")
            heading_err[rows] = dev
            azimuth[rows] = ref
        return dataclasses.replace(runs, azimuth=azimuth, heading_err=heading_err, surveyed=surveyed)


@dataclass(frozen=True, eq=False)
class Plan(_Table):
    """A test plan (``PLAN.csv``), one row per planned alignment in execution order; SI inside.

    Attributes
    ----------
    run : numpy.ndarray of int64, shape (n,)
        Unique run ids.
    rate : numpy.ndarray, shape (n,)
        Signed table bias rate Omega, rad/s.
    azimuth : numpy.ndarray, shape (n,)
        Test-stand azimuth, rad.
    t_start : numpy.ndarray, shape (n,)
        Time since power-on at the start of the alignment, s.
    duration : numpy.ndarray, shape (n,)
        Alignment length, s.
    tilt_x, tilt_y : numpy.ndarray, shape (n,), or None
        Deliberate tilt of the table base about x and y, rad (both or neither).
    position : numpy.ndarray of str, shape (n,), or None
        Stand-position labels (``position``, text): rows with one label are one placement
        of the system (a field campaign, :func:`hse_opt.sim.run_campaign`).
    covariates : dict[str, numpy.ndarray]
        Other numeric columns, shape (n,), in the file's unit, under the file's name.
    metadata : dict[str, numpy.ndarray of str]
        Text columns, shape (n,), as written: passed through to the simulated runs.
    source : str
        The file the plan came from, or ``'<memory>'``.
    """

    run: np.ndarray
    rate: np.ndarray
    azimuth: np.ndarray
    t_start: np.ndarray
    duration: np.ndarray
    tilt_x: np.ndarray | None = None
    tilt_y: np.ndarray | None = None
    position: np.ndarray | None = None
    covariates: dict = field(default_factory=dict)
    metadata: dict = field(default_factory=dict)
    source: str = "<memory>"

    _ROW_FIELDS = ("position",)
    _TEXT = ("position",)
    _COLUMNS = (_RUN, _RATE, _AZIMUTH, _T_START, _DURATION, _Col("tilt_x_arcsec", "tilt_x", ARCSEC, False),
                _Col("tilt_y_arcsec", "tilt_y", ARCSEC, False))
    _PAIRS = (("tilt_x", "tilt_y"),)
    _RULES = (_POSITIVE_DURATION, _NONNEGATIVE_T_START)


# -- files -----------------------------------------------------------------------------------
def _read(cls, path, min_rate_dps, allow_small_azimuths):
    src = os.fspath(path)
    try:
        reader = csv.reader(io.StringIO(read_text(src, "a UTF-8 CSV file"), newline=""))
        rows, lines = [], []
        for fields in reader:
            if any(f.strip() for f in fields):
                rows.append(fields)
                lines.append(reader.line_num)
            if len(rows) > MAX_ROWS + 1:
                raise DataError(src, f"has more than {MAX_ROWS} data rows; allowed: at most {MAX_ROWS}",
                                line=reader.line_num)
    except UnicodeDecodeError as e:
        raise DataError(src, f"is not UTF-8 text ({e.reason} at byte {e.start}); allowed: a UTF-8 CSV "
                             "file") from None
    except csv.Error as e:
        raise DataError(src, f"is not valid CSV ({e}); allowed: comma-separated values") from None
    if not rows:
        need = ", ".join(c.name for c in cls._COLUMNS if c.required)
        raise DataError(src, f"the file is empty; allowed: a header row with {need}, then data rows")
    header = [h.strip() for h in rows[0]]
    if len(header) > MAX_COLUMNS:
        raise DataError(src, f"the header has {len(header)} columns; allowed: at most {MAX_COLUMNS}",
                        line=lines[0])
    if len(header) == 1 and any(sep in header[0] for sep in ";\t"):
        raise DataError(src, "the header has one column; allowed: comma-separated columns", line=lines[0])
    for j, name in enumerate(header):
        if not name:
            raise DataError(src, f"header field {j + 1} is empty; allowed: a column name", line=lines[0])
        if name in header[:j]:
            raise DataError(src, "column name repeats; allowed: each name once", line=lines[0], column=name)
    for k, fields in enumerate(rows[1:]):
        if len(fields) != len(header):
            raise DataError(src, f"has {len(fields)} fields but the header has {len(header)}; allowed: one "
                                 "value per column", row=k + 1, line=lines[k + 1])
    columns = {name: [fields[j] for fields in rows[1:]] for j, name in enumerate(header)}
    return cls._build(columns, src, lines[1:], min_rate_dps, allow_small_azimuths, header_line=lines[0])


def read_text(path, allowed, limit=MAX_FILE_BYTES):
    """The text of a UTF-8 input file (a BOM is dropped), at most ``limit`` bytes; DataError
    beyond (``/dev/zero`` too) or for bytes that are no UTF-8. ``allowed`` names the file kind."""
    src = os.fspath(path)
    with open(src, "rb") as fh:
        data = fh.read(limit + 1)
    if len(data) > limit:
        raise DataError(src, f"is larger than {limit / 2**20:g} MiB; allowed: {allowed} of at most "
                             f"{limit / 2**20:g} MiB")
    return data.decode("utf-8-sig")


def load_runs(path, *, min_rate_dps=DEFAULT_MIN_RATE_DPS, allow_small_azimuths=False) -> Runs:
    """Read and validate a ``RUNS.csv`` file (the file is only read).

    Parameters
    ----------
    path : str or os.PathLike
        The CSV file.
    min_rate_dps : float
        Lock-in limit, deg/s; ``|rate_dps|`` below it is an error (0 turns the check off).
    allow_small_azimuths : bool
        Accept ``azimuth_deg`` values that look like radians.

    Returns
    -------
    Runs

    Raises
    ------
    DataError
        Invalid content; the message names file, row (and line), column and what is allowed.
    OSError
        The file cannot be read.
    """
    return _read(Runs, path, min_rate_dps, allow_small_azimuths)


def load_plan(path, *, min_rate_dps=DEFAULT_MIN_RATE_DPS, allow_small_azimuths=False) -> Plan:
    """Read and validate a ``PLAN.csv`` file; parameters and errors as :func:`load_runs`."""
    return _read(Plan, path, min_rate_dps, allow_small_azimuths)


def _write_atomic(table, cls, path):
    if not isinstance(table, cls):
        raise TypeError(f"expected a {cls.__name__}, got {type(table).__name__}")
    table = dataclasses.replace(table)  # re-run the checks: arrays could have been made writable
    columns = table._text_columns()

    def write(fh):
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(columns)
        writer.writerows(zip(*columns.values()))
    _atomic(path, write)


def write_text_atomic(path, text):
    """Write ``text`` (UTF-8) to ``path`` whole or not at all (temporary file, fsync, rename)."""
    _atomic(path, lambda fh: fh.write(text))


#: marks the temporary files and folders of a write in progress: ``.NAME.hse-opt-tmp-PID-TOKEN``
#: (+ the target's suffix), beside the target; :func:`remove_leftovers` removes those of dead processes
TEMP_TAG = ".hse-opt-tmp-"
_LEFTOVER = re.compile(r"^\..*" + re.escape(TEMP_TAG) + r"(\d+)-[0-9a-f]{12}(\.[^.]*)?$")


def temp_path(target):
    """A fresh temporary path beside ``target`` (same folder, same suffix), recognisable as ours:
    the pid of the writer is in the name, so a file left by a killed process can be told from
    one being written (:func:`remove_leftovers`)."""
    directory, name = os.path.split(os.path.abspath(os.fspath(target)))
    return os.path.join(directory, f".{name}{TEMP_TAG}{os.getpid()}-{secrets.token_hex(6)}"
                                   f"{os.path.splitext(name)[1]}")


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # e.g. another user's process
        return True
    return True


def remove_leftovers(directory):
    """Remove the temporary files and folders (:func:`temp_path`) that processes killed with
    SIGKILL (which no program can catch) left in ``directory``; those of running processes stay.

    Returns
    -------
    list of str
        The paths removed.
    """
    import shutil
    removed = []
    try:
        names = os.listdir(directory)
    except OSError:
        return removed
    for name in names:
        m = _LEFTOVER.match(name)
        if m is None or _alive(int(m.group(1))):
            continue
        path = os.path.join(directory, name)
        with contextlib.suppress(OSError):
            if os.path.isdir(path) and not os.path.islink(path):
                shutil.rmtree(path)
            else:
                os.unlink(path)
            removed.append(path)
    return removed


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path`` (same suffix, :func:`temp_path`) to write; on
    success it is fsynced and renamed over ``path``, on any error (and on KeyboardInterrupt or
    a signal turned into an exception) removed, ``path`` untouched. The file gets the mode of
    the file it replaces, else the usual one (0666 less the umask)."""
    target = os.path.abspath(os.fspath(path))
    directory = os.path.dirname(target)
    if not os.path.isdir(directory):
        raise FileNotFoundError(f"{os.fspath(path)}: cannot write: the folder {directory} does not exist; "
                                "allowed: a path in an existing folder")
    tmp = temp_path(target)
    os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    try:
        with contextlib.suppress(FileNotFoundError):
            os.chmod(tmp, os.stat(target).st_mode & 0o7777)
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    fsync_folder(directory)


def fsync_folder(directory):
    """Make renames in ``directory`` durable where the platform allows it."""
    with contextlib.suppress(OSError):
        dir_fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)


def _atomic(path, write):
    """Call ``write(fh)`` on a text file written through :func:`atomic_path`."""
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        write(fh)


def save_runs(runs: Runs, path) -> None:
    """Write ``runs`` to ``path`` as ``RUNS.csv``, whole or not at all.

    Contract columns come first, in contract order, then the covariates; numbers are the
    shortest decimals that read back exactly. The file is written to a temporary file in the
    same directory, fsynced and renamed over ``path``; on any error ``path`` is untouched.
    """
    _write_atomic(runs, Runs, path)


def save_plan(plan: Plan, path) -> None:
    """Write ``plan`` to ``path`` as ``PLAN.csv``, whole or not at all (as :func:`save_runs`)."""
    _write_atomic(plan, Plan, path)
