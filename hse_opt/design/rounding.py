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
from .order import min_time
from .problem import directional
from .space import Candidates

#: re-solves the setup-aware pruning may spend (a cap on the work; the design notes when it is reached)
MAX_PRUNE_TRIALS = 30


def apportion(weights, n):
    """Efficient rounding (Pukelsheim & Rieder 1992): whole numbers of runs summing to ``n``.

    ``n_i = ceil((n - l/2) q_i)`` for the ``l`` support points with proportions ``q``, then
    one run at a time is added where ``n_j / q_j`` is smallest, or removed where
    ``(n_j - 1) / q_j`` is largest, until the total is ``n``.

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
    q = w[s] / w[s].sum()
    m = np.maximum(np.ceil((n - q.size / 2.0) * q).astype(int), 0)
    while m.sum() < n:
        m[np.argmin(m / q)] += 1
    while m.sum() > n:
        m[np.argmax(np.where(m > 0, (m - 1) / q, -np.inf))] -= 1
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


def round_design(prob, w):
    """The largest n whose efficiently rounded plan fits the budget with its setups, then
    polished by one-run exchanges."""
    w = caratheodory(prob, w)
    sup = np.flatnonzero(w > 0)
    proportions = w[sup] / w[sup].sum()
    sub = prob.take(sup)
    settings, costs, budget = sub.candidates, prob.costs, prob.total_budget
    n_max = int(np.floor(prob.budget / sub.cost.min() + 1e-9))
    if prob.max_runs is not None:
        n_max = min(n_max, int(prob.max_runs))
    cache = {}
    for n in range(n_max, 0, -1):
        counts = apportion(proportions, n)
        if min_time(settings, counts, costs, cache) <= budget + 1e-6:
            break
    else:
        raise ValueError(f"budget {budget / units.HOUR:.4g} h: no whole-run plan fits it")
    counts = exchange(sub, counts, cache)
    keep = counts > 0
    return Exact(settings.take(keep), counts[keep], sub.rows[:, keep], tuple(g.take(keep) for g in sub.guards),
                 sub.loss(counts), proportions[keep])


def exchange(prob, counts, cache, max_iter=500, screen=24):
    """One-run exchanges (move a run between settings, or add one where time allows) that
    lower the loss, keep each guard at or above its bound (or where it started) and fit the
    budget. Moves are screened by their first-order effect (the directional derivatives);
    the ``screen`` most promising are evaluated exactly."""
    crit, rows, spec, guards = prob.criterion, prob.rows, prob.spec, prob.guards
    settings, costs, budget, max_runs = prob.candidates, prob.costs, prob.total_budget, prob.max_runs
    counts = counts.copy()
    m = counts.size
    run_time = prob.cost
    floors = [min(g.bound, g.log_det(counts)) for g in guards]
    best = prob.loss(counts)
    moves = [(i, j) for i in range(-1, m) for j in range(m) if i != j]
    for _ in range(max_iter):
        try:
            d = directional(crit, rows, spec, counts)
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
            elif c @ run_time > prob.budget or (max_runs is not None and c.sum() > max_runs):
                continue
            tried += 1
            loss = prob.loss(c)
            if (loss < best - 1e-12 * max(1.0, abs(best))
                    and all(g.log_det(c) >= f - 1e-9 for g, f in zip(guards, floors))
                    and min_time(settings, c, costs, cache) <= budget + 1e-6):
                counts, best = c, loss
                break
            if tried >= screen and order is not moves:
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
    pos = np.unique(np.column_stack([cand.not_before, cand.tilt_x, cand.tilt_y, np.mod(cand.azimuth, 2 * np.pi)])
                    .round(9), axis=0, return_inverse=True)[1].ravel()
    weight = np.bincount(pos, w)
    keep = set(np.flatnonzero(weight > SUPPORT_TOL * w.max()).tolist())
    prob = replace(prob, solver=prob.solver or SOLVERS[0])  # the trials: one solver, no fallback
    trials, improved = 0, True
    while improved and len(keep) > 1:
        improved = False
        for g in sorted(keep, key=lambda g: (weight[g], g)):
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
            if trial.loss < exact.loss:
                exact, improved = trial, True
                keep.discard(g)
                full = np.zeros(pos.size)
                full[idx] = reduced
                weight = np.bincount(pos, full, minlength=weight.size)
                break
    return exact, None
