"""Protection: power floors against the catalogue effects a model leaves out.

A plan protects a model against an effect it does not carry when the diagnosis, run on the
plan's data, would detect the effect at the edge of its plausible range
(:data:`hse_opt.diagnose.plausibility.RANGES`) with power >= :data:`TARGET_POWER`. The
diagnosis tests a candidate effect by the nested-model F test of its Jacobian columns against
the fitted model's (:mod:`hse_opt.diagnose.statistics`); for a true effect of size ``delta``
its noncentrality is

    ``nc = || (I - P_A) J_e delta ||^2 / sigma^2``,

the Schur complement of the last column in the information of the rows ``[J_model, J_e
delta] / sigma`` -- a concave function of the run numbers. Power >= 0.8 at the test's level is
``nc >= nc_0(q, dof, level)`` (the noncentral F), so the floor is one more guard of the convex
program (:class:`~hse_opt.design.problem.Guard` with the :class:`~.criteria.LackOfFit` loss):
the design stays a convex program, certified as before.

A multi-parameter effect is protected at every vertex of its plausible box (each parameter at
+- its edge, up to the overall sign; the diagnosis' power against it is that of its least
detectable vertex, :func:`hse_opt.aliasing.effect_power`): e.g. ``(az_c2, az_s2) = (20, 20)``
and ``(20, -20)`` arcsec are two floors of the test with ``q = 2`` columns. The level is the
alias budget's (``alpha / DEFAULT_TESTS``, :mod:`hse_opt.aliasing`), the test's denominator
degrees of freedom those of the planned number of runs. A direction the candidate runs cannot show at all, or cannot show with power 0.8
within the budget even by spending it all on that one effect (the T-optimal design for it), is
named with the reason (:class:`Protection`) instead of being floored: ``needs`` (the effect
acts only with another, :attr:`hse_opt.model.effects.Effect.needs`), time since power-on (a
thermal effect with ``time_slots=1``), a tilt fixture, no plausible range declared, or the best
power reachable in the budget.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import casadi as ca
import numpy as np

from ..information import SENSITIVITY_FLOOR
from ..aliasing import ALPHA, DEFAULT_TESTS, POWER_LIMIT, effect_power, noncentrality_for_power
from ..model import CATALOGUE
from ..model.composition import as_model
from ..model.plausible import RANGES
from .approximate import DesignError
from .criteria import LackOfFit
from .problem import Guard, Problem, Rows, own

#: the diagnosis' level the floors are set for (the alias budget's default)
LEVEL = ALPHA / DEFAULT_TESTS
#: why an effect a plan could show is not protected: no plan of the budget reaches the target
OUT_OF_REACH = "power 0.8 is out of reach in this budget"
#: the floors ask this much more noncentrality than power 0.8 needs at the planned number of
#: runs: rounding to whole runs and to the stand's steps loses a little of it
MARGIN = 1.1


@dataclass(frozen=True)
class Protection:
    """What a plan does against one catalogue effect outside the model.

    Attributes
    ----------
    effect : str
    sizes : str
        The plausible edges it is taken at, in words (``"delay 500 us"``).
    power : float or None
        Power of the diagnosis' test against its least detectable vertex with this plan
        (:func:`hse_opt.aliasing.effect_power`; None when not computed).
    protected : bool
        Floored by the design (the power target was reachable in the budget).
    reason : str
        Why it is not protected ("" when it is).
    """

    effect: str
    sizes: str
    power: float | None
    protected: bool
    reason: str = ""

    def to_dict(self):
        return {"effect": self.effect, "size": self.sizes,
                "power": None if self.power is None else float(self.power), "protected": self.protected,
                "reason": self.reason}

    def line(self):
        what = f"{self.effect} ({self.sizes})" if self.sizes else self.effect
        power = "" if self.power is None else f"power {self.power:.2f}"
        if self.protected:
            return f"{what}: {power}"
        return f"{what}: not protected: {self.reason}" + (f"; {power} with this plan" if power else "")


@dataclass(frozen=True)
class Threat:
    """One effect outside the model at its plausible edge: a rows builder per vertex of its
    box (the model's columns, then the effect's signature at that vertex) and the test's
    numerator dof ``q`` (its parameters with a heading signature)."""

    effect: str
    sizes: str
    q: int
    specs: tuple


def threats(model, tilt_known, samples, space):
    """The catalogue effects outside ``model`` a plan could be asked to show.

    Returns ``(threats, skipped)``: a :class:`Threat` per effect with a plausible range; a
    :class:`Protection` (not protected, with the reason) per effect no plan from ``space``
    can show whatever its runs (``needs``, time since power-on, no range)."""
    model = as_model(model)
    have = set(model.effect_names)
    out, skipped = [], []
    for name, cls in CATALOGUE.items():
        if name in have:
            continue
        eff = cls()
        never = unassessable(eff, have, space.time_slots >= 2)
        if never is not None:
            skipped.append(never)
            continue
        ranged = [q for q in eff.params if q.name not in eff.nonlinear]
        ext = as_model(list(model.effect_names) + [name])
        mm, me = model.measurement(tilt_known), ext.measurement(tilt_known)
        idx = [me.names.index(n) for n in mm.names]
        jdx = [me.names.index(q.name) for q in ranged]
        p, x = ca.SX.sym("p", len(me.names)), ca.SX.sym("x", me.n_x)
        J = me.J(p, x)
        base = J[:, idx] * ca.DM(np.asarray(me.scale)[idx]).T
        J_e = J[:, jdx] * ca.DM(np.asarray(me.scale)[jdx]).T
        ps = [me.vector(own(s, me)) for s in samples]
        edge = plausible_edge(eff)
        specs = []
        for v in _vertices(edge).T:
            fn = ca.Function("threat_rows", [p, x], [ca.horzcat(base, ca.mtimes(J_e, ca.DM(v)))])
            label = ", ".join(f"{q.name} {a:+g}" for q, a in zip(ranged, v))
            specs.append(Rows(mm.names + (f"{name} at {label}",), fn, ps))
        out.append(Threat(name, plausible_sizes(eff), len(ranged), tuple(specs)))
    return out, skipped


def unassessable(eff, have, timed):
    """The :class:`Protection` (not protected, with the reason) of a catalogue effect ``eff``
    (an :class:`~hse_opt.model.effects.Effect`) outside a model of the effects ``have`` when no
    plan can show it whatever its runs: it acts only with an effect the model lacks, it
    changes with time since power-on and ``timed`` (time a factor of the plan) is False, or
    it has no plausible range; None when a plan could show it."""
    missing = [n for n in eff.needs if n not in have]
    if missing:
        return Protection(eff.name, "", None, False, f"no heading signature without "
                          f"{', '.join(missing)} in the model (it acts only with it)")
    if eff.level == "thermal" and not timed:
        return Protection(eff.name, "", None, False, "it changes with time since power-on, which is "
                          "not a factor of this plan: allowed time_slots >= 2 (--time-slots N)")
    ranged = [q for q in eff.params if q.name not in eff.nonlinear]
    if not ranged or any(q.name not in RANGES for q in ranged):
        return Protection(eff.name, "", None, False, "no plausible range declared")
    return None


def plausible_edge(eff):
    """The plausible edge of each of ``eff``'s linear parameters, display units, shape (q,)."""
    return np.array([max(abs(v) for v in RANGES[q.name]) for q in eff.params if q.name not in eff.nonlinear])


def plausible_sizes(eff):
    """The plausible edges of ``eff`` in words (``"delay 500 us"``)."""
    ranged = [q for q in eff.params if q.name not in eff.nonlinear]
    return ", ".join(f"{q.name} {e:g} {q.unit}" for q, e in zip(ranged, plausible_edge(eff)))


def _vertices(edge):
    """The box's vertices up to the overall sign, (q, 2^(q-1))."""
    q = len(edge)
    signs = np.array(np.meshgrid(*([[1.0, -1.0]] * q), indexing="ij")).reshape(q, -1)
    return np.asarray(edge, float)[:, None] * signs[:, signs[0] > 0]


def power_floors(threats_, X, sigma, base, n_runs, k, solve):
    """Guards for the threats the budget can protect, and the others named.

    ``base``: the :class:`~hse_opt.design.problem.Problem` keywords (costs, budget, time
    slots); ``n_runs``: the runs the plan will have (the test's dof ``n_runs - k - q``);
    ``k``: the model's parameters; ``solve``: :func:`~hse_opt.design.approximate.solve_approximate`.
    A vertex's best reachable noncentrality is that of the T-optimal approximate design for
    it alone (the whole budget spent on showing that one effect); an effect one of whose
    vertices cannot reach the floor is named, not floored. Returns ``(guards, skipped)``."""
    guards, skipped = [], []
    for t in threats_:
        rows = [s.numeric(X, sigma) for s in t.specs]
        q = t.q
        if not all(np.max(np.abs(r[..., -1]) * sigma) > SENSITIVITY_FLOOR for r in rows):
            skipped.append(Protection(t.effect, t.sizes, None, False, "no heading signature in any candidate run "
                                      "at the nominal values"))
            continue
        need = noncentrality_for_power(q, max(n_runs - k - q, 1), LEVEL)
        try:
            reach = [-solve(Problem(LackOfFit(), s, r, **base), polish=False, target=0.999).loss
                     for s, r in zip(t.specs, rows)]
        except DesignError as err:
            skipped.append(Protection(t.effect, t.sizes, None, False, f"its best power in this budget could "
                                      f"not be computed ({err})"))
            continue
        if min(reach) < MARGIN * need:
            skipped.append(Protection(t.effect, t.sizes, None, False, f"{OUT_OF_REACH} even with every run "
                                      f"spent on it{_hint(t)}"))
            continue
        guards += [Guard(None, s, r, MARGIN * need, float("nan"), LackOfFit(), t.effect)
                   for s, r in zip(t.specs, rows)]
    return guards, skipped


def raise_floors(floors, threats_, levels, n_runs, k):
    """``(raised floors, short effects)``: the floors raised where a rounded plan falls short
    of power 0.8, and the set of those effects (empty when none is). ``levels``: each floor's
    noncentrality with the plan, ``n_runs`` its runs (the test's dof), ``k`` the model's
    parameters. A short floor is raised by what the rounding lost against it, plus 2 %."""
    q_of = {t.effect: t.q for t in threats_}
    out, short = [], set()
    for g, have in zip(floors, levels):
        q = q_of[g.label]
        need = noncentrality_for_power(q, max(n_runs - k - q, 1), LEVEL)
        if have < need:
            short.add(g.label)
            g = replace(g, bound=g.bound * need / max(have, 1e-12 * need) * 1.02)
        out.append(g)
    return out, short


def _hint(threat):
    if threat.effect == "axis_bias":
        return " (the base's tilt sets its signature: a tilt fixture, --max-tilt-arcsec, enlarges it)"
    return ""


def plan_protection(model, threats_, guarded, skipped, X, sigma, nominal, tilt_known):
    """The :class:`Protection` of a final plan (its inputs ``X``, sigmas ``sigma``): the power
    of the diagnosis against each threat by :func:`hse_opt.aliasing.effect_power` (its least
    detectable vertex at the plausible edge), floored (``guarded``: effect names) or not."""
    out = []
    for t in threats_:
        power = effect_power(model, X, t.effect, 1.0, sigma=sigma, p=nominal, tilt_known=tilt_known)
        if t.effect in guarded:
            out.append(Protection(t.effect, t.sizes, power, power >= POWER_LIMIT, "" if power >= POWER_LIMIT else
                                  "the whole-run plan falls short of the floor the approximate design met"))
    done = {p.effect for p in out}
    for s in skipped:
        if s.effect not in done:
            power = None
            if s.sizes:
                power = effect_power(model, X, s.effect, 1.0, sigma=sigma, p=nominal, tilt_known=tilt_known)
            out.append(Protection(s.effect, s.sizes, power, False, s.reason))
    return tuple(out)


def describe(protection):
    """Report lines of a plan's protection."""
    if not protection:
        return []
    return [f"protection (power of the diagnosis against each effect outside the model at its plausible "
            f"edge; target {POWER_LIMIT:g}):"] + [f"  {p.line()}" for p in protection]
