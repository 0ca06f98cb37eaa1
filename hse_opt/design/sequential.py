"""Sequential design: the next alignments of a campaign that is running.

While a campaign runs, the engineer decides the next alignment while the last one runs (the
paper's on-line procedure). :func:`next_runs` gives it, and the ones after it for the time
left: the protected continuation of :func:`hse_opt.design.field.continue_campaign` (the one
planner of a running campaign, also ``hse-opt design --field --runs``), as the field session
(``hse-opt calibrate``) needs it - one alignment at a time, each with the target's sigma once
it is done:

* **Information.** The runs so far and the new runs together, each unsurveyed position's
  unknown heading eliminated as the fit does (:func:`hse_opt.design.evaluate` with
  ``field=True``); surveyed rows share the stand reading's one constant. The runs so far
  weigh with their own sigmas (the fit's weights), so the sigma now is the fit's statistical
  one; the new runs with the gyro noise whose heading sigma is the runs' median
  (:func:`hse_opt.information.heading_sigma`); the stand as the runs show it: their latitude,
  the tilt measured at the last position.
* **Candidates.** Stay at the last position (its measured tilt and heading) or not, and up to
  three new positions ("move to a new heading": headings spread from the last one, the
  system's measured tilt in b0 kept - its own tilt on its vehicle; on sloping ground the
  slope's own tilt does not turn with the vehicle: choose a place whose slope differs), one
  rate pattern everywhere (:data:`hse_opt.design.field.RATE_PATTERNS_DPS`), repeated as
  often as the time left allows, at the runs' median duration. On a surveyed stand the new
  placements are other stand azimuths (one constant, the tilt fixed in b0).
* **Criterion.** ``protect:lambda2``: the smallest sigma of the target among the candidates
  with power >= 0.8 of the diagnosis against each catalogue effect outside the model that
  some candidate protects (:mod:`hse_opt.design.field_protection`): when the positions so
  far cannot tell, e.g., a sync delay from lambda2, the plan moves on.
* **Time.** The runs start after the last run so far ends; a move costs
  ``costs.azimuth_change``, a rate or sense change ``costs.rate_change``.
* **Stop.** With ``target_sigma``, the plan ends at the first run after which the target's
  sigma is at most the target and every effect the whole plan protects is still protected.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import units
from ..data import Plan
from ..model.composition import as_model
from .evaluation import evaluate
from .field import RATE_PATTERNS_DPS, SURVEYED, _concat, continue_campaign, runs_as_plan
from .space import Costs, Stand

__all__ = ["NextRun", "Continuation", "next_runs"]


@dataclass(frozen=True)
class NextRun:
    """One planned alignment.

    Attributes
    ----------
    position : str or None
        Its position label (an existing one, or ``new1``, ``new2``... for a new position);
        None on a surveyed stand (the azimuth says where).
    new_position : bool
        The first run at a new position: "move to a new heading".
    surveyed : bool
        At a surveyed azimuth (the stand reading is the reference).
    azimuth_deg : float
        The stand azimuth to set (surveyed), else the heading the position is expected at, deg.
    rate_dps : float
        Signed bias rate, deg/s.
    duration_s, t_start_s : float
        Alignment length and its planned start since power-on, s.
    sigma_after : float
        The target's sigma once this run is done (display unit; inf while not estimable).
    """

    position: str | None
    new_position: bool
    surveyed: bool
    azimuth_deg: float
    rate_dps: float
    duration_s: float
    t_start_s: float
    sigma_after: float

    def describe(self):
        """The run in words: where, rate and sense, duration."""
        sense = "positive" if self.rate_dps > 0 else "negative"
        what = f"{abs(self.rate_dps):g} deg/s {sense} sense, {self.duration_s:g} s"
        if self.new_position:
            return f"move to a new heading (about {self.azimuth_deg:.0f} deg), {what}"
        if self.surveyed:
            return f"stand azimuth {self.azimuth_deg:g} deg, {what}"
        return f"at position {self.position}, {what}"

    def to_dict(self):
        return {"position": self.position, "new_position": self.new_position, "surveyed": self.surveyed,
                "azimuth_deg": self.azimuth_deg, "rate_dps": self.rate_dps, "duration_s": self.duration_s,
                "t_start_s": self.t_start_s, "sigma_after": _finite(self.sigma_after),
                "text": self.describe()}


@dataclass(frozen=True)
class Continuation:
    """The rest of a campaign, planned sequentially.

    Attributes
    ----------
    runs : tuple of NextRun
        In order; ``runs[0]`` is the next alignment (empty when nothing fits the time left).
    target : str
        The parameter whose sigma is the criterion.
    unit : str
    sigma_now, sigma_end : float
        Its sigma from the runs so far, and after all of ``runs`` (inf while not estimable).
    time_left : float
        The time that was planned, s.
    plan : hse_opt.data.Plan or None
        ``runs`` as a PLAN table (None when empty).
    notes : tuple of str
    effects : tuple of str
        The model whose information was counted.
    criterion : str
        ``protect:NAME`` (default) or ``c:NAME``.
    protection : tuple of hse_opt.design.protection.Protection
        The power of the diagnosis against each catalogue effect outside the model on the
        runs so far and ``runs`` together, and why an effect is not protected (empty for
        ``c:NAME`` or when nothing was planned).
    """

    runs: tuple
    target: str
    unit: str
    sigma_now: float
    sigma_end: float
    time_left: float
    plan: Plan | None
    notes: tuple = ()
    effects: tuple = ()
    criterion: str = "protect:lambda2"
    protection: tuple = ()

    @property
    def next(self):
        """The next alignment (None when nothing fits)."""
        return self.runs[0] if self.runs else None

    def to_dict(self):
        return {"target": self.target, "unit": self.unit, "sigma_now": _finite(self.sigma_now),
                "sigma_end": _finite(self.sigma_end), "time_left_h": self.time_left / units.HOUR,
                "n_runs": len(self.runs), "next": None if self.next is None else self.next.to_dict(),
                "effects": list(self.effects), "notes": list(self.notes), "criterion": self.criterion,
                "protection": [p.to_dict() for p in self.protection]}


def _finite(x):
    return float(x) if np.isfinite(x) else None


def next_runs(runs, model, time_left, *, values=None, tilt_known=None, target="lambda2", criterion=None,
              sigma=None, costs=None, target_sigma=None, patterns_dps=RATE_PATTERNS_DPS, max_positions=3):
    """Plan the rest of a running campaign, its next alignment first (module docstring).

    Parameters
    ----------
    runs : hse_opt.data.Runs
        The runs so far (surveyed, field or mixed; with ``t_start_s`` the plan continues from
        the last run's end, else from the sum of the durations).
    model : Model, str or sequence of str
        The model being calibrated (e.g. ``fit.model``).
    time_left : float
        Stand time left after the last run so far, s.
    values : mapping name -> value (display units), optional
        Where to linearise (the current estimate); default the nominal values.
    tilt_known : bool, optional
        Default: when the runs carry pitch and roll.
    target : str
        The parameter whose sigma is the criterion.
    criterion : str, optional
        Default ``protect:<target>``; ``c:<target>`` for the smallest sigma alone.
    sigma : numpy.ndarray, shape (n,), optional
        Each run's heading sigma, rad (default ``runs.heading_std``; else
        :func:`hse_opt.information.heading_sigma`): their median sets the noise of the plan.
    costs : Costs, optional
        Setup times (the warm-up is not used: the campaign is running).
    target_sigma : float, optional
        Stop once the target's sigma is at most this (display unit).
    patterns_dps, max_positions
        As :func:`hse_opt.design.field.continue_campaign`.

    Returns
    -------
    Continuation
    """
    from ..information import EARTH_RATE, UnidentifiableError, heading_sigma

    model = as_model(model)
    costs = costs or Costs()
    if tilt_known is None:
        tilt_known = runs.pitch is not None
    mm = model.measurement(bool(tilt_known))
    if target not in mm.names:
        raise ValueError(f"target {target!r} is not a parameter of {'+'.join(model.effect_names)}; "
                         f"allowed: {', '.join(mm.names)}")
    if not np.isfinite(time_left) or time_left < 0:
        raise ValueError(f"time left {time_left!r} s; allowed: a finite time >= 0")
    unit = mm.params[mm.names.index(target)].unit
    if runs.t_start is None:  # run order stands in: each run after the one before
        runs = runs.replace(t_start=np.concatenate([[0.0], np.cumsum(runs.duration)[:-1]]))
    if sigma is None:
        sigma = runs.heading_std if runs.heading_std is not None else heading_sigma(runs.duration, runs.latitude)
    latitude = float(np.median(runs.latitude))
    # the gyro noise whose heading sigma is the runs' median (heading_sigma: arw / (w_ie cos L sqrt T))
    arw = float(np.median(np.asarray(sigma, float) * EARTH_RATE * np.cos(runs.latitude) * np.sqrt(runs.duration)))
    last = int(np.argmax(runs.t_start))
    group, _ = runs.reference_groups()
    here = group == group[last]
    tilt = (0.0, 0.0) if not tilt_known else (float(np.mean(runs.roll[here])), float(np.mean(runs.pitch[here])))
    stand = Stand(latitude=latitude, tilt=tilt, arw=arw)
    duration = round(float(np.median(runs.duration)), 1)   # the stand sets it to 0.1 s
    values = {k: v for k, v in (values or {}).items() if k in mm.names}
    before = runs_as_plan(runs, stand)
    sigma = np.broadcast_to(np.asarray(sigma, float), (len(runs),))

    def std(plan):
        """The target's sigma of ``plan`` (the runs so far first, with their own sigmas)."""
        s = np.concatenate([sigma, stand.sigma(plan.duration[len(runs):])])
        try:
            return evaluate(plan, model, stand=stand, tilt_known=tilt_known, nominal=values, field=True, sigma=s
                            ).std_of(target)
        except UnidentifiableError:
            return np.inf

    sigma_now = std(before)
    crit = criterion or f"protect:{target}"
    try:
        fd = continue_campaign(runs, model, time_left, criterion=crit, costs=costs, stand=stand, duration=duration,
                               max_positions=max_positions, patterns_dps=patterns_dps, tilt_known=tilt_known,
                               nominal=values, sigma=sigma)
    except ValueError as err:
        if time_left > 0 and "no new run fits" not in str(err):
            raise
        note = f"no alignment fits the {time_left / units.HOUR:.3g} h left" if time_left <= 0 else str(err)
        return Continuation((), target, unit, sigma_now, sigma_now, float(time_left), None, (note,),
                            tuple(model.effect_names), crit)
    new = fd.plan
    after = np.array([std(_concat(before, new.subset(np.arange(k + 1)))) for k in range(len(new))])
    stop = len(new)
    if target_sigma is not None:
        guarded = [p.effect for p in fd.protection if p.protected]
        for k in np.flatnonzero(after <= target_sigma):
            if not guarded or _still_protected(before, new.subset(np.arange(k + 1)), model, guarded, stand,
                                               tilt_known, values, sigma):
                stop = int(k) + 1
                break
    new, after = new.subset(np.arange(stop)), after[:stop]
    seen = set(before.position.tolist())
    out = []
    for k in range(len(new)):
        label = str(new.position[k])
        sv = label == SURVEYED
        out.append(NextRun(None if sv else label, label not in seen, sv, round(float(np.degrees(new.azimuth[k])) % 360.0, 6),
                           float(new.rate[k] / units.DEG_PER_S), float(new.duration[k]), float(new.t_start[k]),
                           float(after[k])))
        seen.add(label)
    field = bool(np.any(before.position != SURVEYED) or np.any(new.position != SURVEYED))
    # an unsurveyed position has no azimuth: its rows carry the heading to set (heading_deg)
    plan = Plan.from_columns({
        "run": new.run, "rate_dps": [r.rate_dps for r in out],
        "azimuth_deg": [r.azimuth_deg if r.surveyed else None for r in out],
        **({"heading_deg": [None if r.surveyed else r.azimuth_deg for r in out]} if field else {}),
        "t_start_s": [round(r.t_start_s, 3) for r in out], "duration_s": [r.duration_s for r in out],
        **({"position": [r.position or "stand" for r in out]} if field else {})},
        source="<sequential plan>", min_rate_dps=0.0, allow_small_azimuths=True)
    protection = fd.protection if stop == len(fd.plan) else _protection_of(
        before, new, model, fd, stand, tilt_known, values, sigma)
    return Continuation(tuple(out), target, unit, sigma_now, float(after[-1]), float(time_left), plan, (),
                        tuple(model.effect_names), fd.criterion, protection)


def _still_protected(before, new, model, effects, stand, tilt_known, values, sigma):
    """Whether the runs so far (heading sigmas ``sigma``, rad) and ``new`` keep power >= 0.8
    against every one of ``effects``."""
    from ..aliasing import POWER_LIMIT
    from .field_protection import field_powers

    s = np.concatenate([sigma, stand.sigma(new.duration)])
    return all(t.power >= POWER_LIMIT for t in field_powers(_concat(before, new), model, effects, stand,
                                                            tilt_known, values, s))


def _protection_of(before, new, model, fd, stand, tilt_known, values, sigma):
    """``fd.protection`` with the powers of a shortened plan (the protected ones still are)."""
    from dataclasses import replace

    from .field_protection import field_powers

    named = [p for p in fd.protection if p.power is not None]
    s = np.concatenate([sigma, stand.sigma(new.duration)])
    tests = field_powers(_concat(before, new), model, [p.effect for p in named], stand, tilt_known, values, s)
    power = {p.effect: t.power for p, t in zip(named, tests)}
    return tuple(replace(p, power=power[p.effect]) if p.effect in power else p for p in fd.protection)
