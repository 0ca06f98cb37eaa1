"""Angle addition on arrays of cos/sin, and the bounds of the small-deviation series (private).

Shared by the alignment processor (its half-angle series) and the simulator's fast phase
tables (:mod:`hse_opt.sim._fastmath`), which import them from here: the simulator calls the
processor's package, never the other way round.
"""
from __future__ import annotations

import numpy as np

#: largest deviation from the linear phase handled by the series, rad (error d^5/120 < 1e-17)
MAX_DEVIATION = 1e-3
#: below this deviation, rad, the series of cos d stops at d^2 (the next term d^4/24 < 7e-17)
SMALL_DEVIATION = 2e-4


def rotate(c, s, cd, sd, out, tmp):
    """``(cos, sin)`` of ``phase + d`` written into ``out`` (2, ...) from those of ``phase``
    (``c``, ``s``) and of ``d`` (``cd``, ``sd``), by the angle-addition formulas; ``tmp`` is
    scratch of their shape."""
    cn, sn = out[0], out[1]
    np.multiply(s, sd, out=tmp)
    np.multiply(c, cd, out=cn)
    cn -= tmp
    np.multiply(c, sd, out=tmp)
    np.multiply(s, cd, out=sn)
    sn += tmp
    return cn, sn
