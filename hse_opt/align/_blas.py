"""BLAS on one thread for the raw-log path's sums over a record (private).

A matrix-vector product is the fastest reduction numpy has over the blocks of a record (a third
of ``einsum``'s time, memory-bound), but OpenBLAS splits a large one over threads that then spin
waiting for more work; on a busy machine the call waits for its second thread to be scheduled
(15 ms instead of 0.8 measured on two shared cores). On one thread it is as fast and its result
does not depend on the machine's thread count: each output is one dot product in the kernel's
fixed order (the same bytes in one process, in workers, or on a cluster with the same library).
"""
from __future__ import annotations

import contextlib
import functools
import sys

import numpy as np

__all__ = ["one_thread", "block_dot"]


_NOTHING = contextlib.nullcontext()


@functools.lru_cache(maxsize=1)
def _controller(modules):
    """threadpoolctl's controller and its BLAS libraries' own controllers, made anew when the
    number of imported modules ``modules`` has changed (a BLAS library comes with an import:
    scipy's own, loaded after numpy's; a few milliseconds, never in a steady loop)."""
    from threadpoolctl import ThreadpoolController
    controller = ThreadpoolController()
    return controller, tuple(c for c in controller.lib_controllers if c.user_api == "blas")


def one_thread():
    """A context in which BLAS runs on one thread: nothing to do (well under a microsecond)
    where every BLAS library already runs on one (``hse-opt``: :mod:`hse_opt.app.cli` loads it
    so), else threadpoolctl's limit (5 microseconds to enter and leave)."""
    controller, blas = _controller(len(sys.modules))
    if all(c.get_num_threads() == 1 for c in blas):
        return _NOTHING
    return controller.limit(limits=1, user_api="blas")


def block_dot(x, w, out=None):
    """``x @ w`` on one BLAS thread (into ``out`` when given).

    Parameters
    ----------
    x : numpy.ndarray, shape (..., nb, h)
        Blocks of ``h`` samples (each block contiguous).
    w : numpy.ndarray, shape (h,) or (h, k)
        Weights.
    out : numpy.ndarray, shape (..., nb) or (..., nb, k), optional
        Where to write the product (a row block of a larger array: no copy to join them).

    Returns
    -------
    numpy.ndarray, shape (..., nb) or (..., nb, k)
    """
    with one_thread():
        return np.matmul(x, w, out=out)
