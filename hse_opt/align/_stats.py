"""Robust statistics of the raw-log checks (private): the exact median by partition and the
Gaussian 1-sigma of a median absolute deviation; shared by :mod:`hse_opt.align.quality` and
its step check (:mod:`hse_opt.align.steps`)."""
from __future__ import annotations

import numpy as np

#: robust 1-sigma of a Gaussian from its median absolute deviation
MAD = 1.4826


def median(x):
    """``np.median`` of a 1-D array, or of each column of a 2-D one (the same values: the middle
    order statistic, or the mean of the two middle ones, from a partition of contiguous rows;
    without ``np.median``'s generic path, which cost a 10-minute log's assessment a fifth of
    its time). Finite values (the loader refuses others).

    Parameters
    ----------
    x : array_like, shape (n,) or (n, k)

    Returns
    -------
    float or numpy.ndarray, shape (k,)
        In the unit of ``x``.
    """
    x = np.array(np.asarray(x, dtype=float).T, order="C")     # a copy: columns as rows
    n = x.shape[-1]
    h = n // 2
    if n % 2:
        x.partition(h, axis=-1)
        return x[..., h]
    x.partition((h - 1, h), axis=-1)
    return (x[..., h - 1] + x[..., h]) / 2.0
