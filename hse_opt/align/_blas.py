"""BLAS on one thread for the raw-log path's sums over a record (private).

A matrix-vector product is the fastest reduction numpy has over the blocks of a record (a third
of ``einsum``'s time, memory-bound), but OpenBLAS splits a large one over threads that then spin
waiting for more work; on a busy machine the call waits for its second thread to be scheduled
(15 ms instead of 0.8 measured on two shared cores). On one thread it is as fast and its result
does not depend on the machine's thread count: each output is one dot product in the kernel's
fixed order (the same bytes in one process, in workers, or on a cluster with the same library).
"""
from __future__ import annotations

import functools

import numpy as np

__all__ = ["one_thread", "block_dot"]


@functools.lru_cache(maxsize=1)
def _controller():
    from threadpoolctl import ThreadpoolController
    return ThreadpoolController()


def one_thread():
    """A context in which BLAS runs on one thread (a few microseconds to enter)."""
    return _controller().limit(limits=1, user_api="blas")


def block_dot(x, w):
    """``x @ w`` on one BLAS thread.

    Parameters
    ----------
    x : numpy.ndarray, shape (..., nb, h)
        Blocks of ``h`` samples (each block contiguous).
    w : numpy.ndarray, shape (h,) or (h, k)
        Weights.

    Returns
    -------
    numpy.ndarray, shape (..., nb) or (..., nb, k)
    """
    with one_thread():
        return np.matmul(x, w)
