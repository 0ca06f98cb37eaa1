"""Support reduction (Caratheodory): the same information on as few candidates as possible.

Interior-point solvers return the most spread-out optimum when it is not unique (E-optimal
designs spread over thousands of candidates); a design on fewer points rounds to whole runs
with less loss and fewer setups, and keeps the column generation's convex programs small.
"""
from __future__ import annotations

import numpy as np

#: approximate-design weights below this fraction of the largest are solver noise
SUPPORT_TOL = 1e-4


def caratheodory(prob, w):
    """A design with the same information matrices (every sample, every guard), alignment
    time, number of runs and time per slot as ``w`` on as few candidates as that allows
    (Caratheodory). Interior-point solvers return the most spread-out optimum when it is not
    unique; fewer support points round to whole runs with less loss and fewer setups.

    The ``p`` linear maps (information entries, time, runs, time per slot) of any ``p + 1``
    support points are dependent: along a null direction of those columns the design keeps
    every map while one weight reaches 0. The lightest ``p + 1`` points are taken each step,
    so the heaviest stay; each step costs O(p^3), the reduction O(p^3 n) for ``n`` support
    points (never an n x n matrix)."""
    cost, slot, n_slots = prob.cost, prob.slot, prob.n_slots
    all_rows = [prob.rows, *[g.rows for g in prob.guards]]
    sup = np.flatnonzero(w > SUPPORT_TOL * w.max())
    out = np.zeros_like(w)
    iu = [np.triu_indices(r.shape[2]) for r in all_rows]
    cols = [r[:, sup][:, :, i] * r[:, sup][:, :, j] for r, (i, j) in zip(all_rows, iu)]
    parts = [c.transpose(1, 0, 2).reshape(sup.size, -1) for c in cols]
    parts += [cost[sup, None], np.ones((sup.size, 1)), (slot[sup, None] == np.arange(n_slots)[None, :])]
    A = np.hstack(parts).T
    A /= np.maximum(np.abs(A).max(axis=1, keepdims=True), 1e-300)
    x = w[sup].astype(float)
    live = list(np.argsort(x, kind="stable"))  # positions in sup, lightest first
    q = A.shape[0] + 1
    while len(live) > 1:
        pick = np.array(live[:q])
        _, s, vt = np.linalg.svd(A[:, pick], full_matrices=True)
        rank = int(np.sum(s > 1e-10 * s.max()))
        if rank >= pick.size:  # independent: only when every live point is in ``pick``
            break
        v = vt[rank]
        if not np.any(v < 0):
            v = -v
        neg = np.flatnonzero(v < 0)
        ratio = x[pick[neg]] / -v[neg]
        j = neg[np.argmin(ratio)]
        x[pick] = np.maximum(x[pick] + ratio.min() * v, 0.0)
        x[pick[j]] = 0.0
        gone = set(pick[x[pick] <= SUPPORT_TOL * x.max()].tolist())
        live = [i for i in live[:q] if i not in gone] + live[q:]
    out[sup[live]] = x[live]
    return out
