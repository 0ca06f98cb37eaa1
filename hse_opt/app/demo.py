"""The whole method on an embedded default: ``hse-opt demo`` and :func:`run_demo`.

A simulated calibration campaign whose true system holds one physical effect that the
paper's model lacks; the tools must find it.

The embedded default
--------------------
System
    The simulator's paper-like system (:meth:`hse_opt.sim.TruthConfig.default`: lambda2 =
    4.2 arcsec, the turntable base tilted by (-55, -120) arcsec, 7.9 arcsec heading noise in
    10 minutes) with its cold-start warm-up switched off, so that nothing but the hidden
    effect is missing from the paper's model, and a lab temperature cycle of 1.5 degC over
    4 h (air conditioning) on top of the IMU's self-heating.
Plan (:func:`demo_plan`)
    The paper's alignments (10 minutes at 20, 40 and 60 deg/s, one sense), extended so that
    the catalogue effects can be told apart: six stand azimuths 60 deg apart, every rate at
    each, from power-on; the second pass (reverse azimuth order) with the turntable base on
    a 0.5-deg tilt fixture, which makes the tilt-coupled effects (lambda2, axis bias,
    scale-factor nonlinearity) visible. 36 runs, one every 700 s.
Hidden effect (:func:`hidden_effect`)
    Drawn by the seed from the catalogue effects the simulator can switch on
    (:func:`hse_opt.validation.twins.effect_names`), with a random sign / phase (and, for the
    warm-up, a time constant of 10-30 minutes). Its size follows one rule for every effect:
    over the plan, the part of its heading signature that the paper's model cannot absorb
    has an RMS of :data:`HIDDEN_SIGMAS` noise sigmas (computed with the symbolic measurement
    model). Effects that need more than their parameter's physical bounds (``Param.lower``
    / ``upper``) to reach that size cannot be shown by this plan and are not drawn: the
    encoder's periodic error, as the sizing model ``hse + encoder_harmonic`` sees it (alone
    it averages out over a revolution; its 1st harmonic reaches heading only in a product
    with the horizontal misalignment of the processed rotation axis, of which this model
    knows only lambda2's part). It is not negligible: the demo system's own mount error
    (3, -2) arcsec and its axis calibration error, together xi = (5.0, -0.6) arcsec
    (``mount_xi``, :meth:`hse_opt.model.effects.MountXi.from_axis_error`), make 10 arcsec of
    encoder error move the simulated heading by up to 1.2 arcsec at 40 deg/s, where
    ``hse + encoder_harmonic`` predicts 0.26; ``hse + encoder_harmonic + mount_xi`` at that xi
    is within 0.05 arcsec of the simulator (what is left: the system's eps1..eps3 are not
    equal, and lambda2 spread equally leaks slightly differently; README, "The symbolic
    model"). ``mount_xi`` has no signature without the encoder, so it is not drawn either.

Steps (:func:`run_demo`): simulate the campaign with the numeric simulator, fit the paper's
model, diagnose, add the effect the diagnosis names and refit, design an optimised next
plan and compare its predicted sigmas with the paper's plan.
"""
from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from .. import units
from ..data import Plan, Runs, write_text_atomic
from ..fit import fit as fit_runs
from ..information import heading_sigma
from ..model.effects import effect as make_effect
from ..model.composition import Model
from ..model.inputs import Tilt
from ..validation.twins import effect_names, hideable, twin

__all__ = ["DemoResult", "HiddenEffect", "NextPlan", "run_demo", "demo_truth", "demo_plan",
           "hidden_effect", "hideable", "showable", "design_next", "report_sections", "write_outputs",
           "HIDDEN_SIGMAS", "OUTPUT_FILES"]

#: RMS, in noise sigmas, of the hidden effect's heading signature that the paper's model
#: cannot absorb (over the demo plan)
HIDDEN_SIGMAS = 2.0
_FIXTURE_TILT_ARCSEC = 1800.0          # 0.5 deg
_TIME_SLOTS = 4                         # time since power-on in four slots, for a warm-up
_CADENCE_S = 700.0                      # 10-minute alignment + 100 s to change the setting


def demo_plan():
    """The embedded demo plan (module docstring): 36 ten-minute runs from power-on.

    Returns
    -------
    hse_opt.data.Plan
    """
    azimuths = np.arange(0.0, 360.0, 60.0)
    rates = np.array([20.0, 40.0, 60.0])
    level = [(a, r, 0.0) for a in azimuths for r in rates]
    tilted = [(a, r, _FIXTURE_TILT_ARCSEC) for a in azimuths[::-1] for r in rates]
    rows = level + tilted
    n = len(rows)
    a, r, ty = (np.array(c) for c in zip(*rows))
    return Plan.from_columns({
        "run": np.arange(1, n + 1), "rate_dps": r, "azimuth_deg": a,
        "t_start_s": _CADENCE_S * np.arange(n), "duration_s": np.full(n, 600.0),
        "tilt_x_arcsec": np.zeros(n), "tilt_y_arcsec": ty}, source="demo plan")


def demo_truth():
    """The demo's system without a hidden effect (module docstring).

    Returns
    -------
    hse_opt.sim.TruthConfig
    """
    from ..sim import TruthConfig
    return TruthConfig.default().updated({
        "mount": {"warmup_xi_z_arcsec": 0.0},
        "gyro": {"bias_warmup_dph": [0.0, 0.0, 0.0]},
        "thermal": {"swing_c": 1.5, "swing_period_s": 4 * 3600.0},
    })


# -- the hidden effect -----------------------------------------------------------------------
@dataclass(frozen=True)
class HiddenEffect:
    """The effect put into the truth.

    Attributes
    ----------
    name : str
        Catalogue name.
    values : dict
        Model parameter -> value (display unit), the size the rule gives.
    units : dict
        Model parameter -> display unit.
    truth_changes : dict
        The TOML-shaped changes that put it into the simulator's system.
    """

    name: str
    values: dict
    units: dict
    truth_changes: dict

    def describe(self):
        vals = ", ".join(f"{k} = {v:.4g} {self.units[k]}" for k, v in self.values.items())
        return f"{self.name} ({vals})"


def _plan_inputs(mm, plan, truth):
    """The measurement model's run inputs for the plan on ``truth``'s stand (SI)."""
    from ..sim.truth import temperature
    mount = Tilt(*truth.stand.mount_tilt)  # the simulator's [x, y] = (roll, pitch)
    pitch, roll = mount.pitch + plan.tilt_y, mount.roll + plan.tilt_x
    temp = temperature(truth.thermal, plan.t_start + plan.duration / 2)
    return mm.inputs(plan.rate, plan.azimuth, truth.site.latitude, plan.duration, plan.t_start,
                     pitch, roll, {"temp_c": temp} if mm.covariates else None)


def _sizes(name, plan, truth, direction, fixed):
    """Scale of ``direction`` (display units, over the effect's linear parameters) that gives
    the rule's size, and that size in each parameter."""
    mm = Model(["hse", name]).measurement(tilt_known=True)
    X = _plan_inputs(mm, plan, truth)
    J = mm.jacobian(mm.vector(fixed), X) * mm.scale
    J = J / heading_sigma(plan.duration, truth.site.latitude)[:, None]
    base = [i for i, q in enumerate(mm.names) if q in ("offset", "lambda2")]
    lin = [mm.names.index(q) for q in direction]
    Q, _ = np.linalg.qr(J[:, base])
    R = J[:, lin] - Q @ (Q.T @ J[:, lin])               # what the paper's model cannot absorb
    rms = float(np.sqrt(np.mean((R @ np.array(list(direction.values()))) ** 2)))
    scale = HIDDEN_SIGMAS / rms if rms > 0 else np.inf
    values = {q: scale * d for q, d in direction.items()}
    fits = all(mm.params[mm.names.index(q)].lower <= v <= mm.params[mm.names.index(q)].upper
               for q, v in values.items())
    return values, fits, {q.name: q.unit for q in mm.params}


def _direction(name, rng):
    """A random direction in the effect's linear parameters, and its nonlinear ones."""
    eff = make_effect(name)
    params, nonlinear = eff.params, set(eff.nonlinear)
    fixed = {q.name: float(rng.uniform(600.0, 1800.0)) for q in params if q.name in nonlinear}
    linear = [q.name for q in params if q.name not in nonlinear]
    if len(linear) == 1:
        return {linear[0]: float(rng.choice([-1.0, 1.0]))}, fixed
    d = rng.normal(size=len(linear))
    return dict(zip(linear, d / np.linalg.norm(d))), fixed


def showable(plan=None, truth=None):
    """Catalogue effects the plan can show on ``truth`` at a physical size (module
    docstring); defaults :func:`demo_plan` and :func:`demo_truth`.

    Returns
    -------
    tuple of str
    """
    if plan is None and truth is None:
        return _default_showable(effect_names())
    plan = demo_plan() if plan is None else plan
    truth = demo_truth() if truth is None else truth
    rng = np.random.default_rng(0)
    out = []
    for name in hideable():
        direction, fixed = _direction(name, rng)
        if _sizes(name, plan, truth, direction, fixed)[1]:
            out.append(name)
    return tuple(out)


@lru_cache(maxsize=4)
def _default_showable(names):
    return showable(demo_plan(), demo_truth())


def hidden_effect(seed, plan=None, truth=None):
    """The effect the demo hides for ``seed`` (module docstring): drawn from
    :func:`showable`, sized by the rule.

    Parameters
    ----------
    seed : int
    plan : hse_opt.data.Plan, optional
        Default :func:`demo_plan`.
    truth : hse_opt.sim.TruthConfig, optional
        Default :func:`demo_truth`.

    Returns
    -------
    HiddenEffect
    """
    pool = showable(plan, truth)
    plan = demo_plan() if plan is None else plan
    truth = demo_truth() if truth is None else truth
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 7]))
    name = pool[int(rng.integers(len(pool)))]
    direction, fixed = _direction(name, rng)
    values, _, units_ = _sizes(name, plan, truth, direction, fixed)
    values = {**values, **fixed}
    return HiddenEffect(name, values, {k: units_[k] for k in values}, twin(name).truth_changes(values))


# -- the next plan ---------------------------------------------------------------------------
@dataclass(frozen=True)
class NextPlan:
    """The optimised next plan and the paper's plan, for the same model and test time.

    Attributes
    ----------
    design : hse_opt.design.DesignResult or None
        The default criterion (``protect:lambda2``: the paper's goal, sigma of lambda2, with
        every parameter identified and power against the effects outside the model) within
        the paper plan's test time, rates 20-60 deg/s
        in one sense (the paper's), the campaign's 0.5-deg tilt fixture allowed; None when
        the design failed (``notes`` gives the solver's status).
    level : hse_opt.design.DesignResult or None
        The same under the paper's own limits (no tilt fixture): how much of the gain the
        design makes without new hardware.
    baseline : hse_opt.design.Evaluation or None
        The paper's plan (:func:`hse_opt.design.paper_plan`) for the same model; None when
        it cannot identify the model (``notes`` says why).
    notes : tuple of str
    """

    design: object
    level: object
    baseline: object
    notes: tuple = ()

    @property
    def best(self):
        """The plan to run next: the tilt-fixture design, else the one under the paper's
        limits (None when both failed)."""
        return self.design if self.design is not None else self.level

    def gain(self, which="design"):
        """sigma(lambda2) of the paper's plan over that of ``design`` or ``level`` (None when
        either is missing)."""
        d = getattr(self, which)
        if self.baseline is None or d is None:
            return None
        return self.baseline.std_of("lambda2") / d.std_of("lambda2")

    def to_dict(self):
        def one(d, which):
            if d is None:
                return None
            return {"n_runs": d.n_runs, "total_time_h": d.total_time / units.HOUR,
                    "efficiency": float(d.efficiency), "sigma_lambda2_arcsec": d.std_of("lambda2"),
                    "gain": self.gain(which)}
        d = self.best
        return {"failed": d is None, "criterion": None if d is None else d.criterion,
                "effects": None if d is None else list(d.evaluation.effects),
                "tilt_fixture": one(d, "design"), "paper_limits": one(self.level, "level"),
                "paper_sigma_lambda2_arcsec": (None if self.baseline is None
                                               else self.baseline.std_of("lambda2")),
                "notes": list(self.notes)}


def _design(model, kw, notes, label):
    """``design(model, **kw)`` with the default criterion (``protect:lambda2``); an IPOPT
    refinement failure falls back to the rounded design, any other failure returns None; both
    are noted."""
    from ..design import DesignError, design
    from ..information import UnidentifiableError
    # LinAlgError: a solver's factorisation; UnidentifiableError: the candidates see a parameter
    # of the calibrated model nowhere (the encoder's 2nd harmonic)
    failures = (DesignError, UnidentifiableError, np.linalg.LinAlgError)
    try:
        return design(model, **kw)
    except failures as err:
        if "refinement" in str(err):
            notes.append(f"{label}: {err}; the rounded design on the candidate grid is used.")
            try:
                return design(model, refine=False, **kw)
            except failures as err2:
                err = err2
        notes.append(f"{label}: the design failed: {type(err).__name__}: {err}")
        return None


def design_next(model, values=None):
    """The optimised next plan for ``model`` (:class:`NextPlan`), with and without the tilt
    fixture, and the paper's plan for comparison.

    Parameters
    ----------
    model : hse_opt.model.Model
        The calibrated model (e.g. ``fit.model``).
    values : mapping name -> value (display units), optional
        Where to linearise (e.g. the fitted values); default the parameters' nominal values.

    Covariate effects are left out of the design model (a covariate is recorded, not
    planned). A model with a warm-up (an effect that changes with time since power-on) is
    designed over four time slots from power-on (no warm-up wait: the transient is
    calibrated while it lasts). When the IPOPT refinement fails the rounded design on the candidate grid is
    kept, and said; when a design fails it is None and the notes give the solver's status.
    """
    from ..design import Costs, DesignSpace, evaluate, paper_plan
    from ..information import UnidentifiableError

    effects = [e for e in model.effect_names if not e.startswith("covariate:")]
    notes = []
    if len(effects) < len(model.effect_names):
        notes.append("Covariate effects are recorded, not planned: the plan is designed for "
                     + " + ".join(effects) + ".")
    model = Model(effects)
    names = model.measurement(True).names
    nominal = {n: float(v) for n, v in (values or {}).items() if n in names}
    paper = paper_plan()
    kw = dict(budget=float(paper.t_start[-1] + paper.duration[-1]), nominal=nominal)
    # time since power-on is a factor of the plan when an effect changes with it, and then the
    # plan may start at power-on: a warm-up is calibrated while it lasts
    if any(e.level == "thermal" for e in model.effects):
        kw.update(costs=Costs(warmup=0.0))
        slots = _TIME_SLOTS
    else:
        slots = 1
    fixture = _design(model, {**kw, "space": DesignSpace(max_tilt=_FIXTURE_TILT_ARCSEC * units.ARCSEC,
                                                         time_slots=slots)}, notes, "with the tilt fixture")
    level = _design(model, {**kw, "space": DesignSpace(time_slots=slots)}, notes, "without the tilt fixture")
    try:
        baseline = evaluate(paper, model, nominal=nominal)
    except UnidentifiableError as err:
        baseline = None
        notes.append(f"The paper's plan cannot identify {' + '.join(effects)}: {err}")
    return NextPlan(fixture, level, baseline, tuple(notes))


# -- the chain -------------------------------------------------------------------------------
@dataclass(frozen=True)
class DemoResult:
    """Everything the demo did, for printing, JSON and the report.

    Attributes
    ----------
    seed : int
    hidden : HiddenEffect
    truth : hse_opt.sim.TruthConfig
        The simulated system, hidden effect included.
    plan : hse_opt.data.Plan
    runs : hse_opt.data.Runs
        The simulated campaign.
    noise_arcsec : float
        The runs' median own heading sigma (the noise level), arcsec.
    fit_before, fit_after : hse_opt.fit.FitResult
        The paper's model; the model with the named effect added.
    named : str or None
        The effect the diagnosis named (None when it found the paper's model adequate).
    diagnosis, diagnosis_after : hse_opt.diagnose.Diagnosis
        Of the paper's model; of the model with the named effect (None without one).
    next_plan : NextPlan
        The optimised next plan and the paper's plan, evaluated for the final model.
    paper : hse_opt.model.paper.PaperNumbers
        The paper's own numbers reproduced with the symbolic model.
    seconds : dict
        Wall time of each step.
    session : tuple of str
        The live session (:func:`live_session`): the line ``hse-opt calibrate --watch`` prints
        after each log.
    """

    seed: int
    hidden: HiddenEffect
    truth: object
    plan: Plan
    runs: Runs
    noise_arcsec: float
    fit_before: object
    fit_after: object
    named: str | None
    diagnosis: object = None
    diagnosis_after: object = None
    next_plan: object = None
    paper: object = None
    seconds: dict = field(default_factory=dict)
    session: tuple = ()

    @property
    def found(self):
        """Whether the diagnosis named the hidden effect."""
        return self.named == self.hidden.name

    def to_dict(self):
        """The JSON form (``hse-opt demo --json``)."""
        fb, fa = self.fit_before, self.fit_after
        out = {
            "seed": self.seed,
            "hidden_effect": self.hidden.name,
            "hidden_values": self.hidden.values,
            "hidden_units": self.hidden.units,
            "hidden_sigmas": HIDDEN_SIGMAS,
            "n_runs": len(self.runs),
            "noise_arcsec": self.noise_arcsec,
            "named_effect": self.named,
            "found": self.found,
            "before": {"effects": list(fb.model.effect_names), "rms_arcsec": fb.rms_arcsec,
                       "chi2_red": fb.chi2_red, "bic": fb.bic},
            "after": None if fa is None else {
                "effects": list(fa.model.effect_names), "rms_arcsec": fa.rms_arcsec,
                "chi2_red": fa.chi2_red, "bic": fa.bic,
                "parameters": fa.to_dict()["parameters"]},
            "diagnosis": {"verdict": self.diagnosis.verdict,
                          "candidates": [{k: c[k] for k in ("effect", "p_value", "delta_bic",
                                                             "rms_after_arcsec")}
                                         for c in self.diagnosis.to_dict()["candidates"][:3]],
                          "ambiguous": list(self.diagnosis.ambiguous)},
            "verdict_after": None if self.diagnosis_after is None else self.diagnosis_after.verdict,
            "next_plan": None if self.next_plan is None else self.next_plan.to_dict(),
            "paper": None if self.paper is None else dataclasses.asdict(self.paper),
            "seconds": self.seconds,
            "session": list(self.session),
        }
        return out


def run_demo(seed=0, progress=None):
    """Run the demo chain (module docstring).

    Parameters
    ----------
    seed : int
        Picks the hidden effect and seeds the simulated noise.
    progress : callable, optional
        ``progress(step, done, total)`` as the simulation advances (``step`` a short name);
        the later steps report ``(step, 0, 1)`` as they start.

    Returns
    -------
    DemoResult
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed = {seed!r} is not allowed: an integer >= 0 is required")
    from ..diagnose import diagnose
    from ..sim import run_campaign
    seconds = {}
    t0 = time.perf_counter()
    plan = demo_plan()
    hidden = hidden_effect(seed)
    truth = demo_truth().updated(hidden.truth_changes)
    seconds["setup"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    cb = None if progress is None else (lambda done, total: progress("simulate", done, total))
    runs = run_campaign(plan, truth, int(seed), progress=cb).replace(
        source=f"demo campaign (seed {seed})")
    seconds["simulate"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    before = fit_runs(runs, "hse")
    seconds["fit"] = time.perf_counter() - t0

    def starting(step):  # a step without sub-steps shows as one item, done when the next starts
        if progress is not None:
            progress(step, 0, 1)

    t0 = time.perf_counter()
    starting("diagnose and refit")
    diagnosis = diagnose(runs, before)
    named = None if diagnosis.best is None else diagnosis.best.effect
    after_diagnosis = None if named is None else diagnosis.add(named)
    after = None if after_diagnosis is None else after_diagnosis.fit
    seconds["diagnose"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    starting("design the next plan")
    final = after if after is not None else before
    next_plan = design_next(final.model, dict(zip(final.names, final.values)))
    seconds["design"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    starting("live session")
    session = live_session(truth, int(seed))
    seconds["session"] = time.perf_counter() - t0

    from ..model.paper import reproduce
    noise = float(np.median(runs.heading_std) / units.ARCSEC)
    return DemoResult(seed=int(seed), hidden=hidden, truth=truth, plan=plan, runs=runs,
                      noise_arcsec=noise, fit_before=before, fit_after=after, named=named,
                      diagnosis=diagnosis, diagnosis_after=after_diagnosis, next_plan=next_plan,
                      paper=reproduce(), seconds=seconds, session=session)


#: the live session: the first alignments (position, heading deg, rate deg/s), then the
#: ones the session asks for, two-minute logs
SESSION_START = (("A", 20.0, 20.0), ("A", 20.0, 60.0))
SESSION_LOGS = 7
SESSION_DURATION_S = 120.0
#: the stand time the session is told each log left takes: the log and a move (a position
#: change takes 600 s by default), so it plans for the logs it will run, not for hours
SESSION_SLOT_S = SESSION_DURATION_S + 600.0


def live_session(truth, seed, n_logs=SESSION_LOGS):
    """The field session run by run, as ``hse-opt calibrate --watch`` shows it
    (:mod:`hse_opt.app.session`), on a field campaign of ``truth`` steered by the session: the
    first alignments are :data:`SESSION_START` (position A, no heading reference); after each
    log the session gives the next alignment (a position or a new heading, rate, sense) and
    the simulator runs exactly that one, until ``n_logs`` two-minute raw logs (simulated into
    a temporary folder, aligned with the system's lab calibration).

    Returns
    -------
    tuple of str
        The line after each log (:meth:`hse_opt.app.session.SessionResult.line`).
    """
    import tempfile

    from ..sim import run_campaign
    from ..sim.campaign import align_config_from_truth
    from .session import calibrate

    config = align_config_from_truth(truth)
    headings = {}
    todo = list(SESSION_START)
    lines, cache, logs, t = [], {}, [], 3600.0
    with tempfile.TemporaryDirectory(prefix="hse_opt_session_") as folder:
        for k in range(1, n_logs + 1):
            label, heading, rate = todo.pop(0)
            heading = headings.setdefault(label, heading)
            plan = Plan.from_columns({"run": [k], "rate_dps": [rate], "azimuth_deg": [heading], "t_start_s": [t],
                                      "duration_s": [SESSION_DURATION_S], "position": [label]},
                                     source="demo live session")
            run_campaign(plan, truth, int(seed) + k, field=True, raw_logs=folder)
            logs.append(os.path.join(folder, f"run_{k}.npz"))
            result = calibrate(logs, config=config, cache=cache, time_left_h=(n_logs - k) * SESSION_SLOT_S / 3600.0)
            lines.append(result.line())
            nxt = None if result.continuation is None else result.continuation.next
            if nxt is None:
                break
            t = max(nxt.t_start_s, t + SESSION_DURATION_S)
            if not todo:  # the session's advice, run as given
                todo.append((nxt.position, nxt.azimuth_deg, nxt.rate_dps))
    return tuple(lines)


# -- outputs ---------------------------------------------------------------------------------
#: files :func:`write_outputs` writes into the output directory
OUTPUT_FILES = ("report.html", "summary.json", "RUNS.csv", "PLAN.csv", "TRUTH.toml", "NEXT_PLAN.csv")


def report_sections(result):
    """The report of a demo run, as :class:`hse_opt.report.Section` objects."""
    from .. import report
    r = result
    sections = [
        report.plan_section(r.plan, "The simulated campaign",
                            f"{len(r.plan)} ten-minute alignments of the paper-like system from "
                            "power-on (module hse_opt.demo). The truth hides "
                            f"{r.hidden.describe()}, sized so that what the paper's model "
                            f"cannot absorb has an RMS of {HIDDEN_SIGMAS:g} noise sigmas."),
        report.fit_section(r.fit_before, r.runs, "The paper's model"),
    ]
    from ..diagnose import compare
    sections.append(report.diagnosis_section(r.diagnosis, "Diagnosis of the paper's model",
                                             residuals=False))  # the fit's section shows them
    if r.fit_after is not None:
        sections += [report.comparison_section(compare(r.diagnosis, r.diagnosis_after),
                                               title=f"Adding {r.named}: before and after"),
                     report.fit_section(r.fit_after, r.runs, f"The model with {r.named}")]
    n = r.next_plan
    if n.best is not None:
        label = ("The optimised plan with the 0.5-deg tilt fixture" if n.best is n.design
                 else "The optimised plan (the paper's limits, no fixture)")
        sections.append(report.design_section(n.best, n.baseline, "The next plan",
                                              " ".join(n.notes) or None, label=label))
    else:
        sections.append(report.text_section("The next plan", n.notes))
    if r.session:
        sections.append(report.text_section(
            "The live session (hse-opt calibrate --watch)",
            [f"A short field campaign of the same system ({len(r.session)} two-minute alignments, no heading "
             "reference), steered by the session: two alignments at position A, then each the one the "
             "session asked for. After each log: lambda2 so far with its total uncertainty, the verdict "
             "and the next alignment to run."]
            + list(r.session)))
    return sections


def summary_text(result):
    """Short lines for the top of the report."""
    r = result
    fb, fa = r.fit_before, r.fit_after
    lines = [f"Hidden in the truth: {r.hidden.describe()}.",
             f"The paper's model leaves an RMS of {fb.rms_arcsec:.1f} arcsec against a noise of "
             f"{r.noise_arcsec:.1f} arcsec (reduced chi-square {fb.chi2_red:.2f})."]
    if r.named is not None:
        lines.append(f"The diagnosis names {r.named}"
                     + (" - the hidden effect." if r.found else f", not the hidden {r.hidden.name}."))
    if fa is not None:
        lines.append(f"With it the RMS falls to {fa.rms_arcsec:.1f} arcsec (reduced chi-square "
                     f"{fa.chi2_red:.2f}); verdict {r.diagnosis_after.verdict}.")
    lines.append(next_plan_text(r.next_plan))
    return lines


def next_plan_text(next_plan):
    """The next plan's gain over the paper's plan, in words."""
    n = next_plan
    d = n.best
    if d is None:
        return "; ".join(n.notes)
    which = "with the 0.5-deg tilt fixture" if d is n.design else "under the paper's own limits (no fixture)"
    text = (f"The optimised next plan ({d.n_runs} alignments in the paper plan's "
            f"{d.total_time / units.HOUR:.2f} h, {which}) gives sigma(lambda2) = {d.std_of('lambda2'):.3g} arcsec")
    if n.baseline is None:
        return text + f"; the paper's plan cannot identify {' + '.join(d.evaluation.effects)}."
    text += (f" against {n.baseline.std_of('lambda2'):.3g} arcsec with the paper's plan: "
             f"{n.gain('design' if d is n.design else 'level'):.1f} times smaller")
    if d is n.design and n.level is not None:
        text += (f"; under the paper's own limits (no fixture) {n.level.std_of('lambda2'):.3g} "
                 f"arcsec, {n.gain('level'):.1f} times smaller")
    if n.design is None:
        text += "; the design with the tilt fixture failed: " + "; ".join(n.notes)
    return text + "."


def write_outputs(result, directory, shown=None):
    """Write the report and the data of a demo run into ``directory`` (created when missing;
    each file whole or not at all): :data:`OUTPUT_FILES` (``NEXT_PLAN.csv``, the
    :attr:`NextPlan.best` plan, only when a design succeeded). ``shown``: the folder's name in
    ``summary.json`` when ``directory`` is a temporary folder renamed to it afterwards.

    Returns
    -------
    dict
        The JSON summary (also ``summary.json``), with ``report`` the report's path.
    """
    import json
    from .. import report
    from ..data import save_plan, save_runs

    directory = Path(directory)
    report.write_report(directory, report_sections(result), f"hse-opt demo, seed {result.seed}",
                        summary_text(result))
    save_runs(result.runs, directory / "RUNS.csv")
    save_plan(result.plan, directory / "PLAN.csv")
    if result.next_plan.best is not None:
        save_plan(result.next_plan.best.plan, directory / "NEXT_PLAN.csv")
    write_text_atomic(directory / "TRUTH.toml", result.truth.to_toml())
    data = {**result.to_dict(), "report": str(Path(directory if shown is None else shown) / report.REPORT_NAME)}
    write_text_atomic(directory / "summary.json", json.dumps(data, indent=2, allow_nan=False) + "\n")
    return data
