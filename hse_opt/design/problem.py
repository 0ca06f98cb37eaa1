"""The design problem: the information rows of the candidate runs and what a plan must meet.

A run adds ``a a^T`` to the Fisher information of the parameters; :class:`Rows` builds the
rows ``a`` (display units, over the heading sigma) of a model -- or of a criterion that brings
its own rows -- at each parameter sample (the nominal values or prior draws). :class:`Guard` is
a model the plan must also identify; :class:`Problem` bundles the criterion, the rows, the
guards, the run costs and the budget, the one argument of every step of :func:`~hse_opt.design.design`.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import casadi as ca
import numpy as np

from ..information import Prior
from ..model.composition import Model
from ..model.measurement import BatchEvaluator
from .criteria import Criterion, D
from .space import Candidates, Costs


class Rows:
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


def own(sample, mm):
    return {k: v for k, v in sample.items() if k in mm.names}


def model_rows(mm, samples, prior=None):
    p = ca.SX.sym("p", len(mm.names))
    x = ca.SX.sym("x", mm.n_x)
    fn = ca.Function("rows", [p, x], [mm.J(p, x) * ca.DM(mm.scale).T])
    return Rows(mm.names, fn, [mm.vector(own(s, mm)) for s in samples], prior)


def criterion_rows(crit, model, tilt_known, samples, prior):
    mm = model.measurement(tilt_known)
    custom = crit.features(model, tilt_known)
    if custom is None:
        return model_rows(mm, samples, prior)
    if prior is not None:
        raise ValueError(f"criterion {crit.label} builds its own information rows: prior information cannot "
                         "be used with it")
    names, fn, values = custom
    return Rows(names, fn, [mm.vector({**own(s, mm), **values}) for s in samples])


def samples_of(nominal, prior_sample):
    """List of dicts name -> display value: the nominal values, or one per prior draw."""
    base = dict(nominal or {})
    if not prior_sample:
        return [base]
    cols = {k: np.atleast_1d(np.asarray(v, float)) for k, v in prior_sample.items()}
    lengths = {k: v.size for k, v in cols.items()}
    if len(set(lengths.values())) != 1 or min(lengths.values()) < 1:
        raise ValueError(f"prior_sample: draws per parameter {lengths}; allowed: equal numbers, at least one")
    return [{**base, **{k: float(v[i]) for k, v in cols.items()}} for i in range(next(iter(lengths.values())))]


@dataclass(frozen=True)
class Guard:
    """A constraint on the plan: a concave function of the information of its own rows at the
    candidates, kept at or above ``bound``.

    Two kinds: a model the plan must also identify (``criterion`` D: the mean log det of its
    information, the bound a D-efficiency against its own D-optimum ``d_opt``), and a power
    floor against an effect outside the model (``criterion``
    :class:`~hse_opt.design.criteria.LackOfFit` on the rows ``[J_model, J_effect delta] /
    sigma``: the noncentrality of the diagnosis' test of the effect at size ``delta``,
    :mod:`~hse_opt.design.protection`; ``d_opt`` nan).
    """

    model: Model
    spec: Rows
    rows: np.ndarray
    bound: float
    d_opt: float
    criterion: Criterion = D()
    label: str = ""

    def take(self, idx):
        return replace(self, rows=self.rows[:, idx])

    def at(self, rows):
        """The same guard with the rows of other settings."""
        return replace(self, rows=rows)

    def level(self, counts):
        """The guarded function (mean over the samples) for run numbers ``counts``: the log
        det of a D guard, the noncentrality of a power floor."""
        return -mean_loss(self.criterion, self.rows, self.spec, counts)

    @property
    def is_power(self):
        """A power floor (not a model to identify)."""
        return not isinstance(self.criterion, D)


@dataclass(frozen=True)
class Problem:
    """One design problem: what every step (approximate design, certificate, rounding,
    exchanges, pruning) works on.

    Attributes
    ----------
    criterion : Criterion
    spec : Rows
        Column names, prior information and the row builder of the criterion.
    rows : numpy.ndarray, shape (S, n, k)
        Weighted rows of every candidate at every parameter sample.
    guards : tuple of Guard
        Models the plan must also identify (their rows at the same candidates).
    cost : numpy.ndarray, shape (n,)
        Time one run of each candidate takes (alignment + overhead, s; or any unit).
    budget : float
        Budget for ``sum_i w_i cost_i`` (the alignment time after the warm-up).
    max_runs : int or None
    slot : numpy.ndarray of int, shape (n,)
        Time slot of each candidate (0 ... n_slots - 1); each slot has ``budget / n_slots``
        (or its ``shares`` entry).
    n_slots : int
    candidates : Candidates or None
        The settings (None for :func:`~hse_opt.design.approximate_design` on given rows).
    costs : Costs or None
        Setup costs (rounding to whole runs needs them).
    solver : str or None
        cvxpy solver (None: Clarabel, then SCS).
    shares : numpy.ndarray, shape (n_slots,), or None
        Budget of each time slot (summing to ``budget``; None: equal shares). The rounded
        plan's own slot times, for the optimum it is measured against.
    rank : numpy.ndarray of int, shape (n,)
        Canonical rank of each candidate, which wins ties (:mod:`~hse_opt.design.ties`;
        default: the candidates' settings order, else their index).
    """

    criterion: Criterion
    spec: Rows
    rows: np.ndarray
    guards: tuple = ()
    cost: np.ndarray = None
    budget: float = 1.0
    max_runs: int | None = None
    slot: np.ndarray = None
    n_slots: int = 1
    candidates: Candidates | None = None
    costs: Costs | None = None
    solver: str | None = None
    shares: np.ndarray | None = None
    rank: np.ndarray = None

    def __post_init__(self):
        n = self.rows.shape[1]
        if self.rank is None:
            object.__setattr__(self, "rank", np.arange(n) if self.candidates is None else self.candidates.rank())
        if self.cost is None:
            object.__setattr__(self, "cost", np.ones(n))
        if self.slot is None:
            object.__setattr__(self, "slot", np.zeros(n, int))

    @property
    def n(self):
        return int(self.cost.size)

    @property
    def total_budget(self):
        """Whole test time: the alignment budget plus the warm-up, s."""
        return self.budget + self.costs.warmup

    def take(self, idx):
        """The problem on a subset of the candidates (same slots and budget)."""
        return replace(self, rows=self.rows[:, idx], guards=tuple(g.take(idx) for g in self.guards),
                       cost=self.cost[idx], slot=self.slot[idx], rank=self.rank[idx],
                       candidates=None if self.candidates is None else self.candidates.take(idx))

    def extended(self, settings, rows, guard_rows, cost, slot):
        """The problem with more candidates (e.g. a refined plan's settings, off the grid):
        their ``settings`` (Candidates), weighted ``rows`` (S, m, k), each guard's rows,
        ``cost`` and ``slot`` (m,); they rank after the others in ties."""
        cand = self.candidates
        if cand is not None:
            cand = Candidates(*(np.concatenate([getattr(cand, f), getattr(settings, f)])
                                for f in Candidates._fields()))
        m = np.size(cost)
        return replace(self, rows=np.concatenate([self.rows, rows], axis=1),
                       guards=tuple(g.at(np.concatenate([g.rows, r], axis=1)) for g, r in zip(self.guards, guard_rows)),
                       cost=np.concatenate([self.cost, cost]), slot=np.concatenate([self.slot, slot]),
                       rank=np.concatenate([self.rank, self.rank.max() + 1 + np.arange(m)]), candidates=cand)

    @property
    def slot_budget(self):
        """Budget of each time slot, shape (n_slots,)."""
        if self.shares is None:
            return np.full(self.n_slots, self.budget / self.n_slots)
        return np.asarray(self.shares, float)

    @property
    def slot_length(self):
        """Length of a time slot, s: the runs of a slot start and end within it."""
        return self.budget / self.n_slots

    def with_budget(self, budget, shares=None):
        """The same problem for another budget (``shares``: its split over the time slots,
        summing to ``budget``; default equal)."""
        return replace(self, budget=float(budget), shares=None if shares is None else np.asarray(shares, float))

    def loss(self, w):
        """Criterion loss (mean over the samples) of the run numbers ``w``."""
        return mean_loss(self.criterion, self.rows, self.spec, w)

    def lagrangian_gradient(self, w, mus, h=None):
        """Gradient in w of ``-loss + sum mu_j (level_j - bound_j)`` (``h``: the
        criterion's part, when given)."""
        h = -directional(self.criterion, self.rows, self.spec, w) if h is None else np.array(h, float)
        for g, mu in zip(self.guards, mus):
            if mu > 0:
                h -= mu * directional(g.criterion, g.rows, g.spec, w)
        return h


def mean_loss(crit, rows, spec, w):
    """Loss of ``crit`` averaged over the samples, for run numbers ``w``."""
    return float(np.mean([crit.value(F, spec.names) for F in spec.information(rows, w)]))


def directional(crit, rows, spec, w):
    """d(mean loss)/dw_i of every candidate, (n,)."""
    g = np.zeros(rows.shape[1])
    for s, F in enumerate(spec.information(rows, w)):
        g += np.einsum("ni,ij,nj->n", rows[s], crit.gradient(F, spec.names), rows[s])
    return g / rows.shape[0]


def prior_information(prior, names):
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

