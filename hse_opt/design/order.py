"""Run order: which sequence of a plan's runs the stand goes through.

Runs sharing a setting run together and settings are grouped by their most expensive factor,
which keeps setup time low (:func:`orders`); among such orders (and folded ones, ABBA-like) the
one least sensitive to a slow linear heading drift is taken (``trend-robust``), or the
quickest (``min-setup``): :func:`pick_order`. :func:`min_time` is the least time a plan with
given run numbers takes, :func:`fits` whether it fits the budget and its time slots.
"""
from __future__ import annotations

import itertools

import numpy as np

from . import ties
from .evaluation import DRIFT_UNIT
from .ties import VALUE_RTOL


def group_labels(settings, costs):
    """Labels of each setting's time slot, then its factors by falling change cost (tilt,
    azimuth, rate, duration in the order of ``costs``): shape (5, n)."""
    keys = {"slot": settings.not_before[:, None] / 1e-6,
            "tilt": np.column_stack([settings.tilt_x, settings.tilt_y]) / 1e-12,
            "azimuth": np.mod(settings.azimuth, 2 * np.pi)[:, None] / 1e-12,
            "rate": settings.rate[:, None] / 1e-12, "duration": settings.duration[:, None] / 1e-9}
    cost = {"slot": np.inf, "tilt": costs.tilt_change, "azimuth": costs.azimuth_change,
            "rate": costs.rate_change, "duration": 0.0}
    return np.array([np.unique(np.round(keys[f]), axis=0, return_inverse=True)[1].ravel()
                     for f in sorted(keys, key=lambda f: -cost[f])])


def orders(settings, counts, costs, rng=None, n_random=0, labels=None):
    """Run sequences (arrays of setting indices): each setting's runs together, settings
    in time-slot order, then grouped by their costliest factor (tilt, azimuth, rate, duration
    in the order of the change costs), serpentine (the next group starts where the last
    ended), plain or folded (ABBA: first halves of the groups, then the second halves in
    reverse); ``n_random`` more with random group orders and folds. ``labels``: the
    settings' :func:`group_labels`, when known."""
    labels = group_labels(settings, costs) if labels is None else labels
    key = {int(i): tuple(int(v) for v in labels[:, i]) for i in np.flatnonzero(counts > 0)}

    def tree(members, depth):
        if depth == len(labels):  # settings alike in every factor (refinement can make them so) run together
            return members[0] if len(members) == 1 else list(members)
        groups = itertools.groupby(sorted(members, key=lambda i: key[i][depth]), key=lambda i: key[i][depth])
        return [tree(list(g), depth + 1) for _, g in groups]

    root = tree(list(key), 0)

    def expand(t, reverse, r, fold_p, top=False):
        if not isinstance(t, list):
            return [t] * int(counts[t])
        kids = [t[i] for i in r.permutation(len(t))] if r is not None and not top else list(t)
        # reflected (as a Gray code): every other child reversed, and a reversed node's whole
        # sequence reversed, so that a group starts where the last ended at every level
        seqs = [expand(c, reverse != (j % 2 == 1), r, fold_p) for j, c in enumerate(kids)]
        if reverse:
            seqs = seqs[::-1]
        fold = not top and len(seqs) > 1 and (r.random() < fold_p if r is not None else fold_p > 0)
        if not fold:
            return [i for s in seqs for i in s]
        half = [(len(s) + 1) // 2 for s in seqs]
        return ([i for s, h in zip(seqs, half) for i in s[:h]]
                + [i for s, h in zip(reversed(seqs), reversed(half)) for i in s[h:]])

    out = [expand(root, False, None, 0.0, True), expand(root, False, None, 1.0, True)]
    out += [expand(root, False, rng, rng.choice([0.0, 0.25, 0.5]), True) for _ in range(n_random)]
    return [np.array(s) for s in dict.fromkeys(tuple(s) for s in out)]


def _labels(settings, costs, cache):
    """:func:`group_labels`, kept in ``cache`` (None: computed, not kept)."""
    if cache is None:
        return None
    if "labels" not in cache:
        cache["labels"] = group_labels(settings, costs)
    return cache["labels"]


def min_time(settings, counts, costs, cache=None):
    """Least total time (s) of a plan in one time slot with these counts over the
    deterministic orders: its setups (which depend only on which settings are used, so
    ``cache`` keeps them by that pattern) plus its alignments."""
    used = counts > 0
    key = used.tobytes()
    if cache is None or key not in cache:
        labels = _labels(settings, costs, cache)
        setup = min(float(costs.setups(s.rate, s.azimuth, s.tilt_x, s.tilt_y).sum())
                    for s in (settings.take(seq) for seq in orders(settings, used.astype(int), costs, labels=labels)))
        if cache is None:
            cache = {}
        cache[key] = setup
    return cache[key] + float(counts @ (settings.duration + costs.run_overhead)) - costs.run_overhead


def in_slots(settings, seq, costs, budget, slot_length):
    """Whether the runs in the order ``seq`` end within ``budget`` (s since power-on) and
    each within its time slot (``not_before + slot_length``)."""
    s = settings.take(seq)
    end = costs.schedule(s.rate, s.azimuth, s.tilt_x, s.tilt_y, s.duration, s.not_before) + s.duration
    return bool(end[-1] <= budget + 1e-6 and np.all(end <= s.not_before + slot_length + 1e-6))


def fits(settings, counts, costs, budget, slot_length=None, cache=None):
    """Whether a plan with these run numbers fits ``budget`` (s since power-on) in one of the
    deterministic orders; with time slots (``slot_length``, s) every run must also end within
    its slot, as the approximate design's slot shares assume (the runs are seen there)."""
    counts = np.asarray(counts)
    if slot_length is None:
        return min_time(settings, counts, costs, cache) <= budget + 1e-6
    if not counts.any():
        return True
    key = ("slots", counts.tobytes())
    if cache is None or key not in cache:
        labels = _labels(settings, costs, cache)
        ok = any(in_slots(settings, seq, costs, budget, slot_length)
                 for seq in orders(settings, counts, costs, labels=labels))
        if cache is None:
            return ok
        cache[key] = ok
    return cache[key]


def pick_order(exact, prob, stand, order, rng):
    """The sequence with the least standardised drift bias on the criterion's parameters
    (``trend-robust``) or the least time (``min-setup``), within the budget (and with time
    slots, every run within its slot); scores equal to :data:`~.ties.VALUE_RTOL` are ties,
    which go to the first sequence."""
    spec, crit, costs, budget = prob.spec, prob.criterion, prob.costs, prob.total_budget
    interest = [i for i, nm in enumerate(spec.names) if nm in crit.interest(spec.names)] or list(range(spec.k))
    rows = exact.rows[0]
    best = None
    for seq in orders(exact.settings, exact.counts, costs, rng, n_random=300):
        s = exact.settings.take(seq)
        t = costs.schedule(s.rate, s.azimuth, s.tilt_x, s.tilt_y, s.duration, s.not_before)
        total = float(t[-1] + s.duration[-1])
        if total > budget + 1e-6 or (prob.n_slots > 1 and not in_slots(exact.settings, seq, costs, budget,
                                                                        prob.slot_length)):
            continue
        a = rows[seq]
        cov = np.linalg.pinv(spec.prior + a.T @ a)
        mid = t + s.duration / 2
        b = cov @ (a.T @ ((mid - mid.mean()) * DRIFT_UNIT / stand.sigma(s.duration)))
        score = float(np.max(np.abs(b[interest]) / np.sqrt(np.maximum(np.diag(cov)[interest], 1e-300))))
        key = (score, total) if order == "trend-robust" else (total, score)
        if best is None or ties.less(key, best[0], VALUE_RTOL):
            best = (key, seq)
    return best[1]

