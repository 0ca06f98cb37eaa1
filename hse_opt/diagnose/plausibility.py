"""Physical plausibility of fitted magnitudes against the ranges of
:mod:`hse_opt.model.plausible` (where each range comes from). A candidate whose fit needs a
value beyond its range explains the data only with an implausible magnitude; the diagnosis
says so beside the ranking (it does not change the statistics)."""
from __future__ import annotations

import math

from ..model.plausible import RANGES


def judge(fit_result, base=None):
    """Sentences on ``fit_result``'s parameters beyond their plausible range, and on the
    base model's parameters that the candidate moves by more than 3 sigma (``base``: the base
    model's FitResult). Empty when every magnitude is plausible."""
    out = []
    for name, value, std, unit in zip(fit_result.names, fit_result.values, fit_result.std, fit_result.units):
        lo, hi = RANGES.get(_key(name), (-math.inf, math.inf))
        if not lo <= value <= hi:
            out.append(f"{name} = {value:.3g} {unit} is outside its plausible range [{lo:g}, {hi:g}] {unit}")
    if base is not None:
        for name, v0, s0 in zip(base.names, base.values, base.std):
            if name in fit_result.names and s0 > 0:
                v1 = fit_result.value(name)[0]
                if abs(v1 - v0) > 3 * s0:
                    out.append(f"moves {name} from {v0:.3g} to {v1:.3g} ({abs(v1 - v0) / s0:.1f} sigma)")
    return tuple(out)


def _key(name):
    """``bias_z*tilt_cos`` (a tilt-coupled coefficient when the tilt is unknown) has no range of
    its own: only plain parameter names are judged."""
    return name if "*" not in name else ""
