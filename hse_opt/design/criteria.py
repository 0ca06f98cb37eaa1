"""Optimality criteria: losses of the information matrix, to be minimised.

A :class:`Criterion` writes its loss once with the matrix functions of an ``ops`` back end;
the same code then serves the convex program (:class:`CvxOps`, cvxpy), numeric values
(:class:`NumpyOps`) and derivatives for IPOPT (:class:`CasadiOps`, CasADi). D, A, E and c
(one parameter's variance) are the classic criteria; :class:`Discrimination` (T-optimality)
separates two models.
"""
from __future__ import annotations

import casadi as ca
import cvxpy as cp
import numpy as np
from scipy import sparse

from ..model.composition import as_model


class NotSmooth(Exception):
    """The criterion has no smooth (CasADi) form."""


class NumpyOps:
    """Matrix functions of the criteria, numerically (``inf``/``-inf`` where undefined)."""

    @staticmethod
    def log_det(F):
        L = _cholesky(F)
        return -np.inf if L is None else 2.0 * float(np.sum(np.log(np.diag(L))))

    @staticmethod
    def trace_inv(F):
        L = _cholesky(F)
        if L is None:
            return np.inf
        Li = np.linalg.inv(L)
        return float(np.sum(Li * Li))

    @staticmethod
    def matrix_frac(c, F):
        L = _cholesky(F)
        if L is None:
            return np.inf
        y = np.linalg.solve(L, np.asarray(c, dtype=float))
        return float(np.sum(y * y))

    @staticmethod
    def lambda_min(F):
        return float(np.linalg.eigvalsh(F)[0])

    @staticmethod
    def schur(F):
        F = np.asarray(F)
        if F.shape[0] == 1:
            return float(F[0, 0])
        sol = np.linalg.lstsq(F[:-1, :-1], F[:-1, -1], rcond=None)[0]
        return float(F[-1, -1] - F[-1, :-1] @ sol)


def _cholesky(F):
    try:
        return np.linalg.cholesky(np.asarray(F, dtype=float))
    except np.linalg.LinAlgError:
        return None


class Scaled:
    """An information matrix for cvxpy as ``F = D F' D``: ``F'`` (cvxpy, order-1 entries) and
    the column scales ``d`` (so that the conic solver sees well-scaled data)."""

    def __init__(self, Fp, d):
        self.F, self.d = Fp, np.asarray(d, float)

    @property
    def shape(self):
        return self.F.shape


class CvxOps:
    """The same functions as cvxpy expressions of a :class:`Scaled` information;
    auxiliary variables' constraints are collected in ``constraints``."""

    def __init__(self):
        self.constraints = []
        self.eigen_bounds = []  # (constraint, column scales) of each lambda_min: its dual is a supergradient

    @staticmethod
    def log_det(S):
        return cp.log_det(S.F) + 2.0 * float(np.sum(np.log(S.d)))

    def trace_inv(self, S):
        # tr(F^-1) = tr(D^-1 F'^-1 D^-1) = min tr(T) s.t. [[F', D^-1], [D^-1, T]] >= 0 (Schur complement)
        k = S.shape[0]
        T = cp.Variable((k, k), symmetric=True)
        Di = np.diag(1.0 / S.d)
        self.constraints.append(cp.bmat([[S.F, Di], [Di, T]]) >> 0)
        return cp.trace(T)

    @staticmethod
    def matrix_frac(c, S):
        c = np.asarray(c, dtype=float)
        return cp.matrix_frac(c / (S.d if c.ndim == 1 else S.d[:, None]), S.F)

    def lambda_min(self, S):
        # lambda_min(D F' D) >= t  <=>  F' - t D^-2 >= 0
        t = cp.Variable()
        self.constraints.append(S.F - t * np.diag(S.d ** -2.0) >> 0)
        self.eigen_bounds.append((self.constraints[-1], S.d))
        return t

    def schur(self, S):
        # F - t e e' >= 0 (e the last unit vector): the same conic data as the blocks of F
        # reassembled around the corner F_kk - t, without cvxpy slicing F's dense coefficients
        k = S.shape[0]
        t = cp.Variable()
        F = S.F
        if k == 1:
            self.constraints.append(F[0, 0] >= t)
        else:
            self.constraints.append(F - t * sparse.csc_matrix(([1.0], ([k - 1], [k - 1])), shape=(k, k)) >> 0)
        return t * S.d[-1] ** 2


class CasadiOps:
    """The same functions as CasADi (SX or MX) expressions, for IPOPT and derivatives."""

    @staticmethod
    def log_det(F):
        return ca.log(ca.det(F))

    @staticmethod
    def trace_inv(F):
        return ca.trace(ca.solve(F, ca.DM.eye(F.shape[0])))

    @staticmethod
    def matrix_frac(c, F):
        c = ca.DM(np.asarray(c, dtype=float))
        return ca.trace(ca.mtimes(c.T, ca.solve(F, c)))

    @staticmethod
    def lambda_min(F):
        raise NotSmooth("the smallest eigenvalue is not differentiable")

    @staticmethod
    def schur(F):
        if F.shape[0] == 1:
            return F[0, 0]
        return F[-1, -1] - ca.mtimes(F[-1, :-1], ca.solve(F[:-1, :-1], F[:-1, -1]))


NUMPY, CASADI = NumpyOps(), CasadiOps()


class Criterion:
    """An optimality criterion: a loss of the information matrix, to be minimised.

    Subclasses implement one hook, :meth:`loss`, with the matrix functions of ``ops`` (the
    same code then serves cvxpy, numpy and CasADi). Optional: :meth:`features` (the rows
    the information is built from, default the design model's weighted Jacobian) and
    :meth:`interest` (the parameters the run order protects from drift).

    Attributes
    ----------
    label : str
        Name in reports (``'D'``, ``'c:lambda2'`` ...).
    degree : int
        Homogeneity of the loss in the information: 0 for ``-log det`` (efficiency
        ``exp(-delta/k)``), -1 for a positive loss that falls as information grows (A, c:
        efficiency ``loss_ref/loss``), +1 for a negative loss (E, discrimination:
        ``loss/loss_ref``).
    needs_guard : bool
        The criterion's optimum may leave parameters unidentifiable (c, discrimination): the
        design then also keeps the model identifiable (see ``identify`` in :func:`design`).
    """

    label = ""
    degree = -1
    needs_guard = False

    def loss(self, F, ops, names):  # pragma: no cover - the required hook
        """Loss of the information ``F`` (k, k) whose rows/columns are ``names``."""
        raise NotImplementedError

    def features(self, model, tilt_known):
        """The rows the information is built from, or None for the design model's Jacobian.

        Returns ``(names, fn, values)``: column names; ``fn(p, x)``, a CasADi Function of the
        design model's SI parameters and one run's inputs giving the row (display units,
        before dividing by the heading sigma); parameter values (display units) that
        override the nominal ones at which ``fn`` is evaluated."""
        return None

    def interest(self, names):
        """Parameters whose drift bias the run order keeps small."""
        return tuple(names)

    # -- derived ----------------------------------------------------------------------
    def value(self, F, names):
        """Numeric loss of ``F``."""
        return float(self.loss(np.asarray(F, dtype=float), NUMPY, tuple(names)))

    def gradient(self, F, names):
        """d loss / dF (k, k), by CasADi's automatic differentiation of :meth:`loss`."""
        F = np.asarray(F, dtype=float)
        key = (F.shape[0], tuple(names))
        cache = self.__dict__.setdefault("_gradients", {})
        if key not in cache:
            S = ca.SX.sym("F", *F.shape)
            try:
                expr = self.loss(S, CASADI, key[1])
            except NotSmooth as err:
                raise ValueError(f"criterion {self.label}: no gradient ({err})") from None
            cache[key] = ca.Function("gradient", [S], [ca.gradient(expr, S)])
        return np.array(cache[key](F))

    def efficiency(self, loss, loss_ref, k):
        """Efficiency of a design with ``loss`` against one with ``loss_ref`` (k parameters)."""
        if self.degree == 0:
            return float(np.exp((loss_ref - loss) / k))
        if self.degree < 0:
            return float(loss_ref / loss) if np.isfinite(loss) else 0.0
        return float(loss / loss_ref)

    def __repr__(self):
        return f"<criterion {self.label}>"


class D(Criterion):
    """D-optimality: maximise det F (the volume of the confidence ellipsoid shrinks)."""

    label, degree = "D", 0

    def loss(self, F, ops, names):
        return -ops.log_det(F)


class A(Criterion):
    """A-optimality: minimise trace F^-1, the sum of the parameters' variances."""

    label = "A"

    def loss(self, F, ops, names):
        return ops.trace_inv(F)


class E(Criterion):
    """E-optimality: maximise the smallest eigenvalue of F (the worst-determined direction)."""

    label, degree = "E", 1

    def loss(self, F, ops, names):
        return -ops.lambda_min(F)

    def gradient(self, F, names):
        lam, vec = np.linalg.eigh(np.asarray(F, dtype=float))
        return -np.outer(vec[:, 0], vec[:, 0])  # exact where the smallest eigenvalue is simple


class C(Criterion):
    """c-optimality: minimise the variance of one named parameter (``c:lambda2``)."""

    needs_guard = True

    def __init__(self, name):
        self.name = str(name)
        self.label = f"c:{self.name}"

    def loss(self, F, ops, names):
        return ops.matrix_frac(unit_vector(names, self.name), F)

    def interest(self, names):
        return (self.name,)


class Protect(C):
    """The default criterion: c-optimality for one parameter (``protect:lambda2``) with every
    parameter of the model identified (the D-efficiency guard of :func:`design`) and power
    floors against the catalogue effects outside the model (:mod:`.protection`): the plan
    protects the calibration against what the model cannot see, where the budget allows."""

    protects = True

    def __init__(self, name="lambda2"):
        super().__init__(name)
        self.label = f"protect:{self.name}"


class LackOfFit(Criterion):
    """T-optimality on given rows: the last column is the difference of two models'
    predictions, the others the rival's Jacobian (all over the run sigma). The loss is minus
    the noncentrality of the rival's lack of fit, the Schur complement of the last column:
    how badly the rival, refitted, fits data from the other model (Atkinson & Fedorov 1975).
    For :func:`approximate_design` on rows built by the caller (e.g. two fitted models in
    :func:`hse_opt.diagnose.discriminating_runs`)."""

    label, degree, needs_guard = "T", 1, True

    def loss(self, F, ops, names):
        return -ops.schur(F)

    def interest(self, names):
        return ()


class Discrimination(LackOfFit):
    """T-optimal discrimination (Atkinson & Fedorov 1975): maximise how badly the ``rival``
    model fits data from the design model with the parameter values ``truth``.

    The loss is minus the noncentrality ``min_q sum_i w_i (h(p; x_i) - h_rival(q; x_i))^2 /
    sigma_i^2`` of the rival's lack of fit, with the rival linearised at its nominal values:
    the Schur complement of the information of the rows ``[J_rival, h - h_rival] / sigma``.
    Useful to tell competing effects apart (e.g. ``axis_bias`` against ``sync_delay``).

    Parameters
    ----------
    rival : Model, str or sequence of str
        The competing model (``as_model`` form: ``"hse,sync_delay"``).
    truth : mapping name -> value
        Design-model parameter values (display units) under which to separate the models;
        the rest at nominal.
    """

    degree = 1
    needs_guard = True

    def __init__(self, rival, truth):
        self.rival = as_model(rival)
        self.truth = dict(truth)
        if not self.truth:
            raise ValueError("discrimination needs the size of the effect to detect: truth={name: value}")
        self.label = f"T:{'+'.join(self.rival.effect_names)}"

    def features(self, model, tilt_known):
        ma, mb = model.measurement(tilt_known), self.rival.measurement(tilt_known)
        ma.vector(self.truth)  # names and values checked here
        p = ca.SX.sym("p", len(ma.names))
        x = ca.SX.sym("x", ma.n_x)
        q0 = mb.nominal
        row = ca.horzcat(mb.J(q0, x) * ca.DM(mb.scale).T, ma.h(p, x) - mb.h(q0, x))
        names = mb.names + ("(lack of fit)",)
        return names, ca.Function("discrimination_rows", [p, x], [row]), self.truth


def as_criterion(criterion):
    """A :class:`Criterion` from an instance or ``'D'``, ``'A'``, ``'E'``, ``'c:NAME'``,
    ``'protect'`` / ``'protect:NAME'``."""
    if isinstance(criterion, Criterion):
        return criterion
    text = str(criterion).strip()
    simple = {"D": D, "A": A, "E": E}
    if text.upper() in simple:
        return simple[text.upper()]()
    if text[:2].lower() == "c:" and text[2:].strip():
        return C(text[2:].strip())
    if text.lower() == "protect":
        return Protect()
    if text[:8].lower() == "protect:" and text[8:].strip():
        return Protect(text[8:].strip())
    raise ValueError(f"criterion {criterion!r} is not allowed; allowed: protect (the default, protect:lambda2), "
                     f"protect:NAME, D, A, E, c:NAME (a parameter name, e.g. c:lambda2), or a Criterion instance")


def unit_vector(names, name):
    names = list(names)
    if name not in names:
        raise ValueError(f"criterion c:{name}: unknown parameter {name!r}; allowed: c:NAME with NAME one of "
                         f"the model's parameters: {', '.join(names)}")
    e = np.zeros(len(names))
    e[names.index(name)] = 1.0
    return e

