"""One fit's least-squares problem: data, free set, bounds, constraints and prior over the free
parameters, with the residuals and Jacobian from one batch call of the model."""
import math
from functools import lru_cache

import numpy as np

from ..information import Prior
from ..model.measurement import BatchEvaluator
from .result import Constraint, FitResult


class Problem:
    """Data, free set, bounds, constraints and prior of one fit, in display units over the
    free parameters ``z`` (``p[free] = z * scale``). ``project``: a linear map applied to the
    residuals and the Jacobian (the elimination of the unsurveyed positions' constants,
    :func:`position_projector`)."""

    def __init__(self, mm, X, y, p_base, free, lb, ub, A_eq, b_eq, A_in, l_in, u_in, L, Lmu, jit,
                 project=None):
        self.mm, self.X, self.y, self.jit = mm, X, y, jit
        self.project = project
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

    def subset(self, runs):
        """The same problem on the runs ``runs`` (indices; no projector: the position
        elimination couples every run of a position)."""
        if self.project is not None:
            raise ValueError("a problem with a position projector cannot be subset")
        return Problem(self.mm, self.X[:, runs], self.y[runs], self.p_base, self.free, self.lb, self.ub,
                       self.A_eq, self.b_eq, self.A_in, self.l_in, self.u_in, self.L, self.Lmu, self.jit)

    def p(self, z):
        p = self.p_base.copy()
        p[self.free] = z * self.scale
        return p

    def _evaluate(self, z):
        """Residuals (n,) and dh/dz (n, k) at ``z`` from one batch call, the last kept: a
        Gauss-Newton step needs both at every accepted point."""
        z = np.asarray(z, dtype=float)
        if not np.array_equal(self._last[0], z):
            hJ = residual_jacobian(self.mm)(self.p(z), self.X, self.jit)
            r, J = self.y - hJ[:, 0], hJ[:, 1:][:, self.free] * self.scale[None, :]
            if self.project is not None:
                r, J = self.project(r), self.project(J)
            self._last = (z.copy(), r, J)
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
def residual_jacobian(mm):
    """Batch evaluator of ``[h, dh/dp]`` (n, 1 + n_p) for ``mm``: one Function whose Jacobian
    shares the heading's expression graph, so both cost about what the Jacobian alone does."""
    return BatchEvaluator(mm.hJ, exact=True, graph=mm.graph["hJ"])


def setup(mm, runs, fix, bounds, constraints, prior, notes, start=None):
    """Build the :class:`Problem` pieces from the user's fix/bounds/constraints/prior."""
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
            raise ValueError(f"bound of {nm!r} is {b!r}; allowed: (lower, upper) in {mm.params[i].unit}") from None
        if math.isnan(lo) or math.isnan(hi) or lo > hi:
            raise ValueError(f"bound of parameter {nm!r}: got {lo} and {hi} {mm.params[i].unit}; allowed: lower <= upper")
        if not free[i] and not lo <= values[i] <= hi:
            raise ValueError(f"parameter {nm!r} is fixed at {values[i]:g} {mm.params[i].unit}, outside "
                             f"its bound; allowed: a value in [{lo:g}, {hi:g}]")
        lower[i], upper[i] = lo, hi
        user_bounded.add(nm)
    for i, q in enumerate(mm.params):
        if free[i] and q.name in mm.nonlinear and q.name not in user_bounded:
            lower[i], upper[i] = q.lower, q.upper
            notes.append(f"{q.name} (nonlinear) searched within its declared range "
                         f"[{q.lower:g}, {q.upper:g}] {q.unit}")
    lower[~free] = upper[~free] = values[~free]

    k = int(free.sum())
    if k == 0:
        raise ValueError(f"every parameter is held ({', '.join(names)}: fix, --fix); nothing is left to "
                         "fit; allowed: at least one free parameter")
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


def position_projector(runs, sigma):
    """The exact elimination of each unsurveyed position's unknown constant.

    Each position without a heading reference (:meth:`hse_opt.data.Runs.reference_groups`)
    adds one unknown constant c_g to its runs' heading errors (its true heading, plus the
    offset). The constants enter linearly, so for any model parameters the best constants
    are the weighted means of the position's residuals, and the weighted least-squares
    problem in the model parameters alone is the original one with residuals and Jacobian
    replaced by their within-position deviations from those means (variable projection:
    ``P x = x - G (G' W G)^-1 G' W x``, ``G`` the rows' position indicators, ``W`` the
    weights ``1/sigma^2``). Its minimiser, chi-square and parameter covariance equal those
    of the problem with the constants as free parameters; the constants are never
    estimated or reported.

    Parameters
    ----------
    runs : hse_opt.data.Runs
    sigma : numpy.ndarray, shape (n,)
        Each run's heading sigma, rad (only relative values matter within a position).

    Returns
    -------
    project : callable or None
        ``project(x)`` for x of shape (n,) or (n, k); None when every run is surveyed.
    n_positions : int
        The number of constants eliminated.
    """
    group, labels = runs.reference_groups()
    if not labels:
        return None, 0
    rows = group >= 0
    g = group[rows]
    w = 1.0 / np.asarray(sigma, dtype=float)[rows] ** 2
    wsum = np.bincount(g, w, len(labels))

    def project(x):
        x = np.array(x, dtype=float)
        xr = x[rows]
        if xr.ndim == 1:
            mean = np.bincount(g, w * xr, len(labels)) / wsum
        else:
            mean = np.stack([np.bincount(g, w * xr[:, j], len(labels)) for j in range(xr.shape[1])], axis=1)
            mean /= wsum[:, None]
        x[rows] = xr - mean[g]
        return x
    return project, len(labels)
