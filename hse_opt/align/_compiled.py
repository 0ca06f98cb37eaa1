"""The raw-log path's compiled passes, where they are built (private).

``kernels`` is :mod:`hse_opt.align._kernels` (``hse_opt/align/_kernels.c``: the record's passes
for the quality checks and the Allan analysis, which ``setup.py`` builds where a C compiler is
present), else None: the callers then take numpy's route, the same figures to rounding. They
read ``kernels`` here at each call (the tests compare both routes by setting it to None).
"""
import numpy as np

try:
    import hse_opt.align._kernels as kernels
except ImportError:             # built without a C compiler: numpy's route
    kernels = None

__all__ = ["kernels", "rows"]


def rows(x):
    """The columns of ``x`` (n, 3) as contiguous float64 rows (3, n) when they are (a
    column-major log), else None."""
    r = np.asarray(x).T
    return r if r.dtype == np.float64 and r.strides[1] == 8 else None
