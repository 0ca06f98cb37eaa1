"""Exact designs: whole runs from the approximate design, within the budget with its setups.

The approximate design's support is first reduced (:func:`caratheodory`: the same information
on fewer candidates), then rounded efficiently (:func:`apportion`, Pukelsheim & Rieder 1992)
to the largest number of runs whose plan fits the budget with its setup times, then polished
by one-run exchanges (:func:`exchange`). Setups are not linear in the run numbers: a greedy
search (:func:`prune`) drops stand positions while the rounded plan gets better.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .. import units
from .approximate import SOLVERS, SUPPORT_TOL, DesignError, solve_approximate
from .reduction import caratheodory
from . import ties
from .order import fits
from .problem import directional
from .space import Candidates
from .ties import VALUE_RTOL, WEIGHT_RTOL

#: re-solves the setup-aware pruning may spend (a cap on the work; the design notes when it is reached)
MAX_PRUNE_TRIALS = 30


def apportion(weights, n, rank=None):
    """Efficient rounding (Pukelsheim & Rieder 1992): whole numbers of runs summing to ``n``.

    ``n_i = ceil((n - l/2) q_i)`` for the ``l`` support points with proportions ``q``, then
    one run at a time is added where ``n_j / q_j`` is smallest, or removed where
    ``(n_j - 1) / q_j`` is largest, until the total is ``n``. Ratios equal within
    :data:`~.ties.WEIGHT_RTOL` are ties, won by the lowest ``rank``.

    Parameters
    ----------
    weights : array_like, shape (m,)
        Nonnegative design weights (any scale).
    n : int
        Total number of runs, >= 1.
    rank : array_like of int, shape (m,), optional
        Tie-break order (default: the index).

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
    rank = (np.arange(w.size) if rank is None else np.asarray(rank))[s]
    q = w[s] / w[s].sum()
    # ceil, with a product within WEIGHT_RTOL of a whole number taken as that number
    x = (n - q.size / 2.0) * q
    m = np.maximum(np.ceil(x - WEIGHT_RTOL * np.maximum(np.abs(x), 1.0)).astype(int), 0)
    while m.sum() < n:
        m[ties.argmin(m / q, rank, WEIGHT_RTOL)] += 1
    while m.sum() > n:
        m[ties.argmin(np.where(m > 0, -(m - 1) / q, np.inf), rank, WEIGHT_RTOL)] -= 1
    out[s] = m
    return out


@dataclass
class Exact:
    """Whole runs on support settings (with their rows and guards)."""

    settings: Candidates
    counts: np.ndarray
    rows: np.ndarray
    guards: tuple
    loss: float
    proportions: np.ndarray  # the approximate design's proportions that were rounded (same order)
    slot: np.ndarray  # time slot of each setting

    def slot_times(self, run_overhead, n_slots):
        """Alignment time (with the per-run overheads) in each time slot, s, (n_slots,)."""
        return np.bincount(self.slot, self.counts * (self.settings.duration + run_overhead), minlength=n_slots)


def round_design(prob, w):
    """The largest n whose efficiently rounded plan fits the budget with its setups, then
    polished by one-run exchanges. With time slots each slot is rounded in turn, the largest
    number of its runs that end within the slot (:func:`~.order.fits`): the approximate
    design gave each slot its share, and its runs are seen there."""
    w = caratheodory(prob, w)
    sup = np.flatnonzero(w > 0)
    proportions = w[sup] / w[sup].sum()
    sub = prob.take(sup)
    settings, costs, budget = sub.candidates, prob.costs, prob.total_budget
    slot_length = prob.slot_length if prob.n_slots > 1 else None
    cache = {}

    def fit(c):
        return fits(settings, c, costs, budget, slot_length, cache)

    def most(idx, counts, limit):
        """``counts`` with the most runs on ``idx`` (apportioned) that fit, at most ``limit``."""
        for n in range(limit, -1, -1):
            c = counts.copy()
            c[idx] = apportion(proportions[idx], n, sub.rank[idx]) if n else 0
            if fit(c):
                return c
        return counts

    limit = int(np.floor(prob.budget / sub.cost.min() + 1e-9))
    if prob.max_runs is not None:
        limit = min(limit, int(prob.max_runs))
    counts = np.zeros(sup.size, int)
    if slot_length is None:
        counts = most(np.arange(sup.size), counts, limit)
    else:
        for k in np.unique(sub.slot):
            idx = np.flatnonzero(sub.slot == k)
            per_slot = int(np.floor(prob.slot_budget[k] / sub.cost[idx].min() + 1e-9))
            counts = most(idx, counts, min(per_slot, limit - int(counts.sum())))
    if counts.sum() == 0:
        raise ValueError(f"budget {budget / units.HOUR:.4g} h: no whole-run plan fits it"
                         + (" (each run must end within its time slot)" if slot_length else "")
                         + "; allowed: a budget (--budget-h) of at least one run with its set-up")
    counts = exchange(sub, counts, fit)
    keep = counts > 0
    return Exact(settings.take(keep), counts[keep], sub.rows[:, keep], tuple(g.take(keep) for g in sub.guards),
                 sub.loss(counts), proportions[keep], sub.slot[keep])


def exchange(prob, counts, fit, max_iter=500, screen=24):
    """One-run exchanges (move a run between settings, or add one where time allows) that
    lower the loss, keep each guard at or above its bound (or where it started) and ``fit``
    (counts -> bool: within the budget and the time slots). Moves are screened by their
    first-order effect (the directional derivatives; equal within :data:`~.ties.VALUE_RTOL`,
    by the settings' rank); the ``screen`` most promising are evaluated exactly, the first
    that lowers the loss by more than that tolerance is made."""
    crit, rows, spec, guards = prob.criterion, prob.rows, prob.spec, prob.guards
    max_runs = prob.max_runs
    counts = counts.copy()
    m = counts.size
    run_time = prob.cost
    floors = [min(g.bound, g.level(counts)) for g in guards]
    best = prob.loss(counts)
    src, dst = (a.ravel() for a in np.meshgrid(np.arange(-1, m), np.arange(m), indexing="ij"))
    src, dst = src[src != dst], dst[src != dst]
    by_rank = np.lexsort((prob.rank[dst], np.where(src >= 0, prob.rank[src], -1)))
    src, dst = src[by_rank], dst[by_rank]
    for _ in range(max_iter):
        try:
            d = directional(crit, rows, spec, counts)
            first = d[dst] - np.where(src >= 0, d[src], 0.0)
            order = np.lexsort((np.arange(src.size), ties.levels(first, VALUE_RTOL, np.max(np.abs(d)))))
            limit = screen
        except ValueError:  # no gradient: evaluate every move
            order, limit = np.arange(src.size), None
        tried = 0
        for i, j in zip(src[order], dst[order]):
            if i >= 0 and counts[i] == 0:
                continue
            c = counts.copy()
            c[j] += 1
            if i >= 0:
                c[i] -= 1
            elif c @ run_time > prob.budget or (max_runs is not None and c.sum() > max_runs):
                continue
            tried += 1
            loss = prob.loss(c)
            if (loss < best - VALUE_RTOL * (max(1.0, abs(best)) if crit.degree == 0 else abs(best))
                    and all(g.level(c) >= f - 1e-9 for g, f in zip(guards, floors)) and fit(c)):
                counts, best = c, loss
                break
            if limit is not None and tried >= limit:
                return counts
        else:
            return counts
    return counts


def prune(prob, w, exact, max_trials=MAX_PRUNE_TRIALS):
    """Greedy setup-aware search: remove one stand position (time slot, tilt, azimuth) of the
    approximate design ``w`` (reduced by :func:`caratheodory`, so at most as many positions as
    the design has linear maps) at a time -- the lightest first -- re-solve on the candidates
    of the others and round; keep the first removal that gives a better rounded plan, and go
    on until none does, or ``max_trials`` re-solves are spent. Returns the best plan and a
    note when the cap stopped the search."""
    cand = prob.candidates
    pos = cand.positions()
    weight = np.bincount(pos, w)
    keep = set(np.flatnonzero(weight > SUPPORT_TOL * w.max()).tolist())
    prob = replace(prob, solver=prob.solver or SOLVERS[0])  # the trials: one solver, no fallback
    trials, improved = 0, True
    while improved and len(keep) > 1:
        improved = False
        light = ties.levels(weight, WEIGHT_RTOL, w.max())
        for g in sorted(keep, key=lambda g: (light[g], g)):
            if trials >= max_trials:
                return exact, (f"setup-aware pruning stopped at its cap of {max_trials} re-solves; the plan keeps "
                               f"{len(keep)} stand positions (prune=False skips the search)")
            trials += 1
            idx = np.flatnonzero(np.isin(pos, sorted(keep - {g})))
            sub = prob.take(idx)
            try:
                reduced = caratheodory(sub, solve_approximate(sub, polish=False, target=0.999).runs)
                trial = round_design(sub, reduced)
            except (ValueError, DesignError):  # the others cannot identify the model, or meet a guard
                continue
            if trial.loss < exact.loss - VALUE_RTOL * abs(exact.loss):
                exact, improved = trial, True
                keep.discard(g)
                full = np.zeros(pos.size)
                full[idx] = reduced
                weight = np.bincount(pos, full, minlength=weight.size)
                break
    return exact, None
