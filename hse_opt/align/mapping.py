"""Mapping files: a test stand's own CSV read as a raw log, without conversion scripts.

A mapping file (TOML) says where a stand's CSV keeps each channel and in which units, time
base, pulse weights, counts per revolution, signs and axis order; :func:`read_mapped` turns
such a file into a :class:`~hse_opt.align.rawlog.RawLog` (the same checks as a native log),
and ``hse-opt align LOGS --mapping MAP.toml`` aligns them. Two documented examples ship
with the package (``hse_opt/datasets/mappings/``, :func:`example_mapping`); docs/rawlogs.md
walks through them and gives the frames and axes of every channel.

Keys (every number's unit is in its key or in the section's ``unit``)
---------------------------------------------------------------------
``[file]`` (optional)
    ``delimiter`` -- one character (default ``","``) or ``"whitespace"``;
    ``decimal`` -- ``"."`` (default) or ``","`` (then the delimiter is not ``","``);
    ``header_line`` -- the line holding the column names, 1 = the first (default 1); the
    lines above it (a stand's preamble) are skipped;
    ``comment`` -- lines starting with it are skipped (default none).
``[time]``
    ``column``; ``unit`` -- ``s``, ``ms``, ``us``, ``ns`` or ``counts``; ``counts_per_s`` --
    the tick rate, with ``counts``; ``wrap_counts`` (optional) -- a counter that rolls over
    at this value (e.g. 4294967296 for 32 bits) is unrolled.
``[gyro]``, ``[accel]``
    ``columns`` -- three column names, in the order of the raw log's axes x, y, z (gyro
    axes g; accelerometer axes along s: docs/rawlogs.md); ``signs`` (optional) -- three of
    +1 / -1, multiplying each column (a stand axis pointing the other way);
    ``unit`` -- increments over each sample interval: ``rad``, ``mrad``, ``deg``,
    ``arcsec`` (gyro), ``m/s``, ``mm/s`` (accel), or ``pulses`` with the weights
    ``pulse_arcsec`` (gyro) / ``pulse_mps`` (accel), one number or three; or rates held over
    the interval (multiplied by its length): ``rad/s``, ``deg/s``, ``deg/h`` (gyro),
    ``m/s^2``, ``g`` (accel, standard gravity 9.80665 m/s^2);
    ``cumulative`` (optional, default false) -- the columns are running totals (counters):
    the increments are their differences (the first row's is zero: the processor does not
    use it); ``wrap_counts`` (optional) -- such a counter rolls over at this value.
``[encoder]``
    ``column``; ``unit`` -- ``rad``, ``deg``, ``arcsec`` or ``counts``;
    ``counts_per_rev`` -- with ``counts`` (also the encoder's quantum in the quality checks:
    each log read gets it as its metadata ``encoder_counts_per_rev``); ``sign`` (optional, +1 / -1) -- +1 when the
    reading grows as the table turns positively about z_b (down: clockwise seen from above);
    ``zero_deg`` (optional) -- the reading at the zero-position indicator, deg.
``[temperature]`` (optional)
    ``column``; ``unit`` -- ``degC`` or ``K``. The quality checks note a drift
    (:mod:`hse_opt.align.quality`); RUNS.csv's ``temp_c`` is its mean unless the metadata
    give one.
``[meta]`` (optional)
    Metadata for every log read with the mapping (``latitude_deg``, ``source``, ...); a
    log's own ``<file>.json`` sidecar wins key by key.

A bad mapping file is a ValueError naming the file, the key and what is allowed; a CSV that
does not fit it names the CSV, the line and the column.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from importlib import resources

import numpy as np

from hse_opt import units

__all__ = ["Mapping", "MappedLog", "load_mapping", "read_mapped", "example_mapping", "EXAMPLES"]

#: the example mappings shipped in hse_opt/datasets/mappings/ (docs/rawlogs.md)
EXAMPLES = ("counter_stand", "rate_stand")

_TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
#: unit -> (SI factor, is a rate held over the interval)
_GYRO_UNITS = {"rad": (1.0, False), "mrad": (units.MRAD, False), "deg": (units.DEG, False),
               "arcsec": (units.ARCSEC, False), "pulses": (None, False), "rad/s": (1.0, True),
               "deg/s": (units.DEG_PER_S, True), "deg/h": (units.DEG_PER_H, True)}
_ACCEL_UNITS = {"m/s": (1.0, False), "mm/s": (1e-3, False), "pulses": (None, False), "m/s^2": (1.0, True),
                "g": (units.STANDARD_GRAVITY, True)}
_ENCODER_UNITS = {"rad": 1.0, "deg": units.DEG, "arcsec": units.ARCSEC, "counts": None}
_KEYS = {
    "file": {"delimiter", "decimal", "header_line", "comment"},
    "time": {"column", "unit", "counts_per_s", "wrap_counts"},
    "gyro": {"columns", "signs", "unit", "pulse_arcsec", "cumulative", "wrap_counts"},
    "accel": {"columns", "signs", "unit", "pulse_mps", "cumulative", "wrap_counts"},
    "encoder": {"column", "unit", "counts_per_rev", "sign", "zero_deg"},
    "temperature": {"column", "unit"},
    "meta": None,
}
_REQUIRED = {"time": ("column", "unit"), "gyro": ("columns", "unit"), "accel": ("columns", "unit"),
             "encoder": ("column", "unit"), "temperature": ("column", "unit")}


@dataclass(frozen=True)
class Triad:
    """Three columns of a gyro or accelerometer triad: names, signs, SI factor per column (the
    pulse weight for ``pulses``), rate or increment, counters."""

    columns: tuple
    signs: tuple
    factors: tuple
    rate: bool
    cumulative: bool
    wrap: float


@dataclass(frozen=True)
class Mapping:
    """A parsed mapping file (see the module docstring); build with :func:`load_mapping`.

    Attributes
    ----------
    source : str
        The file.
    delimiter : str or None
        None: whitespace.
    decimal : str
    header_line : int
        1-based.
    comment : str or None
    time_column : str
    time_factor : float
        s per unit (``1 / counts_per_s`` for counts).
    time_wrap : float
        Counts (0: none).
    gyro, accel : Triad
    encoder_column : str
    encoder_factor : float
        rad per unit.
    encoder_sign : float
    encoder_zero : float
        rad.
    temperature_column : str or None
    temperature_offset : float
        Added to the column to give degC (-273.15 for K).
    meta : dict
    encoder_counts_per_rev : float or None
        ``encoder.counts_per_rev`` (with ``unit = "counts"``, else None): the encoder's
        resolution, which the quality checks take as its quantum (each log read gets it as its
        metadata ``encoder_counts_per_rev``).
    """

    source: str
    delimiter: str | None
    decimal: str
    header_line: int
    comment: str | None
    time_column: str
    time_factor: float
    time_wrap: float
    gyro: Triad
    accel: Triad
    encoder_column: str
    encoder_factor: float
    encoder_sign: float
    encoder_zero: float
    temperature_column: str | None
    temperature_offset: float
    meta: tuple = ()
    encoder_counts_per_rev: float | None = None

    @property
    def columns(self):
        """Every column the mapping reads, in the order of :func:`read_mapped`'s array."""
        return ((self.time_column,) + self.gyro.columns + self.accel.columns + (self.encoder_column,)
                + ((self.temperature_column,) if self.temperature_column else ()))


@dataclass(frozen=True, eq=False)
class MappedLog:
    """A stand's CSV read through a mapping.

    Attributes
    ----------
    log : RawLog
    temperature : numpy.ndarray, shape (n,), or None
        The temperature column, degC.
    """

    log: object
    temperature: np.ndarray | None = None


# -- the mapping file ----------------------------------------------------------------------------
class _Keys:
    """Typed access to one section, each error naming the file and the key."""

    def __init__(self, source, name, d):
        self.source, self.name, self.d = source, name, d

    def fail(self, key, got, allowed):
        raise ValueError(f"{self.source}: key '{self.name}.{key}' = {got!r}; allowed: {allowed}")

    def get(self, key, default=None):
        return self.d.get(key, default)

    def text(self, key, default=None, choices=None):
        v = self.d.get(key, default)
        if not isinstance(v, str) or not v.strip() or (choices is not None and v not in choices):
            self.fail(key, v, ", ".join(choices) if choices else "a text")
        return v

    def number(self, key, default=None, *, positive=True):
        v = self.d.get(key, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or \
                (positive and v <= 0):
            self.fail(key, v, "a positive number" if positive else "a finite number")
        return float(v)

    def flag(self, key, default):
        v = self.d.get(key, default)
        if not isinstance(v, bool):
            self.fail(key, v, "true or false")
        return v

    def three(self, key, test, allowed, default=None):
        v = self.d.get(key, default)
        if isinstance(v, list) and len(v) == 3 and all(test(x) for x in v):
            return tuple(v)
        self.fail(key, v, allowed)


def _sign(x):
    return not isinstance(x, bool) and x in (1, -1)


def _positive(x):
    return not isinstance(x, bool) and isinstance(x, (int, float)) and math.isfinite(x) and x > 0


def _triad(sec, unit_table, pulse_key, pulse_unit):
    cols = sec.three("columns", lambda c: isinstance(c, str) and c.strip() != "", "three column names (x, y, z)")
    signs = sec.three("signs", _sign, "three of +1 or -1", default=[1, 1, 1])
    unit = sec.text("unit", choices=list(unit_table))
    factor, rate = unit_table[unit]
    if unit == "pulses":
        w = sec.get(pulse_key)
        if _positive(w):
            w = [w] * 3
        if not (isinstance(w, list) and len(w) == 3 and all(_positive(x) for x in w)):
            sec.fail(pulse_key, w, "one positive number or three (the pulse weights)")
        factors = tuple(float(x) * pulse_unit for x in w)
    else:
        if pulse_key in sec.d:
            sec.fail(pulse_key, sec.d[pulse_key], f"only with unit = \"pulses\" (the unit is \"{unit}\")")
        factors = (factor,) * 3
    cumulative = sec.flag("cumulative", False)
    wrap = sec.number("wrap_counts", 0.0, positive=False) if "wrap_counts" in sec.d else 0.0
    if wrap < 0 or (wrap and not cumulative):
        sec.fail("wrap_counts", sec.d["wrap_counts"], "a positive number, with cumulative = true")
    if rate and cumulative:
        sec.fail("cumulative", True, f"false for a rate unit (\"{unit}\")")
    return Triad(cols, tuple(float(s) for s in signs), factors, rate, cumulative, wrap)


def mapping_from_dict(d, source="<mapping>"):
    """A :class:`Mapping` from the tables of a mapping file; ValueError naming ``source``, the
    key and what is allowed."""
    if not isinstance(d, dict):
        raise ValueError(f"{source}: a mapping is a TOML table; allowed: the sections {sorted(_KEYS)}")
    for name, v in d.items():
        if name not in _KEYS:
            raise ValueError(f"{source}: section '{name}' is not known; allowed: {', '.join(_KEYS)}")
        if not isinstance(v, dict):
            raise ValueError(f"{source}: '{name}' = {v!r}; allowed: a table [{name}]")
        known = _KEYS[name]
        for key in v if known is not None else ():
            if key not in known:
                raise ValueError(f"{source}: key '{name}.{key}' is not known; allowed: {', '.join(sorted(known))}")
    for name, keys in _REQUIRED.items():
        if name == "temperature" and name not in d:
            continue
        for key in keys:
            if key not in d.get(name, {}):
                raise ValueError(f"{source}: key '{name}.{key}' is missing; allowed: see docs/rawlogs.md "
                                 "(every channel's column and unit)")
    sec = {name: _Keys(source, name, d.get(name, {})) for name in _KEYS}
    f = sec["file"]
    delim = f.text("delimiter", ",")
    if delim != "whitespace" and len(delim) != 1:
        f.fail("delimiter", delim, "one character or \"whitespace\"")
    decimal = f.text("decimal", ".", choices=[".", ","])
    if decimal == "," and delim == ",":
        f.fail("decimal", decimal, "\".\" when the delimiter is \",\"")
    header_line = f.get("header_line", 1)
    if isinstance(header_line, bool) or not isinstance(header_line, int) or header_line < 1:
        f.fail("header_line", header_line, "an integer >= 1")
    comment = f.text("comment") if "comment" in f.d else None

    t = sec["time"]
    tunit = t.text("unit", choices=[*_TIME_UNITS, "counts"])
    if tunit == "counts":
        tfactor = 1.0 / t.number("counts_per_s")
    else:
        if "counts_per_s" in t.d:
            t.fail("counts_per_s", t.d["counts_per_s"], "only with unit = \"counts\"")
        tfactor = _TIME_UNITS[tunit]
    twrap = t.number("wrap_counts") if "wrap_counts" in t.d else 0.0

    e = sec["encoder"]
    eunit = e.text("unit", choices=list(_ENCODER_UNITS))
    counts = None
    if eunit == "counts":
        counts = e.number("counts_per_rev")
        efactor = 2 * math.pi / counts
    else:
        if "counts_per_rev" in e.d:
            e.fail("counts_per_rev", e.d["counts_per_rev"], "only with unit = \"counts\"")
        efactor = _ENCODER_UNITS[eunit]
    esign = e.get("sign", 1)
    if not _sign(esign):
        e.fail("sign", esign, "+1 or -1")
    ezero = e.number("zero_deg", 0.0, positive=False) * units.DEG

    temp_col, temp_off = None, 0.0
    if "temperature" in d:
        tt = sec["temperature"]
        temp_col = tt.text("column")
        temp_off = {"degC": 0.0, "K": -273.15}[tt.text("unit", choices=["degC", "K"])]
    meta = d.get("meta", {})
    try:
        json.dumps(meta)
    except (TypeError, ValueError):
        raise ValueError(f"{source}: [meta] holds values JSON cannot carry (dates?); allowed: numbers, text, "
                         "true/false and arrays of them") from None
    m = Mapping(source=source, delimiter=None if delim == "whitespace" else delim, decimal=decimal,
                header_line=header_line, comment=comment, time_column=t.text("column"), time_factor=tfactor,
                time_wrap=twrap, gyro=_triad(sec["gyro"], _GYRO_UNITS, "pulse_arcsec", units.ARCSEC),
                accel=_triad(sec["accel"], _ACCEL_UNITS, "pulse_mps", 1.0), encoder_column=e.text("column"),
                encoder_factor=efactor, encoder_sign=float(esign), encoder_zero=ezero,
                temperature_column=temp_col, temperature_offset=temp_off, meta=tuple(sorted(meta.items())),
                encoder_counts_per_rev=counts)
    seen = {}
    for key, col in zip(("time.column", "gyro.columns", "gyro.columns", "gyro.columns", "accel.columns",
                         "accel.columns", "accel.columns", "encoder.column", "temperature.column"), m.columns):
        if col in seen:
            raise ValueError(f"{source}: key '{key}' names column {col!r} again (also in '{seen[col]}'); allowed: "
                             "each channel its own column")
        seen[col] = key
    return m


def load_mapping(path):
    """Read a mapping file (TOML, the module docstring's keys).

    Raises
    ------
    ValueError
        Not TOML, or a key missing, unknown or of the wrong type or value (the file and the
        key named, with what is allowed).
    """
    from hse_opt.data import read_toml
    src = os.fspath(path)
    try:
        d = read_toml(src, "a mapping file (TOML: docs/rawlogs.md)")
    except OSError as err:
        raise ValueError(f"{src}: cannot read the mapping: {err.strerror or err}; allowed: a mapping file "
                         "(TOML) you can read") from None
    return mapping_from_dict(d, source=src)


def example_mapping(name):
    """Path of an example mapping shipped with the package (``name`` in :data:`EXAMPLES`)."""
    if name not in EXAMPLES:
        raise ValueError(f"example mapping {name!r} is not known; allowed: {', '.join(EXAMPLES)}")
    return str(resources.files("hse_opt.datasets").joinpath("mappings", f"{name}.toml"))


# -- reading a stand's CSV -----------------------------------------------------------------------
def _rows(path, m):
    """(header, data lines, line number of the first data line) of a stand CSV."""
    from hse_opt.data import read_text
    lines = read_text(path, "a stand's CSV log (text)", limit=2**31).splitlines()
    if len(lines) < m.header_line:
        raise ValueError(f"has {len(lines)} lines; the mapping's header_line is {m.header_line} "
                         f"({m.source}); allowed: a header on that line")
    header = [h.strip().strip('"').strip() for h in
              (lines[m.header_line - 1].split(m.delimiter) if m.delimiter else lines[m.header_line - 1].split())]
    body = lines[m.header_line:]
    return header, body


def _parse(body, first_line, header, idx, m):
    """The mapped columns of the data lines as floats (n, k); errors name line and column."""
    keep = [(k, ln) for k, ln in enumerate(body)
            if ln.strip() and not (m.comment and ln.lstrip().startswith(m.comment))]
    text = [ln for _, ln in keep]
    if m.decimal == ",":
        text = [ln.replace(",", ".") for ln in text]
    try:
        data = np.loadtxt(text, delimiter=m.delimiter, usecols=idx, ndmin=2, dtype=float, quotechar='"')
    except ValueError:
        for (k, ln), row in zip(keep, text):
            fields = row.split(m.delimiter) if m.delimiter else row.split()
            if len(fields) <= max(idx):
                end = " (the file is truncated)" if k == len(body) - 1 else ""
                raise ValueError(f"line {first_line + k} has {len(fields)} fields, the header {len(header)}{end}; "
                                 "allowed: one value per column") from None
            for j in idx:
                try:
                    float(fields[j].strip().strip('"'))
                except ValueError:
                    raise ValueError(f"line {first_line + k}, column {header[j]}: {fields[j].strip()!r} is not a "
                                     f"number (decimal '{m.decimal}'); allowed: numbers in the mapped "
                                     "columns") from None
        raise
    if data.shape[0] < 3:
        raise ValueError(f"has {data.shape[0]} data lines; allowed: at least 3 samples")
    return np.asfortranarray(data)          # each column contiguous (the compiled passes read channels)


def _unroll(x, wrap):
    """A counter that rolls over at ``wrap``, made monotone (a step below -wrap / 2 adds wrap)."""
    if not wrap:
        return x
    step = np.diff(x)
    fix = np.where(step < -wrap / 2, wrap, np.where(step > wrap / 2, -wrap, 0.0))
    return x + np.concatenate(([0.0], np.cumsum(fix)))


def _increments(raw, triad, dt):
    """A triad's columns (n, 3) -> increments over each sample interval (n, 3), SI."""
    x = raw * (np.asarray(triad.signs) * np.asarray(triad.factors))
    if triad.cumulative:
        x = np.vstack([_unroll(x[:, j], triad.wrap * abs(triad.factors[j])) for j in range(3)]).T
        return np.asfortranarray(np.vstack([np.zeros((1, 3)), np.diff(x, axis=0)]))
    if triad.rate:
        return x * dt[:, None]
    return x


def read_mapped(path, mapping, meta=None):
    """Read a stand's CSV through a mapping.

    Parameters
    ----------
    path : str or os.PathLike
        The CSV; its ``<path>.json`` sidecar, if any, holds the log's metadata.
    mapping : Mapping or str
        The mapping (or its file).
    meta : dict, optional
        Overrides the metadata (mapping ``[meta]`` < sidecar < ``meta``).

    Returns
    -------
    MappedLog
        ``log`` passed :func:`~hse_opt.align.rawlog.validate_rawlog` and
        :func:`~hse_opt.align.rawlog.check_rawlog`.

    Raises
    ------
    ValueError
        The file named: a mapped column missing from the header, a malformed line, the raw
        log's own checks.
    """
    from hse_opt.align.rawlog import RawLog, check_rawlog

    m = mapping if isinstance(mapping, Mapping) else load_mapping(mapping)
    path = os.fspath(path)
    try:
        header, body = _rows(path, m)
        idx = []
        for col in m.columns:
            if col not in header:
                raise ValueError(f"has no column {col!r} (mapping {m.source}); its header: {header}; allowed: "
                                 "the columns the mapping names")
            idx.append(header.index(col))
        data = _parse(body, m.header_line + 1, header, idx, m)
        t = _unroll(data[:, 0], m.time_wrap) * m.time_factor
        dt = np.diff(t)
        dt = np.concatenate((dt[:1], dt))
        gyro = _increments(data[:, 1:4], m.gyro, dt)
        accel = _increments(data[:, 4:7], m.accel, dt)
        encoder = m.encoder_sign * (data[:, 7] * m.encoder_factor - m.encoder_zero)
        temperature = data[:, 8] + m.temperature_offset if m.temperature_column else None
        file_meta = dict(m.meta)
        side = path + ".json"
        if os.path.isfile(side):
            with open(side, encoding="utf-8") as fh:
                try:
                    extra = json.load(fh)
                except json.JSONDecodeError as exc:
                    raise ValueError(f"{side}: not valid JSON ({exc}); allowed: a JSON object") from None
            if not isinstance(extra, dict):
                raise ValueError(f"{side}: holds a JSON {type(extra).__name__}; allowed: a JSON object of metadata")
            file_meta.update(extra)
        file_meta.update(meta or {})
        if m.encoder_counts_per_rev is not None:     # the checks' encoder quantum (quality.assess)
            given = file_meta.setdefault("encoder_counts_per_rev", m.encoder_counts_per_rev)
            if given != m.encoder_counts_per_rev:
                raise ValueError(f"metadata encoder_counts_per_rev = {given!r} and the mapping's encoder."
                                 f"counts_per_rev = {m.encoder_counts_per_rev:g} ({m.source}) differ; allowed: one "
                                 "resolution, or leave the key out of the metadata")
        if temperature is not None and "temp_c" not in file_meta and np.isfinite(temperature).all():
            file_meta["temp_c"] = float(np.mean(temperature))
        log = RawLog(t, gyro, accel, encoder, file_meta)
        check_rawlog(log)
        return MappedLog(log, temperature)
    except ValueError as exc:
        text = str(exc)
        raise ValueError(text if text.startswith(path) else f"{path}: {text}") from None
