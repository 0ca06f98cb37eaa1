"""``RUNS.csv`` in memory: :class:`Runs`, with the field campaigns' positions without a heading
reference (see "Field campaigns" in :mod:`hse_opt.data`)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from ..ranges import RANGES
from ..units import ARCSEC, DEG
from .decimals import _heading_err_text, _missing, _to_text
from .errors import DataError
from .table import (_AZIMUTH, _DURATION, _NONNEGATIVE_T_START, _POSITIVE_DURATION, _RATE, _RUN, _T_START,
                    _Col, _looks_like_radians, _sequence, _Table)

__all__ = ["Runs", "MAX_POSITION_SPREAD_DEG", "COPY_TOL_ARCSEC"]

#: largest distance of an unsurveyed row's heading from its position's mean heading, deg
MAX_POSITION_SPREAD_DEG = 2.0
#: rows of one setting whose headings differ by less than this (arcsec) are copies of one
#: measurement (:meth:`Runs.copies`): far below any alignment's noise, above rounding
COPY_TOL_ARCSEC = 1e-6


def _wrap(angle):
    """Angle (rad) wrapped to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi



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

    def copies(self):
        """Rows that repeat another row's measurement: the same rate, azimuth (or position),
        latitude, duration and tilt, and a heading (``heading_err``, and ``heading`` where given)
        within :data:`COPY_TOL_ARCSEC` -- a row written twice (under a new run id, say), or
        repeats without noise, not a run measured again (a measured heading differs by its
        noise, arcseconds).

        Returns
        -------
        labels : numpy.ndarray of int64, shape (n,)
            The measurement of each row, 0 .. m-1 (copies share one), in order of first
            appearance.
        m : int
            How many distinct measurements there are (``m == n``: no copies).

        The fit counts each measurement once (its copies share its weight) and says so
        (:func:`hse_opt.fit.run_sigma`); the diagnosis counts its degrees of freedom over the
        ``m`` measurements.
        """
        n = len(self)
        if n == 0:
            return np.zeros(0, np.int64), 0
        cols = [self.rate, self.azimuth, self.latitude, self.duration]
        cols += [a for a in (self.pitch, self.roll) if a is not None]
        if self.position is not None:
            cols.append(np.unique(self.position, return_inverse=True)[1].astype(float))
        setting = np.unique(np.column_stack(cols), axis=0, return_inverse=True)[1].ravel()
        # within a setting, headings within COPY_TOL_ARCSEC of a neighbour's are one measurement
        err = np.asarray(self.heading_err, float) / ARCSEC
        own = np.zeros(n) if self.heading is None else np.asarray(self.heading, float) / ARCSEC
        order = np.lexsort((own, err, setting))
        new = np.ones(n, bool)
        new[1:] = ((np.diff(setting[order]) != 0) | (np.abs(np.diff(err[order])) > COPY_TOL_ARCSEC)
                   | (np.abs(np.diff(own[order])) > COPY_TOL_ARCSEC))
        group = np.empty(n, np.int64)
        group[order] = np.cumsum(new) - 1
        first = np.full(int(new.sum()), n)
        np.minimum.at(first, group, np.arange(n))
        rank = np.empty(first.size, np.int64)
        rank[np.argsort(first, kind="stable")] = np.arange(first.size)  # in order of first appearance
        return rank[group], int(first.size)

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
        for i in np.flatnonzero(~surveyed & np.array([_missing(v) for v in heading], dtype=bool)):
            raise DataError(src, "is empty in a row without azimuth_deg; allowed: the alignment's own heading "
                                 "in deg in every row without a stand azimuth (a field position's rows)",
                            row=int(i) + 1, column="heading_deg")
        for i in np.flatnonzero(~surveyed & ~err_missing):
            raise DataError(src, "is given where azimuth_deg is empty; allowed: heading_err_arcsec only "
                                 "with the stand azimuth it refers to", row=int(i) + 1, column="heading_err_arcsec")
        # the common parse on stand-ins: the own heading for a missing azimuth, 0 for a missing error
        columns["azimuth_deg"] = [a if ok else h for a, h, ok in zip(seqs["azimuth_deg"], heading, surveyed)]
        columns["heading_err_arcsec"] = [_heading_err_text(a, h) if ok else 0 if miss else e for a, h, e, ok, miss
                                         in zip(seqs["azimuth_deg"], heading, seqs["heading_err_arcsec"],
                                                surveyed, err_missing)]
        try:
            runs = super()._parse(columns, src, min_rate_dps, True, header_line)
        except DataError as e:
            # a value that stands in for a missing one is named as what the file holds
            i = None if e.row is None else e.row - 1
            if i is None or not ((e.column == "azimuth_deg" and not surveyed[i])
                                 or (e.column == "heading_err_arcsec" and err_missing[i])):
                raise
            problem = e.problem.replace("azimuth_deg", "heading_deg").replace("heading_err_arcsec", "heading_deg")
            if "out of range" in problem:
                problem = (f"value {heading[i]!r} is out of range; allowed: "
                           f"{RANGES['heading_deg'].allowed('heading_deg')}")
            raise DataError(src, problem, row=e.row, line=e.line, column="heading_deg") from None
        for name, x in (("azimuth_deg", runs.azimuth[surveyed]), ("heading_deg", runs.heading)):
            if not allow_small_azimuths and _looks_like_radians(x / DEG):
                raise DataError(src, "the values look like radians (all within +-2 pi, spread over at least "
                                     "1, not whole numbers); allowed: degrees, or allow_small_azimuths=True "
                                     "(--allow-small-azimuths) for a fine sweep in degrees", column=name)
        heading_err, azimuth = np.array(runs.heading_err), np.array(runs.azimuth)
        labels = runs.position
        groups = labels if labels is not None else np.full(n, "field")
        copy_of, _ = runs.copies()  # a row written twice counts once in its position's mean
        share = 1.0 / np.bincount(copy_of)[copy_of]
        for label in np.unique(groups[~surveyed]):
            rows = np.flatnonzero((groups == label) & ~surveyed)
            h = runs.heading[rows]
            ref = np.angle(np.sum(share[rows] * np.exp(1j * h)) / rows.size)  # np.mean without copies
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

