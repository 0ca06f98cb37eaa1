"""The records of a fit: :class:`FitResult`, :class:`Constraint` (a linear constraint between
parameters) and :class:`SolverError`."""
import math
from dataclasses import dataclass, field, fields, replace
from typing import Mapping

import numpy as np

from .. import units
from ..model.composition import Model


class SolverError(RuntimeError):
    """A solver did not succeed; ``status`` is its own status string."""

    def __init__(self, message, status):
        super().__init__(f"{message} (status: {status})")
        self.status = status


def chi2_sf(x, dof):
    """P(chi2 with ``dof`` degrees of freedom > ``x``) for a whole ``dof`` >= 1: the closed
    form of the regularised upper incomplete gamma function at half-integer order (a finite
    Poisson sum, plus ``erfc`` for odd ``dof``), its terms in logs. numpy and math only: scipy
    costs a third of a second of every ``hse-opt fit`` to import."""
    x, half = max(float(x), 0.0) / 2.0, int(dof) // 2
    if int(dof) != dof or dof < 1:
        raise ValueError(f"dof {dof}: allowed a whole number >= 1")
    if x == 0.0:
        return 1.0
    if dof % 2 == 0:  # sum_{k < dof/2} e^-x x^k / k!
        k = np.arange(half, dtype=float)
        log_terms = k * math.log(x) - x - np.concatenate([[0.0], np.cumsum(np.log(k[1:]))])
        return float(min(1.0, np.exp(log_terms).sum()))
    # odd: erfc(sqrt x) + sum_{k < (dof - 1)/2} e^-x x^(k + 1/2) / Gamma(k + 3/2)
    k = np.arange(half, dtype=float)
    log_gamma = math.lgamma(1.5) + np.concatenate([[0.0], np.cumsum(np.log(k[1:] + 0.5))])
    log_terms = (k + 0.5) * math.log(x) - x - log_gamma
    return float(min(1.0, math.erfc(math.sqrt(x)) + np.exp(log_terms).sum()))


def chi2_isf(q, dof):
    """The ``x`` with :func:`chi2_sf` ``(x, dof) = q`` (0 < q < 1), by bisection to 1e-12
    relative: the chi-square quantile without scipy."""
    if not 0.0 < q < 1.0:
        raise ValueError(f"q {q}: allowed 0 < q < 1")
    lo, hi = 0.0, float(dof) + 10.0 * math.sqrt(2.0 * dof) + 50.0
    while chi2_sf(hi, dof) > q:
        lo, hi = hi, 2.0 * hi
    while hi - lo > 1e-12 * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if chi2_sf(mid, dof) > q else (lo, mid)
    return 0.5 * (lo + hi)


def f_sf(F, dof1, dof2):
    """P(F with ``(dof1, dof2)`` degrees of freedom > ``F``): the regularised incomplete beta
    function ``I_x(dof2/2, dof1/2)`` at ``x = dof2 / (dof2 + dof1 F)``, by its continued fraction
    (modified Lentz), numpy and math only like :func:`chi2_sf`. ``F = inf`` gives 0."""
    if dof1 <= 0 or dof2 <= 0:
        raise ValueError(f"dof ({dof1}, {dof2}): allowed numbers > 0")
    F = float(F)
    if F <= 0.0:
        return 1.0
    if math.isinf(F):
        return 0.0
    x = dof2 / (dof2 + dof1 * F)
    return _betainc(dof2 / 2.0, dof1 / 2.0, x)


def _betainc(a, b, x):
    """The regularised incomplete beta function ``I_x(a, b)``, 0 <= x <= 1."""
    if x <= 0.0 or x >= 1.0:
        return 0.0 if x <= 0.0 else 1.0
    if x > (a + 1.0) / (a + b + 2.0):        # the fraction converges fast below the mean
        return 1.0 - _betainc(b, a, 1.0 - x)
    log_front = (a * math.log(x) + b * math.log1p(-x) - math.log(a)
                 - (math.lgamma(a) + math.lgamma(b) - math.lgamma(a + b)))
    tiny = 1e-300
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 10000):
        for num in (m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)),
                    -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1))):
            d = 1.0 + num * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + num / c
            c = c if abs(c) > tiny else tiny
            h *= d * c
        if abs(d * c - 1.0) < 1e-15:
            break
    return float(min(1.0, math.exp(log_front) * h))


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
        the calibration holds (:mod:`hse_opt.fit.export`). None for a FIT.json without them.
    confounded : tuple of ConfoundedGroup
        Groups of free parameters these runs cannot separate (|r| > 0.99 or variance inflation
        > 100, :func:`hse_opt.information.confounded`), with their sigma inflation and the runs
        that would separate them; empty when none.
    systematic : numpy.ndarray, shape (n_p,), or None
        Per parameter the largest shift (display unit) that a catalogue effect missing from the
        model could cause while the diagnosis would miss it, when it exceeds the parameter's
        statistical sigma (0: no such risk); None when not assessed
        (:func:`hse_opt.aliasing.alias_budget`, :meth:`with_budget`).
    systematic_by : tuple of dict
        Per parameter ``{effect: shift}`` of the effects behind ``systematic``.
    lack_of_fit : LackOfFit or None
        The replicates' test of the model (:func:`hse_opt.fit.weights.lack_of_fit_test`: the
        replicate groups' means about the model against the scatter within them, F with
        ``(groups - k, measurements - groups)`` degrees of freedom); None without replicates,
        with a prior, or in a FIT.json written before it.
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
    confounded: tuple = ()
    systematic: np.ndarray = None
    systematic_by: tuple = ()
    lack_of_fit: object = None

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

    def with_budget(self, budget):
        """This fit with the systematic part of an :class:`~hse_opt.aliasing.AliasBudget` of it
        (``systematic``, ``systematic_by``) and its sentences among the notes ("lambda2 = 10.4
        +- 1.5 arcsec statistical; sync_delay, undetectable here below 340 us, could move it by
        up to 6.2 arcsec")."""
        if tuple(budget.names) != tuple(self.names):
            raise ValueError(f"the alias budget's parameters {list(budget.names)} are not this fit's "
                             f"{list(self.names)}")
        said = tuple(f"systematic risk: {line}" for line in budget.sentences(self.values))
        return replace(self, systematic=np.asarray(budget.systematic, float),
                       systematic_by=tuple(dict(d) for d in budget.systematic_by),
                       notes=tuple(n for n in self.notes if not n.startswith("systematic risk: ")) + said)

    def tilt_amplitudes(self):
        """Without tilt columns a tilt-coupled parameter ``b`` is the azimuth sinusoid
        ``b*tilt_cos cos(psi) + b*tilt_sin sin(psi)`` (plus a constant): its amplitude
        ``A = hypot(b*tilt_cos, b*tilt_sin)`` is ``b`` times the amplitude of C23 (the README's
        "3.3 +- 1.1 arcsec*mrad" of the paper's Table 1). Returns ``{b: (A, sigma_A, unit)}``
        for every such pair fitted free, sigma by the delta method
        (``g' C g``, ``g = (cos, sin) / A``)."""
        out = {}
        for i, name in enumerate(self.names):
            if not name.endswith("*tilt_cos"):
                continue
            base = name[: -len("*tilt_cos")]
            j = self.names.index(f"{base}*tilt_sin") if f"{base}*tilt_sin" in self.names else None
            if j is None or not (self.free[i] and self.free[j]):
                continue
            c, s = float(self.values[i]), float(self.values[j])
            a = math.hypot(c, s)
            g = np.array([c, s]) / a if a > 0 else np.array([1.0, 0.0]) / math.sqrt(2.0)
            C = self.covariance[np.ix_([i, j], [i, j])]
            out[base] = (a, float(np.sqrt(max(g @ C @ g, 0.0))), self.units[i])
        return out

    def tilt_amplitude_lines(self):
        """The sinusoids of :meth:`tilt_amplitudes` in words, one line each (the text summary
        and the report say the same): ``'heading-sensitive sinusoid lambda2 * C23 (tilt
        unknown): amplitude 3.28 +- 1.1 arcsec*mrad'``."""
        return [f"heading-sensitive sinusoid {base} * C23 (tilt unknown): amplitude {a:.3g} +- {sa:.2g} {unit}"
                for base, (a, sa, unit) in self.tilt_amplitudes().items()]

    def high_correlations(self, threshold=0.9):
        """``(name_a, name_b, r)`` for free-parameter pairs with ``|r| > threshold``."""
        out = []
        for i in range(len(self.names)):
            for j in range(i + 1, len(self.names)):
                r = self.correlation[i, j]
                if abs(r) > threshold:
                    out.append((self.names[i], self.names[j], float(r)))
        return out

    def summary(self):
        """The fit as lines of text (the CLI prints them after its title): parameters with their
        units and standard errors, the fit statistics, bounds that bind, active constraints,
        down-weighted runs, strong correlations and the notes."""
        d = self.to_dict()
        lines = [f"{self.n_runs} runs, effects {', '.join(d['effects'])}",
                 f"  weighting: {self.weighting}; solver: {self.method} ({self.status})", ""]
        width = max(len(n) for n in self.names) + 2
        sys_col = self.systematic is not None
        lines.append(f"  {'parameter':<{width}}{'value':>12}  {'1-sigma':>10}  "
                     + (f"{'systematic':>10}  " if sys_col else "") + "unit")
        for name, p in d["parameters"].items():
            state = ("(fixed)" if not p["free"] else "(at its bound)" if name in self.binding else "")
            sigma = f"{p['std']:>10.4g}" if p["std"] > 0 else f"{'':>10}"
            if sys_col:
                sigma += f"  {p['systematic']:>10.3g}" if p["systematic"] else f"  {'':>10}"
            lines.append(f"  {name:<{width}}{p['value']:>12.5g}  {sigma}  {p['unit']} {state}".rstrip())
        lines.append("")
        fit_line = f"  chi2 {self.chi2:.4g} / dof {self.dof} = {self.chi2_red:.4g}"
        if self.weighting == "heading_std":
            fit_line += f" (p = {chi2_sf(self.chi2, self.dof):.3g})"
        elif self.weighting == "pure-error":
            fit_line += " (sigma from the replicates' scatter: the test is the lack of fit below)"
        elif self.lack_of_fit is not None:
            fit_line += " (sigma from the residuals: the test is the lack of fit below)"
        else:
            fit_line += " (sigma from the residuals: no goodness-of-fit test)"
        lines += [f"  {text}" for text in self.tilt_amplitude_lines()]
        if self.lack_of_fit is not None:
            fit_line += f"\n  {self.lack_of_fit.text()}"
        lines += [*fit_line.split("\n"), f"  AIC {self.aic:.4g}, BIC {self.bic:.4g}, residual RMS "
                            f"{self.rms_arcsec:.4g} arcsec, condition number {self.condition:.3g}"]
        lines.append(f"  bounds that bind: {', '.join(self.binding) or 'none'}")
        if self.constraints:
            lines.append(f"  constraints: {'; '.join(str(c) for c in self.constraints)}"
                         f" (active: {'; '.join(self.active) or 'none'})")
        if self.downweighted:
            lines.append(f"  down-weighted runs (Huber): {', '.join(str(r) for r in self.downweighted)}")
        high = self.high_correlations()
        lines.append("  correlations above 0.9: " + (", ".join(f"{a}/{b} {r:+.3f}" for a, b, r in high)
                                                      or "none"))
        if self.notes:
            lines.append("  notes:")
            lines += [f"    - {n}" for n in self.notes]
        return lines

    def to_dict(self):
        """The JSON form (the contract of ``docs/formats.md``, plus more keys)."""
        lower = self.lower if self.lower is not None else np.full(len(self.names), -np.inf)
        upper = self.upper if self.upper is not None else np.full(len(self.names), np.inf)
        return {
            "effects": list(self.model.effect_names),
            "n_runs": self.n_runs,
            "parameters": {n: {"value": float(v), "std": float(s), "unit": u, "free": bool(f),
                               "lower": _finite(lo), "upper": _finite(hi),
                               "systematic": None if self.systematic is None else float(self.systematic[i]),
                               "systematic_by": ({} if not self.systematic_by else
                                                 {e: float(x) for e, x in self.systematic_by[i].items()})}
                           for i, (n, v, s, u, f, lo, hi) in enumerate(zip(self.names, self.values, self.std,
                                                                           self.units, self.free, lower, upper))},
            "confounded": [g.to_dict() for g in self.confounded],
            "tilt_amplitudes": {b: {"value": a, "std": sa, "unit": u}
                                for b, (a, sa, u) in self.tilt_amplitudes().items()},
            "chi2": float(self.chi2), "dof": int(self.dof), "chi2_red": float(self.chi2_red),
            "lack_of_fit": None if self.lack_of_fit is None else self.lack_of_fit.to_dict(),
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
