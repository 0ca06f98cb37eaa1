"""Field campaigns planned: positions whose true headings nobody knows.

:func:`design_field` plans such a campaign for a time budget that counts moving between
positions: how many positions, which rates and senses, how many repeats, scored by the
predicted sigma of lambda2 with every position's heading unknown
(:func:`hse_opt.design.evaluate` with ``field=True``); :func:`continue_campaign` plans the
rest of one under way, the runs so far counted. The default criterion ``protect:lambda2``
chooses among these candidates the smallest sigma with power >= 0.8 of the diagnosis against
each catalogue effect outside the model at its plausible edge, and names those no candidate
can protect (:mod:`hse_opt.design.field_protection`); ``c:lambda2`` is the smallest sigma
alone. What a fit of such a campaign says at each position is :mod:`hse_opt.fit.field`.
"""
import dataclasses
from dataclasses import dataclass

import numpy as np

from .. import units
from ..data import Plan
from .evaluation import evaluate
from .field_protection import choose, field_criterion
from .protection import describe as describe_protection
from .space import Costs, Stand

__all__ = ["FieldDesign", "field_plan", "design_field", "continue_campaign", "runs_as_plan", "RATE_PATTERNS_DPS"]

#: the position label of surveyed rows in :func:`runs_as_plan` (the stand reading's one constant)
SURVEYED = "surveyed"
#: label prefix of a continued campaign's new positions (``new1``, ``new2``, ...)
NEW_POSITION = "new"
#: rate patterns a field design tries at each position, deg/s, in execution order
RATE_PATTERNS_DPS = ((20.0, 40.0, 60.0), (20.0, 60.0), (60.0, -60.0), (40.0, -40.0), (20.0, 60.0, -60.0),
                     (60.0, -60.0, 20.0, -20.0))


def field_plan(patterns_dps, repeats, headings, costs, duration=600.0, tilts=None):
    """A field plan: at position k (heading ``headings[k]``, rad) the rate pattern
    ``patterns_dps[k]`` repeated ``repeats[k]`` times; start times from ``costs`` (the first
    run after ``costs.warmup``, a move between positions costs ``costs.azimuth_change``, a
    rate or sense change ``costs.rate_change``). ``tilts``: each placement's deliberate tilt
    (x, y), rad (default none). No position has a heading reference: ``azimuth`` holds the
    heading to set the system to (written as ``heading_deg``, ``azimuth_deg`` empty)."""
    rate, az, lab, tx, ty = [], [], [], [], []
    for k, (pattern, rep) in enumerate(zip(patterns_dps, repeats)):
        for r in tuple(pattern) * int(rep):
            rate.append(r * units.DEG_PER_S)
            az.append(headings[k])
            lab.append(f"P{k + 1}")
            t = (0.0, 0.0) if tilts is None else tilts[k]
            tx.append(t[0])
            ty.append(t[1])
    rate, az, tx, ty = map(np.array, (rate, az, tx, ty))
    dur = np.full(rate.size, float(duration))
    return Plan(run=np.arange(1, rate.size + 1), rate=rate, azimuth=np.mod(az, 2 * np.pi),
                t_start=costs.schedule(rate, az, tx, ty, dur), duration=dur, tilt_x=tx, tilt_y=ty,
                position=np.array(lab), surveyed=np.zeros(rate.size, bool))


@dataclass(frozen=True, eq=False)
class FieldDesign:
    """The best field plan found and what it was chosen from.

    Attributes
    ----------
    plan : hse_opt.data.Plan
    evaluation : hse_opt.design.Evaluation
    positions, repeats : int
    pattern_dps : tuple of float
        The rate pattern at each position, deg/s.
    tried : tuple of (positions, pattern_dps, repeats, sigma_lambda2_arcsec, hours)
    before : Plan or None
        For a continued campaign (:func:`continue_campaign`): the runs so far as plan rows
        (their measured tilts, positions and start times); ``evaluation`` is then that of
        the runs so far and ``plan`` together, and ``plan`` holds the new runs only.
    stay : bool
        The new runs start at the last position of the runs so far (no move).
    criterion : str
        ``protect:NAME`` (the default) or ``c:NAME``.
    protection : tuple of hse_opt.design.protection.Protection
        With ``protect:NAME``: the power of the diagnosis against each catalogue effect
        outside the model at its plausible edge on this plan (with the runs so far), and why
        an effect is not protected (:mod:`hse_opt.design.field_protection`); else empty.
    unprotected_std : float or None
        The smallest predicted sigma of the target among all candidates (display unit): what
        ``c:NAME`` would give, the price of the protection being ``evaluation``'s sigma
        against it.
    """

    plan: Plan
    evaluation: object
    positions: int
    repeats: int
    pattern_dps: tuple
    tried: tuple
    before: Plan | None = None
    stay: bool = False
    criterion: str = "protect:lambda2"
    protection: tuple = ()
    unprotected_std: float | None = None

    @property
    def target(self):
        """The parameter whose sigma the criterion minimises."""
        return self.criterion.split(":", 1)[1]

    def summary(self):
        """Report lines: the sigma of the target, the price of the protection and each
        effect's power (never the one without the other)."""
        s = self.evaluation.std_of(self.target)
        unit = self.evaluation.units[self.evaluation.names.index(self.target)]
        lines = [f"criterion {self.criterion}: sigma({self.target}) {s:.4g} {unit}"]
        if self.protection:
            guarded = [p.effect for p in self.protection if p.protected]
            what = f"protects {', '.join(guarded)}" if guarded else "protects none of the effects outside the model"
            price = (f"at no cost in sigma({self.target})" if s <= self.unprotected_std * (1 + 1e-9) else
                     f"at sigma({self.target}) {s:.4g} against {self.unprotected_std:.4g} {unit} of the "
                     f"unprotected best (--criterion c:{self.target})")
            lines.append(f"the plan {what} {price}")
            lines += describe_protection(self.protection)
        return lines

    def to_dict(self):
        """The JSON keys of ``design --field`` that describe the choice."""
        return {"criterion": self.criterion, "positions": self.positions, "pattern_dps": list(self.pattern_dps),
                "repeats": self.repeats, "protection": [p.to_dict() for p in self.protection],
                "unprotected_std": self.unprotected_std}


def design_field(budget, model="hse", *, criterion="protect:lambda2", costs=None, stand=None, duration=600.0,
                 max_positions=4, patterns_dps=RATE_PATTERNS_DPS, heading0=0.0, prior=None):
    """The field campaign with the smallest predicted sigma of lambda2 within a time budget,
    protected against the effects outside the model where the budget allows.

    Searched: 1 to ``max_positions`` positions at headings spread evenly from ``heading0``
    (rad; their true headings are unknown to the campaign, only their spread matters through
    C23), every rate pattern of ``patterns_dps`` at all of them, repeated as often as the
    budget allows. The time counts the warm-up, every alignment, every rate or sense change
    and every move between positions (``costs.azimuth_change``). Among these candidates the
    criterion chooses (:mod:`hse_opt.design.field_protection`).

    Parameters
    ----------
    budget : float
        Time from power-on to the end of the last alignment, s.
    model : Model, str or sequence of str
    criterion : str
        ``'protect:lambda2'`` (default): the smallest sigma among the plans with power >= 0.8
        of the diagnosis against each catalogue effect outside the model that some candidate
        protects; ``'c:lambda2'``: the smallest sigma alone (``NAME`` another parameter).
    costs : hse_opt.design.Costs, optional
    stand : hse_opt.design.Stand, optional
        The stand's own tilt stands for every placement's.
    duration : float
        Alignment length, s.
    prior : FitResult, Prior or numpy.ndarray, optional
        An earlier calibration as prior information (:func:`hse_opt.design.evaluate`).

    Returns
    -------
    FieldDesign

    Raises
    ------
    ValueError
        No plan fits the budget, or none identifies lambda2.
    """

    costs, stand, crit = costs or Costs(), stand or Stand(), field_criterion(criterion)
    cands, tried = [], []
    for n_pos in range(1, int(max_positions) + 1):
        headings = [heading0 + 2 * np.pi * k / n_pos for k in range(n_pos)]
        for pattern in patterns_dps:
            for rep, plan, ev, end in _by_repeats(
                    lambda rep: field_plan([pattern] * n_pos, [rep] * n_pos, headings, costs, duration), budget,
                    lambda plan: evaluate(plan, model, stand=stand, field=True, prior=prior)):
                s = _target_std(ev, crit.target)
                tried.append((n_pos, tuple(pattern), rep, s, end / units.HOUR))
                cands.append((s, plan, FieldDesign(plan, ev, n_pos, rep, tuple(pattern), ()), None))
    if not cands:
        raise ValueError(f"budget {budget / units.HOUR:g} h: no field plan fits it and identifies {crit.target}; "
                         f"allowed: at least the warm-up ({costs.warmup / units.HOUR:g} h) and two alignments "
                         "at different rates")
    return _chosen(cands, tried, model, crit, stand)


def _target_std(ev, target):
    """The predicted sigma of ``target``; ValueError naming the field evaluation's parameters."""
    if target not in ev.names:
        raise ValueError(f"criterion parameter {target!r} is not estimable in a field campaign of "
                         f"{'+'.join(ev.effects)}; allowed: {', '.join(ev.names)}")
    return ev.std_of(target)


def _chosen(cands, tried, model, crit, stand, tilt_known=True, nominal=None, prefer=None):
    """The candidate ``(sigma, plan the diagnosis tests, FieldDesign, its runs' heading sigmas
    or None)`` the criterion picks,
    with its protection and the tried list (``prefer``: :func:`~.field_protection.choose`)."""
    k, protection, unprotected = choose([(s, plan, sig) for s, plan, _, sig in cands], model, crit, stand,
                                        tilt_known, nominal, prefer)
    return dataclasses.replace(cands[k][2], tried=tuple(tried), criterion=crit.label, protection=protection,
                               unprotected_std=unprotected)


def runs_as_plan(runs, stand=None):
    """The runs of a campaign as plan rows, for evaluating it with more runs: rates, azimuths
    (a field position's: its mean heading), durations, start times, each position's label
    (surveyed rows share ``'surveyed'``: the stand reading's one constant) and the measured
    tilts as offsets from the ``stand``'s (``tilt_x = roll - stand roll``, ``tilt_y = pitch -
    stand pitch``; none measured: the stand's). Raises ValueError without ``t_start_s``."""

    stand = stand or Stand()
    if runs.t_start is None:
        raise ValueError(f"{runs.source}: column t_start_s is required to continue a campaign (the time since "
                         "power-on of the runs so far); allowed: RUNS.csv with t_start_s, as hse-opt align writes")
    n = len(runs)
    tx = np.zeros(n) if runs.roll is None else np.asarray(runs.roll, float) - stand.tilt[0]
    ty = np.zeros(n) if runs.pitch is None else np.asarray(runs.pitch, float) - stand.tilt[1]
    group, labels = runs.reference_groups()
    pos = np.array([SURVEYED if g < 0 else str(labels[g]) for g in group])
    return Plan(run=np.asarray(runs.run), rate=np.asarray(runs.rate, float), azimuth=np.asarray(runs.azimuth, float),
                t_start=np.asarray(runs.t_start, float), duration=np.asarray(runs.duration, float), tilt_x=tx,
                tilt_y=ty, position=pos, source=runs.source)


def continue_campaign(runs_so_far, model="hse", time_left=None, *, criterion="protect:lambda2", prior=None,
                      costs=None, stand=None, duration=600.0, max_positions=3, patterns_dps=RATE_PATTERNS_DPS,
                      tilt_known=True, nominal=None, sigma=None):
    """The rest of a field campaign: the new runs that, with the runs so far, give the
    smallest predicted sigma of lambda2 in the time left, protected as :func:`design_field`
    protects (the diagnosis's power on the runs so far and the new runs together).

    Searched: stay at the last position of the runs so far (its measured tilt and heading,
    no move) or not, then 0 to ``max_positions`` new positions (headings spread evenly from
    the last one; the stand's tilt; labels ``new1``, ``new2``, ... that no position has yet),
    one rate pattern of ``patterns_dps`` (or a rotation of it: any of its rates first)
    everywhere, repeated as often as the time allows
    (more repeats never raise the predicted sigma nor lower a power: only the most that fit
    are scored); among plans as good (:data:`~.field_protection.TIE`) the one whose first run
    lowers the sigma most is taken, as a campaign is planned again after each run. Staying
    completes the pattern x repeats of the last position's current visit: the runs done there
    since the system came count among them (planned again after each run, the plan would
    otherwise stay at one position for ever). When the last runs were surveyed (a stand with a heading reference), the
    new placements are stand azimuths: they share the stand reading's one constant and the
    tilt measured on the stand (fixed in b0 as the stand turns). The runs so far count in the information
    (:func:`runs_as_plan`: their positions' unknown constants, measured tilts and times
    since power-on); the new runs start after the last one ends (a move to a new position
    costs ``costs.azimuth_change``, a rate or sense change ``costs.rate_change``; the
    warm-up is over) and end within ``time_left``.

    Parameters
    ----------
    runs_so_far : hse_opt.data.Runs
        The campaign's runs so far (RUNS.csv), with ``t_start_s``.
    model : Model, str or sequence of str
    time_left : float
        s, from the end of the last run so far.
    criterion : str
        As :func:`design_field`.
    prior : FitResult, Prior or numpy.ndarray, optional
        An earlier calibration (not of these runs) as prior information.
    costs, stand, duration, max_positions, patterns_dps
        As :func:`design_field`.
    tilt_known : bool
        Whether the runs carry pitch and roll (else the tilt-coupled terms are free
        coefficients, :func:`hse_opt.design.evaluate`).
    nominal : mapping name -> value, optional
        Where the model is linearised (display units; e.g. the current estimate).
    sigma : array_like, shape (n,), optional
        The runs so far's heading 1-sigma, rad (e.g. the fit's weights); default the stand's
        noise model, which the new runs always get.

    Returns
    -------
    FieldDesign
        ``plan``: the new runs (run ids after the last one), ``before``: the runs so far as
        plan rows, ``evaluation``: both together.

    Raises
    ------
    ValueError
        No new run fits the time left (named), or the runs lack ``t_start_s``.
    """
    costs, stand, crit = costs or Costs(), stand or Stand(), field_criterion(criterion)
    if time_left is None or not np.isfinite(time_left) or time_left <= 0:
        raise ValueError(f"time_left = {time_left!r}; allowed: the time left after the last run, s > 0")
    before = runs_as_plan(runs_so_far, stand)
    s_before = stand.sigma(before.duration) if sigma is None else np.broadcast_to(np.asarray(sigma, float),
                                                                                  before.duration.shape)
    t_end = float(np.max(before.t_start + before.duration))
    last = int(np.argmax(before.t_start))
    last_az, last_pos = float(before.azimuth[last]), str(before.position[last])
    at_last = before.position == last_pos
    last_tilt = (float(np.mean(before.tilt_x[at_last])), float(np.mean(before.tilt_y[at_last])))
    first_id = int(np.max(before.run)) + 1
    stand_reference = last_pos == SURVEYED
    taken = set(before.position.tolist())
    fresh = [f"{NEW_POSITION}{j}" for j in range(1, len(taken) + int(max_positions) + 2)
             if f"{NEW_POSITION}{j}" not in taken][:int(max_positions)]
    # this visit of the last position: its runs since the system came there, rates in deg/s
    order = np.argsort(before.t_start, kind="stable")
    same = (before.position[order] == last_pos) & (np.abs(before.azimuth[order] - last_az) < 1e-9)
    n_visit = len(order) - (int(np.flatnonzero(~same)[-1]) + 1 if (~same).any() else 0)
    visit = [float(r / units.DEG_PER_S) for r in before.rate[order][len(order) - n_visit:]]
    def both(new):
        """The heading sigmas of the runs so far and the new runs, rad."""
        return np.concatenate([s_before, stand.sigma(new.duration)])

    cands, tried = [], []
    for stay in (True, False):
        for n_new in range(0 if stay else 1, int(max_positions) + 1):
            headings = ([last_az] if stay else []) + [last_az + 2 * np.pi * k / (n_new + 1) for k in range(1, n_new + 1)]
            if stand_reference:  # other azimuths of the surveyed stand: its constant, its tilt
                labels, tilts = [SURVEYED] * len(headings), [last_tilt] * len(headings)
            else:
                labels = ([last_pos] if stay else []) + fresh[:n_new]
                tilts = ([last_tilt] if stay else []) + [(0.0, 0.0)] * n_new
            for pattern in _rotations(patterns_dps):
                def make(rep):
                    # staying completes the pattern x rep of this visit: the runs done count
                    pats = [_rest(pattern, rep, visit) if stay else pattern] + [pattern] * n_new
                    reps = [1 if stay else rep] + [rep] * n_new
                    first_rate = next(iter(p[0] for p in pats if p), pattern[0])
                    move = costs.azimuth_change if not (stay and pats[0]) else (
                        costs.rate_change if abs(first_rate * units.DEG_PER_S - before.rate[last]) > 1e-12 else 0.0)
                    c = dataclasses.replace(costs, warmup=t_end + move)
                    new = field_plan(pats[len(pats) - len(headings):], reps[len(pats) - len(headings):], headings, c,
                                     duration)
                    k = [int(p[1:]) - 1 for p in new.position]
                    return new.replace(run=first_id + np.arange(len(new)), position=np.array(labels)[k],
                                       tilt_x=np.array([tilts[i][0] for i in k]),
                                       tilt_y=np.array([tilts[i][1] for i in k]),
                                       surveyed=np.array(labels)[k] == SURVEYED)

                for rep, new, ev, end in _most_repeats(
                        make, t_end + time_left + 1e-6,
                        lambda new: evaluate(_concat(before, new), model, stand=stand, tilt_known=tilt_known,
                                             field=True, prior=prior, nominal=nominal, sigma=both(new))):
                    sd = _target_std(ev, crit.target)
                    tried.append((len(headings), tuple(pattern), rep, sd, (end - t_end) / units.HOUR))
                    cands.append((sd, _concat(before, new),
                                  FieldDesign(new, ev, len(headings), rep, tuple(pattern), (), before, stay),
                                  both(new)))
    if not cands:
        raise ValueError(f"time left {time_left / units.HOUR:g} h: no new run fits it and, with the runs so far, "
                         f"identifies {crit.target}; allowed: at least one alignment ({duration:g} s) and its setup")

    def first(i):
        """The target's sigma once the candidate's first run is done (inf: not yet estimable)."""
        from ..information import UnidentifiableError
        try:
            one = cands[i][2].plan.subset([0])
            ev = evaluate(_concat(before, one), model, stand=stand, tilt_known=tilt_known, field=True, prior=prior,
                          nominal=nominal, sigma=both(one))
        except UnidentifiableError:
            return np.inf
        return ev.std_of(crit.target) if crit.target in ev.names else np.inf

    return _chosen(cands, tried, model, crit, stand, tilt_known, nominal, first)


def _rest(pattern, rep, done):
    """``pattern`` repeated ``rep`` times without the runs ``done`` (rates, deg/s; each taken
    out once where it first occurs)."""
    seq = list(pattern) * int(rep)
    for r in done:
        hit = next((i for i, v in enumerate(seq) if abs(v - r) < 1e-9), None)
        if hit is not None:
            del seq[hit]
    return tuple(seq)


def _rotations(patterns):
    """Each pattern and its rotations (each rate of it first), once: a campaign continued
    after every run would otherwise restart every pattern at its first rate."""
    out = {}
    for p in patterns:
        for k in range(len(p)):
            out.setdefault(tuple(p[k:]) + tuple(p[:k]), None)
    return tuple(out)


def _most_repeats(make, end_limit, score):
    """The last of :func:`_by_repeats` (the most repeats that fit and identify), or nothing."""
    last = None
    for last in _by_repeats(make, end_limit, score):
        pass
    if last is not None:
        yield last


def _by_repeats(make, end_limit, score):
    """``(repeats, plan, evaluation, end)`` for ``plan = make(repeats)``, repeats 1, 2, ...
    while the plan ends by ``end_limit`` (s), skipping those ``score`` cannot identify."""
    from ..information import UnidentifiableError

    rep = 0
    while True:
        rep += 1
        plan = make(rep)
        if not len(plan):    # a position's pattern x rep all done already: more repeats
            continue
        end = float(np.max(plan.t_start + plan.duration))
        if end > end_limit:
            return
        try:
            ev = score(plan)
        except UnidentifiableError:
            continue
        yield rep, plan, ev, end


def _concat(a, b):
    """Two plans as one (the columns both have)."""
    return Plan(run=np.concatenate([a.run, b.run]), rate=np.concatenate([a.rate, b.rate]),
                azimuth=np.concatenate([a.azimuth, b.azimuth]), t_start=np.concatenate([a.t_start, b.t_start]),
                duration=np.concatenate([a.duration, b.duration]), tilt_x=np.concatenate([a.tilt_x, b.tilt_x]),
                tilt_y=np.concatenate([a.tilt_y, b.tilt_y]), position=np.concatenate([a.position, b.position]),
                source="runs so far and the next plan")
