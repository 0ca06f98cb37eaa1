"""Field campaigns planned: positions whose true headings nobody knows.

:func:`design_field` plans such a campaign for a time budget that counts moving between
positions: how many positions, which rates and senses, how many repeats, scored by the
predicted sigma of lambda2 with every position's heading unknown
(:func:`hse_opt.design.evaluate` with ``field=True``); :func:`continue_campaign` plans the
rest of one under way, the runs so far counted. What a fit of such a campaign says at each
position is :mod:`hse_opt.fit.field`.
"""
from dataclasses import dataclass

import numpy as np

from .. import units
from ..data import Plan
from .evaluation import evaluate
from .space import Costs, Stand

__all__ = ["FieldDesign", "field_plan", "design_field", "continue_campaign", "runs_as_plan", "RATE_PATTERNS_DPS"]

#: rate patterns a field design tries at each position, deg/s, in execution order
RATE_PATTERNS_DPS = ((20.0, 40.0, 60.0), (20.0, 60.0), (60.0, -60.0), (40.0, -40.0), (20.0, 60.0, -60.0),
                     (60.0, -60.0, 20.0, -20.0))


def field_plan(patterns_dps, repeats, headings, costs, duration=600.0, tilts=None):
    """A field plan: at position k (heading ``headings[k]``, rad) the rate pattern
    ``patterns_dps[k]`` repeated ``repeats[k]`` times; start times from ``costs`` (the first
    run after ``costs.warmup``, a move between positions costs ``costs.azimuth_change``, a
    rate or sense change ``costs.rate_change``). ``tilts``: each placement's deliberate tilt
    (x, y), rad (default none)."""
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
                position=np.array(lab))


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
    """

    plan: Plan
    evaluation: object
    positions: int
    repeats: int
    pattern_dps: tuple
    tried: tuple
    before: Plan | None = None
    stay: bool = False


def design_field(budget, model="hse", *, costs=None, stand=None, duration=600.0, max_positions=4,
                 patterns_dps=RATE_PATTERNS_DPS, heading0=0.0, prior=None):
    """The field campaign with the smallest predicted sigma of lambda2 within a time budget.

    Searched: 1 to ``max_positions`` positions at headings spread evenly from ``heading0``
    (rad; their true headings are unknown to the campaign, only their spread matters through
    C23), every rate pattern of ``patterns_dps`` at all of them, repeated as often as the
    budget allows. The time counts the warm-up, every alignment, every rate or sense change
    and every move between positions (``costs.azimuth_change``).

    Parameters
    ----------
    budget : float
        Time from power-on to the end of the last alignment, s.
    model : Model, str or sequence of str
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

    costs = costs or Costs()
    best, tried = None, []
    for n_pos in range(1, int(max_positions) + 1):
        headings = [heading0 + 2 * np.pi * k / n_pos for k in range(n_pos)]
        for pattern in patterns_dps:
            for rep, plan, ev, end in _by_repeats(
                    lambda rep: field_plan([pattern] * n_pos, [rep] * n_pos, headings, costs, duration), budget,
                    lambda plan: evaluate(plan, model, stand=stand, field=True, prior=prior)):
                s = ev.std_of("lambda2")
                tried.append((n_pos, tuple(pattern), rep, s, end / units.HOUR))
                if best is None or s < best[0]:
                    best = (s, FieldDesign(plan, ev, n_pos, rep, tuple(pattern), ()))
    if best is None:
        raise ValueError(f"budget {budget / units.HOUR:g} h: no field plan fits it and identifies lambda2; "
                         f"allowed: at least the warm-up ({costs.warmup / units.HOUR:g} h) and two alignments "
                         "at different rates")
    d = best[1]
    return FieldDesign(d.plan, d.evaluation, d.positions, d.repeats, d.pattern_dps, tuple(tried))


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
    pos = np.array(["surveyed" if g < 0 else str(labels[g]) for g in group])
    return Plan(run=np.asarray(runs.run), rate=np.asarray(runs.rate, float), azimuth=np.asarray(runs.azimuth, float),
                t_start=np.asarray(runs.t_start, float), duration=np.asarray(runs.duration, float), tilt_x=tx,
                tilt_y=ty, position=pos, source=runs.source)


def continue_campaign(runs_so_far, model="hse", time_left=None, *, prior=None, costs=None, stand=None,
                      duration=600.0, max_positions=3, patterns_dps=RATE_PATTERNS_DPS):
    """The rest of a field campaign: the new runs that, with the runs so far, give the
    smallest predicted sigma of lambda2 in the time left.

    Searched: stay at the last position of the runs so far (its measured tilt and heading,
    no move) or not, then 0 to ``max_positions`` new positions (headings spread evenly from
    the last one; the stand's tilt), one rate pattern of ``patterns_dps`` everywhere,
    repeated as often as the time allows. The runs so far count in the information
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
    prior : FitResult, Prior or numpy.ndarray, optional
        An earlier calibration (not of these runs) as prior information.
    costs, stand, duration, max_positions, patterns_dps
        As :func:`design_field`.

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
    import dataclasses


    costs, stand = costs or Costs(), stand or Stand()
    if time_left is None or not np.isfinite(time_left) or time_left <= 0:
        raise ValueError(f"time_left = {time_left!r}; allowed: the time left after the last run, s > 0")
    before = runs_as_plan(runs_so_far, stand)
    t_end = float(np.max(before.t_start + before.duration))
    last = int(np.argmax(before.t_start))
    last_az, last_pos = float(before.azimuth[last]), str(before.position[last])
    at_last = before.position == last_pos
    last_tilt = (float(np.mean(before.tilt_x[at_last])), float(np.mean(before.tilt_y[at_last])))
    first_id = int(np.max(before.run)) + 1
    best, tried = None, []
    for stay in (True, False):
        for n_new in range(0 if stay else 1, int(max_positions) + 1):
            headings = ([last_az] if stay else []) + [last_az + 2 * np.pi * k / (n_new + 1) for k in range(1, n_new + 1)]
            labels = ([last_pos] if stay else []) + [f"new{k}" for k in range(1, n_new + 1)]
            tilts = ([last_tilt] if stay else []) + [(0.0, 0.0)] * n_new
            for pattern in patterns_dps:
                move = 0.0 if stay else costs.azimuth_change
                if stay and abs(pattern[0] * units.DEG_PER_S - before.rate[last]) > 1e-12:
                    move = costs.rate_change
                c = dataclasses.replace(costs, warmup=t_end + move)
                def make(rep):
                    new = field_plan([pattern] * len(headings), [rep] * len(headings), headings, c, duration)
                    k = [int(p[1:]) - 1 for p in new.position]
                    return new.replace(run=first_id + np.arange(len(new)), position=np.array(labels)[k],
                                       tilt_x=np.array([tilts[i][0] for i in k]),
                                       tilt_y=np.array([tilts[i][1] for i in k]))

                for rep, new, ev, end in _by_repeats(
                        make, t_end + time_left + 1e-6,
                        lambda new: evaluate(_concat(before, new), model, stand=stand, field=True, prior=prior)):
                    sd = ev.std_of("lambda2")
                    tried.append((len(headings), tuple(pattern), rep, sd, (end - t_end) / units.HOUR))
                    if best is None or sd < best[0]:
                        best = (sd, FieldDesign(new, ev, len(headings), rep, tuple(pattern), (), before, stay))
    if best is None:
        raise ValueError(f"time left {time_left / units.HOUR:g} h: no new run fits it and, with the runs so far, "
                         f"identifies lambda2; allowed: at least one alignment ({duration:g} s) and its setup")
    return dataclasses.replace(best[1], tried=tuple(tried))


def _by_repeats(make, end_limit, score):
    """``(repeats, plan, evaluation, end)`` for ``plan = make(repeats)``, repeats 1, 2, ...
    while the plan ends by ``end_limit`` (s), skipping those ``score`` cannot identify."""
    from ..information import UnidentifiableError

    rep = 0
    while True:
        rep += 1
        plan = make(rep)
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
