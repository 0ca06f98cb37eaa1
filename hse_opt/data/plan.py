"""``PLAN.csv`` in memory: :class:`Plan`."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..units import ARCSEC
from .table import _AZIMUTH, _DURATION, _NONNEGATIVE_T_START, _POSITIVE_DURATION, _RATE, _RUN, _T_START, _Col, _Table

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

