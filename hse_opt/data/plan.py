"""``PLAN.csv`` in memory: :class:`Plan`."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..units import ARCSEC, DEG
from .decimals import _missing, _to_text
from .errors import DataError
from .table import (_AZIMUTH, _DURATION, _NONNEGATIVE_T_START, _POSITIVE_DURATION, _RATE, _RUN, _T_START, _Col, _Table,
                    _sequence)

__all__ = ["Plan"]


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
    surveyed : numpy.ndarray of bool, shape (n,), or None
        False for rows at an unsurveyed position (a field plan: ``azimuth_deg`` empty,
        ``heading_deg`` the heading to set the system to, approximately - nobody knows its
        true heading; only the spread between positions matters). In those rows ``azimuth``
        holds that heading. None: every row has a stand azimuth.
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
    surveyed: np.ndarray | None = None

    _ROW_FIELDS = ("position", "surveyed")
    _TEXT = ("position",)
    _COLUMNS = (_RUN, _RATE, _AZIMUTH, _T_START, _DURATION, _Col("tilt_x_arcsec", "tilt_x", ARCSEC, False),
                _Col("tilt_y_arcsec", "tilt_y", ARCSEC, False))
    _PAIRS = (("tilt_x", "tilt_y"),)
    _RULES = (_POSITIVE_DURATION, _NONNEGATIVE_T_START)

    def __post_init__(self):
        super().__post_init__()
        if self.surveyed is not None:
            sv = np.array(self.surveyed)
            if sv.dtype != bool or sv.shape != self.run.shape:
                raise TypeError(f"surveyed must be a boolean array of shape ({self.run.size},)")
            sv.setflags(write=False)
            object.__setattr__(self, "surveyed", sv)

    def _text_columns(self):
        """The file's columns: at an unsurveyed row ``azimuth_deg`` empty and ``heading_deg``
        the heading to set (``heading_deg`` empty where a stand azimuth is given)."""
        cols = super()._text_columns()
        if self.surveyed is None:
            return cols
        out = {}
        for name, col in cols.items():
            if name == "azimuth_deg":
                ok = self.surveyed.tolist()
                out[name] = [v if k else "" for v, k in zip(col, ok)]
                out["heading_deg"] = ["" if k else _to_text(a, DEG) for a, k in zip(self.azimuth, ok)]
            else:
                out[name] = col
        return out

    @classmethod
    def _parse(cls, columns, src, min_rate_dps, allow_small_azimuths, header_line):
        """``heading_deg`` stands in for an empty ``azimuth_deg`` (an unsurveyed position of a
        field plan), then the common parse."""
        if "heading_deg" not in columns or "run" not in columns:
            return super()._parse(columns, src, min_rate_dps, allow_small_azimuths, header_line)
        columns = dict(columns)
        heading = _sequence(columns.pop("heading_deg"), src, "heading_deg")
        n = len(heading)
        azimuth = _sequence(columns["azimuth_deg"], src, "azimuth_deg") if "azimuth_deg" in columns else [None] * n
        if len(azimuth) != n:
            raise DataError(src, f"has {len(azimuth)} values but heading_deg has {n}; allowed: equal lengths",
                            column="azimuth_deg")
        surveyed = np.array([not _missing(v) for v in azimuth], dtype=bool)
        for i in np.flatnonzero(~surveyed & np.array([_missing(v) for v in heading], dtype=bool)):
            raise DataError(src, "is empty in a row without azimuth_deg; allowed: the heading to set the system "
                                 "to, deg, in every row without a stand azimuth (an unsurveyed position)",
                            row=int(i) + 1, column="heading_deg")
        columns["azimuth_deg"] = [a if ok else h for a, h, ok in zip(azimuth, heading, surveyed)]
        try:
            plan = super()._parse(columns, src, min_rate_dps, allow_small_azimuths, header_line)
        except DataError as e:
            if e.column == "azimuth_deg" and e.row is not None and not surveyed[e.row - 1]:
                raise DataError(src, e.problem.replace("azimuth_deg", "heading_deg"), row=e.row, line=e.line,
                                column="heading_deg") from None
            raise
        return plan if surveyed.all() else plan.replace(surveyed=surveyed)

