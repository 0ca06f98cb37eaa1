"""Where a calibration holds: its validity domain, in the space the model extrapolates in.

A calibration is trusted where its runs were: a correction applied elsewhere is the model's
extrapolation, and what the campaign could not rule out (an unmodelled effect aliased into the
fitted parameters) grows with the distance. The domain bounds the quantities *through which
the fitted parameters reach the correction* - never an input whose influence is the modelled
physics alone:

``rate``
    ``|rate|`` within the calibration runs' interval widened by the margin, and only the
    rotation senses the runs used (every parameter's heading signature depends on the rate).
``c23``
    ``C23 = -roll cos(heading) + pitch sin(heading)`` (:func:`hse_opt.model.inputs.c23`, the
    east component of the rotation axis; heading and tilt together) within the runs'
    interval widened by the margin - for fits with known tilt whose correction depends on the
    tilt. Pitch and roll are not bounded separately, nor the heading: a field campaign whose
    positions all had C23 near -290 arcsec says nothing about a heading 180 deg away, where
    C23 is +290 arcsec, and that is the case the domain refuses. A tilt-unknown fit's C23
    sinusoid is fitted for its stand as a function of the heading: no C23 bound.
``t_start``, ``duration``, covariates
    bounded only when the correction depends on them (e.g. ``warmup``): no bound on time or
    duration when no parameter depends on them.

The margin around the runs' interval ``[lo, hi]`` of a quantity is
``max(MARGIN_FRACTION * (hi - lo), MARGIN_FLOOR[name])`` (covariates: no floor); ``|rate|``,
times and durations are not bounded below 0.

Beside the domain, each input's model limits (not the campaign's): every input finite; with
known tilt, ``|pitch|`` and ``|roll|`` at most ``RANGES['pitch_arcsec']`` (the model is first
order in the tilt; the exported C's small-angle series hold far beyond); ``|latitude|`` at most
89 deg (:data:`hse_opt.ranges.RANGES`). Heading and latitude are otherwise free: the model's
dependence on them is the gyrocompass's own physics.

Status: bit ``k`` (``1 << k``) for input ``k`` that is not finite, beyond its model limit or
(``rate``, ``t_start``, ``duration``, covariates) outside its domain interval or sense;
bit :data:`C23_BIT` (``1 << 30``) for C23 outside its interval. :meth:`Domain.status` is the
exported C's return value, bit for bit (``tests/test_domain.py``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import units
from ..model.inputs import RUN_FIELDS, RunInputs
from ..ranges import RANGES

__all__ = ["Domain", "MARGIN_FRACTION", "MARGIN_FLOOR", "C23_BIT", "MAX_INPUTS", "describe_input", "describe_c23"]

#: margin around the calibration runs' interval, as a fraction of that interval ...
MARGIN_FRACTION = 0.1
#: ... or at least this (SI) per quantity; covariates have no floor
MARGIN_FLOOR = {"rate": 1.0 * units.DEG_PER_S, "c23": 30.0 * units.ARCSEC, "t_start": 10 * units.MINUTE,
                "duration": 1 * units.MINUTE}
#: the status bit of C23 (fixed, whatever the number of covariates)
C23_BIT = 30
#: inputs a calibration may have (their status bits stay below C23's)
MAX_INPUTS = C23_BIT
#: display unit and factor of each domain quantity (messages)
_DISPLAY = {"rate": ("deg/s", units.DEG_PER_S), "c23": ("arcsec", units.ARCSEC), "t_start": ("s", 1.0),
            "duration": ("s", 1.0)}
#: model limits, SI: input -> largest |value|
LIMITS = {"pitch": RANGES["pitch_arcsec"].hi * units.ARCSEC, "roll": RANGES["roll_arcsec"].hi * units.ARCSEC,
          "latitude": RANGES["latitude_deg"].hi * units.DEG}


@dataclass(frozen=True)
class Domain:
    """The validity domain of one calibration (module docstring).

    Attributes
    ----------
    names : tuple of str
        The inputs, in the measurement model's order (:data:`RUN_FIELDS`, then covariates).
    tilt_known : bool
    bounded : tuple of str
        The domain's quantities: ``rate`` (of ``|rate|``), ``c23``, and the inputs among
        ``t_start``, ``duration`` and the covariates the correction depends on.
    data_lower, data_upper, lower, upper : numpy.ndarray, shape (len(bounded),)
        The runs' interval and the accepted one (with the margin), SI (covariates: file unit).
    senses : tuple of int
        The rotation senses the runs used (+1, -1).
    """

    names: tuple
    tilt_known: bool
    bounded: tuple
    data_lower: np.ndarray
    data_upper: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    senses: tuple

    @classmethod
    def from_inputs(cls, X, names, tilt_known, depends, margin_fraction=MARGIN_FRACTION):
        """From the calibration runs' inputs ``X`` (n_x, n; measurement-model order, SI) and
        ``depends[k]``, whether the correction depends on input ``k``."""
        X = np.asarray(X, dtype=float)
        names = tuple(names)
        if len(names) > MAX_INPUTS:
            raise ValueError(f"a calibration with {len(names)} inputs; allowed: at most {MAX_INPUTS} (run "
                             "fields and covariates: each has its status bit below C23's)")
        dep = dict(zip(names, depends))
        bounded = ["rate"]
        if tilt_known and (dep["pitch"] or dep["roll"]):
            bounded.append("c23")
        bounded += [nm for nm in names[len(RUN_FIELDS) - 2:] if dep[nm]]
        q = _quantities(X, names, bounded)
        lo, hi = q.min(axis=1), q.max(axis=1)
        margin = np.array([max(margin_fraction * (h - lo_), MARGIN_FLOOR.get(nm, 0.0))
                           for nm, lo_, h in zip(bounded, lo, hi)])
        lower = np.array([max(v, 0.0) if nm in ("rate", "t_start", "duration") else v
                          for nm, v in zip(bounded, lo - margin)])
        senses = tuple(s for s in (1, -1) if np.any(np.sign(RunInputs(X).rate) == s))
        return cls(names, bool(tilt_known), tuple(bounded), lo, hi, lower, hi + margin, senses)

    def bit(self, name):
        """The status bit (``1 << k``) of a domain quantity or an input."""
        return 1 << (C23_BIT if name == "c23" else self.names.index(name))

    def limited(self):
        """The inputs with a model limit: ``{name: largest |value|}``, SI."""
        return {nm: v for nm, v in LIMITS.items() if self.tilt_known or nm == "latitude"}

    def status(self, X):
        """The status of each column of ``X`` (n_x, n): 0 inside, else the bitmask (module
        docstring) - the exported C's return value."""
        X = np.asarray(X, dtype=float)
        bits = (1 << np.arange(len(self.names), dtype=np.int64))[:, None]
        status = np.sum(np.where(np.isfinite(X), 0, bits), axis=0)
        for nm, limit in self.limited().items():
            with np.errstate(invalid="ignore"):
                status |= np.where(np.abs(X[self.names.index(nm)]) <= limit, 0, self.bit(nm))
        q = _quantities(X, self.names, self.bounded)
        with np.errstate(invalid="ignore"):
            inside = (q >= self.lower[:, None]) & (q <= self.upper[:, None])
        inside[0] &= np.isin(np.sign(RunInputs(X).rate), self.senses)
        for k, nm in enumerate(self.bounded):
            status |= np.where(inside[k], 0, self.bit(nm))
        return status

    def reasons(self, X):
        """One phrase per column of ``X`` outside: what is outside and where the domain is
        (``'C23 +288.1 arcsec outside [-316.3, -259.7]'``); ``''`` inside."""
        X = np.asarray(X, dtype=float)
        status = self.status(X)
        q = _quantities(X, self.names, self.bounded)
        out = []
        for j, s in enumerate(status):
            parts = []
            for k, nm in enumerate(self.bounded):
                if s & self.bit(nm):
                    unit, f = _DISPLAY.get(nm, ("", 1.0))
                    label = {"rate": "|rate|", "c23": "C23"}.get(nm, nm)
                    sense = ("" if nm != "rate" or np.sign(X[0, j]) in self.senses else
                             f" (sense {'+' if X[0, j] > 0 else '-'}: the runs used only "
                             f"{'+' if self.senses[0] > 0 else '-'})")
                    parts.append(f"{label} {q[k, j] / f:+.4g} {unit} outside [{self.lower[k] / f:.4g}, "
                                 f"{self.upper[k] / f:.4g}]{sense}".replace("  ", " "))
            bad = [nm for i, nm in enumerate(self.names) if s & (1 << i) and nm not in self.bounded]
            parts += [f"{nm} not finite or beyond its model limit" for nm in bad]
            out.append("; ".join(parts))
        return out

    def to_dict(self):
        """The JSON form (calibration.json's ``domain``)."""
        qs = []
        for k, nm in enumerate(self.bounded):
            unit = {"rate": "rad/s", "c23": "rad", "t_start": "s", "duration": "s"}.get(nm, "file unit")
            qs.append({"name": nm, "of": {"rate": "|rate|", "c23": "-roll cos(heading) + pitch sin(heading)"}.get(
                nm, nm), "unit": unit, "lower": float(self.lower[k]), "upper": float(self.upper[k]),
                "data_lower": float(self.data_lower[k]), "data_upper": float(self.data_upper[k]),
                "status_bit": self.bit(nm)})
        return {"quantities": qs, "senses": list(self.senses),
                "limits": [{"name": nm, "abs_max": v, "unit": "rad", "status_bit": self.bit(nm)}
                           for nm, v in self.limited().items()],
                "margin_fraction": MARGIN_FRACTION, "margin_floor": dict(MARGIN_FLOOR),
                "rule": "each bounded quantity within the calibration runs' interval widened by "
                        "max(margin_fraction * interval, floor), SI; the rate's senses those the runs used; "
                        "every input finite; pitch, roll, latitude within their model limits"}


def describe_input(row):
    """One input's validity in words, from a row of ``calibration.json``'s ``inputs`` (what
    ``hse-opt export`` prints and the session report shows): ``'0.279253 .. 1.11701 (of
    |rate|)'`` (SI), ``'|.| <= 0.0349066 (model limit)'`` or ``'any finite value'``."""
    rng = row.get("range")
    if rng:
        text = f"{rng['lower']:.6g} .. {rng['upper']:.6g}"
        of = row.get("range_of")
        senses = row.get("senses") or ()
        only = (f", the {'positive' if senses[0] > 0 else 'negative'} sense only" if len(senses) == 1 else "")
        return text + (f" (of {of}{only})" if of else "")
    if row.get("limit_abs"):
        return f"|.| <= {row['limit_abs']:.6g} (model limit)"
    return "any finite value"


def describe_c23(calibration):
    """The C23 interval in words, from a ``calibration.json`` object: ``'C23 = -roll
    cos(heading) + pitch sin(heading): -340 .. -236 arcsec (the runs': -310 .. -266)'``;
    ``None`` when the domain does not bound C23 (tilt unknown, or no tilt dependence)."""
    for q in calibration["domain"]["quantities"]:
        if q["name"] == "c23":
            return (f"C23 = {q['of']}: {q['lower'] / units.ARCSEC:.6g} .. {q['upper'] / units.ARCSEC:.6g} arcsec "
                    f"(the runs': {q['data_lower'] / units.ARCSEC:.6g} .. {q['data_upper'] / units.ARCSEC:.6g})")
    return None


def _quantities(X, names, bounded):
    """The bounded quantities of each column of ``X``: (len(bounded), n)."""
    run = RunInputs(X, names[len(RUN_FIELDS):])
    rows = []
    for nm in bounded:
        if nm == "rate":
            rows.append(np.abs(run.rate))
        elif nm == "c23":
            rows.append(run.c23)
        else:
            rows.append(X[names.index(nm)])
    return np.array(rows, dtype=float).reshape(len(bounded), X.shape[1])
