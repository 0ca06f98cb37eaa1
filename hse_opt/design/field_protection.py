"""Protection of field plans: the default criterion's choice among candidate field plans.

A field plan (:mod:`hse_opt.design.field`) is one of a finite set of candidates (positions x
rate pattern x repeats), each scored by the predicted sigma of the target with every
position's heading unknown. The default criterion, ``protect:lambda2``, keeps the stand
designs' promise (:mod:`hse_opt.design.protection`) for them: among the candidates that
identify every parameter, the plan with the smallest sigma of the target among those with
power >= :data:`~hse_opt.aliasing.POWER_LIMIT` of the diagnosis against each catalogue effect
outside the model at the edge of its plausible range. The power is the diagnosis's own test
(:func:`hse_opt.aliasing.effect_power`) on the plan's runs with each position's unknown
constant in the model (a continued campaign: the runs so far and the new runs together).

An effect no candidate in the budget protects is named with the reason: it acts only with
another effect, no plausible range (:func:`~hse_opt.design.protection.unassessable`); no
heading signature beyond the model's within a position (each position's unknown heading and
the model absorb it); too few runs for its test; the best power among the candidates; or, when no candidate protects every effect some candidate
protects, the effects it cannot be protected together with. The plan chosen then protects
the most effects, and the smallest sigma among those plans decides. ``c:lambda2`` is the
unprotected choice: the smallest sigma alone.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..aliasing import POWER_LIMIT, effect_test
from ..model import CATALOGUE
from ..model.composition import as_model
from .criteria import C, as_criterion
from .protection import OUT_OF_REACH, Protection, plausible_sizes, unassessable

__all__ = ["FieldCriterion", "field_criterion", "field_powers", "choose"]


@dataclass(frozen=True)
class FieldCriterion:
    """A field design's criterion: the target parameter and whether it protects.

    Attributes
    ----------
    label : str
        ``protect:NAME`` or ``c:NAME``.
    target : str
        The parameter whose predicted sigma is minimised.
    protects : bool
        Power floors against the catalogue effects outside the model.
    """

    label: str
    target: str
    protects: bool


def field_criterion(criterion):
    """The :class:`FieldCriterion` of ``'protect'``, ``'protect:NAME'`` or ``'c:NAME'`` (or such
    a :class:`~hse_opt.design.criteria.Criterion`); ValueError for another."""
    crit = as_criterion(criterion)
    if not isinstance(crit, C):
        raise ValueError(f"criterion {crit.label!r} with a field plan; allowed: protect (the default, "
                         "protect:lambda2), protect:NAME or c:NAME (e.g. c:lambda2, the smallest sigma alone)")
    return FieldCriterion(crit.label, crit.name, bool(getattr(crit, "protects", False)))


def field_powers(plan, model, effects, stand, tilt_known=True, nominal=None, sigma=None):
    """Power of the diagnosis against each of ``effects`` at its plausible edge on a field plan.

    Parameters
    ----------
    plan : hse_opt.data.Plan
        With ``position`` labels: each label one unknown heading constant.
    model : Model, str or sequence of str
        The model that would be fitted.
    effects : sequence of str
        Catalogue effects outside it, each with a plausible range.
    stand : hse_opt.design.Stand
        Its tilt, latitude and heading noise (the plan's tilts are offsets from its tilt).
    tilt_known : bool
    nominal : mapping name -> value, optional
        Where the test is linearised (display units; default nominal).
    sigma : array_like, shape (n,), optional
        Each run's heading 1-sigma, rad (default the stand's noise model).

    Returns
    -------
    list of hse_opt.aliasing.EffectTest
        :func:`hse_opt.aliasing.effect_test` of each: power (0 .. 1) and degrees of freedom.
    """
    model = as_model(model)
    mm = model.measurement(tilt_known)
    tx = plan.tilt_x if plan.tilt_x is not None else 0.0
    ty = plan.tilt_y if plan.tilt_y is not None else 0.0
    X = stand.inputs(mm, plan.rate, plan.azimuth, tx, ty, plan.duration, plan.t_start)
    sigma = stand.sigma(plan.duration) if sigma is None else np.asarray(sigma, float)
    _, positions = np.unique(plan.position, return_inverse=True)
    p = {k: v for k, v in (nominal or {}).items() if k in mm.names}
    return [effect_test(model, X, e, 1.0, sigma=sigma, p=p, tilt_known=tilt_known, positions=positions)
            for e in effects]


def _threats(model):
    """``(effects, skipped)``: the catalogue effects outside ``model`` a field plan could show
    (time since power-on is always a factor of one), and a not-protected
    :class:`~hse_opt.design.protection.Protection` for each it cannot."""
    model = as_model(model)
    have = set(model.effect_names)
    effects, skipped = [], []
    for name, cls in CATALOGUE.items():
        if name in have:
            continue
        never = unassessable(cls(), have, True)
        if never is None:
            effects.append(name)
        else:
            skipped.append(never)
    return effects, skipped


def _hint(effect):
    if effect == "warmup":
        return "; it decays after power-on: runs sooner after it, a shorter --warmup-s, show more of it"
    return ""


#: candidates whose sigma is within this fraction of the best (and that protect as many
#: effects) are as good: ``prefer`` breaks the tie
TIE = 0.01


def choose(candidates, model, criterion, stand, tilt_known=True, nominal=None, prefer=None):
    """The candidate the criterion picks, and its protection.

    Parameters
    ----------
    candidates : sequence of (float, Plan, numpy.ndarray or None)
        Each candidate's predicted sigma of the target (display unit), the plan the
        diagnosis would test (a continued campaign: the runs so far and the new runs) and its
        runs' heading sigmas, rad (None: the stand's noise model).
    model : Model, str or sequence of str
    criterion : FieldCriterion
    stand : hse_opt.design.Stand
    tilt_known : bool
    nominal : mapping name -> value, optional
        Where the tests are linearised (display units).
    prefer : callable, optional
        ``prefer(i)``: a score (smaller is better) that decides among the candidates as good
        as the best (the same effects protected, sigma within :data:`TIE` of it); e.g. the
        sigma after a continued plan's first run, when the campaign is planned again after it.

    Returns
    -------
    index : int
        The candidate chosen.
    protection : tuple of Protection
        One per catalogue effect outside the model (empty for ``c:NAME``).
    unprotected : float
        The smallest sigma among all candidates (what ``c:NAME`` would choose).
    """
    sigma = np.array([float(c[0]) for c in candidates])
    if not sigma.size:
        raise ValueError("no candidate field plan to choose from")
    unprotected = float(np.min(sigma))
    if not criterion.protects:
        return _prefer(int(np.argmin(sigma)), sigma, np.ones(sigma.size, bool), prefer), (), unprotected
    effects, skipped = _threats(model)
    tests = [field_powers(plan, model, effects, stand, tilt_known, nominal, sig) for _, plan, sig in candidates]
    P = np.array([[t.power for t in row] for row in tests]).reshape(len(candidates), len(effects))
    Q = np.array([[t.q for t in row] for row in tests], int).reshape(P.shape)
    D = np.array([[t.dof for t in row] for row in tests], int).reshape(P.shape)
    ok = P >= POWER_LIMIT
    reachable = ok.any(axis=0)
    count = ok[:, reachable].sum(axis=1)
    # the most effects protected, then the smallest sigma (lexicographic)
    best = int(np.lexsort((sigma, -count))[0])
    same = np.all(ok[:, reachable] == ok[best, reachable], axis=1)
    best = _prefer(best, sigma, same, prefer)
    out = []
    for j, name in enumerate(effects):
        size, power = plausible_sizes(CATALOGUE[name]()), float(P[best, j])
        if ok[best, j]:
            out.append(Protection(name, size, power, True))
        elif reachable[j]:
            others = [e for i, e in enumerate(effects) if ok[best, i]]
            out.append(Protection(name, size, power, False, f"{OUT_OF_REACH} together with {', '.join(others)} "
                                  f"in any candidate field plan (alone: power {P[:, j].max():.2g})"))
        elif np.all(Q[:, j] == 0):
            out.append(Protection(name, size, power, False, "no heading signature beyond the model's within a "
                                  "position in any candidate field plan: each position's unknown heading and "
                                  "the model absorb it (at one position a sync delay moves the heading with the "
                                  "rate as lambda2 does; a surveyed position shows what is constant at it)"))
        elif np.all(D[:, j][Q[:, j] > 0] < 1):
            out.append(Protection(name, size, power, False, f"too few runs for the diagnosis's test of its "
                                  f"{int(Q[:, j].max())} directions in any candidate field plan of this budget"))
        else:
            out.append(Protection(name, size, power, False, f"{OUT_OF_REACH} in any candidate field plan "
                                  f"(best power {P[:, j].max():.2g}{_hint(name)})"))
    return best, tuple(out) + tuple(skipped), unprotected


def _prefer(best, sigma, same, prefer):
    """``best``, or the candidate ``prefer`` scores lowest among those as good (``same``
    protection, sigma within :data:`TIE` of ``best``'s)."""
    if prefer is None:
        return best
    near = np.flatnonzero(same & (sigma <= sigma[best] * (1 + TIE)))
    scores = np.array([prefer(int(i)) for i in near])
    if not np.any(np.isfinite(scores)):
        return best
    return int(near[np.lexsort((sigma[near], scores))[0]])
