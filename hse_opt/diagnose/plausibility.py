"""Physical plausibility of fitted magnitudes against the ranges of
:mod:`hse_opt.model.plausible` (where each range comes from). A candidate whose fit needs a
value beyond its range explains the data only with an implausible magnitude; the diagnosis
says so beside the ranking (it does not change the statistics)."""
from __future__ import annotations

import math

from ..model.plausible import RANGES


def judge(fit_result, base=None):
    """Sentences on ``fit_result``'s parameters beyond their plausible range; empty when every
    magnitude is plausible. (``base`` is accepted for callers of the former signature: how a
    candidate moves the base model's parameters is no judgement, :func:`moves`.)"""
    out = []
    for name, value, std, unit in zip(fit_result.names, fit_result.values, fit_result.std, fit_result.units):
        lo, hi = RANGES.get(_key(name), (-math.inf, math.inf))
        if not lo <= value <= hi:
            out.append(f"{name} = {value:.3g} {unit} is outside its plausible range [{lo:g}, {hi:g}] {unit}")
    return tuple(out)


def moves(fit_result, base):
    """Sentences on the base model's parameters that adding the candidate moves by more than 3
    of their sigmas. No judgement: a real effect missing from the base model shifts its
    parameters by exactly its alias (:mod:`hse_opt.aliasing`: ``B delta``), so a large move is
    what a correct addition does when the base fit was biased by the effect's absence."""
    out = []
    for name, v0, s0 in zip(base.names, base.values, base.std):
        if name in fit_result.names and s0 > 0:
            v1 = fit_result.value(name)[0]
            if abs(v1 - v0) > 3 * s0:
                out.append(f"{name} {v0:.3g} -> {v1:.3g} ({abs(v1 - v0) / s0:.1f} sigma of the base fit)")
    return tuple(out)


def _key(name):
    """``bias_z*tilt_cos`` (a tilt-coupled coefficient when the tilt is unknown) has no range of
    its own: only plain parameter names are judged."""
    return name if "*" not in name else ""
