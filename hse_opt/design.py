"""Experiment design: the calibration test plan that calibrates best in limited stand time.

A plan (``PLAN.csv``) is a sequence of alignments. Each run has a *setting* -- signed bias
rate Omega, stand azimuth psi, deliberate tilt of the turntable base (a tilt fixture, fixed in
b0) and alignment duration -- and adds ``a a^T`` to the Fisher information of the model's
parameters, ``a = (dh/dp) / sigma`` in display units (:mod:`hse_opt.information`; ``sigma``
is :func:`~hse_opt.information.heading_sigma` of the duration). A :class:`Criterion` turns
the information matrix into a loss; :func:`design` minimises it within a test-time budget:

1. **Candidates** -- every combination of the :class:`DesignSpace` factors (rate levels
   within the limits, one or both rotation senses, stand azimuths, tilt-fixture settings,
   durations).
2. **Approximate design** -- a convex program (cvxpy) over the number of runs ``w_i >= 0`` of
   every candidate, the alignment time linear: ``sum w_i (T_i + overhead) <= budget -
   warm-up``, ``sum w_i <= max_runs``. Certified by the general equivalence theorem: the
   Frank-Wolfe gap of the (Lagrangian) objective over all candidates bounds the loss of
   optimality (``ApproximateDesign.certified_efficiency``). Each conic solution is re-solved
   on its support with IPOPT (conic solvers leave ~1e-4 in the weights). The solver's
   ``problem.status`` is checked: a failure raises :class:`DesignError` with it; an
   ``optimal_inaccurate`` end is judged by the certificate (kept at >= 0.99, and said in the
   result's notes below 0.999).
3. **Exact design** -- the approximate design's support is first reduced (Caratheodory: same
   information matrices on fewer candidates), then rounded efficiently (Pukelsheim & Rieder
   1992, :func:`apportion`) to ``n`` whole runs, ``n`` the largest for which the plan with its
   setup times (:class:`Costs`) fits the budget, then polished by one-run exchanges. Setups
   are not linear in the run numbers: a greedy search drops stand positions while the rounded
   plan gets better (``prune``). The *efficiency* is measured against the approximate
   optimum for the same alignment time (``efficiency``) and for the whole budget
   (``budget_efficiency``, which also counts the time the setups take).
4. **Refinement** -- IPOPT (CasADi) moves the exact design's rates and azimuths off the
   candidate grid (runs sharing an azimuth or a rate keep sharing it, so setups do not grow).
5. **Run order** -- runs sharing a setting run together and settings are grouped by their
   most expensive factor, which keeps setup time low; among such orders (and folded ones,
   ABBA-like, where the budget has room for the extra setups) the one least sensitive to a
   slow linear heading drift is taken (``order='trend-robust'``), or the quickest
   (``'min-setup'``). The plan's start times ``t_start_s`` follow from the costs.
6. **Evaluation** -- :func:`evaluate` gives each parameter's predicted sigma for the final
   plan and the bias a linear heading drift of 1 arcsec/h would put on it.

Tilt modes. With the tilt known (``tilt_known=True``: pitch and roll from the alignments'
own leveling, as in the paper's step 3 and in simulated RUNS) lambda2 is a model parameter
and its heading signature is proportional to ``lambda1 C23``: the tilt of the base (the
:class:`Stand`'s own plus the fixture's) and the rate set its size. With the tilt unknown
the tilt-coupled parameters are free C23 coefficients (``lambda2*tilt_cos`` ...; see
:mod:`hse_opt.model.measurement`), which assume one tilt fixed in b0 for every run: a tilt
fixture is then not allowed.

Nonlinear parameters (e.g. ``warmup_tau``) enter the information at their nominal values
(``nominal``) or, robustly, the criterion is averaged over a prior sample of them
(``prior_sample``). Time since power-on is a factor when ``DesignSpace.time_slots`` > 1
(needed for ``warmup``): each candidate is seen at the middle of its slot; else at the middle
of the test. The final plan is always evaluated at its real start times.

:func:`monte_carlo` checks a plan's predicted sigmas with the numeric simulator: it
simulates the plan many times (:func:`hse_opt.sim.run_campaign`, in parallel), fits every
replicate and compares the empirical scatter of each estimate with the prediction.
"""
from __future__ import annotations

import itertools
import sys
import time
import types
import warnings
from dataclasses import dataclass

import casadi as ca
import cvxpy as cp
import numpy as np

from . import units
from .data import Plan
from .fit import as_model
from .information import (DEFAULT_ARW, Prior, UnidentifiableError, analyse, check_identifiable,
                          heading_sigma, separation_advice, weighted_jacobian)
from .model.measurement import BatchEvaluator, Model

__all__ = ["A", "ApproximateDesign", "C", "Candidates", "Costs", "Criterion", "D", "DesignError",
           "DesignResult", "DesignSpace", "Discrimination", "E", "Evaluation", "LackOfFit", "MonteCarloResult",
           "Stand", "apportion", "approximate_design", "as_criterion", "design", "evaluate", "monte_carlo",
           "paper_plan", "plan_lines"]


#: a heading drift of this size (rad/s) is the unit of the reported drift bias: 1 arcsec/h
DRIFT_UNIT = units.ARCSEC / units.HOUR
#: approximate-design weights below this fraction of the largest are solver noise
_SUPPORT_TOL = 1e-4
_SOLVERS = ("CLARABEL", "SCS")


class DesignError(RuntimeError):
    """A solver failed; the message carries its status."""


# =========================================================================== criteria
class _NotSmooth(Exception):
    """The criterion has no smooth (CasADi) form."""


class _Numpy:
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


class _Scaled:
    """An information matrix for cvxpy as ``F = D F' D``: ``F'`` (cvxpy, order-1 entries) and
    the column scales ``d`` (so that the conic solver sees well-scaled data)."""

    def __init__(self, Fp, d):
        self.F, self.d = Fp, np.asarray(d, float)

    @property
    def shape(self):
        return self.F.shape


class _Cvx:
    """The same functions as cvxpy expressions of a :class:`_Scaled` information;
    auxiliary variables' constraints are collected in ``constraints``."""

    def __init__(self):
        self.constraints = []

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
        return t

    def schur(self, S):
        k = S.shape[0]
        t = cp.Variable()
        F = S.F
        if k == 1:
            self.constraints.append(F[0, 0] >= t)
        else:
            corner = F[-1:, -1:] - cp.reshape(t, (1, 1), order="C")
            self.constraints.append(cp.bmat([[F[:-1, :-1], F[:-1, -1:]], [F[-1:, :-1], corner]]) >> 0)
        return t * S.d[-1] ** 2


class _Casadi:
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
        raise _NotSmooth("the smallest eigenvalue is not differentiable")

    @staticmethod
    def schur(F):
        if F.shape[0] == 1:
            return F[0, 0]
        return F[-1, -1] - ca.mtimes(F[-1, :-1], ca.solve(F[:-1, :-1], F[:-1, -1]))


_NUMPY, _CASADI = _Numpy(), _Casadi()


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
        return float(self.loss(np.asarray(F, dtype=float), _NUMPY, tuple(names)))

    def gradient(self, F, names):
        """d loss / dF (k, k), by CasADi's automatic differentiation of :meth:`loss`."""
        F = np.asarray(F, dtype=float)
        key = (F.shape[0], tuple(names))
        cache = self.__dict__.setdefault("_gradients", {})
        if key not in cache:
            S = ca.SX.sym("F", *F.shape)
            try:
                expr = self.loss(S, _CASADI, key[1])
            except _NotSmooth as err:
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
        return ops.matrix_frac(_unit_vector(names, self.name), F)

    def interest(self, names):
        return (self.name,)


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
    """A :class:`Criterion` from an instance or ``'D'``, ``'A'``, ``'E'``, ``'c:NAME'``."""
    if isinstance(criterion, Criterion):
        return criterion
    text = str(criterion).strip()
    simple = {"D": D, "A": A, "E": E}
    if text.upper() in simple:
        return simple[text.upper()]()
    if text[:2].lower() == "c:" and text[2:].strip():
        return C(text[2:].strip())
    raise ValueError(f"criterion {criterion!r} is not allowed; allowed: D, A, E, c:NAME (a parameter "
                     f"name, e.g. c:lambda2), or a Criterion instance")


def _unit_vector(names, name):
    names = list(names)
    if name not in names:
        raise ValueError(f"criterion c:{name}: unknown parameter {name!r}; this model has: "
                         f"{', '.join(names)}")
    e = np.zeros(len(names))
    e[names.index(name)] = 1.0
    return e


# ====================================================================== problem data
def _positive(name, value, allow_zero=False):
    v = float(value)
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ValueError(f"{name} = {value!r} is not allowed; allowed: a finite number "
                         f"{'>= 0' if allow_zero else '> 0'}")
    return v


@dataclass(frozen=True)
class Costs:
    """Stand-time costs of a plan, s.

    Attributes
    ----------
    warmup : float
        Before the first run (power-on to thermal steady state).
    azimuth_change : float
        Turning the stand to another azimuth (and settling).
    rate_change : float
        Changing the table rate or its sense.
    tilt_change : float
        Resetting the tilt fixture.
    run_overhead : float
        Per alignment beyond its duration (data saving, restart).
    """

    warmup: float = 3600.0
    azimuth_change: float = 600.0
    rate_change: float = 60.0
    tilt_change: float = 1200.0
    run_overhead: float = 0.0

    def __post_init__(self):
        for name in ("warmup", "azimuth_change", "rate_change", "tilt_change", "run_overhead"):
            object.__setattr__(self, name, _positive(f"costs.{name} (s)", getattr(self, name), True))

    def setups(self, rate, azimuth, tilt_x, tilt_y):
        """Setup time before each run (s, shape (n,); the first is the warm-up)."""
        rate, azimuth = np.asarray(rate, float), np.asarray(azimuth, float)
        out = np.zeros(rate.size)
        if rate.size == 0:
            return out
        out[0] = self.warmup
        d_az = np.abs(np.angle(np.exp(1j * np.diff(azimuth)))) > 1e-9
        d_tilt = (np.abs(np.diff(tilt_x)) > 1e-12) | (np.abs(np.diff(tilt_y)) > 1e-12)
        d_rate = np.abs(np.diff(rate)) > 1e-12
        out[1:] = self.azimuth_change * d_az + self.tilt_change * d_tilt + self.rate_change * d_rate
        return out

    def schedule(self, rate, azimuth, tilt_x, tilt_y, duration, not_before=None):
        """Start times since power-on (s, shape (n,)) of runs done in this order, each
        waiting, where given, until ``not_before`` (s)."""
        setup = self.setups(rate, azimuth, tilt_x, tilt_y)
        busy = np.concatenate([[0.0], np.asarray(duration, float)[:-1] + self.run_overhead])
        if not_before is None:
            return np.cumsum(setup + busy)
        t = np.empty(setup.size)
        prev = 0.0
        for i in range(setup.size):
            prev = t[i] = max(prev + busy[i] + setup[i], not_before[i])
        return t


@dataclass(frozen=True)
class Stand:
    """The test stand and system as the design sees them.

    Attributes
    ----------
    latitude : float
        rad (default 28.07 deg, the paper's 0.49 rad).
    tilt : tuple of 2 float
        Tilt of the turntable base on the stand, fixed in b0: ``(x, y)`` = (roll, pitch), rad,
        as the leveling measures it; a plan's ``tilt_x, tilt_y`` add to it. Default: the
        default simulated system's (-55, -120) arcsec.
    arw : float
        Gyro angle random walk, rad/sqrt(s) (heading noise model,
        :func:`~hse_opt.information.heading_sigma`).
    floor : float
        Run-to-run heading scatter beyond the noise, rad.
    """

    latitude: float = 28.07 * units.DEG
    tilt: tuple = (-55.0 * units.ARCSEC, -120.0 * units.ARCSEC)
    arw: float = DEFAULT_ARW
    floor: float = 0.0

    def __post_init__(self):
        tilt = tuple(float(v) for v in self.tilt)
        if len(tilt) != 2 or not all(np.isfinite(tilt)):
            raise ValueError(f"stand tilt = {self.tilt!r}; allowed: two finite angles (x roll, y pitch), rad")
        object.__setattr__(self, "tilt", tilt)
        if not abs(self.latitude) < np.pi / 2:
            raise ValueError(f"stand latitude = {self.latitude!r} rad; allowed: |latitude| < 90 deg")
        _positive("stand arw", self.arw, True)
        _positive("stand floor", self.floor, True)

    def sigma(self, duration):
        """1-sigma heading error of alignments of these durations, rad."""
        return heading_sigma(duration, self.latitude, self.arw, self.floor)

    def inputs(self, mm, rate, azimuth, tilt_x, tilt_y, duration, t_start):
        """Measurement-model inputs (n_x, n) of runs on this stand (SI arrays)."""
        n = np.size(rate)
        tilt_x = np.broadcast_to(np.asarray(tilt_x, float), (n,))
        tilt_y = np.broadcast_to(np.asarray(tilt_y, float), (n,))
        return mm.inputs(rate, azimuth, self.latitude, duration, t_start,
                         pitch=self.tilt[1] + tilt_y, roll=self.tilt[0] + tilt_x)


@dataclass(frozen=True)
class Candidates:
    """Candidate run settings (SI arrays of one length): ``rate`` (signed, rad/s),
    ``azimuth`` (rad), ``tilt_x``, ``tilt_y`` (fixture tilt, rad), ``duration`` (s) and the
    nominal ``t_start`` (s since power-on: the middle of the run's time slot) and
    ``not_before`` (s: the start of the slot, before which the run waits)."""

    rate: np.ndarray
    azimuth: np.ndarray
    tilt_x: np.ndarray
    tilt_y: np.ndarray
    duration: np.ndarray
    t_start: np.ndarray
    not_before: np.ndarray

    def __len__(self):
        return int(self.rate.size)

    def take(self, idx):
        return Candidates(*(getattr(self, f)[idx] for f in self._fields()))

    def replace(self, **kw):
        return Candidates(**{f: np.asarray(kw.get(f, getattr(self, f)), float) for f in self._fields()})

    def inputs(self, mm, stand):
        """Measurement-model inputs (n_x, n) on ``stand``."""
        return stand.inputs(mm, self.rate, self.azimuth, self.tilt_x, self.tilt_y, self.duration, self.t_start)

    @property
    def slot(self):
        """Time-slot label of each candidate (int, in time order)."""
        return np.unique(np.round(self.t_start, 6), return_inverse=True)[1].ravel()

    @staticmethod
    def _fields():
        return ("rate", "azimuth", "tilt_x", "tilt_y", "duration", "t_start", "not_before")


@dataclass(frozen=True)
class DesignSpace:
    """What a plan may vary.

    Attributes
    ----------
    rates : tuple of 2 float
        Limits of the bias rate's magnitude |Omega|, rad/s (default 20-60 deg/s).
    n_rates : int
        Rate levels between the limits (candidates; refinement moves off them).
    reverse : bool
        Both rotation senses; else only ``sense``.
    sense : int
        +1 or -1, the sense used when ``reverse`` is False.
    azimuths : tuple of float, optional
        Allowed stand azimuths, rad; default every ``azimuth_step`` round the circle.
    azimuth_step : float
        rad (default 15 deg).
    max_tilt : float
        Tilt-fixture limit, rad (0: no fixture); fixture settings are no tilt and the limit
        in ``n_tilt_directions`` directions.
    n_tilt_directions : int
    durations : tuple of float
        Allowed alignment durations, s (default 600 s, the paper's 10 minutes).
    time_slots : int
        Time since power-on as a factor: the test time is cut into this many slots, the
        approximate design spends at most its share of the budget in each, and the runs follow
        slot by slot. Needed for effects that depend on time (``warmup``); with 1 every
        candidate is seen at the middle of the test.
    """

    rates: tuple = (20.0 * units.DEG_PER_S, 60.0 * units.DEG_PER_S)
    n_rates: int = 5
    reverse: bool = False
    sense: int = 1
    azimuths: tuple | None = None
    azimuth_step: float = 15.0 * units.DEG
    max_tilt: float = 0.0
    n_tilt_directions: int = 8
    durations: tuple = (600.0,)
    time_slots: int = 1

    def __post_init__(self):
        lo, hi = (float(v) for v in self.rates)
        if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi):
            raise ValueError(f"rate limits {self.rates!r} rad/s; allowed: 0 < low <= high")
        if hi > 400 * units.DEG_PER_S:
            raise ValueError(f"rate limit {hi / units.DEG_PER_S:g} deg/s is not allowed; allowed: <= 400 deg/s "
                             "(rates are rad/s inside: was a deg/s value passed?)")
        object.__setattr__(self, "rates", (lo, hi))
        if int(self.n_rates) < 1:
            raise ValueError(f"n_rates = {self.n_rates!r}; allowed: an integer >= 1")
        object.__setattr__(self, "n_rates", 1 if lo == hi else int(self.n_rates))
        if self.sense not in (1, -1):
            raise ValueError(f"sense = {self.sense!r}; allowed: +1 or -1")
        if self.azimuths is not None:
            az = tuple(float(a) for a in np.atleast_1d(self.azimuths))
            if not az or not all(np.isfinite(az)):
                raise ValueError("azimuths: allowed a non-empty list of finite angles, rad")
            object.__setattr__(self, "azimuths", az)
        elif not 0 < self.azimuth_step <= 2 * np.pi:
            raise ValueError(f"azimuth_step = {self.azimuth_step!r} rad; allowed: 0 < step <= 2 pi")
        _positive("max_tilt (rad)", self.max_tilt, True)
        if self.max_tilt > 1.0 * units.DEG:
            raise ValueError(f"max_tilt = {self.max_tilt / units.ARCSEC:g} arcsec is not allowed; allowed: "
                             f"<= 3600 arcsec (the model is first order in the tilt)")
        if int(self.n_tilt_directions) < 1:
            raise ValueError(f"n_tilt_directions = {self.n_tilt_directions!r}; allowed: an integer >= 1")
        d = tuple(float(v) for v in np.atleast_1d(self.durations))
        if not d or not all(np.isfinite(d)) or min(d) <= 0:
            raise ValueError(f"durations = {self.durations!r}; allowed: positive seconds")
        object.__setattr__(self, "durations", d)
        if isinstance(self.time_slots, bool) or int(self.time_slots) != self.time_slots or self.time_slots < 1:
            raise ValueError(f"time_slots = {self.time_slots!r}; allowed: an integer >= 1")

    @property
    def azimuth_grid(self):
        if self.azimuths is not None:
            return np.array(self.azimuths)
        n = max(1, int(round(2 * np.pi / self.azimuth_step)))
        return np.arange(n) * (2 * np.pi / n)

    @property
    def azimuth_spacing(self):
        """Half-width of the refinement's azimuth window, rad."""
        g = np.sort(np.mod(self.azimuth_grid, 2 * np.pi))
        if g.size < 2:
            return 0.0
        return float(np.max(np.diff(np.concatenate([g, [g[0] + 2 * np.pi]]))))

    def candidates(self, warmup=0.0, test_time=0.0):
        """Every combination of the factors (:class:`Candidates`); a run of slot k of the
        ``test_time`` after the ``warmup`` (s) is seen at the slot's middle and does not start
        before the slot does."""
        lo, hi = self.rates
        mags = np.linspace(lo, hi, self.n_rates)
        rates = np.concatenate([mags, -mags]) if self.reverse else self.sense * mags
        tilts = [(0.0, 0.0)]
        if self.max_tilt > 0:
            ang = np.arange(self.n_tilt_directions) * 2 * np.pi / self.n_tilt_directions
            tilts += [(self.max_tilt * np.cos(a), self.max_tilt * np.sin(a)) for a in ang]
        slots = range(int(self.time_slots))
        g = np.array(list(itertools.product(slots, rates, self.azimuth_grid, range(len(tilts)),
                                            self.durations)), dtype=float)
        t = np.array(tilts)[g[:, 3].astype(int)]
        start = warmup + g[:, 0] * test_time / self.time_slots
        centre = start + 0.5 * test_time / self.time_slots
        return Candidates(g[:, 1], g[:, 2], t[:, 0], t[:, 1], g[:, 4], np.maximum(start, centre - g[:, 4] / 2),
                          start)


# ======================================================================= features
class _Rows:
    """Per-run feature rows of one model (or criterion) at each parameter sample.

    ``fn(p, x)`` is a CasADi Function (display units, before dividing by sigma); ``ps`` the
    SI parameter vectors of the samples; ``prior`` a Fisher matrix added to the information.
    """

    def __init__(self, names, fn, ps, prior=None):
        self.names = tuple(names)
        self.fn = fn
        self.ps = [np.asarray(p, float) for p in ps]
        self.k = len(self.names)
        self.prior = np.zeros((self.k, self.k)) if prior is None else np.asarray(prior, float)
        self._batch = None if fn is None else BatchEvaluator(fn)

    def numeric(self, X, sigma):
        """Weighted rows, shape (S, n, k)."""
        out = np.stack([np.asarray(self._batch(p, X)).reshape(X.shape[1], self.k) for p in self.ps])
        return out / np.asarray(sigma, float)[None, :, None]

    def information(self, rows, counts):
        """F of each sample (S, k, k) for runs with these weighted rows and counts."""
        return self.prior[None] + np.einsum("sni,n,snj->sij", rows, np.asarray(counts, float), rows)


def _own(sample, mm):
    return {k: v for k, v in sample.items() if k in mm.names}


def _model_rows(mm, samples, prior=None):
    p = ca.SX.sym("p", len(mm.names))
    x = ca.SX.sym("x", mm.n_x)
    fn = ca.Function("rows", [p, x], [mm.J(p, x) * ca.DM(mm.scale).T])
    return _Rows(mm.names, fn, [mm.vector(_own(s, mm)) for s in samples], prior)


def _criterion_rows(crit, model, tilt_known, samples, prior):
    mm = model.measurement(tilt_known)
    custom = crit.features(model, tilt_known)
    if custom is None:
        return _model_rows(mm, samples, prior)
    if prior is not None:
        raise ValueError(f"criterion {crit.label} builds its own information rows: prior information cannot "
                         "be used with it")
    names, fn, values = custom
    return _Rows(names, fn, [mm.vector({**_own(s, mm), **values}) for s in samples])


def _samples(nominal, prior_sample):
    """List of dicts name -> display value: the nominal values, or one per prior draw."""
    base = dict(nominal or {})
    if not prior_sample:
        return [base]
    cols = {k: np.atleast_1d(np.asarray(v, float)) for k, v in prior_sample.items()}
    lengths = {k: v.size for k, v in cols.items()}
    if len(set(lengths.values())) != 1 or min(lengths.values()) < 1:
        raise ValueError(f"prior_sample: draws per parameter {lengths}; allowed: equal numbers, at least one")
    return [{**base, **{k: float(v[i]) for k, v in cols.items()}} for i in range(next(iter(lengths.values())))]


@dataclass
class _Guard:
    """A model the plan must also identify: its rows at the candidates, and the bound on the
    mean log det of its information (D-efficiency against its own D-optimum)."""

    model: Model
    spec: _Rows
    rows: np.ndarray
    bound: float
    d_opt: float

    def take(self, idx):
        return _Guard(self.model, self.spec, self.rows[:, idx], self.bound, self.d_opt)

    def log_det(self, counts):
        return -_mean_loss(D(), self.rows, self.spec, counts)


# ===================================================================== approximate
@dataclass(frozen=True)
class ApproximateDesign:
    """The optimal approximate design over the candidates.

    Attributes
    ----------
    candidates : Candidates
    runs : numpy.ndarray, shape (n_candidates,)
        Optimal (fractional) number of runs of each candidate.
    loss : float
        Criterion loss (mean over the prior sample).
    status, solver : str
        cvxpy's ``problem.status`` and the solver that reached it.
    certified_efficiency : float
        Lower bound on this design's efficiency against the true optimum over all
        candidates, from the equivalence theorem (duality gap of the Lagrangian).
    solve_time : float
        s, including building the problems.
    iterations : int
        Column-generation rounds (each a convex program over the active candidates).
    n_active : int
        Candidates in the last convex program.
    """

    candidates: Candidates
    runs: np.ndarray
    loss: float
    status: str
    solver: str
    certified_efficiency: float
    solve_time: float
    iterations: int = 1
    n_active: int = 0

    @property
    def support(self):
        """Indices of the candidates that carry runs."""
        return np.flatnonzero(self.runs > _SUPPORT_TOL * self.runs.max())


def _approximate(crit, rows, spec, guards, cand, cost, budget, max_runs, solver=None, batch=128, polish=True):
    """The approximate design by column generation: convex programs over a growing active
    set until the equivalence theorem certifies the solution over every candidate
    (``polish``: each solution re-solved on its support by :func:`_polish_weights`)."""
    t0 = time.perf_counter()
    n = cost.size
    active = _initial_active(rows, [g.rows for g in guards], cost)
    slot = np.zeros(n, int) if cand is None else cand.slot
    for it in range(1, 100):
        w_a, mus, status, used = _convex(crit, rows[:, active], spec, [g.take(active) for g in guards],
                                         cost[active], budget, max_runs, solver, slot[active])
        w = np.zeros(n)
        w[active] = w_a
        loss, h, cert = _certify(crit, rows, spec, guards, w, mus, cost, budget, max_runs, slot)
        polished = _polish_weights(crit, rows, spec, guards, w, loss, cost, budget, max_runs, slot) if polish else None
        if polished is not None:
            trial = _certify(crit, rows, spec, guards, *polished, cost, budget, max_runs, slot)
            if trial[2] > cert:
                (w, mus), (loss, h, cert) = polished, trial
        if active.size == n or cert >= 1 - 1e-7:
            break
        # a candidate enters when spending its slot's share of the budget on it beats the slot's runs
        n_slots = slot.max() + 1
        value = h * np.minimum(budget / cost / n_slots, np.inf if max_runs is None else max_runs)
        now = np.bincount(slot, h * w, minlength=n_slots)[slot]
        order = np.argsort(-(value - now))
        new = order[(value[order] > now[order] + 1e-9 * abs(now[order])) & ~np.isin(order, active)][:batch]
        if new.size == 0:
            break
        active = np.union1d(active, new)
    if status != cp.OPTIMAL and not cert >= 0.99:  # an inaccurate solve is judged by its certificate
        raise DesignError(f"the approximate design's convex program ended {status} ({used}) with a "
                          f"certified efficiency of only {cert:.4g}")
    return ApproximateDesign(cand, w, loss, status, used, cert, time.perf_counter() - t0, it, int(active.size))


def _certify(crit, rows, spec, guards, w, mus, cost, budget, max_runs, slot):
    """Loss, Lagrangian gradient and certified efficiency of the weights ``w``."""
    loss = _mean_loss(crit, rows, spec, w)
    h = _lagrangian_gradient(crit, rows, spec, guards, mus, w)
    return loss, h, _certificate(crit, spec.k, loss, h, w, mus, guards, cost, budget, max_runs, slot)


def _polish_weights(crit, rows, spec, guards, w, loss0, cost, budget, max_runs, slot):
    """The convex program re-solved by IPOPT (CasADi) on the conic solution's support.

    Interior-point conic solvers stop at about 1e-8 in the objective; the loss is flat at the
    optimum, so that leaves about 1e-4 in the weights and small weights spread over
    near-optimal candidates, which then differ from one solver build to the next. The smooth
    problem on the support (the same loss, time budget per slot, run limit and guards) is
    solved to 1e-12 (``loss0``: the loss at ``w``, the objective's scale). Returns
    ``(weights, guard multipliers)``, or None when the criterion has no smooth form or IPOPT
    fails (the caller keeps whichever the certificate prefers)."""
    sup = np.flatnonzero(w > 1e-6 * w.max())
    m, n_slots = sup.size, int(slot.max()) + 1
    u = ca.MX.sym("u", m)  # runs of each support candidate

    def mean_loss(r, sp, fun):
        total = 0
        for s in range(r.shape[0]):
            a = ca.DM(r[s][sup])
            total = total + fun(ca.DM(sp.prior) + ca.mtimes(a.T, a * ca.repmat(u, 1, sp.k)))
        return total / r.shape[0]

    try:
        f = mean_loss(rows, spec, lambda F: crit.loss(F, _CASADI, spec.names))
    except _NotSmooth:
        return None
    scale = max(1.0, abs(loss0)) if crit.degree == 0 else abs(loss0)
    if not (np.isfinite(loss0) and scale > 0):
        return None
    S = np.zeros((n_slots, m))
    S[slot[sup], np.arange(m)] = cost[sup]
    lin = [S] + ([np.ones((1, m))] if max_runs is not None else [])
    ub = [np.full(n_slots, budget / n_slots)] + ([[max_runs]] if max_runs is not None else [])
    g = [ca.mtimes(ca.DM(np.vstack(lin)), u)] + [mean_loss(gd.rows, gd.spec, _CASADI.log_det) for gd in guards]
    solver = ca.nlpsol("weights", "ipopt", {"x": u, "f": (f - loss0) / scale, "g": ca.vertcat(*g)}, {
        "ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes", "ipopt.max_iter": 200,
        "ipopt.tol": 1e-12, "ipopt.bound_push": 1e-12, "ipopt.bound_frac": 1e-12, "ipopt.mu_init": 1e-8})
    n_lin = n_slots + len(lin) - 1
    sol = solver(x0=w[sup], lbx=0.0, ubx=np.inf,
                 lbg=np.concatenate([np.full(n_lin, -np.inf), [gd.bound for gd in guards]]),
                 ubg=np.concatenate([np.concatenate(ub), np.full(len(guards), np.inf)]))
    if not solver.stats()["success"]:
        return None
    out = np.zeros_like(w)
    out[sup] = np.clip(np.array(sol["x"]).ravel(), 0.0, None)
    lam = np.array(sol["lam_g"]).ravel()[n_lin:]
    return out, [max(0.0, -float(v) * scale) for v in lam]


def _initial_active(rows, guard_rows, cost, size=256):
    """A strided subset of the candidates plus the extremes of every feature column."""
    n = cost.size
    if n <= 2 * size:
        return np.arange(n)
    picks = [np.linspace(0, n - 1, size).astype(int)]
    for r in [rows, *guard_rows]:
        z = r / np.sqrt(cost)[None, :, None]
        picks += [np.argmax(z, axis=1).ravel(), np.argmin(z, axis=1).ravel()]
    return np.unique(np.concatenate(picks))


def _convex(crit, rows, spec, guards, cost, budget, max_runs, solver, slot):
    """One convex program (cvxpy): returns run numbers, guard duals, status, solver."""
    n = cost.size
    scale = budget / cost  # runs per unit budget fraction
    u = cp.Variable(n, nonneg=True)  # fraction of the alignment-time budget per candidate
    n_slots = int(slot.max()) + 1 if n else 1
    if n_slots == 1:
        cons = [cp.sum(u) <= 1]
    else:  # each time slot its share of the budget
        S = np.zeros((n_slots, n))
        S[slot, np.arange(n)] = 1.0
        cons = [S @ u <= 1.0 / n_slots]
    if max_runs is not None:
        cons.append(scale @ u <= max_runs)

    def info(r, sp):
        out = []
        for s in range(r.shape[0]):
            # column scales: the information of spending the whole budget evenly
            d = np.sqrt(np.mean(r[s] ** 2 * scale[:, None], axis=0) + np.diag(sp.prior) / n)
            blind = [nm for nm, v in zip(sp.names, d) if not v > 0]
            if blind:
                raise UnidentifiableError(f"no candidate run carries information on {', '.join(blind)}", blind)
            rs = r[s] / d[None, :]
            Q = np.einsum("ni,nj->ijn", rs, rs).reshape(sp.k * sp.k, n) * scale[None, :]
            F = cp.reshape(Q @ u, (sp.k, sp.k), order="C") + sp.prior / np.outer(d, d)
            out.append(_Scaled((F + F.T) / 2, d))
        return out

    ops = _Cvx()
    objective = sum(crit.loss(F, ops, spec.names) for F in info(rows, spec)) / rows.shape[0]
    guard_cons = [sum(ops.log_det(F) for F in info(g.rows, g.spec)) / g.rows.shape[0] >= g.bound
                  for g in guards]
    problem = cp.Problem(cp.Minimize(objective), cons + ops.constraints + guard_cons)
    status, used = _solve(problem, solver)
    mus = [max(0.0, float(c.dual_value)) if c.dual_value is not None else 0.0 for c in guard_cons]
    return np.clip(u.value, 0.0, None) * scale, mus, status, used


def _solve(problem, solver):
    """Solve with the first solver that reaches ``optimal``; else the first
    ``optimal_inaccurate`` (its certificate decides, in :func:`_approximate`); else raise
    with every status."""
    tried, inaccurate = [], None
    for name in ((solver,) if solver else _SOLVERS):
        try:
            with warnings.catch_warnings():  # an inaccurate solution is judged by its certificate
                warnings.simplefilter("ignore", UserWarning)
                _run_solver(problem, name)
        except cp.error.SolverError as err:
            tried.append(f"{name}: solver error ({str(err).splitlines()[0]})")
            continue
        if problem.status == cp.OPTIMAL:
            return problem.status, name
        tried.append(f"{name}: status {problem.status}")
        if problem.status == cp.OPTIMAL_INACCURATE and inaccurate is None:
            inaccurate = (problem.status, name, [v.value for v in problem.variables()],
                          [c.dual_value for c in problem.constraints])
    if inaccurate is not None:  # put the first inaccurate solution back
        for v, val in zip(problem.variables(), inaccurate[2]):
            v.value = val
        for c, val in zip(problem.constraints, inaccurate[3]):
            if val is not None:
                c.dual_variables[0].value = val
        return inaccurate[0], inaccurate[1]
    raise DesignError("the approximate design's convex program was not solved: " + "; ".join(tried))


def _run_solver(problem, name):
    if name == "SCS":
        problem.solve(solver=name, eps_abs=1e-8, eps_rel=1e-8, max_iters=20000)  # a fallback: seconds, not minutes
    elif name == "CLARABEL":  # the chordal split of the small dense cones costs accuracy
        problem.solve(solver=name, chordal_decomposition_enable=False)
    else:
        problem.solve(solver=name)


def _mean_loss(crit, rows, spec, w):
    return float(np.mean([crit.value(F, spec.names) for F in spec.information(rows, w)]))


def _directional(crit, rows, spec, w):
    """d(mean loss)/dw_i of every candidate, (n,)."""
    g = np.zeros(rows.shape[1])
    for s, F in enumerate(spec.information(rows, w)):
        g += np.einsum("ni,ij,nj->n", rows[s], crit.gradient(F, spec.names), rows[s])
    return g / rows.shape[0]


def _lagrangian_gradient(crit, rows, spec, guards, mus, w):
    """Gradient in w of ``-loss + sum mu_j (mean log det_j - bound_j)``."""
    h = -_directional(crit, rows, spec, w)
    for g, mu in zip(guards, mus):
        if mu > 0:
            h -= mu * _directional(D(), g.rows, g.spec, w)
    return h


def _certificate(crit, k, loss, h, w, mus, guards, cost, budget, max_runs, slot=None):
    """Efficiency lower bound of ``w`` from weak duality: the optimum is at most the
    Lagrangian's maximum over the feasible set, itself at most its value at ``w`` plus the
    Frank-Wolfe gap (a concave function lies below its tangent)."""
    slot = np.zeros(cost.size, int) if slot is None else slot
    n_slots = int(slot.max()) + 1
    if max_runs is None:
        per_slot = np.full(n_slots, -np.inf)
        np.maximum.at(per_slot, slot, h / cost)
        best = float(np.sum(np.maximum(per_slot, 0.0)) * budget / n_slots)
    else:
        from scipy.optimize import linprog
        S = np.zeros((n_slots, cost.size))
        S[slot, np.arange(cost.size)] = cost
        res = linprog(-h, A_ub=np.vstack([S, np.ones_like(cost)]),
                      b_ub=[budget / n_slots] * n_slots + [max_runs], bounds=(0, None), method="highs")
        if res.status != 0:
            raise DesignError(f"equivalence-theorem bound: linprog status {res.status} ({res.message})")
        best = float(-res.fun)
    gap = max(0.0, best - float(h @ w))
    gap += sum(mu * max(0.0, g.log_det(w) - g.bound) for g, mu in zip(guards, mus))
    if crit.degree == 0:
        return float(np.exp(-gap / k))
    if crit.degree < 0:
        return float(max(0.0, 1.0 - gap / loss))
    return float(abs(loss) / (abs(loss) + gap)) if loss < 0 else 0.0


def approximate_design(features, criterion="D", *, cost=None, budget=1.0, max_runs=None, names=None,
                       prior=None, solver=None):
    """The optimal approximate design for any linear(ised) model: the convex program of
    :func:`design` on given information rows.

    Parameters
    ----------
    features : array_like, shape (n, k) or (S, n, k)
        Row ``a_i`` of each candidate (``a_i a_i^T`` is one run's information), or one set
        per prior draw (the criterion is averaged over them).
    criterion : Criterion or str
    cost : array_like, shape (n,), optional
        Cost of one run of each candidate (default 1).
    budget : float
        ``sum_i w_i cost_i <= budget``.
    max_runs : float, optional
        ``sum_i w_i <= max_runs``.
    names : sequence of str, optional
        Column names (default ``p0, p1, ...``), for ``c:NAME``.
    prior : numpy.ndarray, shape (k, k), optional
        Information added to every design.
    solver : str, optional

    Returns
    -------
    ApproximateDesign
        ``runs`` is the optimal number of runs of each candidate (``candidates`` is None).
    """
    rows = np.asarray(features, dtype=float)
    if rows.ndim == 2:
        rows = rows[None]
    if rows.ndim != 3 or rows.shape[1] < 1 or rows.shape[2] < 1 or not np.all(np.isfinite(rows)):
        raise ValueError(f"features has shape {np.shape(features)}; allowed: (n, k) or (S, n, k) finite "
                         "numbers")
    n, k = rows.shape[1:]
    cost = np.ones(n) if cost is None else np.asarray(cost, dtype=float)
    if cost.shape != (n,) or np.any(~np.isfinite(cost)) or np.any(cost <= 0):
        raise ValueError(f"cost: allowed ({n},) positive numbers")
    names = tuple(names) if names is not None else tuple(f"p{i}" for i in range(k))
    if len(names) != k:
        raise ValueError(f"names: {len(names)} given for {k} feature columns")
    crit = as_criterion(criterion)
    spec = _Rows(names, None, [], prior)
    return _approximate(crit, rows, spec, [], None, cost, _positive("budget", budget), max_runs, solver)


# ======================================================================= rounding
def apportion(weights, n):
    """Efficient rounding (Pukelsheim & Rieder 1992): whole numbers of runs summing to ``n``.

    ``n_i = ceil((n - l/2) xi_i)`` for the ``l`` support points with proportions ``xi``, then
    one run at a time is added where ``n_j / xi_j`` is smallest, or removed where
    ``(n_j - 1) / xi_j`` is largest, until the total is ``n``.

    Parameters
    ----------
    weights : array_like, shape (m,)
        Nonnegative design weights (any scale).
    n : int
        Total number of runs, >= 1.

    Returns
    -------
    numpy.ndarray of int, shape (m,)
    """
    w = np.asarray(weights, dtype=float)
    if w.ndim != 1 or w.size == 0 or np.any(~np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
        raise ValueError("weights: allowed a non-empty 1-D array of nonnegative numbers, not all zero")
    if isinstance(n, bool) or int(n) != n or n < 1:
        raise ValueError(f"n = {n!r}; allowed: an integer >= 1")
    n = int(n)
    out = np.zeros(w.size, dtype=int)
    s = w > 0
    xi = w[s] / w[s].sum()
    m = np.maximum(np.ceil((n - xi.size / 2.0) * xi).astype(int), 0)
    while m.sum() < n:
        m[np.argmin(m / xi)] += 1
    while m.sum() > n:
        m[np.argmax(np.where(m > 0, (m - 1) / xi, -np.inf))] -= 1
    out[s] = m
    return out


@dataclass
class _Exact:
    """Whole runs on support settings (with their rows and guards)."""

    settings: Candidates
    counts: np.ndarray
    rows: np.ndarray
    guards: list
    loss: float
    xi: np.ndarray  # the approximate proportions rounded (same order)


def _caratheodory(w, rows, guards, cost, slot):
    """A design with the same information matrices (every sample, every guard), alignment
    time, number of runs and time per slot as ``w`` on as few candidates as that allows
    (Caratheodory: move along a null direction of those linear maps until a weight is 0).
    Interior-point solvers return the most spread-out optimum when it is not unique; fewer
    support points round to whole runs with less loss and fewer setups."""
    sup = np.flatnonzero(w > _SUPPORT_TOL * w.max())
    w = w.copy()
    w[np.setdiff1d(np.arange(w.size), sup)] = 0.0
    iu = [np.triu_indices(r.shape[2]) for r in [rows, *[g.rows for g in guards]]]
    n_slots = int(slot.max()) + 1

    def maps(idx):
        cols = [r[:, idx][:, :, i] * r[:, idx][:, :, j]
                for r, (i, j) in zip([rows, *[g.rows for g in guards]], iu)]
        parts = [c.transpose(1, 0, 2).reshape(idx.size, -1) for c in cols]
        parts += [cost[idx, None], np.ones((idx.size, 1)), (slot[idx, None] == np.arange(n_slots)[None, :])]
        A = np.hstack(parts).T
        return A / np.maximum(np.abs(A).max(axis=1, keepdims=True), 1e-300)

    while sup.size > 1:
        A = maps(sup)
        _, s, vt = np.linalg.svd(A, full_matrices=True)
        rank = int(np.sum(s > 1e-10 * s.max()))
        if rank >= sup.size:
            break
        v = vt[rank]
        if not np.any(v < 0):
            v = -v
        neg = v < 0
        t = np.min(w[sup][neg] / -v[neg])
        w[sup] = np.maximum(w[sup] + t * v, 0.0)
        w[sup[np.argmin(np.where(neg, w[sup] / -np.where(neg, v, -1), np.inf))]] = 0.0
        sup = sup[w[sup] > _SUPPORT_TOL * w.max()]
    out = np.zeros_like(w)
    out[sup] = w[sup]
    return out


def _round(crit, rows, spec, guards, approx_w, cand, cost, costs, budget, max_runs):
    """The largest n whose efficiently rounded plan fits the budget with its setups, then
    polished by one-run exchanges."""
    approx_w = _caratheodory(approx_w, rows, guards, cost, cand.slot)
    sup = np.flatnonzero(approx_w > 0)
    xi = approx_w[sup] / approx_w[sup].sum()
    settings, srows, sguards = cand.take(sup), rows[:, sup], [g.take(sup) for g in guards]
    n_max = int(np.floor((budget - costs.warmup) / cost[sup].min() + 1e-9))
    if max_runs is not None:
        n_max = min(n_max, int(max_runs))
    cache = {}
    for n in range(n_max, 0, -1):
        counts = apportion(xi, n)
        if _min_time(settings, counts, costs, cache) <= budget + 1e-6:
            break
    else:
        raise ValueError(f"budget {budget / units.HOUR:.4g} h: no whole-run plan fits it")
    counts = _polish(crit, srows, spec, sguards, counts, settings, costs, budget, max_runs, cache)
    keep = counts > 0
    return _Exact(settings.take(keep), counts[keep], srows[:, keep], [g.take(keep) for g in sguards],
                  _mean_loss(crit, srows, spec, counts), xi[keep])


def _polish(crit, rows, spec, guards, counts, settings, costs, budget, max_runs, cache, max_iter=500,
            screen=24):
    """One-run exchanges (move a run between settings, or add one where time allows) that
    lower the loss, keep each guard at or above its bound (or where it started) and fit the
    budget. Moves are screened by their first-order effect (the directional derivatives);
    the ``screen`` most promising are evaluated exactly."""
    counts = counts.copy()
    m = counts.size
    run_time = settings.duration + costs.run_overhead
    floors = [min(g.bound, g.log_det(counts)) for g in guards]
    best = _mean_loss(crit, rows, spec, counts)
    moves = [(i, j) for i in range(-1, m) for j in range(m) if i != j]
    for _ in range(max_iter):
        try:
            d = _directional(crit, rows, spec, counts)
            order = sorted(moves, key=lambda ij: d[ij[1]] - (d[ij[0]] if ij[0] >= 0 else 0.0))
        except ValueError:  # no gradient: evaluate every move
            order = moves
        tried = 0
        for i, j in order:
            if i >= 0 and counts[i] == 0:
                continue
            c = counts.copy()
            c[j] += 1
            if i >= 0:
                c[i] -= 1
            elif c @ run_time > budget - costs.warmup or (max_runs is not None and c.sum() > max_runs):
                continue
            tried += 1
            loss = _mean_loss(crit, rows, spec, c)
            if (loss < best - 1e-12 * max(1.0, abs(best))
                    and all(g.log_det(c) >= f - 1e-9 for g, f in zip(guards, floors))
                    and _min_time(settings, c, costs, cache) <= budget + 1e-6):
                counts, best = c, loss
                break
            if tried >= screen and order is not moves:
                return counts
        else:
            return counts
    return counts


def _prune(crit, rows, spec, guards, w, cand, cost, costs, budget, max_runs, solver, exact):
    """Greedy setup-aware search: remove one stand position (time slot, tilt, azimuth) of the
    approximate design's support at a time -- the lightest first -- re-solve on the
    candidates of the others and round; keep the first removal that gives a better rounded
    plan, and go on until none does."""
    pos = np.unique(np.column_stack([cand.t_start, cand.tilt_x, cand.tilt_y, np.mod(cand.azimuth, 2 * np.pi)])
                    .round(9), axis=0, return_inverse=True)[1].ravel()
    weight = np.bincount(pos, w)
    keep = set(np.flatnonzero(weight > _SUPPORT_TOL * w.max()).tolist())
    improved = True
    while improved and len(keep) > 1:
        improved = False
        for g in sorted(keep, key=lambda g: weight[g]):
            idx = np.flatnonzero(np.isin(pos, sorted(keep - {g})))
            sub_guards = [gd.take(idx) for gd in guards]
            try:
                sub = _approximate(crit, rows[:, idx], spec, sub_guards, cand.take(idx), cost[idx],
                                   budget - costs.warmup, max_runs, solver or _SOLVERS[0], polish=False)
                trial = _round(crit, rows[:, idx], spec, sub_guards, sub.runs, cand.take(idx), cost[idx], costs,
                               budget, max_runs)
            except (ValueError, DesignError):  # the others cannot identify the model, or meet a guard
                continue
            if trial.loss < exact.loss:
                exact, improved = trial, True
                keep.discard(g)
                full = np.zeros(pos.size)
                full[idx] = sub.runs
                weight = np.bincount(pos, full, minlength=weight.size)
                break
    return exact


# ======================================================================= ordering
def _orders(settings, counts, costs, rng=None, n_random=0):
    """Run sequences (arrays of setting indices): each setting's runs together, settings
    in time-slot order, then grouped by their costliest factor (tilt, azimuth, rate, duration
    in the order of the change costs), serpentine (the next group starts where the last
    ended), plain or folded (ABBA: first halves of the groups, then the second halves in
    reverse); ``n_random`` more with random group orders and folds."""
    keys = {"slot": settings.t_start[:, None] / 1e-6,
            "tilt": np.column_stack([settings.tilt_x, settings.tilt_y]) / 1e-12,
            "azimuth": np.mod(settings.azimuth, 2 * np.pi)[:, None] / 1e-12,
            "rate": settings.rate[:, None] / 1e-12, "duration": settings.duration[:, None] / 1e-9}
    cost = {"slot": np.inf, "tilt": costs.tilt_change, "azimuth": costs.azimuth_change,
            "rate": costs.rate_change, "duration": 0.0}
    labels = [np.unique(np.round(keys[f]), axis=0, return_inverse=True)[1].ravel()
              for f in sorted(keys, key=lambda f: -cost[f])]
    key = {int(i): tuple(int(lab[i]) for lab in labels) for i in np.flatnonzero(counts > 0)}

    def tree(members, depth):
        if depth == len(labels):
            return members[0]
        groups = itertools.groupby(sorted(members, key=lambda i: key[i][depth]), key=lambda i: key[i][depth])
        return [tree(list(g), depth + 1) for _, g in groups]

    root = tree(list(key), 0)

    def expand(t, reverse, r, fold_p, top=False):
        if not isinstance(t, list):
            return [t] * int(counts[t])
        kids = [t[i] for i in r.permutation(len(t))] if r is not None and not top else list(t)
        if reverse:
            kids = kids[::-1]
        seqs = [expand(c, j % 2 == 1, r, fold_p) for j, c in enumerate(kids)]
        fold = not top and len(seqs) > 1 and (r.random() < fold_p if r is not None else fold_p > 0)
        if not fold:
            return [i for s in seqs for i in s]
        half = [(len(s) + 1) // 2 for s in seqs]
        return ([i for s, h in zip(seqs, half) for i in s[:h]]
                + [i for s, h in zip(reversed(seqs), reversed(half)) for i in s[h:]])

    out = [expand(root, False, None, 0.0, True), expand(root, False, None, 1.0, True)]
    out += [expand(root, False, rng, rng.choice([0.0, 0.25, 0.5]), True) for _ in range(n_random)]
    return [np.array(s) for s in dict.fromkeys(tuple(s) for s in out)]


def _total_time(settings, seq, costs):
    s = settings.take(seq)
    t = costs.schedule(s.rate, s.azimuth, s.tilt_x, s.tilt_y, s.duration, s.not_before)
    return float(t[-1] + s.duration[-1])


def _min_time(settings, counts, costs, cache=None):
    """Least total time (s) of a plan with these counts over the deterministic orders. In one
    time slot that is its setups (which depend only on which settings are used, so ``cache``
    keeps them by that pattern) plus its alignments; with slots, waits count too."""
    if np.ptp(settings.not_before) > 0:
        return min(_total_time(settings, seq, costs) for seq in _orders(settings, counts, costs))
    used = counts > 0
    key = used.tobytes()
    if cache is None or key not in cache:
        one = used.astype(int)
        setup = min(float(costs.setups(s.rate, s.azimuth, s.tilt_x, s.tilt_y).sum())
                    for s in (settings.take(seq) for seq in _orders(settings, one, costs)))
        if cache is None:
            cache = {}
        cache[key] = setup
    return cache[key] + float(counts @ (settings.duration + costs.run_overhead)) - costs.run_overhead


def _pick_order(exact, spec, crit, costs, budget, stand, order, rng):
    """The sequence with the least standardised drift bias on the criterion's parameters
    (``trend-robust``) or the least time (``min-setup``), within the budget."""
    interest = [i for i, nm in enumerate(spec.names) if nm in crit.interest(spec.names)] or list(range(spec.k))
    rows = exact.rows[0]
    best = None
    for seq in _orders(exact.settings, exact.counts, costs, rng, n_random=300):
        s = exact.settings.take(seq)
        t = costs.schedule(s.rate, s.azimuth, s.tilt_x, s.tilt_y, s.duration, s.not_before)
        total = float(t[-1] + s.duration[-1])
        if total > budget + 1e-6:
            continue
        a = rows[seq]
        cov = np.linalg.pinv(spec.prior + a.T @ a)
        mid = t + s.duration / 2
        b = cov @ (a.T @ ((mid - mid.mean()) * DRIFT_UNIT / stand.sigma(s.duration)))
        score = float(np.max(np.abs(b[interest]) / np.sqrt(np.maximum(np.diag(cov)[interest], 1e-300))))
        key = (score, total) if order == "trend-robust" else (total, score)
        if best is None or key < best[0]:
            best = (key, seq)
    return best[1]


# ==================================================================== evaluation
@dataclass(frozen=True)
class Evaluation:
    """What a plan predicts for a model.

    Attributes
    ----------
    criterion : str
    criterion_value : float
        The criterion's loss for this plan (nan when no criterion was given).
    effects : tuple of str
    tilt_known : bool
    names, units : tuple of str
    std : numpy.ndarray, shape (n_p,)
        Predicted standard deviations, display units.
    covariance, correlation : numpy.ndarray, shape (n_p, n_p)
    condition : float
    n_runs : int
    total_time : float
        End of the last alignment since power-on, s.
    drift_bias : numpy.ndarray, shape (n_p,)
        Bias of each estimate from a linear heading drift of 1 arcsec/h, display units.
    """

    criterion: str
    criterion_value: float
    effects: tuple
    tilt_known: bool
    names: tuple
    units: tuple
    std: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    condition: float
    n_runs: int
    total_time: float
    drift_bias: np.ndarray

    def std_of(self, name):
        """Predicted standard deviation of one parameter, display units."""
        if name not in self.names:
            raise ValueError(f"unknown parameter {name!r}; this model has: {', '.join(self.names)}")
        return float(self.std[self.names.index(name)])

    def to_dict(self):
        """The JSON form (DESIGN.md contract keys, and more)."""
        return {
            "criterion": self.criterion,
            "criterion_value": float(self.criterion_value) if np.isfinite(self.criterion_value) else None,
            "effects": list(self.effects),
            "tilt_known": self.tilt_known,
            "n_runs": self.n_runs,
            "total_time_h": self.total_time / units.HOUR,
            "predicted_std": {n: {"value": float(s), "unit": u}
                              for n, s, u in zip(self.names, self.std, self.units)},
            "drift_bias_per_arcsec_per_h": {n: {"value": float(b), "unit": u}
                                            for n, b, u in zip(self.names, self.drift_bias, self.units)},
            "condition": float(self.condition),
            "correlation": self.correlation.tolist(),
        }

    def summary(self):
        """Report lines."""
        lines = [f"model {'+'.join(self.effects)} (tilt {'known' if self.tilt_known else 'unknown'}): "
                 f"{self.n_runs} runs, {self.total_time / units.HOUR:.3f} h from power-on to the last run's "
                 "end",
                 f"  {'parameter':<20}{'predicted sigma':>22}{'bias per arcsec/h drift':>28}"]
        for n, s, b, u in zip(self.names, self.std, self.drift_bias, self.units):
            b = 0.0 if abs(b) < 1e-9 * s else b  # rounding of a trend-free order
            lines.append(f"  {n:<20}{s:>14.4g} {u:<7}{b:>+20.3g} {u}")
        return lines


def _prior(prior, names):
    """Prior information (k, k, display units) on ``names`` from a Fisher matrix in that
    order, a :class:`~hse_opt.information.Prior` or a FitResult (the earlier calibration;
    its other parameters are marginalised out)."""
    if prior is None:
        return None
    if isinstance(prior, np.ndarray):
        if prior.shape != (len(names), len(names)):
            raise ValueError(f"prior information has shape {prior.shape}; allowed: ({len(names)}, "
                             f"{len(names)}) in the order {', '.join(names)}")
        return np.asarray(prior, float)
    if not isinstance(prior, Prior):
        if not hasattr(prior, "covariance"):
            raise ValueError(f"prior: a FitResult, a Prior or a Fisher matrix is required, got "
                             f"{type(prior).__name__}")
        prior = Prior.from_fit(prior)
    return prior.fisher(names)[0]


def evaluate(plan, model=None, *, stand=None, tilt_known=True, criterion=None, nominal=None, prior=None):
    """Predicted sigmas of a plan for a model.

    Parameters
    ----------
    plan : hse_opt.data.Plan
    model : Model, str or sequence of str, optional
        Default: the paper's model.
    stand : Stand, optional
    tilt_known : bool
    criterion : Criterion or str, optional
        Also report this criterion's loss.
    nominal : mapping name -> value, optional
        Values (display units) at which the model is linearised.
    prior : FitResult, Prior or numpy.ndarray, optional
        Prior information (see :func:`design`).

    Returns
    -------
    Evaluation

    Raises
    ------
    UnidentifiableError
        The plan cannot identify the model; the parameters are named, with runs that would
        separate them.
    """
    model = as_model(model)
    stand = stand or Stand()
    if not isinstance(plan, Plan):
        raise TypeError(f"expected a hse_opt.data.Plan, got {type(plan).__name__}")
    tx, ty = (plan.tilt_x, plan.tilt_y) if plan.tilt_x is not None else (0.0, 0.0)
    if not tilt_known and np.any(np.asarray(tx) != 0) | np.any(np.asarray(ty) != 0):
        raise ValueError(f"{plan.source}: columns tilt_x_arcsec/tilt_y_arcsec vary the tilt, but with the tilt "
                         "unknown the model assumes one tilt fixed in b0; allowed: tilt_known=True")
    mm = model.measurement(tilt_known)
    X = stand.inputs(mm, plan.rate, plan.azimuth, tx, ty, plan.duration, plan.t_start)
    sigma = stand.sigma(plan.duration)
    p = mm.vector(_own(nominal or {}, mm))
    Aw = weighted_jacobian(mm.jacobian(p, X), sigma, mm.scale)
    F0 = _prior(prior, mm.names)

    info = analyse(Aw.T @ Aw + (0 if F0 is None else F0), mm.names, [q.unit for q in mm.params],
                   advice=lambda d: separation_advice(mm, p, X, np.ones(len(mm.names), bool), d))
    mid = plan.t_start + plan.duration / 2
    bias = info.covariance @ (Aw.T @ ((mid - mid.mean()) * DRIFT_UNIT / sigma))
    label, value = "", float("nan")
    if criterion is not None:
        crit = as_criterion(criterion)
        spec = _criterion_rows(crit, model, tilt_known, [dict(nominal or {})], F0)
        label, value = crit.label, _mean_loss(crit, spec.numeric(X, sigma), spec, np.ones(plan.run.size))
    return Evaluation(label, value, model.effect_names, bool(tilt_known), mm.names, info.units, info.std,
                      info.covariance, info.correlation, info.condition, int(plan.run.size),
                      float(np.max(plan.t_start + plan.duration)), bias)


# ======================================================================== design
@dataclass(frozen=True)
class DesignResult:
    """An optimised plan and what it achieves.

    Attributes
    ----------
    plan : hse_opt.data.Plan
        In execution order, with ``t_start`` from the costs.
    evaluation : Evaluation
        Predicted sigmas and drift biases of the plan (at its start times).
    criterion : str
    efficiency : float
        Against the approximate optimum for the plan's alignment time (rounding, then
        refinement: above 1 when refinement gains more off the candidate grid than the
        rounding lost).
    rounding_efficiency : float
        The same before refinement: the rounding alone.
    budget_efficiency : float
        Against the approximate optimum for the whole budget (time spent on setups counts
        as lost).
    approximate : ApproximateDesign
        The setup-free optimum over the candidates.
    setup_time, alignment_time : float
        s: warm-up and changes; alignments and per-run overheads.
    refinement : str
        IPOPT's return status, or why there was none.
    guards : tuple of dict
        Models the plan must also identify: ``effects``, ``d_efficiency`` (against their own
        D-optimal approximate design), ``min_efficiency``, ``std`` (name -> predicted sigma).
    notes : tuple of str
    """

    plan: Plan
    evaluation: Evaluation
    criterion: str
    efficiency: float
    rounding_efficiency: float
    budget_efficiency: float
    approximate: ApproximateDesign
    setup_time: float
    alignment_time: float
    refinement: str
    guards: tuple = ()
    notes: tuple = ()

    @property
    def n_runs(self):
        return int(self.plan.run.size)

    @property
    def total_time(self):
        return self.evaluation.total_time

    def std_of(self, name):
        """Predicted standard deviation of one parameter, display units."""
        return self.evaluation.std_of(name)

    def to_dict(self):
        """The JSON form (DESIGN.md contract keys, and more)."""
        a = self.approximate
        out = self.evaluation.to_dict()
        out.update({
            "criterion": self.criterion, "efficiency": float(self.efficiency),
            "rounding_efficiency": float(self.rounding_efficiency),
            "budget_efficiency": float(self.budget_efficiency),
            "approximate": {"status": a.status, "solver": a.solver, "n_candidates": int(a.runs.size),
                            "support": int(a.support.size), "iterations": a.iterations, "n_active": a.n_active,
                            "certified_efficiency": float(a.certified_efficiency),
                            "solve_time_s": a.solve_time},
            "setup_time_h": self.setup_time / units.HOUR, "alignment_time_h": self.alignment_time / units.HOUR,
            "refinement": self.refinement, "guards": [dict(g) for g in self.guards], "notes": list(self.notes),
        })
        return out

    def summary(self):
        """Report lines."""
        a = self.approximate
        hours = lambda t: f"{t / units.HOUR:.3f} h"  # noqa: E731
        lines = [f"criterion {self.criterion}: {self.n_runs} runs in {hours(self.total_time)} (setups "
                 f"{hours(self.setup_time)}, alignments {hours(self.alignment_time)})",
                 f"approximate design: {a.runs.size} candidates ({a.n_active} active after {a.iterations} "
                 f"round(s)), {a.support.size} in the support, {a.solver} {a.status} in {a.solve_time:.2f} s, "
                 f"certified efficiency >= {a.certified_efficiency:.6f}",
                 f"exact design: efficiency {self.efficiency:.4f} against the approximate optimum for the same "
                 f"alignment time (rounding alone {self.rounding_efficiency:.4f}; refinement {self.refinement}); "
                 f"{self.budget_efficiency:.4f} against the whole budget"]
        lines += self.evaluation.summary()
        for g in self.guards:
            lines.append(f"also identifies {'+'.join(g['effects'])}: D-efficiency {g['d_efficiency']:.3f} "
                         f"(at least {g['min_efficiency']:.3f} required)")
        return lines + [f"note: {n}" for n in self.notes]


def design(model=None, criterion="c:lambda2", *, budget, space=None, stand=None, costs=None,
           max_runs=None, tilt_known=True, nominal=None, prior_sample=None, prior=None,
           identify=None, identify_efficiency=0.25, prune=True, refine=True,
           order="trend-robust", rng=None, solver=None):
    """The test plan that minimises ``criterion`` within the stand-time ``budget``.

    Parameters
    ----------
    model : Model, str or sequence of str, optional
        Default: the paper's model (``hse``).
    criterion : Criterion or str
        ``'D'``, ``'A'``, ``'E'``, ``'c:NAME'`` or a :class:`Criterion` (e.g.
        :class:`Discrimination`). Default ``c:lambda2``, the paper's goal. A and E depend on
        the parameters' display units.
    budget : float
        Total test time, s, from power-on to the end of the last alignment.
    space : DesignSpace, optional
    stand : Stand, optional
    costs : Costs, optional
    max_runs : int, optional
    tilt_known : bool
        Pitch/roll from the alignments' leveling (see the module docstring).
    nominal : mapping name -> value, optional
        Display-unit values at which the model is linearised (nonlinear parameters).
    prior_sample : mapping name -> array, optional
        Draws (display units, equal numbers) over which the criterion is averaged: a design
        robust to the nonlinear parameters.
    prior : FitResult, Prior or numpy.ndarray, optional
        Prior information from an earlier calibration (a FitResult or
        :class:`~hse_opt.information.Prior`; or a Fisher matrix in the model's order).
    identify : Model, str or sequence, optional
        Models the plan must also identify (a list of effect names is one model; a list of
        models or ``"a,b"`` strings is several), each with a D-efficiency of at least
        ``identify_efficiency`` against its own D-optimal approximate design. Default: the
        design model itself when the criterion may leave it unidentifiable (c, T).
    identify_efficiency : float
        In (0, 1).
    prune : bool
        Setup-aware search: drop stand positions (time slot, tilt, azimuth) of the
        approximate design one at a time, re-solving on the rest, while the rounded plan --
        which has more time for runs with fewer setups -- gets better.
    refine : bool
        Move rates and azimuths off the candidate grid with IPOPT.
    order : {'trend-robust', 'min-setup'}
    rng : numpy.random.Generator, optional
        For the run-order search (default: seeded, reproducible).
    solver : str, optional
        cvxpy solver (default: Clarabel, then SCS).

    Returns
    -------
    DesignResult

    Raises
    ------
    ValueError
        Bad arguments (named), or a budget too small for the model
        (:class:`~hse_opt.information.UnidentifiableError` names the parameters).
    DesignError
        A solver failed (its status is in the message).
    """
    model, crit = as_model(model), as_criterion(criterion)
    space, stand, costs = space or DesignSpace(), stand or Stand(), costs or Costs()
    rng = rng if rng is not None else np.random.default_rng(0)
    budget = _positive("budget (s)", budget)
    if order not in ("trend-robust", "min-setup"):
        raise ValueError(f"order = {order!r}; allowed: 'trend-robust', 'min-setup'")
    if max_runs is not None and (isinstance(max_runs, bool) or int(max_runs) != max_runs or max_runs < 1):
        raise ValueError(f"max_runs = {max_runs!r}; allowed: an integer >= 1")
    if not 0 < identify_efficiency < 1:
        raise ValueError(f"identify_efficiency = {identify_efficiency!r}; allowed: 0 < value < 1")
    if not tilt_known and space.max_tilt > 0:
        raise ValueError("a tilt fixture (max_tilt > 0) needs tilt_known=True: with the tilt unknown the model "
                         "assumes one tilt fixed in b0 for every run")
    guard_models = _guard_models(identify, model, crit)
    for m in (model, *guard_models):
        if m.covariates:
            raise ValueError(f"effects {[e.name for e in m.effects if hasattr(e, 'column')]} follow recorded "
                             "covariates, which a plan cannot set; allowed: effects without covariates")
    samples = _samples(nominal, prior_sample)
    known = {q.name for m in (model, *guard_models) for q in m.measurement(tilt_known).params}
    unknown = sorted(set().union(*samples) - known)
    if unknown:
        raise ValueError(f"nominal/prior_sample: {unknown} are not parameters of the model(s); allowed: "
                         f"{', '.join(sorted(known))}")
    B = budget - costs.warmup
    cand = space.candidates(costs.warmup, B)
    cost = cand.duration + costs.run_overhead
    if B < cost.min():
        raise ValueError(f"budget {budget / units.HOUR:.4g} h leaves no time for one alignment after the "
                         f"warm-up of {costs.warmup:g} s; allowed: budget > warm-up + one run")
    mm = model.measurement(tilt_known)
    X = cand.inputs(mm, stand)
    sigma = stand.sigma(cand.duration)
    spec = _criterion_rows(crit, model, tilt_known, samples, _prior(prior, mm.names))
    if isinstance(crit, C):
        _unit_vector(spec.names, crit.name)
    rows = spec.numeric(X, sigma)
    _check_candidates(rows, spec, space, model)

    guards = []
    for gm in guard_models:
        gmm = gm.measurement(tilt_known)
        gspec = _model_rows(gmm, samples, _prior(prior, gmm.names))
        g = _Guard(gm, gspec, gspec.numeric(X, sigma), -np.inf, 0.0)
        _check_candidates(g.rows, gspec, space, gm)
        dopt = _approximate(D(), g.rows, gspec, [], cand, cost, B, max_runs, solver)
        guards.append(_Guard(gm, gspec, g.rows, -dopt.loss + gspec.k * np.log(identify_efficiency), dopt.loss))

    approx = _approximate(crit, rows, spec, guards, cand, cost, B, max_runs, solver)
    notes = []
    if approx.certified_efficiency < 0.999:
        notes.append(f"the approximate design is certified only to efficiency "
                     f"{approx.certified_efficiency:.4f}")
    exact = _round(crit, rows, spec, guards, approx.runs, cand, cost, costs, budget, max_runs)
    if prune:
        exact = _prune(crit, rows, spec, guards, approx.runs, cand, cost, costs, budget, max_runs, solver,
                       exact)
    if not np.isfinite(exact.loss):
        raise UnidentifiableError(f"{int(exact.counts.sum())} whole runs within the budget cannot identify "
                                  f"the model for criterion {crit.label}", spec.names)

    # the approximate optimum for the exact plan's alignment time
    t_align = float(exact.counts @ (exact.settings.duration + costs.run_overhead))
    if prior is None and max_runs is None:
        loss_same = _mean_loss(crit, rows, spec, approx.runs * t_align / B)
    else:
        loss_same = _approximate(crit, rows, spec, guards, cand, cost, t_align, max_runs, solver).loss
    rounding_eff = crit.efficiency(exact.loss, loss_same, spec.k)

    status = "off"
    if refine:
        try:
            status = _refine(crit, spec, exact, stand, mm, space)
        except _NotSmooth as err:
            status = f"none: criterion {crit.label} is not smooth ({err})"
    efficiency = crit.efficiency(exact.loss, loss_same, spec.k)
    budget_eff = crit.efficiency(exact.loss, approx.loss, spec.k)

    seq = _pick_order(exact, spec, crit, costs, budget, stand, order, rng)
    s = exact.settings.take(seq)
    fixture = space.max_tilt > 0
    plan = Plan(run=np.arange(1, seq.size + 1), rate=s.rate, azimuth=np.mod(s.azimuth, 2 * np.pi),
                t_start=costs.schedule(s.rate, s.azimuth, s.tilt_x, s.tilt_y, s.duration, s.not_before),
                duration=s.duration,
                tilt_x=s.tilt_x if fixture else None, tilt_y=s.tilt_y if fixture else None)
    evaluation = evaluate(plan, model, stand=stand, tilt_known=tilt_known, criterion=crit, nominal=nominal,
                          prior=prior)
    guard_out = []
    for g in guards:
        g_exact = _Guard(g.model, g.spec, g.spec.numeric(s.inputs(mm, stand), stand.sigma(s.duration)),
                         g.bound, g.d_opt)
        try:
            ev = evaluate(plan, g.model, stand=stand, tilt_known=tilt_known, nominal=nominal, prior=prior)
            std = {nm: float(v) for nm, v in zip(ev.names, ev.std)}
        except UnidentifiableError as err:
            std = {}
            notes.append(f"the plan does not identify {'+'.join(g.model.effect_names)}: {err}")
        guard_out.append({"effects": list(g.model.effect_names), "min_efficiency": float(identify_efficiency),
                          "d_efficiency": float(np.exp((g.d_opt + g_exact.log_det(np.ones(seq.size)))
                                                       / g.spec.k)),
                          "std": std})
    return DesignResult(plan, evaluation, crit.label, efficiency, rounding_eff, budget_eff, approx,
                        float(costs.setups(s.rate, s.azimuth, s.tilt_x, s.tilt_y).sum()),
                        float(np.sum(s.duration + costs.run_overhead)), status, tuple(guard_out), tuple(notes))


def _check_candidates(rows, spec, space, model):
    """Raise :class:`~hse_opt.information.UnidentifiableError` when even every candidate run
    together cannot identify the model: then no plan from this design space can."""
    for r in rows:
        try:
            check_identifiable(spec.prior + np.einsum("ni,nj->ij", r, r) / r.shape[0], spec.names)
        except UnidentifiableError as err:
            timed = [e.name for e in model.effects if e.level == "thermal"]
            hint = (f" Time since power-on is not a factor of this design space (time_slots=1), and "
                    f"{', '.join(timed)} changes with it: allowed time_slots >= 2 (DesignSpace(time_slots=N); "
                    f"hse-opt design --time-slots N)."
                    if timed and space.time_slots == 1 else "")
            curved = [n for e in model.effects for n in e.nonlinear if n in err.names]
            if curved:
                hint += (f" {', '.join(curved)} {'enters' if len(curved) == 1 else 'enter'} the model nonlinearly "
                         f"and the design linearises at the nominal values, where the heading may not depend on "
                         f"{'it' if len(curved) == 1 else 'them'}: give values where it does "
                         f"(nominal={{...}}; hse-opt design --nominal NAME=VALUE, e.g. a warm-up amplitude).")
            raise UnidentifiableError(f"no plan from these candidate runs can identify the model: "
                                      f"{str(err).rstrip('.')}.{hint}", err.names) from None


def _guard_models(identify, model, crit):
    if identify is None:
        return [model] if crit.needs_guard else []
    items = [identify] if isinstance(identify, (Model, str)) else list(identify)
    if items and all(isinstance(i, str) and "," not in i for i in items) and len(items) > 1:
        return [as_model(items)]  # a list of effect names is one model
    return [as_model(i) for i in items]


def _refine(crit, spec, exact, stand, mm, space):
    """IPOPT over the distinct azimuths and signed rates of the exact design's settings
    (counts fixed; guards kept at or above their bounds). Updates ``exact`` in place when
    the loss falls; returns IPOPT's status."""
    st, counts = exact.settings, exact.counts
    az_u, ia = np.unique(np.round(st.azimuth, 12), return_inverse=True)
    r_u, ir = np.unique(np.round(st.rate, 12), return_inverse=True)
    ia, ir, n_az = ia.ravel(), ir.ravel(), az_u.size
    v = ca.MX.sym("v", n_az + r_u.size)
    lo, hi = space.rates
    half = space.azimuth_spacing
    lbx = np.concatenate([az_u - half, np.where(r_u > 0, lo, -hi)])
    ubx = np.concatenate([az_u + half, np.where(r_u > 0, hi, -lo)])
    sigma = stand.sigma(st.duration)
    X0 = st.inputs(mm, stand)
    xs = [ca.vertcat(v[n_az + ir[i]], v[ia[i]], X0[2:, i]) for i in range(counts.size)]

    def mean_over_samples(sp, fun):
        total = 0
        for p in sp.ps:
            F = ca.MX(sp.prior)
            for i, x in enumerate(xs):
                a = sp.fn(p, x) / sigma[i]
                F = F + counts[i] * ca.mtimes(a.T, a)
            total = total + fun(F)
        return total / len(sp.ps)

    loss0 = exact.loss
    f = mean_over_samples(spec, lambda F: crit.loss(F, _CASADI, spec.names))
    g = [mean_over_samples(gd.spec, _CASADI.log_det) for gd in exact.guards]
    floors = [min(gd.bound, gd.log_det(counts)) for gd in exact.guards]
    nlp = {"x": v, "f": f / abs(loss0)}  # order 1, so that IPOPT's barrier starts small against it
    if g:
        nlp["g"] = ca.vertcat(*g)
    solver = ca.nlpsol("refine", "ipopt", nlp, {
        "ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes", "ipopt.max_iter": 200,
        "ipopt.bound_push": 1e-10, "ipopt.bound_frac": 1e-10, "ipopt.mu_init": 1e-6})
    args = {"x0": np.concatenate([az_u, r_u]), "lbx": lbx, "ubx": ubx}
    if g:
        args.update(lbg=np.array(floors) + 1e-7, ubg=np.full(len(g), np.inf))  # inside: IPOPT's tolerance
    sol = solver(**args)
    stats = solver.stats()
    # verify IPOPT's point independently: within the bounds, guards kept, loss lower
    vopt = np.clip(np.array(sol["x"]).ravel(), lbx, ubx)
    new = st.replace(azimuth=vopt[:n_az][ia], rate=vopt[n_az:][ir])
    X1 = new.inputs(mm, stand)
    rows = spec.numeric(X1, sigma)
    loss = _mean_loss(crit, rows, spec, counts)
    guards = [_Guard(gd.model, gd.spec, gd.spec.numeric(X1, sigma), gd.bound, gd.d_opt) for gd in exact.guards]
    # (guards to 1e-6 in log det, i.e. 1e-6/k in D-efficiency: IPOPT's tolerance and the clipping to the bounds)
    better = (loss < loss0 - 1e-9 * abs(loss0)
              and all(gd.log_det(counts) >= f - 1e-6 for gd, f in zip(guards, floors)))
    status = stats["return_status"]
    if not better:
        if not stats["success"]:
            raise DesignError(f"IPOPT refinement of rates and azimuths failed: {status}")
        return f"{status} (no improvement: the grid settings are kept)"
    exact.settings, exact.rows, exact.guards, exact.loss = new, rows, guards, loss
    return status if stats["success"] else f"{status} (its last point checked: feasible and better, kept)"


def paper_plan(azimuth0=0.0, costs=None, azimuths_deg=(0.0, 91.8795, 181.2953, 272.8711)):
    """The paper's plan: 3 alignments at each of 20, 40, 60 deg/s at one position, then 3 at
    40 deg/s at each of 4 stand azimuths (Table 1's, shifted by ``azimuth0``, rad; the one
    position is Table 1's first): 21 ten-minute alignments, start times from ``costs``."""
    costs = costs or Costs()
    rate = np.array([20.0] * 3 + [40.0] * 3 + [60.0] * 3 + [40.0] * 12) * units.DEG_PER_S
    az = np.concatenate([np.zeros(9), np.repeat(np.asarray(azimuths_deg) * units.DEG, 3)]) + azimuth0
    dur = np.full(rate.size, 600.0)
    return Plan(run=np.arange(1, rate.size + 1), rate=rate, azimuth=np.mod(az, 2 * np.pi),
                t_start=costs.schedule(rate, az, np.zeros(rate.size), np.zeros(rate.size), dur), duration=dur)


def plan_lines(plan):
    """Runs grouped by setting, in order: ``runs 1-5  -60 deg/s  az 294.62 deg ...``."""
    cols = plan.to_columns()
    keys = [cols["rate_dps"], cols["azimuth_deg"], cols["duration_s"]]
    if "tilt_x_arcsec" in cols:
        keys += [cols["tilt_x_arcsec"], cols["tilt_y_arcsec"]]
    key = np.round(np.column_stack(keys), 6)
    lines, i, n = [], 0, key.shape[0]
    while i < n:
        j = i
        while j + 1 < n and np.array_equal(key[j + 1], key[i]):
            j += 1
        ids = f"{plan.run[i]}" if i == j else f"{plan.run[i]}-{plan.run[j]}"
        text = (f"  runs {ids:<8} {key[i, 0]:+8.3f} deg/s  azimuth {key[i, 1]:8.3f} deg  {key[i, 2]:g} s"
                f"  from {plan.t_start[i] / units.HOUR:6.3f} h")
        if key.shape[1] > 3:
            text += f"  tilt ({key[i, 3]:+.0f}, {key[i, 4]:+.0f}) arcsec"
        lines.append(text)
        i = j + 1
    return lines


# ======================================================================= Monte Carlo
@dataclass(frozen=True)
class MonteCarloResult:
    """Empirical against predicted scatter of the estimates of a simulated plan.

    Attributes
    ----------
    names, units : tuple of str
    predicted_std : numpy.ndarray, shape (n_p,)
        The design's prediction (its heading-noise model), display units.
    empirical_std, mean : numpy.ndarray, shape (n_p,)
        Scatter and mean of the replicates' estimates, display units.
    run_scatter_ratio : float
        The simulated alignments' own heading scatter (each run of the plan across the
        replicates, pooled) over the noise model's sigma: how far the noise model is off.
    estimates : numpy.ndarray, shape (n_rep, n_p)
    n_rep : int
    """

    names: tuple
    units: tuple
    predicted_std: np.ndarray
    empirical_std: np.ndarray
    mean: np.ndarray
    run_scatter_ratio: float
    estimates: np.ndarray
    n_rep: int

    @property
    def ratio(self):
        """Empirical / predicted sigma of each parameter."""
        return self.empirical_std / self.predicted_std

    @property
    def propagated_std(self):
        """The prediction with the noise model scaled to the simulated alignments' scatter:
        what the design's information propagation predicts from the real run noise."""
        return self.predicted_std * self.run_scatter_ratio

    def to_dict(self):
        return {"n_rep": self.n_rep, "run_scatter_ratio": self.run_scatter_ratio, "parameters": {
            n: {"predicted_std": float(p), "empirical_std": float(e), "ratio": float(e / p),
                "propagated_std": float(p * self.run_scatter_ratio), "mean": float(m), "unit": u}
            for n, u, p, e, m in zip(self.names, self.units, self.predicted_std, self.empirical_std,
                                     self.mean)}}


def monte_carlo(plan, model=None, n_rep=100, *, truth=None, seed=0, jobs=1, tilt_known=True, progress=True,
                client=None):
    """Simulate ``plan`` ``n_rep`` times, fit each replicate, compare the scatter of the
    estimates with the prediction.

    The prediction is :func:`evaluate` on the stand of the simulated system (latitude, base
    tilt, gyro ARW). Replicate ``r`` uses run ids ``r n + 1 ... r n + n`` and so its own
    random numbers (:func:`hse_opt.sim.run_campaign` seeds each run by its id); every
    replicate has the plan's start times.

    Parameters
    ----------
    plan : hse_opt.data.Plan
    model : Model, str, sequence of str, or a list of models
        A list of :class:`~hse_opt.model.Model` (or ``"a,b"`` strings) fits every replicate
        with each and returns one result per model.
    n_rep : int
        Replicates, >= 2.
    truth : hse_opt.sim.TruthConfig, optional
        Default: the default simulated system.
    seed : int
    jobs : int
        Worker processes of the campaign runner.
    tilt_known : bool
    progress : bool
        A tqdm bar on stderr.
    client : dask.distributed.Client, optional

    Returns
    -------
    MonteCarloResult, or a tuple of them for a list of models
    """
    from .fit import fit
    from .sim import TruthConfig, run_campaign

    if isinstance(n_rep, bool) or int(n_rep) != n_rep or n_rep < 2:
        raise ValueError(f"n_rep = {n_rep!r}; allowed: an integer >= 2")
    n_rep = int(n_rep)
    several = isinstance(model, list) and all(isinstance(m, (Model, str)) for m in model)
    models = [as_model(m) for m in model] if several else [as_model(model)]
    truth = truth or TruthConfig.default()
    if any(v != 0 for v in truth.stand.tilt):
        raise ValueError("truth stand.tilt_arcsec (a tilt fixed in n) is not in the design's Stand model; "
                         "allowed: [0, 0] (the base tilt is stand.mount_tilt_arcsec)")
    # the truth's white heading noise: the gyros' own ARW and the pulse quantization (the
    # counters' remainder, dithered by the table jitter: q |Omega| sqrt(dt / 12)) at the plan's
    # RMS rate, in quadrature (studies/simulator_noise.py)
    rms_rate = float(np.sqrt(np.mean(np.square(plan.rate))))
    n_quant = truth.gyro.pulse * rms_rate * np.sqrt(truth.timing.sample_period / 12.0)
    stand = Stand(latitude=truth.site.latitude, tilt=tuple(truth.stand.mount_tilt),
                  arw=float(np.hypot(truth.gyro.arw, n_quant)))
    preds = [evaluate(plan, m, stand=stand, tilt_known=tilt_known) for m in models]
    cols, n = plan.to_columns(), plan.run.size
    rows = [{k: (r * n + i + 1 if k == "run" else float(v[i])) for k, v in cols.items()}
            for r in range(n_rep) for i in range(n)]
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(rows), unit="run", file=sys.stderr, desc="monte carlo")
    try:
        out = run_campaign(rows, truth, seed, jobs=jobs, client=client,
                           progress=None if bar is None else (lambda done, total: bar.update(done - bar.n)))
    finally:
        if bar is not None:
            bar.close()
    replicates = [out.subset(np.arange(r * n, (r + 1) * n)).replace(source=f"replicate {r}")
                  for r in range(n_rep)]
    # every replicate repeats each run's deterministic errors: the scatter across them is noise
    h = np.asarray(out.heading_err).reshape(n_rep, n)
    ratio = float(np.sqrt(np.mean(h.var(axis=0, ddof=1) / stand.sigma(plan.duration) ** 2)))
    results = []
    for m, pred in zip(models, preds):
        est = np.empty((n_rep, len(pred.names)))
        for r, runs in enumerate(replicates):
            res = fit(runs, m, tilt_known=tilt_known)
            est[r] = [res.values[res.names.index(nm)] for nm in pred.names]
        results.append(MonteCarloResult(pred.names, pred.units, pred.std, est.std(axis=0, ddof=1),
                                        est.mean(axis=0), ratio, est, n_rep))
    return tuple(results) if several else results[0]


class _CallableModule(types.ModuleType):
    """``hse_opt.design(model, criterion, budget=...)`` calls :func:`design`: the package
    exports this module under the function's name."""

    def __call__(self, *args, **kwargs):
        return design(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
