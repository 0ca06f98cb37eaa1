"""Robust statistics of the raw-log checks (private): the exact median by partition, the
Gaussian 1-sigma of a median absolute deviation and the encoder steps' centre and spread; shared by :mod:`hse_opt.align.quality` and
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


def step_stats(d, taken=False):
    """(centre, robust 1-sigma) of the encoder steps ``d`` from every 29th step (the table's
    step and its jitter; a handful of glitches does not move a median); ``taken``: ``d`` is
    already that selection (:func:`every_29th_step`)."""
    sub = d if taken else d[::29] if d.size >= 2900 else d
    c = float(median(sub))
    return c, MAD * float(median(np.abs(sub - c)))


def every_29th_step(enc):
    """The steps of the encoder ``enc`` (n,) that :func:`step_stats` takes, without the others."""
    return enc[1::29] - enc[:-1:29] if enc.size > 2900 else np.diff(enc)
