"""Run inputs of the measurement model: the named view :class:`RunInputs` on the input matrix
``x`` (one column per run), the tilt of b0 as :class:`Tilt` (roll, pitch) and :func:`c23`.

The matrix has the rows of :data:`RUN_FIELDS` (SI: rate rad/s signed, azimuth rad, pitch
and roll of b0 rad, latitude rad, t_start s since power-on, duration s), then the covariates
the model's effects use, in the model's order. Code reads and writes it through the view
(``RunInputs(X).t_start``), never by row number.
"""
from typing import NamedTuple

import numpy as np

RUN_FIELDS = ("rate", "azimuth", "pitch", "roll", "latitude", "t_start", "duration")


class Tilt(NamedTuple):
    """Tilt of the turntable base b0 from level, rad: ``roll`` (gamma, about x) and ``pitch``
    (theta, about y), ``C_b0^n = rot_z(psi) rot_y(theta) rot_x(gamma)``. The same order as a
    plan's ``tilt_x``/``tilt_y`` columns."""

    roll: float
    pitch: float


def c23(azimuth, tilt):
    """East component of the rotation axis, ``C23 = -roll cos(psi) + pitch sin(psi)`` (paper
    Eq. 3, first order in the tilt), rad, for the stand azimuth ``psi`` (rad) and a
    :class:`Tilt`; arrays broadcast."""
    return -tilt.roll * np.cos(azimuth) + tilt.pitch * np.sin(azimuth)


def _field(i, name):
    def get(self):
        return self.X[i]

    def set_(self, value):
        self.X[i] = value
    return property(get, set_, doc=f"Row ``{name}`` of the run inputs (SI).")


class RunInputs:
    """Named view on a run-input matrix ``X`` (``(n_x, n)`` numpy, or a CasADi column of one
    run): ``RunInputs(X).rate`` is ``X``'s rate row, and assigning to a field writes ``X``.

    Parameters
    ----------
    X : numpy.ndarray or casadi.SX
        The run inputs (module docstring).
    covariate_names : sequence of str
        The covariate rows after the run fields, in order.
    """

    rate = _field(0, "rate")
    azimuth = _field(1, "azimuth")
    pitch = _field(2, "pitch")
    roll = _field(3, "roll")
    latitude = _field(4, "latitude")
    t_start = _field(5, "t_start")
    duration = _field(6, "duration")
    #: row of each field
    INDEX = {name: i for i, name in enumerate(RUN_FIELDS)}

    def __init__(self, X, covariate_names=()):
        self.X = X
        self.covariate_names = tuple(covariate_names)

    @property
    def tilt(self):
        return Tilt(roll=self.roll, pitch=self.pitch)

    @tilt.setter
    def tilt(self, tilt):
        self.roll, self.pitch = tilt.roll, tilt.pitch

    @property
    def covariates(self):
        """``{name: row}`` of the covariates."""
        return {c: self.X[len(RUN_FIELDS) + i] for i, c in enumerate(self.covariate_names)}

    @property
    def c23(self):
        """:func:`c23` of every run."""
        return c23(self.azimuth, self.tilt)
