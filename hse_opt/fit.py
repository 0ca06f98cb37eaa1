"""Weighted least squares of the measurement model to alignment results -> :class:`FitResult`.

``fit(runs, model)`` minimises the sum of squared standardised residuals
``(heading_err - h(p; run)) / sigma`` over the model's free parameters, plus a Gaussian prior
term when one is given, subject to bounds and linear constraints.

Solvers (``FitResult.method``)
------------------------------
``qr``, ``gauss-newton``
    No inequality constraints: Gauss-Newton steps, each solved by QR on the weighted,
    column-scaled Jacobian in the null space of the equalities, with step halving; one batch
    call of the model gives the residuals and the Jacobian of a step. Models linear in their
    free parameters (``qr``; the atan2 of the gyrocompass makes them very slightly nonlinear:
    two or three steps converge) and nonlinear ones (``gauss-newton``, e.g. ``warmup_tau``).
    Bounds (nonlinear parameters get their declared range, :class:`~hse_opt.model.Param`
    ``lower``/``upper``, by default) are kept when every step stays strictly inside them: a
    minimum inside the bounds is the bounded problem's, and no bound binds.
``ipopt``
    Inequality constraints, a bound that binds, or Gauss-Newton stepping out of the bounds:
    CasADi ``nlpsol``/IPOPT with a Gauss-Newton Hessian ``J'J`` (built once per model, run
    count and constraint shape, then reused), followed by the same Gauss-Newton/QR polish
    on the active set IPOPT finds, so bounds that bind hold exactly and a fit whose bounds
    do not bind equals the unconstrained one.

Weights (``FitResult.weighting``)
---------------------------------
``heading_std``
    the runs' own 1-sigma (``heading_std_arcsec``); the covariance is not rescaled.
``pure-error``
    no sigmas but replicated settings (same rate, azimuth, tilt, duration, latitude): one
    sigma from the scatter within replicate groups, independent of the model.
``residual``
    neither: one sigma from the residuals, ``s^2 = RSS / dof`` (chi2_red is then 1 by
    construction and no goodness-of-fit test is possible).
``robust-scale``
    ``robust=True`` without ``heading_std``: one sigma from the median absolute deviation of
    the residuals, ``1.4826 MAD``.

Robust fits (``robust=True``) minimise Huber's loss (quadratic within ``huber_c`` sigma,
linear beyond) by iteratively reweighted least squares; runs with weight below 1 are named
in ``FitResult.downweighted``, and the covariance is Huber's ``H1`` form
``K^2 [sum psi^2 / (n - k)] / mean(psi')^2 (A'A)^-1``.

AIC and BIC are ``chi2 + 2k`` and ``chi2 + k ln n`` when sigma is given or from pure error
(model-independent), and ``n ln(RSS/n) + 2k`` / ``+ k ln n`` when it is from the residuals;
``k`` counts the free parameters less the active constraints.

A prior (``prior=``: a :class:`~hse_opt.information.Prior` or a previous
:class:`FitResult`) adds ``(z - mu)' C^-1 (z - mu)`` to chi2 (``FitResult.chi2_prior``) and
its rank to the degrees of freedom; for a model linear in its parameters and known sigmas,
updating a fit with new runs this way gives the batch fit of all the runs.
"""
import json
import math
import os
from dataclasses import dataclass, field, fields
from functools import lru_cache
from typing import Mapping

import casadi as ca
import numpy as np
from scipy.linalg import solve_triangular

from . import units
from .information import (Prior, UnidentifiableError, analyse, blind_out, heading_sigma, invisible,
                          null_space, propagated_std, separation_advice)
from .model.effects import effect as make_effect
from .model.measurement import RUN_FIELDS, BatchEvaluator, Model, paper_model
from .model.symbolic import Geometry

__all__ = ["FitResult", "Constraint", "Prior", "SolverError", "UnidentifiableError", "fit",
           "compensate", "compensation", "compensated_parameters", "save_fit", "load_fit", "as_model",
           "replicate_groups", "pure_error", "run_sigma", "report_data", "COMPENSATED_COLUMN",
           "COMPENSATION_STD_COLUMN", "HUBER_C"]

#: Huber's threshold in sigmas (95 % efficiency for Gaussian data)
HUBER_C = 1.345
#: columns :func:`compensate` adds (arcsec): compensated heading error and its 1-sigma
COMPENSATED_COLUMN = "heading_err_comp_arcsec"
COMPENSATION_STD_COLUMN = "heading_comp_std_arcsec"
#: FIT.json format tag
FIT_FORMAT = "hse_opt.fit"
FIT_VERSION = 1


class SolverError(RuntimeError):
    """A solver did not succeed; ``status`` is its own status string."""

    def __init__(self, message, status):
        super().__init__(f"{message} (status: {status})")
        self.status = status


def as_model(model=None):
    """A :class:`Model` from ``None`` (the paper's), a Model, or effect names (``"hse,warmup"``
    or a list; ``hse`` is added when missing)."""
    if model is None:
        return paper_model()
    if isinstance(model, Model):
        return model
    names = [s.strip() for s in model.split(",")] if isinstance(model, str) else list(model)
    names = [n for n in names if n]
    if "hse" not in names:
        names = ["hse"] + names
    return Model(names)


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

    def save(self, path):
        """Write FIT.json (see :func:`save_fit`)."""
        save_fit(self, path)


# -- weights ------------------------------------------------------------------------------------
def replicate_groups(runs, mm=None, tilt_tol=10 * units.ARCSEC):
    """Replicate groups: runs with the same settings share a label. Returns ``(labels, n_groups)``.

    Settings are the rate, azimuth, duration and latitude, the tilt (pitch and roll within
    ``tilt_tol``: measured tilts carry noise) and -- for a measurement model ``mm`` whose
    heading depends on them (a warm-up, a covariate effect) -- time since power-on and the
    covariate columns: runs the model tells apart are not replicates, or their modelled
    differences would count as noise. Without ``mm`` the tilt counts when the runs have it."""
    cols = [np.round(np.asarray(a, float) / 1e-9)
            for a in (runs.rate, np.mod(runs.azimuth, 2 * np.pi), runs.duration, runs.latitude)]
    if runs.pitch is not None and (mm is None or mm.tilt_known):
        cols += [np.round(np.asarray(runs.pitch) / tilt_tol), np.round(np.asarray(runs.roll) / tilt_tol)]
    if mm is not None:
        X = mm.inputs_from_runs(runs)
        used = _inputs_used(mm)
        extra = [RUN_FIELDS.index("t_start"), *range(len(RUN_FIELDS), mm.n_x)]  # time, covariates
        cols += [X[i] for i in extra if used[i]]
    _, labels = np.unique(np.column_stack(cols), axis=0, return_inverse=True)
    labels = labels.ravel()
    return labels, int(labels.max()) + 1 if labels.size else 0


@lru_cache(maxsize=64)
def _inputs_used(mm):
    """Whether the model's heading depends on each run input (from the expression graph)."""
    p, x = ca.SX.sym("p", len(mm.names)), ca.SX.sym("x", mm.n_x)
    sp = ca.jacobian(mm.h(p, x), x).sparsity()
    used = np.zeros(mm.n_x, dtype=bool)
    used[np.asarray(sp.get_col(), dtype=int)] = True
    return used


def pure_error(runs, mm=None):
    """``(sigma, dof)`` from the scatter within replicate groups (rad), or ``(None, dof)``."""
    labels, g = replicate_groups(runs, mm)
    dof = runs.rate.size - g
    if dof < 2:
        return None, dof
    y = runs.heading_err
    mean = np.bincount(labels, y, g) / np.bincount(labels, minlength=g)
    return float(np.sqrt(np.sum((y - mean[labels]) ** 2) / dof)), dof


def run_sigma(runs, robust=False, mm=None):
    """``(sigma (n,) rad, weighting, notes)`` by the rules of the module docstring (replicates
    as :func:`replicate_groups` of the measurement model ``mm``); where sigma is estimated
    later from the residuals, the default noise model's (:func:`heading_sigma`)."""
    n = len(runs)
    if runs.heading_std is not None:
        return np.asarray(runs.heading_std, dtype=float), "heading_std", []
    # to be estimated from the residuals: start from the default noise model
    guess = np.full(n, float(np.sqrt(np.mean(heading_sigma(runs.duration, runs.latitude) ** 2))))
    if robust:
        return guess, "robust-scale", []
    s_pe, dof_pe = pure_error(runs, mm)
    if s_pe is not None and s_pe > 0:
        return np.full(n, s_pe), "pure-error", [
            f"sigma {s_pe / units.ARCSEC:.3g} arcsec from {dof_pe} replicate degrees of freedom "
            f"(pure error)"]
    return guess, "residual", []


# -- the problem ------------------------------------------------------------------------------
class _Problem:
    """Data, free set, bounds, constraints and prior of one fit, in display units over the
    free parameters ``z`` (``p[free] = z * scale``)."""

    def __init__(self, mm, X, y, p_base, free, lb, ub, A_eq, b_eq, A_in, l_in, u_in, L, Lmu, jit):
        self.mm, self.X, self.y, self.jit = mm, X, y, jit
        self.p_base, self.free = p_base, free
        self.scale = mm.scale[free]
        self.k = int(free.sum())
        self.lb, self.ub = lb, ub
        self.A_eq, self.b_eq, self.A_in, self.l_in, self.u_in = A_eq, b_eq, A_in, l_in, u_in
        self.L, self.Lmu = L, Lmu
        names = np.array(mm.names)[free]
        self.names = tuple(str(nm) for nm in names)
        self.nonlinear = np.array([nm in mm.nonlinear for nm in names], dtype=bool)
        self.ranges = np.array([q.upper - q.lower for q, f in zip(mm.params, free) if f])
        self._last = (None, None, None)

    def p(self, z):
        p = self.p_base.copy()
        p[self.free] = z * self.scale
        return p

    def _evaluate(self, z):
        """Residuals (n,) and dh/dz (n, k) at ``z`` from one batch call, the last kept: a
        Gauss-Newton step needs both at every accepted point."""
        z = np.asarray(z, dtype=float)
        if not np.array_equal(self._last[0], z):
            hJ = _residual_jacobian(self.mm)(self.p(z), self.X, self.jit)
            self._last = (z.copy(), self.y - hJ[:, 0], hJ[:, 1:][:, self.free] * self.scale[None, :])
        return self._last[1], self._last[2]

    def residual(self, z):
        return self._evaluate(z)[0]

    def jacobian(self, z):
        """dh/dz (n, k), rad per display unit."""
        return self._evaluate(z)[1]

    def inside(self, z):
        """Whether ``z`` lies strictly within the bounds (no bound can bind there)."""
        return bool(np.all(z > self.lb) and np.all(z < self.ub))

    def objective(self, z, w, r=None):
        """chi2 (data and prior) at ``z``; ``r``: the residuals there, when known."""
        r = w * (self.residual(z) if r is None else r)
        e = self.L @ z - self.Lmu
        return float(r @ r + e @ e)


@lru_cache(maxsize=64)
def _residual_jacobian(mm):
    """Batch evaluator of ``[h, dh/dp]`` (n, 1 + n_p) for ``mm``: one Function whose Jacobian
    shares the heading's expression graph, so both cost about what the Jacobian alone does."""
    p = ca.SX.sym("p", len(mm.names))
    x = ca.SX.sym("x", mm.n_x)
    h = mm.h(p, x)
    return BatchEvaluator(ca.Function("hJ", [p, x], [ca.densify(ca.vertcat(h, ca.jacobian(h, p).T))],
                                      ["p", "x"], ["h_dh_dp"]), exact=True)


def _setup(mm, runs, fix, bounds, constraints, prior, notes, start=None):
    """Build the :class:`_Problem` pieces from the user's fix/bounds/constraints/prior."""
    names = list(mm.names)
    fix = dict(fix or {})
    p_base = mm.vector({**(start or {}), **fix})
    free = np.array([nm not in fix for nm in names])
    values = p_base / mm.scale
    lower = np.full(len(names), -np.inf)
    upper = np.full(len(names), np.inf)
    user_bounded = set()
    for nm, b in dict(bounds or {}).items():
        i = mm.parameter_index(nm)
        try:
            lo, hi = (-np.inf if b[0] is None else float(b[0])), (np.inf if b[1] is None else float(b[1]))
        except (TypeError, ValueError, IndexError):
            raise ValueError(f"bound of {nm!r} must be (lower, upper) in {mm.params[i].unit}, "
                             f"got {b!r}") from None
        if math.isnan(lo) or math.isnan(hi) or lo > hi:
            raise ValueError(f"bound of {nm!r}: need lower <= upper, got {lo} and {hi} "
                             f"{mm.params[i].unit}")
        if not free[i] and not lo <= values[i] <= hi:
            raise ValueError(f"parameter {nm!r} is fixed at {values[i]:g} {mm.params[i].unit}, outside "
                             f"its bound [{lo:g}, {hi:g}]")
        lower[i], upper[i] = lo, hi
        user_bounded.add(nm)
    for i, q in enumerate(mm.params):
        if free[i] and q.name in mm.nonlinear and q.name not in user_bounded:
            lower[i], upper[i] = q.lower, q.upper
            notes.append(f"{q.name} (nonlinear) searched within its declared range "
                         f"[{q.lower:g}, {q.upper:g}] {q.unit}")
    lower[~free] = upper[~free] = values[~free]

    k = int(free.sum())
    idx = {nm: j for j, nm in enumerate(np.array(names)[free])}
    rows_eq, b_eq, rows_in, l_in, u_in, kept = [], [], [], [], [], []
    for c in constraints or ():
        if not isinstance(c, Constraint):
            raise ValueError(f"constraints must be Constraint records, got {type(c).__name__}")
        row, shift = np.zeros(k), 0.0
        for nm, coef in c.coefficients:
            i = mm.parameter_index(nm)
            if free[i]:
                row[idx[nm]] += coef
            else:
                shift += coef * values[i]
        if not row.any():
            if not c.lower - 1e-12 <= shift <= c.upper + 1e-12:
                raise ValueError(f"constraint {c} fails for the fixed values ({shift:g})")
            continue
        kept.append(c)
        if c.is_equality:
            rows_eq.append(row)
            b_eq.append(c.lower - shift)
        else:
            rows_in.append(row)
            l_in.append(c.lower - shift)
            u_in.append(c.upper - shift)

    if prior is not None:
        if isinstance(prior, FitResult):
            prior = Prior.from_fit(prior)
        if not isinstance(prior, Prior):
            raise ValueError(f"prior must be a Prior or a FitResult, got {type(prior).__name__}")
        free_names = list(np.array(names)[free])
        used, dropped = prior.restrict(free_names)
        if dropped:
            notes.append(f"prior on {', '.join(dropped)} not used (not free in this model; "
                         f"marginalised)")
        if not used.names:
            raise ValueError(f"{prior.source}: the prior names none of the free parameters "
                             f"({', '.join(free_names)})")
        notes.append(f"Gaussian prior from {prior.source} on {', '.join(used.names)}")
        F, b = used.fisher(free_names)
        lam, V = np.linalg.eigh(F)
        keep = lam > 1e-12 * lam.max()
        L = (np.sqrt(lam[keep])[:, None] * V[:, keep].T)
        Lmu = L @ (np.linalg.pinv(F) @ b)
    else:
        L, Lmu = np.zeros((0, k)), np.zeros(0)
    arr = lambda rows: np.array(rows, dtype=float).reshape(-1, k)  # noqa: E731
    return (p_base, free, lower, upper, arr(rows_eq), np.array(b_eq, dtype=float), arr(rows_in),
            np.array(l_in, dtype=float), np.array(u_in, dtype=float), L, Lmu, tuple(kept))


#: chi2 changes below this are rounding, not fit: the gyrocompass heading carries ~1e-12
#: relative rounding (Earth rate read out of a rate 1e4 times larger)
_CHI2_NOISE = 1e-6


# -- Gauss-Newton with QR on the active set ------------------------------------------------------
def _gauss_newton(prob, w, z, C, d, max_iter=50, mask=None, tol=1e-6, box=False):
    """Minimise ``|w r(z)|^2 + |L z - Lmu|^2`` subject to ``C z = d`` by Gauss-Newton, each step
    by QR in the null space of ``C``. ``mask`` (k,) bool: only those parameters move.
    Converged when a step is below ``tol`` of every parameter's sigma. ``box``: give up (not
    converged) as soon as a step leaves the open box of the bounds, where the solution of
    the bounded problem is another one (IPOPT's).

    Returns ``(z, converged)``.
    """
    k = prob.k
    mask = np.ones(k, bool) if mask is None else mask
    # the parameters outside the mask are held: add them to the equalities
    held = np.eye(k)[~mask]
    C = np.vstack([C.reshape(-1, k), held])
    d = np.concatenate([np.asarray(d, dtype=float).ravel(), z[~mask]])
    Z = null_space(C, k)
    z = z + np.linalg.pinv(C) @ (d - C @ z) if C.shape[0] else z.copy()
    m = Z.shape[1]
    if m == 0:
        return z, True
    r = prob.residual(z)
    f_old = prob.objective(z, w, r)
    for _ in range(max_iter):
        M = np.vstack([w[:, None] * prob.jacobian(z), prob.L]) @ Z
        rhs = np.concatenate([w * r, prob.Lmu - prob.L @ z])
        R_aug = np.linalg.qr(np.column_stack([M, rhs]), mode="r")  # Q' rhs in the last column
        R = R_aug[:m, :m]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            step = Z @ solve_triangular(R, R_aug[:m, m], check_finite=False)
            # converged when the step is a negligible fraction of each parameter's sigma
            std = np.linalg.norm(Z @ solve_triangular(R, np.eye(m), check_finite=False), axis=1)
        if not np.all(np.isfinite(step)) or (box and not prob.inside(z + step)):
            return z, False
        if np.all(np.abs(step) <= tol * std + 1e-14 * np.abs(z)):
            return z + step, True
        t = 1.0
        while True:  # step halving keeps the objective from rising on a nonlinear model
            z_new = z + t * step
            r_new = prob.residual(z_new)
            f_new = prob.objective(z_new, w, r_new)
            if f_new <= f_old + _CHI2_NOISE or t < 1e-3:
                break
            t *= 0.5
        z, r, f_old = z_new, r_new, f_new
    return z, False


# -- IPOPT with a Gauss-Newton Hessian -----------------------------------------------------------
#: IPOPT finds the active set and a point within ~1e-4 sigma of the optimum (variables are
#: scaled to sigma units); the Gauss-Newton polish converges from there. Tighter IPOPT
#: tolerances only make its line search fight the rounding of chi2 (see _CHI2_NOISE).
_IPOPT_OPTIONS = {"ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": False,
                  "ipopt.tol": 1e-6, "ipopt.acceptable_tol": 1e-4, "ipopt.acceptable_iter": 1,
                  "ipopt.compl_inf_tol": 1e-8, "ipopt.acceptable_compl_inf_tol": 1e-7,
                  "ipopt.bound_relax_factor": 0.0,
                  "ipopt.honor_original_bounds": "yes", "ipopt.max_iter": 200,
                  "ipopt.mu_strategy": "adaptive"}


@lru_cache(maxsize=32)
def _nlp_solver(mm, n, free_key, m, r, linear, jit):
    """The IPOPT solver for ``mm`` over ``n`` runs, free set ``free_key``, ``m`` linear
    constraint rows and an ``r``-row prior; data enter as NLP parameters (built once)."""
    free = np.array(free_key, dtype=bool)
    k, n_p, n_x = int(free.sum()), len(free), mm.n_x
    sizes = [("X", n_x * n), ("y", n), ("w", n), ("p0", n_p), ("L", r * k), ("Lmu", r), ("A", m * k),
             ("D", k)]
    P = ca.MX.sym("P", sum(s for _, s in sizes))
    parts, i = {}, 0
    for name, s in sizes:
        parts[name] = P[i:i + s]
        i += s
    X = ca.reshape(parts["X"], n_x, n)
    y, w, p0 = parts["y"], parts["w"], parts["p0"]
    L, Lmu, A = ca.reshape(parts["L"], r, k), parts["Lmu"], ca.reshape(parts["A"], m, k)
    v = ca.MX.sym("v", k)  # the variables: z (display units) = D v, D ~ each parameter's sigma
    z = parts["D"] * v
    S = ca.DM(np.eye(n_p)[:, free] * mm.scale[free][None, :])  # z (display) -> p (SI)
    p = p0 + ca.mtimes(S, z)
    res = w * (y - mm.predict_graph(p, X, jit).T)
    e = ca.mtimes(L, z) - Lmu
    f = 0.5 * (ca.sumsqr(res) + ca.sumsqr(e))
    Jv = -ca.mtimes(ca.transpose(S * ca.repmat(ca.transpose(parts["D"]), n_p, 1)),
                    mm.jacobian_graph(p, X, jit)) * ca.repmat(ca.transpose(w), k, 1)  # dres/dv'
    LD = L * ca.repmat(ca.transpose(parts["D"]), r, 1)
    grad = ca.mtimes(Jv, res) + ca.mtimes(ca.transpose(LD), e)
    H = ca.mtimes(Jv, ca.transpose(Jv)) + ca.mtimes(ca.transpose(LD), LD)
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", m)
    opts = dict(_IPOPT_OPTIONS)
    opts["grad_f"] = ca.Function("nlp_grad_f", [v, P], [f, grad], ["x", "p"], ["f", "grad_f_x"])
    opts["hess_lag"] = ca.Function("nlp_hess_l", [v, P, lam_f, lam_g], [ca.triu(lam_f * H)],
                                   ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])
    if linear:
        opts["ipopt.hessian_constant"] = "yes"
    if m:
        opts["ipopt.jac_c_constant"] = opts["ipopt.jac_d_constant"] = "yes"
    nlp = {"x": v, "p": P, "f": f}
    if m:
        nlp["g"] = ca.mtimes(A, z)
    return ca.nlpsol(f"fit_{n}", "ipopt", nlp, opts)


def _ipopt(prob, w, z0):
    """Solve with IPOPT; return ``(z, lam_x, lam_g)``. Raises :class:`SolverError`."""
    mm, n = prob.mm, prob.y.size
    A = np.vstack([prob.A_eq, prob.A_in])
    m, r = A.shape[0], prob.L.shape[0]
    solver = _nlp_solver(mm, n, tuple(bool(b) for b in prob.free), m, r, not prob.nonlinear.any(),
                         prob.jit)
    p0 = np.where(prob.free, 0.0, prob.p_base)  # the NLP adds the free part
    z0 = np.clip(z0, prob.lb, prob.ub)
    # variables in units of each parameter's sigma at the start: IPOPT's tolerances then mean
    # the same for every parameter
    a = np.sqrt(np.sum((w[:, None] * prob.jacobian(z0)) ** 2, axis=0) + np.sum(prob.L ** 2, axis=0))
    D = np.where(a > 0, 1 / np.where(a > 0, a, 1), np.where(np.isfinite(prob.ub - prob.lb),
                                                             prob.ub - prob.lb, 1.0))
    P = np.concatenate([prob.X.ravel(order="F"), prob.y, w, p0, prob.L.ravel(order="F"),
                        prob.Lmu, A.ravel(order="F"), D])
    args = {"x0": z0 / D, "p": P, "lbx": prob.lb / D, "ubx": prob.ub / D}
    if m:
        args["lbg"] = np.concatenate([prob.b_eq, prob.l_in])
        args["ubg"] = np.concatenate([prob.b_eq, prob.u_in])
    sol = solver(**args)
    stats = solver.stats()
    if not stats["success"]:
        status = stats["return_status"]
        if status in ("Infeasible_Problem_Detected", "Restoration_Failed") and m:
            raise ValueError(f"the bounds and constraints cannot all hold (IPOPT: {status}); check "
                             f"them against each other")
        raise SolverError("IPOPT did not solve the fit", status)
    return (np.array(sol["x"]).ravel() * D, np.array(sol["lam_x"]).ravel() / D,
            np.array(sol["lam_g"]).ravel()[prob.A_eq.shape[0]:], stats["return_status"], D)


def _active_set(prob, z, lam_x, lam_g, D):
    """Rows ``(C, d)`` of the equalities, binding bounds and active inequalities, with the
    binding parameter indices and active inequality indices. A bound is active when the
    solution is within 1e-5 sigma of it (``D``: sigma per parameter) and its multiplier
    pushes against it."""
    tol = 1e-5
    lam_tol = 1e-8 * max(1.0, np.abs(lam_x * D).max(initial=0.0), np.abs(lam_g).max(initial=0.0))
    at_lo = np.isfinite(prob.lb) & ((z - prob.lb) / D <= tol) & (lam_x * D < -lam_tol)
    at_hi = np.isfinite(prob.ub) & ((prob.ub - z) / D <= tol) & (lam_x * D > lam_tol)
    g = prob.A_in @ z
    g_sigma = np.sqrt(np.sum((prob.A_in * D[None, :]) ** 2, axis=1))  # sigma of each combination
    g_lo = np.isfinite(prob.l_in) & ((g - prob.l_in) / g_sigma <= tol) & (lam_g < -lam_tol)
    g_hi = np.isfinite(prob.u_in) & ((prob.u_in - g) / g_sigma <= tol) & (lam_g > lam_tol)
    binding = np.flatnonzero(at_lo | at_hi)
    bound_val = np.where(at_lo, prob.lb, prob.ub)[binding]
    act = np.flatnonzero(g_lo | g_hi)
    act_val = np.where(g_lo, prob.l_in, prob.u_in)[act]
    C = np.vstack([prob.A_eq, np.eye(prob.k)[binding], prob.A_in[act]])
    d = np.concatenate([prob.b_eq, bound_val, act_val])
    return C, d, binding, bound_val, act


def _feasible(prob, z, eps=1e-9):
    g = prob.A_in @ z
    tol = lambda b: eps * (1 + np.abs(np.where(np.isfinite(b), b, 0)))  # noqa: E731
    return bool(np.all(z >= prob.lb - tol(prob.lb)) and np.all(z <= prob.ub + tol(prob.ub))
                and np.all(g >= prob.l_in - tol(prob.l_in)) and np.all(g <= prob.u_in + tol(prob.u_in)))


def _solve(prob, w, z, notes):
    """One weighted solve. Returns ``(z, C_active, binding, active, method, status)``.

    Without inequality constraints, Gauss-Newton first: when it converges strictly inside the
    bounds (nonlinear parameters always have some), no bound binds and that is the bounded
    problem's solution too. Otherwise (and with inequalities) IPOPT finds the active set.
    """
    bounded = bool(np.isfinite(prob.lb).any() or np.isfinite(prob.ub).any())
    if not prob.A_in.shape[0]:
        z_gn, ok = _gauss_newton(prob, w, z, prob.A_eq, prob.b_eq, box=bounded)
        if ok:
            method = "gauss-newton" if prob.nonlinear.any() else "qr"
            return z_gn, prob.A_eq, np.zeros(0, int), np.zeros(0, int), method, "converged"
        if not bounded and not prob.nonlinear.any():
            raise SolverError("Gauss-Newton did not converge in 50 steps", "max_iter")
    z_ip, lam_x, lam_g, status, D = _ipopt(prob, w, z)
    C, d, binding, bound_val, act = _active_set(prob, z_ip, lam_x, lam_g, D)
    z_pol, ok = _gauss_newton(prob, w, z_ip, C, d)
    z_pol[binding] = bound_val
    if ok and _feasible(prob, z_pol) and prob.objective(z_pol, w) <= prob.objective(z_ip, w) + _CHI2_NOISE:
        return z_pol, C, binding, act, "ipopt", status
    notes.append("the Gauss-Newton polish on IPOPT's active set was not accepted; IPOPT's solution kept")
    return z_ip, C, binding, act, "ipopt", status


def _huber(u, c):
    """Huber weights ``min(1, c/|u|)`` of standardised residuals ``u``."""
    a = np.abs(u)
    return np.where(a <= c, 1.0, c / np.maximum(a, 1e-300))


def _mad_scale(res):
    return 1.4826 * float(np.median(np.abs(res - np.median(res))))


# -- the fit ------------------------------------------------------------------------------------
def fit(runs, model=None, *, fix=None, tilt_known=None, bounds=None, constraints=(), prior=None,
        robust=False, huber_c=HUBER_C, max_iter=100, jit=None, start=None):
    """Calibrate ``model`` on ``runs`` by weighted least squares.

    Parameters
    ----------
    runs : hse_opt.data.Runs
    model : Model, str or sequence of str, optional
        Default: the paper's model (``hse``). See :func:`as_model`.
    fix : mapping name -> value (display unit), optional
        Parameters held at a value.
    tilt_known : bool, optional
        Use the runs' pitch/roll (default: when the runs have them).
    bounds : mapping name -> (lower, upper), optional
        Display units; ``None`` for an open side. Nonlinear parameters default to their
        declared range.
    constraints : sequence of Constraint, optional
        Linear equalities and inequalities between parameters.
    prior : Prior or FitResult, optional
        Gaussian prior information, e.g. the previous calibration (on-line update).
    robust : bool
        Huber loss instead of squares; ``huber_c`` is its threshold in sigmas.
    max_iter : int
        Iterations of the robust reweighting.
    jit : bool, optional
        Compile the model's batch Functions with the C compiler (a one-off ~1 s per model and
        batch size, then several times faster): default for 5000 runs and more; worth it for
        repeated fits of the same model, such as on-line updates.
    start : mapping name -> value (display unit), optional
        Where the iteration starts for free parameters (default: their nominal values); needed
        when a parameter's signature vanishes at the nominal values of the others.

    Returns
    -------
    FitResult

    Raises
    ------
    UnidentifiableError
        The runs cannot separate some free parameters (named, with runs that would).
    SolverError
        The solver failed (its status in the message and ``.status``).
    ValueError
        Bad arguments, infeasible constraints, too few runs.
    """
    model = as_model(model)
    if runs.surveyed is not None:
        raise ValueError(f"{runs.source}: rows without azimuth_deg (unsurveyed positions) are not "
                         "supported by the fit yet; allowed: azimuth_deg in every row")
    if tilt_known is None:
        tilt_known = runs.pitch is not None
    if tilt_known and runs.pitch is None:
        raise ValueError(f"{runs.source}: tilt_known=True needs pitch_arcsec/roll_arcsec columns")
    if not huber_c > 0:
        raise ValueError(f"huber_c must be > 0 sigma, got {huber_c}")
    mm = model.measurement(tilt_known)
    X = mm.inputs_from_runs(runs)
    y = np.asarray(runs.heading_err, dtype=float)
    n = y.size
    notes = list(runs.notes)
    if tilt_known is False and runs.pitch is not None:
        notes.append("pitch/roll given but not used: tilt-coupled terms fitted as free C23 coefficients")
    (p_base, free, lower, upper, A_eq, b_eq, A_in, l_in, u_in, L, Lmu,
     kept) = _setup(mm, runs, fix, bounds, constraints, prior, notes, start)
    k = int(free.sum())
    if k == 0:
        raise ValueError("every parameter is fixed: nothing to fit")
    prob = _Problem(mm, X, y, p_base, free, lower[free], upper[free], A_eq, b_eq, A_in, l_in, u_in,
                    L, Lmu, jit)
    r_prior = L.shape[0]
    k_eq = np.linalg.matrix_rank(A_eq) if A_eq.size else 0
    if n + r_prior <= k - k_eq:
        raise ValueError(f"{runs.source}: {n} runs cannot fit {k - k_eq} free parameters "
                         f"({', '.join(prob.names)}); need more runs than parameters")

    sigma, weighting, more = run_sigma(runs, robust, mm)
    notes += more
    units_free = [q.unit for q, f in zip(mm.params, free) if f]

    def advice_for(mask):
        full = free.copy()
        full[free] = mask

        def advice(direction):
            return separation_advice(mm, prob.p(z), X, full, direction)
        return advice

    # identifiability of the linear part before solving (nonlinear parameters held)
    z = np.clip(p_base[free] / prob.scale, prob.lb, prob.ub)
    lin = ~prob.nonlinear
    eq_lin = A_eq[:, lin][~np.any(A_eq[:, ~lin] != 0, axis=1)] if A_eq.size else np.zeros((0, int(lin.sum())))

    def check_start(z):
        J0 = prob.jacobian(z)
        A0 = J0[:, lin] / sigma[:, None]
        analyse(blind_out(A0.T @ A0, invisible(J0, prob.ranges)[lin]) + L[:, lin].T @ L[:, lin],
                np.array(prob.names)[lin], np.array(units_free)[lin],
                advice=advice_for(lin), Z=null_space(eq_lin, int(lin.sum())))

    # a bilinear effect (the encoder harmonics act through lambda2) has no heading signature
    # where the parameters it multiplies start at 0: solve the others first
    blind = lin & invisible(prob.jacobian(z), prob.ranges)
    if blind.any() and (lin & ~blind).any() and not A_eq.size:
        z, _ = _gauss_newton(prob, 1 / sigma, z, np.zeros((0, k)), np.zeros(0), mask=lin & ~blind)
    check_start(z)
    if prob.nonlinear.any():  # start: the linear parameters solved with the nonlinear ones held
        eq_rows = ~np.any(A_eq[:, ~lin] != 0, axis=1) if A_eq.size else np.zeros(0, bool)
        z, _ = _gauss_newton(prob, 1 / sigma, z, A_eq[eq_rows], b_eq[eq_rows], max_iter=1, mask=lin)
        z = np.clip(z, prob.lb, prob.ub)

    # solve; with robust weights or a sigma estimated from the residuals, re-solve until the
    # weights settle (the sigma matters to the solution only against a prior, and to IPOPT's
    # tolerances)
    hw = np.ones(n)
    if robust:
        notes.append(f"Huber loss, threshold {huber_c:g} sigma (iteratively reweighted)")
    for _ in range(max_iter):
        z, C, binding, act, method, status = _solve(prob, np.sqrt(hw) / sigma, z, notes)
        res = prob.residual(z)
        k_eff = null_space(C, k).shape[1]
        dof = n + r_prior - k_eff
        if dof <= 0:
            raise ValueError(f"{runs.source}: no degrees of freedom left ({n} runs, {k_eff} free "
                             "directions)")
        new_sigma = sigma
        if weighting in ("residual", "robust-scale"):
            s = np.sqrt(np.sum(res ** 2) / dof) if weighting == "residual" else _mad_scale(res)
            if s <= 0:
                raise ValueError(f"{runs.source}: the model fits the runs exactly; sigma cannot be "
                                 "estimated from the residuals (give heading_std_arcsec)")
            new_sigma = np.full(n, s)
        new_hw = _huber(res / new_sigma, huber_c) if robust else hw
        settled = (np.max(np.abs(new_hw - hw)) < 1e-7  # ~1e-7/n sigma on the estimates
                   and np.max(np.abs(new_sigma / sigma - 1)) < 1e-6)
        sigma, hw = new_sigma, new_hw
        if settled or not (robust or (weighting == "residual" and (r_prior > 0 or method == "ipopt"))):
            break
    else:
        raise SolverError(f"the weights did not settle in {max_iter} re-solves", "max_iter")
    if robust:
        method += "+huber"
    if weighting == "residual":
        notes.append(f"sigma {sigma[0] / units.ARCSEC:.3g} arcsec estimated from the residuals")
    elif weighting == "robust-scale":
        notes.append(f"sigma {sigma[0] / units.ARCSEC:.3g} arcsec from the residuals' median absolute "
                     "deviation")
    Z = null_space(C, k)

    A = prob.jacobian(z) / sigma[:, None]
    F_data = A.T @ A
    u = res / sigma
    if robust:
        psi, dpsi = np.clip(u, -huber_c, huber_c), (np.abs(u) <= huber_c).astype(float)
        m_ = dpsi.mean()
        if m_ == 0:
            raise ValueError(f"{runs.source}: every run is beyond the Huber threshold; raise huber_c")
        K = 1 + k_eff / n * dpsi.var() / m_ ** 2
        F_data = F_data / (K ** 2 * np.sum(psi ** 2) / max(n - k_eff, 1) / m_ ** 2)
    info = analyse(blind_out(F_data, invisible(A * sigma[:, None], prob.ranges)) + L.T @ L,
                   prob.names, units_free, advice=advice_for(np.ones(k, bool)), Z=Z)

    n_p = len(mm.names)
    cov = np.zeros((n_p, n_p))
    cov[np.ix_(free, free)] = info.covariance
    corr = np.zeros((n_p, n_p))
    corr[np.ix_(free, free)] = info.correlation
    std = np.sqrt(np.diag(cov))
    e = L @ z - Lmu
    chi2_prior = float(e @ e)
    chi2 = float(u @ u) + chi2_prior
    ll_term = n * np.log(np.sum(res ** 2) / n) + chi2_prior if weighting == "residual" else chi2
    binding_names = tuple(str(prob.names[j]) for j in binding)
    for nm in binding_names:
        notes.append(f"{nm} is held at its bound (std 0: the bound, not the data, sets it)")
    inequalities = [c for c in kept if not c.is_equality]
    active = tuple(str(inequalities[j]) for j in act)
    order = np.argsort(hw, kind="stable")
    down = tuple(int(runs.run[i]) for i in order if hw[i] < 1 - 1e-12)
    p = prob.p(z)
    return FitResult(
        model=model, tilt_known=tilt_known, names=mm.names, units=tuple(q.unit for q in mm.params),
        values=p / mm.scale, std=std, covariance=cov, correlation=corr, free=free, p=p,
        run=np.asarray(runs.run), residuals=res, sigma=sigma, standardized=u,
        chi2=chi2, dof=int(dof), chi2_red=chi2 / dof, aic=ll_term + 2 * k_eff,
        bic=ll_term + k_eff * np.log(n), condition=info.condition, weighting=weighting,
        method=method, status=status, binding=binding_names, downweighted=down, notes=tuple(notes),
        lower=lower, upper=upper, constraints=kept, active=active, weights=hw, chi2_prior=chi2_prior)


# -- compensation -------------------------------------------------------------------------------
def compensated_parameters(fit_result):
    """The parameters whose error a compensation removes: every parameter of the system
    (sensor, encoder, processing, thermal effects) except the stand's own errors - the
    ``offset`` of the b0 zero mark against the stand and the ``reference``-level effects
    (stand azimuth reading errors, covariate offsets)."""
    mm = fit_result.measurement
    stand = {"offset"}
    for e in fit_result.model.effects:
        if e.level == "reference":
            stand.update(q.name for q in e.params)
    return tuple(nm for nm in mm.names
                 if nm not in stand and nm.split("*", 1)[0] not in stand)


def compensation(runs, fit_result, parameters=None):
    """The modelled heading error of each run that compensation removes, and its 1-sigma.

    Parameters
    ----------
    runs : hse_opt.data.Runs
        Alignments to compensate (any position, rate or latitude). A tilt-known fit needs
        their pitch/roll (Eq. 14 uses each alignment's own leveling); a tilt-unknown fit's
        C23 coefficients hold for the stand it was calibrated on.
    fit_result : FitResult
    parameters : sequence of str, optional
        Parameters whose error is removed (default :func:`compensated_parameters`); the
        others are set to their nominal (no-error) value, nonlinear ones kept as fitted.

    Returns
    -------
    correction, std : numpy.ndarray, shape (n,)
        Heading error (estimated - true) predicted from those parameters, rad, and its
        1-sigma from the fit's covariance, rad (the calibration's uncertainty, not the
        run's own noise; :func:`~hse_opt.information.propagated_std`).

    Raises
    ------
    ValueError
        The runs lack what the fit needs, or the fit's covariance is not positive
        semidefinite (a damaged FIT.json): the message names the parameters.
    """
    mm = fit_result.measurement
    if fit_result.tilt_known and runs.pitch is None:
        raise ValueError(f"{runs.source}: the calibration was fitted with known tilt; compensating "
                         "needs each run's pitch_arcsec/roll_arcsec (Eq. 14 uses C23 from leveling)")
    names = compensated_parameters(fit_result) if parameters is None else tuple(parameters)
    for nm in names:
        mm.parameter_index(nm)
    use = np.array([nm in names for nm in mm.names])
    keep = use | np.array([nm in mm.nonlinear for nm in mm.names])
    p = np.where(keep, fit_result.p, mm.nominal)
    X = mm.inputs_from_runs(runs)
    correction = mm.predict(p, X)
    Jd = mm.jacobian(p, X)[:, use] * mm.scale[use][None, :]
    C = np.asarray(fit_result.covariance)[np.ix_(use, use)]
    return correction, propagated_std(Jd, C, np.array(mm.names)[use])


def compensate(runs, fit_result, parameters=None):
    """``runs`` with the compensated heading error and its 1-sigma added as columns.

    ``heading_err_comp_arcsec`` = ``heading_err_arcsec`` minus the :func:`compensation`;
    ``heading_comp_std_arcsec`` = the compensation's 1-sigma from the fit's covariance. The
    other columns are unchanged. Raises ``ValueError`` when ``runs`` already has them.
    """
    for col in (COMPENSATED_COLUMN, COMPENSATION_STD_COLUMN):
        if col in runs.covariates:
            raise ValueError(f"{runs.source}, column '{col}': already present; allowed: runs without "
                             "it (compensate the uncompensated runs)")
    correction, std = compensation(runs, fit_result, parameters)
    return runs.replace(**{COMPENSATED_COLUMN: (runs.heading_err - correction) / units.ARCSEC,
                           COMPENSATION_STD_COLUMN: std / units.ARCSEC})


# -- FIT.json -------------------------------------------------------------------------------------
def _fit_json(fit_result):
    g = fit_result.model.geometry
    out = fit_result.to_dict()
    out.update({
        "format": FIT_FORMAT, "version": FIT_VERSION,
        "geometry": {"r_zb_s": g.r_zb_s.tolist(), "K_g": g.K_g.tolist()},
        "names": list(fit_result.names), "p_si": [float(v) for v in fit_result.p],
        "runs": {"run": [int(r) for r in fit_result.run],
                 "residual_arcsec": (fit_result.residuals / units.ARCSEC).tolist(),
                 "sigma_arcsec": (fit_result.sigma / units.ARCSEC).tolist(),
                 "weight": (fit_result.weights if fit_result.weights is not None
                            else np.ones(fit_result.n_runs)).tolist()},
    })
    return out


def save_fit(fit_result, path):
    """Write ``fit_result`` as FIT.json: the JSON contract plus what :func:`load_fit` needs to
    rebuild the model by effect names (geometry, full covariance, SI values, per-run residuals).
    Written whole (temporary file, then rename) or not at all."""
    from .data import write_text_atomic
    write_text_atomic(path, json.dumps(_fit_json(fit_result), indent=1, allow_nan=False) + "\n")


def load_fit(path, model=None):
    """Read FIT.json back into a :class:`FitResult`.

    The model is rebuilt from the file's effect names (catalogue effects and
    ``covariate:<column>``); pass ``model`` for effects of your own with the same names.
    """
    src = os.fspath(path)
    try:
        with open(src, encoding="utf-8") as fh:
            d = json.load(fh)
    except json.JSONDecodeError as err:
        raise ValueError(f"{src}: not JSON ({err}); allowed: a FIT.json written by hse-opt fit -o") from None
    if not isinstance(d, dict) or d.get("format") != FIT_FORMAT:
        raise ValueError(f"{src}: not a FIT.json (no \"format\": \"{FIT_FORMAT}\"); allowed: a file "
                         "written by hse-opt fit -o")
    if d.get("version") != FIT_VERSION:
        raise ValueError(f"{src}: FIT.json version {d.get('version')!r}; allowed: {FIT_VERSION}")
    try:
        geometry = Geometry(np.array(d["geometry"]["r_zb_s"]), np.array(d["geometry"]["K_g"]))
        if model is None:
            model = Model([make_effect(e) for e in d["effects"]], geometry)
        elif list(model.effect_names) != list(d["effects"]):
            raise ValueError(f"{src}: the file's effects {d['effects']} differ from the model's "
                             f"{list(model.effect_names)}")
        tilt_known = bool(d["tilt_known"])
        mm = model.measurement(tilt_known)
        names = tuple(d["names"])
        if names != mm.names:
            raise ValueError(f"{src}: parameters {list(names)} do not match the model's "
                             f"{list(mm.names)}")
        par = d["parameters"]
        get = lambda key: np.array([par[nm][key] for nm in names], dtype=float)  # noqa: E731
        bound = lambda key, inf: np.array([inf if par[nm][key] is None else par[nm][key]  # noqa: E731
                                           for nm in names], dtype=float)
        runs = d["runs"]
        residuals = np.array(runs["residual_arcsec"], dtype=float) * units.ARCSEC
        sigma = np.array(runs["sigma_arcsec"], dtype=float) * units.ARCSEC
        constraints = tuple(Constraint(c["coefficients"], -math.inf if c["lower"] is None else c["lower"],
                                       math.inf if c["upper"] is None else c["upper"])
                            for c in d.get("constraints", []))
        return FitResult(
            model=model, tilt_known=tilt_known, names=names, units=tuple(par[nm]["unit"] for nm in names),
            values=get("value"), std=get("std"), covariance=np.array(d["covariance"], dtype=float),
            correlation=np.array(d["correlation"], dtype=float),
            free=np.array([par[nm]["free"] for nm in names], dtype=bool),
            p=np.array(d["p_si"], dtype=float), run=np.array(runs["run"], dtype=np.int64),
            residuals=residuals, sigma=sigma, standardized=residuals / sigma,
            chi2=float(d["chi2"]), dof=int(d["dof"]), chi2_red=float(d["chi2_red"]),
            aic=float(d["aic"]), bic=float(d["bic"]), condition=float(d["condition"]),
            weighting=d["weighting"], method=d["method"], status=d["status"],
            binding=tuple(d["binding"]), downweighted=tuple(int(r) for r in d["downweighted"]),
            notes=tuple(d["notes"]), lower=bound("lower", -np.inf), upper=bound("upper", np.inf),
            constraints=constraints,
            active=tuple(str(c) for c, cd in zip(constraints, d.get("constraints", [])) if cd.get("active")),
            weights=np.array(runs["weight"], dtype=float), chi2_prior=float(d.get("chi2_prior", 0.0)))
    except (KeyError, TypeError) as err:
        raise ValueError(f"{src}: FIT.json is missing or has a malformed entry {err}; allowed: a file "
                         "written by hse-opt fit -o") from None


# -- the seam for reports ---------------------------------------------------------------------------
def report_data(fit_result, runs):
    """Everything a report shows about a fit, as plain data (display units).

    Returns a dict: ``fit`` (:meth:`FitResult.to_dict`), ``runs`` (columns ``run``,
    ``rate_dps``, ``azimuth_deg``, ``t_start_s``, ``heading_err_arcsec``,
    ``predicted_arcsec``, ``residual_arcsec``, ``standardized``, ``weight``,
    ``sigma_arcsec``) and ``parameters`` (rows of name, value, std, unit, free, bound state,
    description).
    """
    mm = fit_result.measurement
    if len(runs) != fit_result.n_runs or not np.array_equal(np.asarray(runs.run), fit_result.run):
        raise ValueError(f"{runs.source}: these runs are not the ones the fit used (run ids differ)")
    predicted = runs.heading_err - fit_result.residuals
    X = mm.inputs_from_runs(runs)
    rows = []
    for i, q in enumerate(mm.params):
        state = ("fixed" if not fit_result.free[i] else "at bound" if q.name in fit_result.binding
                 else "free")
        rows.append({"name": q.name, "value": float(fit_result.values[i]), "std": float(fit_result.std[i]),
                     "unit": q.unit, "state": state, "description": q.description})
    return {
        "fit": fit_result.to_dict(),
        "runs": {"run": fit_result.run.tolist(), "rate_dps": (runs.rate / units.DEG_PER_S).tolist(),
                 "azimuth_deg": (runs.azimuth / units.DEG).tolist(), "t_start_s": X[5].tolist(),
                 "heading_err_arcsec": (runs.heading_err / units.ARCSEC).tolist(),
                 "predicted_arcsec": (predicted / units.ARCSEC).tolist(),
                 "residual_arcsec": (fit_result.residuals / units.ARCSEC).tolist(),
                 "standardized": fit_result.standardized.tolist(),
                 "weight": (fit_result.weights if fit_result.weights is not None
                            else np.ones(fit_result.n_runs)).tolist(),
                 "sigma_arcsec": (fit_result.sigma / units.ARCSEC).tolist()},
        "parameters": rows,
    }
