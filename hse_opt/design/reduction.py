"""Support reduction (Caratheodory): the same information on as few candidates as possible.

Interior-point solvers return the most spread-out optimum when it is not unique (E-optimal
designs spread over thousands of candidates); a design on fewer points rounds to whole runs
with less loss and fewer setups, and keeps the column generation's convex programs small.
Among the designs with the same information, one on few stand positions is sought first
(:func:`few_positions`): every position costs a setup.
"""
from __future__ import annotations

import numpy as np

from . import ties
from .ties import WEIGHT_RTOL

#: approximate-design weights below this fraction of the largest are solver noise
SUPPORT_TOL = 1e-4


def linear_maps(prob, sup):
    """The maps the reduction keeps, as columns of the support points ``sup``: the entries of
    every information matrix (each sample, each guard), time, runs and time per slot; each
    row scaled to a largest entry of 1. Shape (p, sup.size)."""
    cost, slot, n_slots = prob.cost, prob.slot, prob.n_slots
    all_rows = [prob.rows, *[g.rows for g in prob.guards]]
    iu = [np.triu_indices(r.shape[2]) for r in all_rows]
    cols = [r[:, sup][:, :, i] * r[:, sup][:, :, j] for r, (i, j) in zip(all_rows, iu)]
    parts = [c.transpose(1, 0, 2).reshape(sup.size, -1) for c in cols]
    parts += [cost[sup, None], np.ones((sup.size, 1)), (slot[sup, None] == np.arange(n_slots)[None, :])]
    A = np.hstack(parts).T
    return A / np.maximum(np.abs(A).max(axis=1, keepdims=True), 1e-300)


def few_positions(prob, w, rounds=6):
    """A design with the same linear maps as ``w`` (:func:`linear_maps`) on few stand positions.

    The designs with ``w``'s information form a polytope ``{x >= 0: A x = A w}`` over ``w``'s
    support (the whole optimal face when ``w`` is an interior-point solution); a linear
    program reaches one of its vertices (at most ``p`` points), and reweighting the cost of
    each point by the inverse weight of its position (reweighted l1, a few rounds) steers it
    to a vertex on few positions. Costs equal to rounding are ordered by the candidates'
    rank. Returns ``w`` itself when there is no choice (no candidates, a unique design) or
    the program fails."""
    from scipy.optimize import linprog

    sup = np.flatnonzero(w > SUPPORT_TOL * w.max())
    if prob.candidates is None:
        return w
    A = linear_maps(prob, sup)
    pos = prob.candidates.take(sup).positions()
    if sup.size <= A.shape[0] or pos.max() == 0:  # (nearly) a vertex already, or one position
        return w
    x = w[sup].astype(float)
    b = A @ x
    tie = 1.0 + 1e-6 * np.argsort(np.argsort(prob.rank[sup])) / sup.size  # canonical among equal costs
    used = None
    for _ in range(rounds):
        weight = np.bincount(pos, x)
        res = linprog(tie / (weight[pos] + 1e-3 * x.sum()), A_eq=A, b_eq=b, bounds=(0, None), method="highs")
        if res.status != 0 or not np.allclose(A @ res.x, b, rtol=0, atol=1e-9 * np.abs(b).max()):
            break
        x = np.clip(res.x, 0.0, None)
        now = np.unique(pos[x > SUPPORT_TOL * x.max()])
        if used is not None and np.array_equal(now, used):
            break
        used = now
    out = np.zeros_like(w)
    out[sup] = x
    return out


def caratheodory(prob, w):
    """A design with the same information matrices (every sample, every guard), alignment
    time, number of runs and time per slot as ``w`` on as few candidates as that allows
    (Caratheodory), and few stand positions (:func:`few_positions`). Interior-point solvers
    return the most spread-out optimum when it is not unique; fewer support points round to
    whole runs with less loss and fewer setups.

    The ``p`` linear maps (information entries, time, runs, time per slot) of any ``p + 1``
    support points are dependent: along a null direction of those columns the design keeps
    every map while one weight reaches 0. The lightest ``p + 1`` points are taken each step,
    so the heaviest stay (weights equal within :data:`~.ties.WEIGHT_RTOL` by the candidates'
    rank, and so is the point that leaves); each step costs O(p^3), the reduction O(p^3 n) for
    ``n`` support points (never an n x n matrix)."""
    w = few_positions(prob, w)
    sup = np.flatnonzero(w > SUPPORT_TOL * w.max())
    out = np.zeros_like(w)
    A = linear_maps(prob, sup)
    x = w[sup].astype(float)
    rank = prob.rank[sup]
    live = list(ties.order(x, rank, WEIGHT_RTOL))  # positions in sup, lightest first (canonical ties)
    q = A.shape[0] + 1
    while len(live) > 1:
        pick = np.array(live[:q])
        _, s, vt = np.linalg.svd(A[:, pick], full_matrices=True)
        r = int(np.sum(s > 1e-10 * s.max()))
        if r >= pick.size:  # independent: only when every live point is in ``pick``
            break
        v = vt[r]  # its sign is the SVD's: made canonical (largest entry positive), then
        v = v * np.sign(v[ties.argmin(-np.abs(v), rank[pick], WEIGHT_RTOL)])  # as needed to lower one
        if not np.any(v < 0):
            v = -v
        neg = np.flatnonzero(v < 0)
        ratio = x[pick[neg]] / -v[neg]
        j = neg[ties.argmin(ratio, rank[pick[neg]], WEIGHT_RTOL)]
        x[pick] = np.maximum(x[pick] + ratio[neg == j][0] * v, 0.0)
        x[pick[j]] = 0.0
        gone = set(pick[x[pick] <= SUPPORT_TOL * x.max()].tolist())
        live = [i for i in live[:q] if i not in gone] + live[q:]
    out[sup[live]] = x[live]
    return out
