"""Orchestration: :func:`design` runs the steps -- candidates, approximate design, rounding,
pruning, refinement, run order, evaluation -- and returns a :class:`DesignResult`."""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .. import units
from ..data import Plan
from ..information import SENSITIVITY_FLOOR, UnidentifiableError, blind_out, check_identifiable, invisible
from ..model.composition import Model, as_model
from .approximate import ApproximateDesign, DesignError, solve_approximate
from .criteria import C, D, NotSmooth, as_criterion, unit_vector
from .evaluation import Evaluation, evaluate
from .order import pick_order
from .problem import Guard, Problem, criterion_rows, model_rows, prior_information, samples_of
from .protection import describe as describe_protection
from .protection import Protection, plan_protection, power_floors, raise_floors, threats
from .refine import refine as refine_plan
from .reduction import caratheodory
from .resolution import stand_plan, to_resolution
from .rounding import prune as prune_plan
from .rounding import round_design
from .space import Costs, DesignSpace, Resolution, Stand, positive


#: at most this many designs when the rounded plan falls short of a power floor (each raises the
#: short floors to what the rounded plan needs)
MAX_FLOOR_ROUNDS = 3


@dataclass(frozen=True)
class DesignResult:
    """An optimised plan and what it achieves.

    Attributes
    ----------
    plan : hse_opt.data.Plan
        In execution order, with ``t_start`` from the costs.
    evaluation : Evaluation
        Predicted sigmas and drift biases of the plan (at its start times).
    criterion : str
    efficiency : float
        Against the approximate optimum for the plan's alignment time (with time slots: the
        plan's alignment time in each slot) over the candidates and the plan's own settings
        (refinement and the stand's steps move them off the grid): at most 1, up to the
        solvers' tolerance.
    rounding_efficiency : float
        The same before refinement: the rounding alone.
    budget_efficiency : float
        Against the approximate optimum for the whole budget, over the same candidates (time
        spent on setups counts as lost).
    approximate : ApproximateDesign
        The setup-free optimum over the candidates.
    setup_time, alignment_time : float
        s: warm-up and changes; alignments and per-run overheads.
    refinement : str
        IPOPT's return status, or why there was none.
    guards : tuple of dict
        Models the plan must also identify: ``effects``, ``d_efficiency`` (against their own
        D-optimal approximate design), ``min_efficiency``, ``std`` (name -> predicted sigma).
    notes : tuple of str
    protection : tuple of Protection
        For a protecting criterion (the default ``protect:lambda2``): the power of the
        diagnosis against each catalogue effect outside the model at its plausible edge, or
        why the plan does not protect against it (:mod:`.protection`).
    """

    plan: Plan
    evaluation: Evaluation
    criterion: str
    efficiency: float
    rounding_efficiency: float
    budget_efficiency: float
    approximate: ApproximateDesign
    setup_time: float
    alignment_time: float
    refinement: str
    guards: tuple = ()
    notes: tuple = ()
    protection: tuple = ()

    @property
    def n_runs(self):
        return int(self.plan.run.size)

    @property
    def total_time(self):
        return self.evaluation.total_time

    def std_of(self, name):
        """Predicted standard deviation of one parameter, display units."""
        return self.evaluation.std_of(name)

    def to_dict(self):
        """The JSON form (the contract keys of ``docs/formats.md``, and more)."""
        a = self.approximate
        out = self.evaluation.to_dict()
        out.update({
            "criterion": self.criterion, "efficiency": float(self.efficiency),
            "rounding_efficiency": float(self.rounding_efficiency),
            "budget_efficiency": float(self.budget_efficiency),
            "approximate": {"status": a.status, "solver": a.solver, "n_candidates": int(a.runs.size),
                            "support": int(a.support.size), "iterations": a.iterations, "n_active": a.n_active,
                            "certified_efficiency": float(a.certified_efficiency),
                            "solve_time_s": a.solve_time},
            "setup_time_h": self.setup_time / units.HOUR, "alignment_time_h": self.alignment_time / units.HOUR,
            "refinement": self.refinement, "guards": [dict(g) for g in self.guards], "notes": list(self.notes),
            "protection": [p.to_dict() for p in self.protection],
        })
        return out

    def summary(self):
        """Report lines."""
        a = self.approximate
        hours = lambda t: f"{t / units.HOUR:.3f} h"  # noqa: E731
        lines = [f"criterion {self.criterion}: {self.n_runs} runs in {hours(self.total_time)} (setups "
                 f"{hours(self.setup_time)}, alignments {hours(self.alignment_time)})",
                 f"approximate design: {a.runs.size} candidates ({a.n_active} active after {a.iterations} "
                 f"round(s)), {a.support.size} in the support, {a.solver} {a.status} in {a.solve_time:.2f} s, "
                 f"certified efficiency >= {a.certified_efficiency:.6f}",
                 f"exact design: efficiency {self.efficiency:.4f} against the approximate optimum for the same "
                 f"alignment time over the candidates and the plan's own settings (rounding alone {self.rounding_efficiency:.4f}; refinement {self.refinement}); "
                 f"{self.budget_efficiency:.4f} against the whole budget"]
        lines += self.evaluation.summary()
        for g in self.guards:
            if g["d_efficiency"] >= g["min_efficiency"]:
                lines.append(f"also identifies {'+'.join(g['effects'])}: D-efficiency {g['d_efficiency']:.3f} "
                             f"(at least {g['min_efficiency']:.3f} required)")
            else:   # whole runs lost what the approximate design kept: said, not claimed
                lines.append(f"does not identify {'+'.join(g['effects'])} as required: D-efficiency "
                             f"{g['d_efficiency']:.3f}, below the {g['min_efficiency']:.3f} required (the plan's "
                             "whole runs in this budget lost it; a longer --budget-h or a lower "
                             "--identify-efficiency)")
        lines += describe_protection(self.protection)
        return lines + [f"note: {n}" for n in self.notes]


def design(model=None, criterion="protect:lambda2", *, budget, space=None, stand=None, costs=None,
           max_runs=None, tilt_known=True, nominal=None, prior_sample=None, prior=None,
           identify=None, identify_efficiency=0.25, prune=True, refine=True,
           order="trend-robust", rng=None, solver=None, resolution=Resolution()):
    """The test plan that minimises ``criterion`` within the stand-time ``budget``.

    Parameters
    ----------
    model : Model, str or sequence of str, optional
        Default: the paper's model (``hse``).
    criterion : Criterion or str
        ``'D'``, ``'A'``, ``'E'``, ``'c:NAME'``, ``'protect:NAME'`` or a :class:`Criterion`
        (e.g. :class:`Discrimination`). Default ``protect:lambda2``: the smallest sigma of
        lambda2 (the paper's goal) with every parameter identified and power >= 0.8 of the
        diagnosis against each catalogue effect outside the model at its plausible edge,
        where the budget allows; those it cannot protect are named with the reason
        (``DesignResult.protection``, :mod:`.protection`). A and E depend on the parameters'
        display units.
    budget : float
        Total test time, s, from power-on to the end of the last alignment.
    space : DesignSpace, optional
    stand : Stand, optional
    costs : Costs, optional
    max_runs : int, optional
    tilt_known : bool
        Pitch/roll from the alignments' leveling (see the module docstring).
    nominal : mapping name -> value, optional
        Display-unit values at which the model is linearised (nonlinear parameters).
    prior_sample : mapping name -> array, optional
        Draws (display units, equal numbers) over which the criterion is averaged: a design
        robust to the nonlinear parameters.
    prior : FitResult, Prior or numpy.ndarray, optional
        Prior information from an earlier calibration (a FitResult or
        :class:`~hse_opt.information.Prior`; or a Fisher matrix in the model's order).
    identify : Model, str or sequence, optional
        Models the plan must also identify (a list of effect names is one model; a list of
        models or ``"a,b"`` strings is several), each with a D-efficiency of at least
        ``identify_efficiency`` against its own D-optimal approximate design. Default: the
        design model itself when the criterion may leave it unidentifiable (c, T).
    identify_efficiency : float
        In (0, 1).
    prune : bool
        Setup-aware search: drop stand positions (time slot, tilt, azimuth) of the
        approximate design one at a time, re-solving on the rest, while the rounded plan --
        which has more time for runs with fewer setups -- gets better.
    refine : bool
        Move rates and azimuths off the candidate grid with IPOPT.
    order : {'trend-robust', 'min-setup'}
    rng : numpy.random.Generator, optional
        For the run-order search (default: seeded, reproducible).
    solver : str, optional
        cvxpy solver (default: Clarabel, then SCS).
    resolution : Resolution or None
        The stand's setting steps: the final plan's rates, azimuths and tilts are rounded to
        them and the plan re-certified (its efficiency is the rounded plan's); None keeps the
        optimiser's values.

    Returns
    -------
    DesignResult

    Raises
    ------
    ValueError
        Bad arguments (named), or a budget too small for the model
        (:class:`~hse_opt.information.UnidentifiableError` names the parameters).
    DesignError
        A solver failed (its status is in the message).
    """
    model, crit = as_model(model), as_criterion(criterion)
    space, stand, costs = space or DesignSpace(), stand or Stand(), costs or Costs()
    rng = rng if rng is not None else np.random.default_rng(0)
    budget = positive("budget (s)", budget)
    if order not in ("trend-robust", "min-setup"):
        raise ValueError(f"order = {order!r}; allowed: 'trend-robust', 'min-setup'")
    if max_runs is not None and (isinstance(max_runs, bool) or int(max_runs) != max_runs or max_runs < 1):
        raise ValueError(f"max_runs = {max_runs!r}; allowed: an integer >= 1")
    if not 0 < identify_efficiency < 1:
        raise ValueError(f"identify_efficiency = {identify_efficiency!r}; allowed: 0 < value < 1")
    if space.max_tilt + max(abs(v) for v in stand.tilt) > 1.0 * units.DEG:
        raise ValueError(f"max_tilt {space.max_tilt / units.ARCSEC:g} arcsec with the stand's tilt "
                         f"{', '.join(f'{v / units.ARCSEC:g}' for v in stand.tilt)} arcsec is not allowed; allowed: "
                         "|fixture + stand tilt| <= 3600 arcsec in each axis (the model is first order in the tilt)")
    if not tilt_known and space.max_tilt > 0:
        raise ValueError("a tilt fixture (max_tilt > 0, --max-tilt-arcsec) needs tilt_known=True: with the tilt "
                         "unknown the model assumes one tilt fixed in b0 for every run; allowed: max_tilt 0 "
                         "with the tilt unknown")
    guard_models = _guard_models(identify, model, crit)
    for m in (model, *guard_models):
        if m.covariates:
            raise ValueError(f"effects {[e.name for e in m.effects if hasattr(e, 'column')]} follow recorded "
                             "covariates, which a plan cannot set; allowed: effects without covariates")
    samples = samples_of(nominal, prior_sample)
    known = {q.name for m in (model, *guard_models) for q in m.measurement(tilt_known).params}
    unknown = sorted(set().union(*samples) - known)
    if unknown:
        raise ValueError(f"nominal/prior_sample: {unknown} are not parameters of the model(s); allowed: "
                         f"{', '.join(sorted(known))}")
    B = budget - costs.warmup
    cand = space.candidates(costs.warmup, B)
    cost = cand.duration + costs.run_overhead
    if B < cost.min():
        raise ValueError(f"budget {budget / units.HOUR:.4g} h leaves no time for one alignment after the "
                         f"warm-up of {costs.warmup:g} s; allowed: budget > warm-up + one run")
    mm = model.measurement(tilt_known)
    X = cand.inputs(mm, stand)
    sigma = stand.sigma(cand.duration)
    spec = criterion_rows(crit, model, tilt_known, samples, prior_information(prior, mm.names))
    if isinstance(crit, C):
        unit_vector(spec.names, crit.name)
    rows = spec.numeric(X, sigma)
    _check_candidates(rows, spec, space, model, X, sigma, mm)
    base = dict(cost=cost, budget=B, max_runs=max_runs, slot=cand.slot, n_slots=int(space.time_slots),
                candidates=cand, costs=costs, solver=solver)

    guards = []
    for gm in guard_models:
        gmm = gm.measurement(tilt_known)
        gspec = model_rows(gmm, samples, prior_information(prior, gmm.names))
        grows = gspec.numeric(X, sigma)
        _check_candidates(grows, gspec, space, gm, X, sigma, gmm)
        dopt = solve_approximate(Problem(D(), gspec, grows, **base))
        guards.append(Guard(gm, gspec, grows, -dopt.loss + gspec.k * np.log(identify_efficiency), dopt.loss))

    threats_, skipped, floors, notes = (), (), [], []
    if getattr(crit, "protects", False):
        threats_, skipped = threats(model, tilt_known, samples, space)
        n_plan = int(B // cost.min()) if max_runs is None else min(int(B // cost.min()), int(max_runs))
        floors, more = power_floors(threats_, X, sigma, base, n_plan, len(mm.names), solve_approximate)
        skipped = tuple(skipped) + tuple(more)
    # power floors are set for the planned number of runs; when the rounded plan falls short
    # (fewer runs, rounding), the short floors are raised and the design solved again; floors
    # still short after that (whole runs and their setups cannot keep them) are dropped, named
    raises, dropped = 0, {}
    while True:
        try:
            trial = _solve_and_round(Problem(crit, spec, rows, tuple(guards) + tuple(floors), **base), prune)
        except DesignError as err:
            if not floors:
                raise
            why = f"the convex program with its power floor failed ({err})"
            short = {g.label for g in floors} if raises == 0 else short
            dropped.update({e: why for e in short})
            floors, raises = [g for g in floors if g.label not in short], MAX_FLOOR_ROUNDS
            continue
        prob, approx, reduced, exact, notes = trial
        if not floors:
            break
        raised, short = raise_floors(floors, threats_, [g.level(exact.counts) for g in exact.guards[len(guards):]],
                                     int(exact.counts.sum()), len(mm.names))
        if not short:
            break
        if raises < MAX_FLOOR_ROUNDS - 1:
            floors, raises = raised, raises + 1
            continue
        dropped.update({e: "whole runs and their setups cannot keep its power floor in this budget" for e in short})
        floors = [g for g in floors if g.label not in short]
    skipped = tuple(skipped) + tuple(Protection(t.effect, t.sizes, None, False, dropped[t.effect])
                                     for t in threats_ if t.effect in dropped)
    if not np.isfinite(exact.loss):
        raise UnidentifiableError(f"{int(exact.counts.sum())} whole runs within the budget cannot identify "
                                  f"the model for criterion {crit.label}", spec.names)

    # the approximate optimum for the exact plan's alignment time (in each time slot), with the
    # guards the plan meets (rounding may leave one a little below its bound)
    t_slot = exact.slot_times(costs.run_overhead, prob.n_slots)
    t_align = float(t_slot.sum())
    shares = t_slot if prob.n_slots > 1 else None
    if prior is None and max_runs is None and not prob.guards and np.ptp(t_slot) <= 1e-9 * t_align:
        loss_same = prob.loss(approx.runs * t_align / B)
    else:
        loss_same = solve_approximate(_met(prob, exact).with_budget(t_align, shares), start=approx.support).loss
    rounding_eff = crit.efficiency(exact.loss, loss_same, spec.k)

    status = "off"
    if refine:
        try:
            status = refine_plan(prob, exact, stand, mm, space)
        except NotSmooth as err:
            status = f"none: criterion {crit.label} is not smooth ({err})"
    loss_refined = exact.loss
    if resolution is not None:
        for g in to_resolution(prob, exact, stand, mm, space, resolution):
            notes.append(f"rounded to the stand's resolution, the plan's power against {g.label} is below the "
                         "floor" if g.is_power else
                         f"rounded to the stand's resolution, the plan's D-efficiency for "
                         f"{'+'.join(g.model.effect_names)} is below the {identify_efficiency:g} required")
    loss_full = approx.loss
    if status != "off" or resolution is not None or prob.guards:
        # refinement and the stand's steps move settings off the candidate grid: the optimum
        # the plan is measured against then also has the plan's own settings as candidates,
        # and the guards the plan meets, so that no plan can beat it (efficiency <= 1 up to
        # the solvers' tolerance)
        ext = _met(prob, exact).extended(exact.settings, exact.rows, [g.rows for g in exact.guards],
                                         exact.settings.duration + costs.run_overhead, exact.slot)
        start = np.concatenate([approx.support, prob.n + np.arange(exact.counts.size)])
        loss_same = min(loss_same, solve_approximate(ext.with_budget(t_align, shares), start=start).loss)
        loss_full = min(loss_full, solve_approximate(ext, start=start).loss)
    efficiency = crit.efficiency(exact.loss, loss_same, spec.k)
    budget_eff = crit.efficiency(exact.loss, loss_full, spec.k)
    before = crit.efficiency(loss_refined, loss_same, spec.k)
    if resolution is not None and efficiency < before - 1e-4:
        notes.append(f"rounding the settings to the stand's resolution lowered the efficiency from "
                     f"{before:.4f} to {efficiency:.4f}")

    seq = pick_order(exact, prob, stand, order, rng)
    s = exact.settings.take(seq)
    t_start = costs.schedule(s.rate, s.azimuth, s.tilt_x, s.tilt_y, s.duration, s.not_before)
    plan = stand_plan(s, t_start, space, resolution, space.max_tilt > 0)
    evaluation = evaluate(plan, model, stand=stand, tilt_known=tilt_known, criterion=crit, nominal=nominal,
                          prior=prior)
    protection = ()
    if getattr(crit, "protects", False):
        X_plan = stand.inputs(mm, plan.rate, plan.azimuth, plan.tilt_x if plan.tilt_x is not None else 0.0,
                              plan.tilt_y if plan.tilt_y is not None else 0.0, plan.duration, plan.t_start)
        protection = plan_protection(model, threats_, {g.label for g in floors}, skipped, X_plan,
                                     stand.sigma(plan.duration), nominal, tilt_known)
    guard_out = []
    for g in guards:
        g_plan = g.at(g.spec.numeric(s.inputs(mm, stand), stand.sigma(s.duration)))
        try:
            ev = evaluate(plan, g.model, stand=stand, tilt_known=tilt_known, nominal=nominal, prior=prior)
            std = {nm: float(v) for nm, v in zip(ev.names, ev.std)}
        except UnidentifiableError as err:
            std = {}
            notes.append(f"the plan does not identify {'+'.join(g.model.effect_names)}: {err}")
        guard_out.append({"effects": list(g.model.effect_names), "min_efficiency": float(identify_efficiency),
                          "d_efficiency": float(np.exp((g.d_opt + g_plan.level(np.ones(seq.size)))
                                                       / g.spec.k)),
                          "std": std})
    return DesignResult(plan, evaluation, crit.label, efficiency, rounding_eff, budget_eff, approx,
                        float(costs.setups(s.rate, s.azimuth, s.tilt_x, s.tilt_y).sum()),
                        float(np.sum(s.duration + costs.run_overhead)), status, tuple(guard_out), tuple(notes),
                        protection)


def _met(prob, exact):
    """``prob`` with each guard's bound lowered to what the plan ``exact`` meets: the plan is
    then feasible for it, and the optimum it is measured against cannot be worse than it."""
    return replace(prob, guards=tuple(replace(g, bound=min(g.bound, ge.level(exact.counts)))
                                      for g, ge in zip(prob.guards, exact.guards)))


def _solve_and_round(prob, prune):
    """Approximate design, reduction, rounding and (``prune``) the setup-aware search:
    ``(prob, approx, reduced, exact, notes)``."""
    approx = solve_approximate(prob)     # with power floors: the conic solution, certified
    notes = []
    if approx.certified_efficiency < 0.999:
        notes.append(f"the approximate design is certified only to efficiency "
                     f"{approx.certified_efficiency:.4f}")
    reduced = caratheodory(prob, approx.runs)
    exact = round_design(prob, reduced)
    if prune:
        exact, note = prune_plan(prob, reduced, exact)
        notes += [note] if note else []
    return prob, approx, reduced, exact, notes


def _check_candidates(rows, spec, space, model, X, sigma, mm):
    """Raise :class:`~hse_opt.information.UnidentifiableError` when even every candidate run
    together cannot identify the model: then no plan from this design space can.

    A parameter whose heading signature stays below the fit's floor
    (:func:`~hse_opt.information.invisible`: 1e-6 arcsec across its whole declared range) in
    every candidate run at every parameter sample has no information, however the column
    normalisation of :func:`~hse_opt.information.check_identifiable` would scale it up; it is
    named, as the fit names it. ``rows`` (S, n, k): the weighted rows of ``spec``; ``X``, ``sigma``
    (n,): the candidates' inputs and heading sigmas (rad); ``mm``: the model's measurement model."""
    bounds = {q.name: (q.lower, q.upper) for q in mm.params}
    ranges = np.array([np.subtract(*bounds[n][::-1]) if n in bounds else np.inf for n in spec.names])
    sigma = np.asarray(sigma, dtype=float)
    blind = np.logical_and.reduce([invisible(r * sigma[:, None], ranges) for r in rows])
    for r in rows:
        try:
            check_identifiable(blind_out(spec.prior + np.einsum("ni,nj->ij", r, r) / r.shape[0],
                                         blind & (np.diag(spec.prior) == 0)), spec.names)
        except UnidentifiableError as err:
            timed = [e.name for e in model.effects if e.level == "thermal"]
            hint = (f" Time since power-on is not a factor of this design space (time_slots=1), and "
                    f"{', '.join(timed)} changes with it: allowed time_slots >= 2 (DesignSpace(time_slots=N); "
                    f"hse-opt design --time-slots N)."
                    if timed and space.time_slots == 1 else "")
            curved = [n for e in model.effects for n in e.nonlinear if n in err.names]
            if curved:
                hint += (f" {', '.join(curved)} {'enters' if len(curved) == 1 else 'enter'} the model nonlinearly "
                         f"and the design linearises at the nominal values, where the heading may not depend on "
                         f"{'it' if len(curved) == 1 else 'them'}: give values where it does "
                         f"(nominal={{...}}; hse-opt design --nominal NAME=VALUE, e.g. a warm-up amplitude).")
            hint += _blind_hint([n for n, b in zip(spec.names, blind) if b and n in err.names and n not in curved],
                                spec, X, sigma, mm, ranges)
            raise UnidentifiableError(f"no plan from these candidate runs can identify the model: "
                                      f"{str(err).rstrip('.')}.{hint}", err.names) from None


def _blind_hint(names, spec, X, sigma, mm, ranges):
    """What would help the parameters ``names`` that no candidate run sees at the nominal
    values: those another parameter's value gives a signature (a product, e.g. the encoder's
    1st harmonic with lambda2 or mount_xi; probed with every parameter at 5 % of its range off
    the middle) need nominal values; the others are out of these runs' reach."""
    if not names:
        return ""
    from .problem import Rows
    probe = np.array([(q.lower + q.upper) / 2 + 0.05 * (q.upper - q.lower) for q in mm.params]) * mm.scale
    seen = ~invisible(Rows(spec.names, spec.fn, [probe]).numeric(X, sigma)[0] * np.asarray(sigma)[:, None], ranges)
    acts = [n for n in names if seen[spec.names.index(n)]]
    never = [n for n in names if n not in acts]
    floor = f"{SENSITIVITY_FLOOR / units.ARCSEC:g} arcsec"
    out = ""
    if acts:
        out += (f" {', '.join(acts)} move{'s' if len(acts) == 1 else ''} no candidate run's heading by {floor} "
                f"across {'its' if len(acts) == 1 else 'their'} whole range at the nominal values, but "
                f"{'does' if len(acts) == 1 else 'do'} with other parameters away from them (a product, as the "
                "encoder's 1st harmonic with lambda2 or mount_xi): give nominal values where the heading depends "
                "on them (nominal={...}; hse-opt design --nominal NAME=VALUE, e.g. lambda2=4).")
    if never:
        out += (f" {', '.join(never)} move{'s' if len(never) == 1 else ''} no candidate run's heading by {floor} "
                f"across {'its' if len(never) == 1 else 'their'} whole range, at the nominal values or away from "
                "them: use a model without "
                f"{'it' if len(never) == 1 else 'them'} (fewer effects, --effects).")
    return out


def _guard_models(identify, model, crit):
    if identify is None:
        return [model] if crit.needs_guard else []
    items = [identify] if isinstance(identify, (Model, str)) else list(identify)
    if items and all(isinstance(i, str) and "," not in i for i in items) and len(items) > 1:
        return [as_model(items)]  # a list of effect names is one model
    return [as_model(i) for i in items]

