"""What :class:`~hse_opt.data.Runs` and :class:`~hse_opt.data.Plan` share: the column schema,
the structural checks, the parse from columns in file units, the ranges and the text columns."""
from __future__ import annotations

import dataclasses
import numbers
from typing import ClassVar, Mapping, NamedTuple

import numpy as np

from ..ranges import RANGES, SMALL_TILT_ARCSEC, SMALL_TILT_FLOOR_ARCSEC
from ..units import ARCSEC, DEG, DEG_PER_S
from .decimals import _first_not_number, _to_run_id, _to_si, _to_text
from .errors import DataError

#: default lock-in limit of the table rate, deg/s (see the module docstring)
DEFAULT_MIN_RATE_DPS = 5.0



#: text columns hse-opt itself writes (``hse-opt align``'s ``quality``: what the log-quality
#: checks repaired or noted; ``noise_source``: where the filter's noise figures came from):
#: kept as metadata like any text column, without the note a user's own text column gets
OWN_TEXT_COLUMNS = ("quality", "noise_source")

class _Col(NamedTuple):
    name: str        # column name in the file, with its unit
    attr: str        # SI attribute
    factor: float    # SI value of one file unit; 0 marks the integer run id
    required: bool



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
        """The physical ranges of :data:`hse_opt.ranges.RANGES` (file units) and a duration of at
        least one table revolution; ``values`` are the columns as given (for the message).
        Pitch/roll that look like radians or degrees are a warning (:attr:`warnings`): a level
        base gives the same numbers."""
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

    # -- helpers ---------------------------------------------------------------------------
    def __len__(self):
        return int(self.run.size)

    @property
    def notes(self):
        """tuple of str: what the tools should tell the user about missing optional columns and
        columns kept as text."""
        out = tuple(note for attr, note in self._NOTES.items() if getattr(self, attr) is None)
        for name, text in self.metadata.items():
            if name in OWN_TEXT_COLUMNS:    # hse-opt's own text: no news to its user
                continue
            cells = text.tolist()
            filled = [k for k, c in enumerate(cells) if str(c).strip()]   # an empty cell shows no text
            i = _first_not_number([cells[k] for k in filled]) if filled else None
            why = (f"row {filled[i] + 1}: {cells[filled[i]]!r} is not a number" if i is not None else
                   "every cell empty" if not filled else f"row {_first_not_number(cells) + 1} is empty")
            out += (f"column '{name}' is text ({why}): kept as "
                    "metadata and passed through to output tables, not a covariate",)
        return out

    @property
    def warnings(self):
        """tuple of str: pitch/roll columns whose every value is below 0.05 arcsec (a level base,
        or radians/degrees: read as given), and the text columns that hold numbers in other
        rows (a NaN, an empty cell or a typo among numbers turns the whole column into text: it
        is passed through, never a covariate). Each names the file, the first row that is not a number and the column;
        the loaders issue them as :class:`~hse_opt.data.errors.DataWarning` and the command
        line prints them on stderr."""
        out = ()
        if getattr(self, "pitch", None) is not None:
            tilt = np.abs(np.concatenate([self.pitch, self.roll])) / ARCSEC
            if np.all(tilt < SMALL_TILT_ARCSEC) and tilt.max() >= SMALL_TILT_FLOOR_ARCSEC:
                out += (f"{self.source}, column 'pitch_arcsec': every pitch and roll is below "
                        f"{SMALL_TILT_ARCSEC:g} arcsec: a level base, or values in radians or degrees "
                        "(1e-3 rad is 206 arcsec)? read as arcsec; allowed: arcsec",)
        for name, text in self.metadata.items():
            cells = text.tolist()
            i = _first_not_number(cells)
            numbers = len(cells) - sum(_first_not_number([c]) is not None for c in cells)
            if numbers:
                out += (f"{self.source}, row {i + 1}, column '{name}': {cells[i]!r} is not a number, so "
                        f"the column is kept as text ({numbers} of {len(cells)} rows are numbers): passed "
                        "through, not a covariate; allowed for a covariate: a finite number in every row",)
        return out

    def covariate(self, name, use):
        """The covariate column ``name`` (file unit, shape (n,)) that ``use`` needs (e.g. "the
        effect covariate:temp_c"); DataError naming the first row that is not a number when the
        column was read as text, or the columns there are when it is absent."""
        if name in self.covariates:
            return self.covariates[name]
        if name in self.metadata:
            cells = self.metadata[name].tolist()
            i = _first_not_number(cells)
            raise DataError(self.source, f"{cells[i]!r} is not a number, so the column is text; allowed: a "
                                         f"finite number in every row of a column used by {use}",
                            row=i + 1, column=name)
        raise DataError(self.source, f"is not in the file, but {use} needs it; allowed: "
                                     f"{', '.join(self.covariates) or 'none (the file has no covariate columns)'}",
                        column=name)

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

    def append(self, other):
        """This table's rows followed by ``other``'s, as a new, validated table (run ids must stay
        unique). Both must carry the same optional columns, covariates and text columns."""
        if type(other) is not type(self):
            raise TypeError(f"cannot append a {type(other).__name__} to a {type(self).__name__}")
        attrs = (*(c.attr for c in self._COLUMNS), *self._ROW_FIELDS)
        differ = [a for a in attrs if (getattr(self, a) is None) != (getattr(other, a) is None)]
        differ += [f"covariates {sorted(set(self.covariates) ^ set(other.covariates))}"
                   if set(self.covariates) != set(other.covariates) else ""]
        differ += [f"text columns {sorted(set(self.metadata) ^ set(other.metadata))}"
                   if set(self.metadata) != set(other.metadata) else ""]
        if any(differ):
            raise ValueError(f"tables with different columns ({', '.join(d for d in differ if d)}); allowed: "
                             "the same optional columns in both")
        take = {a: np.concatenate([getattr(self, a), getattr(other, a)]) for a in attrs
                if getattr(self, a) is not None}
        return dataclasses.replace(
            self, **take, covariates={k: np.concatenate([v, other.covariates[k]]) for k, v in self.covariates.items()},
            metadata={k: np.concatenate([v, other.metadata[k]]) for k, v in self.metadata.items()})

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
