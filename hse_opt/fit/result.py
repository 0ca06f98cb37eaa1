"""The records of a fit: :class:`FitResult`, :class:`Constraint` (a linear constraint between
parameters) and :class:`SolverError`."""
import math
from dataclasses import dataclass, field, fields
from typing import Mapping

import numpy as np

from .. import units
from ..model.composition import Model


class SolverError(RuntimeError):
    """A solver did not succeed; ``status`` is its own status string."""

    def __init__(self, message, status):
        super().__init__(f"{message} (status: {status})")
        self.status = status


@dataclass(frozen=True)
class Constraint:
    """A linear constraint ``lower <= sum(c_i * value_i) <= upper`` between parameters, in
    their display units (``lower == upper`` for an equality).

    ``Constraint({"lambda2*tilt_cos": 1, "lambda2*tilt_sin": -1}, 0, 0)`` or
    ``Constraint.equal({"bias_z": 1}, 0.0)``. Data, never a string to evaluate.

    Attributes
    ----------
    coefficients : tuple of (str, float)
        Parameter name and coefficient (a mapping is accepted).
    lower, upper : float
        Bounds of the combination; one may be infinite.
    """

    coefficients: tuple
    lower: float = -math.inf
    upper: float = math.inf

    def __post_init__(self):
        items = self.coefficients.items() if isinstance(self.coefficients, Mapping) else self.coefficients
        try:
            items = tuple((str(n), float(c)) for n, c in items)
        except (TypeError, ValueError):
            raise ValueError(f"constraint coefficients must map names to numbers, got "
                             f"{self.coefficients!r}") from None
        names = [n for n, _ in items]
        if not items or len(set(names)) != len(names):
            raise ValueError(f"constraint needs distinct parameter names, got {names}")
        if not all(np.isfinite(c) for _, c in items) or not any(c != 0 for _, c in items):
            raise ValueError(f"constraint coefficients must be finite and not all zero: {items}")
        lo, hi = float(self.lower), float(self.upper)
        if math.isnan(lo) or math.isnan(hi) or lo > hi or (math.isinf(lo) and math.isinf(hi)):
            raise ValueError(f"constraint {self._text(items)}: need lower <= upper, one finite; got "
                             f"{lo} and {hi}")
        object.__setattr__(self, "coefficients", items)
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)

    @classmethod
    def equal(cls, coefficients, value):
        """The equality ``sum(c_i * value_i) == value``."""
        return cls(coefficients, value, value)

    @property
    def is_equality(self):
        return self.lower == self.upper

    @staticmethod
    def _text(items):
        return " ".join(f"{'-' if c < 0 else '+'} {abs(c):g}*{n}" for n, c in items).lstrip("+ ")

    def __str__(self):
        body = self._text(self.coefficients)
        if self.is_equality:
            return f"{body} = {self.lower:g}"
        parts = ([f"{self.lower:g} <="] if np.isfinite(self.lower) else []) + [body] + \
            ([f"<= {self.upper:g}"] if np.isfinite(self.upper) else [])
        return " ".join(parts)

    def to_dict(self):
        return {"coefficients": dict(self.coefficients), "lower": _finite(self.lower),
                "upper": _finite(self.upper)}


def _finite(x):
    """JSON-safe float: None for an infinite bound."""
    return float(x) if np.isfinite(x) else None


@dataclass(frozen=True, eq=False)
class FitResult:
    """A weighted least-squares calibration. Parameter quantities are in display units
    (``units``); rows of ``covariance``/``correlation`` follow ``names``.

    Attributes
    ----------
    model : Model
    tilt_known : bool
        Whether runs carried pitch/roll (else tilt-coupled terms are free C23 coefficients).
    names, units : tuple of str
        Every parameter of the measurement model, fixed ones included.
    values, std : numpy.ndarray, shape (n_p,)
        Estimates and standard errors (0 for fixed parameters and those held at a bound),
        display units.
    covariance, correlation : numpy.ndarray, shape (n_p, n_p)
    free : numpy.ndarray of bool, shape (n_p,)
    p : numpy.ndarray, shape (n_p,)
        The estimate in SI, for :meth:`MeasurementModel.predict`.
    run : numpy.ndarray of int, shape (n,)
    residuals : numpy.ndarray, shape (n,)
        heading_err - h(p), rad.
    sigma : numpy.ndarray, shape (n,)
        Heading sigma used for each run, rad.
    standardized : numpy.ndarray, shape (n,)
        residuals / sigma.
    chi2, dof, chi2_red, aic, bic, condition : float
        ``chi2`` includes ``chi2_prior``.
    weighting : str
        ``heading_std``, ``pure-error``, ``residual`` or ``robust-scale`` (module docstring).
    method, status : str
        Solver used and its final status.
    binding : tuple of str
        Parameters whose bound binds at the solution.
    downweighted : tuple of int
        Run ids the robust loss down-weighted, most down-weighted first.
    notes : tuple of str
        What the tool assumed (missing columns, sigma source, constraints, prior).
    lower, upper : numpy.ndarray, shape (n_p,)
        Bounds used (display units; +-inf when none; the value for fixed parameters).
    constraints : tuple of Constraint
    active : tuple of str
        Inequality constraints active at the solution.
    weights : numpy.ndarray, shape (n,)
        Robust weights (1 without ``robust``).
    chi2_prior : float
        The prior's part of chi2 (0 without a prior).
    inputs : numpy.ndarray, shape (n_x, n), or None
        The runs' measurement-model inputs (SI, :meth:`MeasurementModel.inputs` order): where
        the calibration holds (:mod:`hse_opt.export`). None for a FIT.json without them.
    """

    model: Model
    tilt_known: bool
    names: tuple
    units: tuple
    values: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    free: np.ndarray
    p: np.ndarray
    run: np.ndarray
    residuals: np.ndarray
    sigma: np.ndarray
    standardized: np.ndarray
    chi2: float
    dof: int
    chi2_red: float
    aic: float
    bic: float
    condition: float
    weighting: str
    method: str
    status: str
    binding: tuple = ()
    downweighted: tuple = ()
    notes: tuple = field(default_factory=tuple)
    lower: np.ndarray = None
    upper: np.ndarray = None
    constraints: tuple = ()
    active: tuple = ()
    weights: np.ndarray = None
    chi2_prior: float = 0.0
    inputs: np.ndarray = None

    def __post_init__(self):
        for f in fields(self):  # frozen all the way down: read-only copies of the arrays
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray):
                v = v.copy()
                v.setflags(write=False)
                object.__setattr__(self, f.name, v)

    @property
    def n_runs(self):
        return int(self.run.size)

    @property
    def rms_arcsec(self):
        """RMS of the residuals, arcsec."""
        return float(np.sqrt(np.mean(self.residuals ** 2)) / units.ARCSEC)

    @property
    def measurement(self):
        """The :class:`MeasurementModel` this fit used."""
        return self.model.measurement(self.tilt_known)

    def value(self, name):
        """``(value, std)`` of one parameter, display units."""
        i = self.measurement.parameter_index(name)
        return float(self.values[i]), float(self.std[i])

    def high_correlations(self, threshold=0.9):
        """``(name_a, name_b, r)`` for free-parameter pairs with ``|r| > threshold``."""
        out = []
        for i in range(len(self.names)):
            for j in range(i + 1, len(self.names)):
                r = self.correlation[i, j]
                if abs(r) > threshold:
                    out.append((self.names[i], self.names[j], float(r)))
        return out

    def to_dict(self):
        """The JSON form (DESIGN.md contract, plus more keys)."""
        lower = self.lower if self.lower is not None else np.full(len(self.names), -np.inf)
        upper = self.upper if self.upper is not None else np.full(len(self.names), np.inf)
        return {
            "effects": list(self.model.effect_names),
            "n_runs": self.n_runs,
            "parameters": {n: {"value": float(v), "std": float(s), "unit": u, "free": bool(f),
                               "lower": _finite(lo), "upper": _finite(hi)}
                           for n, v, s, u, f, lo, hi in zip(self.names, self.values, self.std,
                                                            self.units, self.free, lower, upper)},
            "chi2": float(self.chi2), "dof": int(self.dof), "chi2_red": float(self.chi2_red),
            "aic": float(self.aic), "bic": float(self.bic), "rms_arcsec": self.rms_arcsec,
            "chi2_prior": float(self.chi2_prior), "tilt_known": bool(self.tilt_known),
            "condition": float(self.condition), "weighting": self.weighting,
            "method": self.method, "status": self.status, "binding": list(self.binding),
            "constraints": [dict(c.to_dict(), active=str(c) in self.active) for c in self.constraints],
            "downweighted": [int(r) for r in self.downweighted], "notes": list(self.notes),
            "high_correlations": [{"a": a, "b": b, "r": r} for a, b, r in self.high_correlations()],
            "correlation": self.correlation.tolist(),
            "covariance": self.covariance.tolist(),
        }
