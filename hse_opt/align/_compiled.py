"""The raw-log path's compiled passes, where they are built (private).

``kernels`` is :mod:`hse_opt.align._kernels` (``hse_opt/align/_kernels.c``, which ``setup.py``
builds where a C compiler is present: the record's passes for the quality checks and the Allan
analysis, the fit of the table's deterministic part, the Allan clusters' squared differences,
check 3b's step statistic, the quanta),
else None: the callers then take numpy's route, the same figures to rounding. They read
``kernels`` here at each call (the tests compare both routes by setting it to None).

Why compiled: issue 25 asks the quality checks and the Allan analysis to add at most half of
the alignment's time to ``hse-opt align``. numpy's route reads the 17-MB record of a 10-minute
log two or three times and runs its small loops as many short passes: 49-61 % of the alignment
(2026-11-26); the kernels read each array once and run those loops in one pass each: 34-37 %
(39-42 % in the command line's order; ``benchmarks/align.py``). A C
extension built at install costs nothing at run time (no start-up or JIT, unlike numba) and
needs no new dependency.
"""
import numpy as np

try:
    import hse_opt.align._kernels as kernels
except ImportError:             # built without a C compiler: numpy's route
    kernels = None

__all__ = ["kernels", "rows", "takes"]


def takes(*arrays):
    """Whether the kernels are built and every one of ``arrays`` is a C-contiguous float64
    array (what they read in place); else the caller takes numpy's route."""
    return kernels is not None and all(a.dtype == np.float64 and a.flags.c_contiguous for a in arrays)


def rows(x):
    """The columns of ``x`` (n, 3) as contiguous float64 rows (3, n) when they are (a
    column-major log), else None."""
    r = np.asarray(x).T
    return r if takes(r[0], r[1], r[2]) else None
