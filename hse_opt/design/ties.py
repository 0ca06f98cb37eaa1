"""Canonical tie-breaks: the design's discrete choices do not depend on floating-point noise.

Symmetric candidates (e.g. azimuths 180 deg apart when the model's azimuth terms are even)
give exactly tied weights, losses and derivatives, whose last bits then depend on the BLAS
build, its threads and the summation order; a plain ``argmin`` would pick another plan on
another machine. Every discrete choice of the design (apportionment, support reduction,
column generation, exchanges, pruning, run order) takes values within a relative tolerance
as equal and then prefers the lower canonical rank: the candidates' settings in lexicographic
order (:meth:`~hse_opt.design.space.Candidates.rank`), which no permutation of the candidates
changes.
"""
from __future__ import annotations

import numpy as np

#: design weights: conic solvers end at ~1e-8, symmetric candidates differ by rounding noise
WEIGHT_RTOL = 1e-6
#: losses, derivatives and scores computed in float64 (noise ~1e-13 relative)
VALUE_RTOL = 1e-9


def levels(values, rtol, scale=None):
    """``values`` on a grid of ``rtol * scale`` (``scale``: the largest finite magnitude):
    equal levels are ties. Infinite values keep their sign."""
    v = np.asarray(values, float)
    if scale is None:
        finite = np.abs(v[np.isfinite(v)])
        scale = float(finite.max()) if finite.size else 0.0
    if not scale > 0:
        return np.where(np.isfinite(v), 0.0, v)
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(v), np.round(v / (rtol * scale)), v)


def order(values, rank, rtol, scale=None):
    """Indices sorting ``values`` ascending, ties (:func:`levels`) by ascending ``rank``."""
    return np.lexsort((np.asarray(rank), levels(values, rtol, scale)))


def argmin(values, rank, rtol):
    """Index of the smallest value; values within ``rtol`` (relative to the smallest's
    magnitude) of it are ties, won by the lowest ``rank``."""
    v = np.asarray(values, float)
    lo = float(np.min(v))
    tied = np.flatnonzero(v <= lo + rtol * abs(lo)) if np.isfinite(lo) else np.flatnonzero(v == lo)
    return int(tied[np.argmin(np.asarray(rank)[tied])])


def less(a, b, rtol):
    """``a < b`` for tuples of numbers, entries equal within ``rtol`` (relative) counting as
    equal (so that the next entry decides)."""
    for x, y in zip(a, b):
        tol = rtol * max(abs(x), abs(y))
        if x < y - tol:
            return True
        if x > y + tol:
            return False
    return False
