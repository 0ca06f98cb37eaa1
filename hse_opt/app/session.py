"""The field session in one call: raw logs in; calibration, evidence, C and the next plan out.

:func:`calibrate` (``hse-opt calibrate LOGS/ --out DIR``) chains what the single commands do:

1. **Align** every raw log (:func:`hse_opt.align.batch.align_logs`, in parallel; a bad log
   is reported and left out, the others go on) into one RUNS table.
2. **Recognise the campaign** from what the logs carry: ``surveyed`` when every log has a
   stand reading (``azimuth_deg`` in its metadata), ``field`` when none has (each position's
   true heading unknown: only differences within a position count), ``mixed`` otherwise.
3. **Fit and diagnose**: the paper's model plus ``effects``, then
   :func:`hse_opt.diagnose.refine` (add the best significant catalogue effect and diagnose
   again, until adequate). The final model is the last step's.
4. **Export** the final calibration for the navigation computer
   (:func:`hse_opt.fit.export.export_calibration`) with test vectors and a C test driver
   (:mod:`hse_opt.fit.export_vectors`).
5. **Plan the rest** of the campaign for the time left, continuing it
   (:func:`hse_opt.design.sequential.next_runs`: the runs so far, their measured tilts and
   times since power-on, the fit's estimate and weights; the smallest sigma of lambda2 with
   power >= 0.8 of the diagnosis against each effect outside the model the time left can
   show, those at systematic risk (step 6) among them, as ``hse-opt design --field --runs``
   plans it): ``runs[0]`` is the next alignment.
6. **Systematic risk**: what the campaign cannot rule out (:func:`hse_opt.aliasing.alias_budget`):
   each missing catalogue effect at the edge of its plausible range, its power under the
   diagnosis's own test and the shift it would cause in every parameter; a parameter's
   ``systematic`` is the largest shift of an effect the runs would not detect that exceeds its
   statistical sigma. lambda2's total uncertainty is the two in quadrature.
7. **Verdict**: ``usable`` when the final model is fitted, the diagnosis finds it adequate, no
   calibrated parameter (those the exported C compensates) carries a systematic risk, the
   correction is known better than its own size (at the calibration runs, the RMS of its
   1-sigma below the RMS of the correction: else compensating could add as much error as it
   removes), and (with ``target_sigma``) the total sigma of lambda2 is at most the target;
   else ``not yet`` with every reason in words.

:func:`write_outputs` writes the report and the data into a folder (:data:`OUTPUT_FILES`);
:func:`watch` is the live session (``--watch``): it waits for new logs in a folder and yields
a new :class:`SessionResult` after each.

Watching: when a log is read
----------------------------
A file in the folder is a raw log when its name ends in ``.npz`` or ``.csv`` and does not start
with ``.`` (temporary files of writers that write then rename, this tool's included). It is
read once its size and modification time (and those of its ``.json`` sidecar, when there is
one) are unchanged over one poll interval (``poll`` s, default :data:`POLL_S`) - a log still
being written grows between polls and is not read half. A log whose file (or sidecar) changes
afterwards is read again; a bad log stays in the report's list of bad logs until its file
changes. Writers that create the file under a temporary name and rename it when complete
(the safe way) are read at the first poll after the rename plus one interval.
"""
from __future__ import annotations

import json
import os
import re
import time
from dataclasses import dataclass, field

import numpy as np

from .. import units
from ..data import write_text_atomic

__all__ = ["SessionResult", "calibrate", "write_outputs", "summary", "watch", "log_signature", "OUTPUT_FILES",
           "POLL_S", "TARGET", "DEFAULT_TIME_LEFT_H", "NoRunsError"]

#: what :func:`write_outputs` writes into the output folder (``nav/`` a folder)
OUTPUT_FILES = ("report.html", "summary.json", "RUNS.csv", "FIT.json", "NEXT_PLAN.csv", "nav/")
#: poll interval of :func:`watch`, s
POLL_S = 0.5
#: the parameter the verdict's target and the next plan's criterion are about
TARGET = "lambda2"
#: stand time left for the rest of the campaign when not given, h
DEFAULT_TIME_LEFT_H = 4.0
_SUFFIXES = (".npz", ".csv")


class NoRunsError(ValueError):
    """No log could be aligned (each bad log is named in the message's first example)."""


@dataclass(frozen=True, eq=False)
class SessionResult:
    """What one pass of the session found (module docstring).

    Attributes
    ----------
    logs : tuple of str
        Every raw log considered, in order.
    rows : tuple of dict
        One aligned RUNS row per good log (:func:`hse_opt.align.batch.align_logs`).
    errors : tuple of str
        One line per bad log (the file named), left out.
    runs : hse_opt.data.Runs or None
        The aligned runs (None when no log could be aligned).
    campaign : str
        ``surveyed``, ``field`` or ``mixed`` (``none`` without runs).
    steps : tuple of hse_opt.diagnose.Diagnosis
        The refinement: the first diagnosis, then one per added effect (empty when no fit).
    failure : str or None
        Why no model could be fitted (e.g. too few runs), else None.
    continuation : hse_opt.design.sequential.Continuation or None
        The rest of the campaign for the time left; ``continuation.next`` the next alignment.
    verdict : str
        ``usable`` or ``not yet``.
    reasons : tuple of str
        Why not yet (empty when usable).
    target_sigma : float or None
        The target for lambda2's total sigma, arcsec.
    time_left : float
        Stand time left, s.
    notes : tuple of str
    seconds : dict
        Wall time of each step, s.
    budget : hse_opt.aliasing.AliasBudget or None
        What the campaign cannot rule out: each missing catalogue effect's detectability and
        the shift it would cause in every parameter (None without a fit).
    """

    logs: tuple
    rows: tuple
    errors: tuple
    runs: object
    campaign: str
    steps: tuple
    failure: str | None
    continuation: object
    verdict: str
    reasons: tuple
    target_sigma: float | None
    time_left: float
    notes: tuple = ()
    seconds: dict = field(default_factory=dict)
    budget: object = None

    @property
    def fit(self):
        """The final model's fit (None when none could be fitted)."""
        return self.steps[-1].fit if self.steps else None

    @property
    def diagnosis(self):
        """The final diagnosis (None without a fit)."""
        return self.steps[-1] if self.steps else None

    def parameters(self):
        """The final model's parameters as in ``fit --json`` (name -> value, std, unit, ...,
        ``systematic``: the largest shift an effect the campaign cannot rule out would cause,
        None where the fit does not give one; ``total``: std and systematic in quadrature)."""
        if self.fit is None:
            return {}
        out = {}
        b = self.budget
        for name, d in self.fit.to_dict()["parameters"].items():
            d = dict(d)
            if "systematic" not in d and b is not None and name in b.names:
                i = b.names.index(name)
                d["systematic"] = float(b.systematic[i])
                d["systematic_by"] = {e: float(v) for e, v in b.systematic_by[i].items()}
            d.setdefault("systematic", None)
            std, sys_ = d.get("std"), d.get("systematic")
            d["total"] = None if std is None else float(np.hypot(std, sys_ or 0.0))
            out[name] = d
        return out

    def target(self):
        """``(value, std, systematic, total, unit)`` of lambda2 (None entries where unknown)."""
        d = self.parameters().get(TARGET)
        if d is None:
            return None, None, None, None, "arcsec"
        return d["value"], d["std"], d["systematic"], d["total"], d["unit"]

    def line(self):
        """One line: the calibration so far with its total uncertainty, the verdict, the next
        alignment (what ``--watch`` prints after each log)."""
        n = 0 if self.runs is None else len(self.runs)
        value, _, _, total, unit = self.target()
        cal = (f"{TARGET} = {value:.3g} +- {total:.2g} {unit}" if value is not None and total is not None
               else f"{TARGET} not yet estimable")
        why = f" ({self.reasons[0].split(':')[0]})" if self.reasons else ""
        nxt = self.continuation.next if self.continuation is not None else None
        step = f"; next: {nxt.describe()}" if nxt is not None else "; next: nothing fits the time left"
        return f"[{n} run{'s' if n != 1 else ''}] {cal}; {self.verdict}{why}{step}"

    def to_dict(self):
        """The JSON summary (``summary.json``, ``--json``)."""
        value, std, sys_, total, unit = self.target()
        d = self.diagnosis
        return {
            "verdict": self.verdict,
            "reasons": list(self.reasons),
            "campaign": self.campaign,
            "n_logs": len(self.logs),
            "n_runs": 0 if self.runs is None else len(self.runs),
            "bad_logs": list(self.errors),
            "effects": [] if self.fit is None else list(self.fit.model.effect_names),
            "parameters": self.parameters(),
            "target": {"name": TARGET, "value": value, "std": std, "systematic": sys_, "total": total,
                       "unit": unit, "target_sigma": self.target_sigma},
            "diagnosis": None if d is None else {
                "verdict": d.verdict, "lack_of_fit_p": d.lack_of_fit_p, "chi2_red": float(d.chi2_red),
                "rms_arcsec": d.rms_arcsec, "ambiguous": list(d.ambiguous),
                "added": [e for e in d.effects if e not in self.steps[0].effects]},
            "failure": self.failure,
            "next": None if self.continuation is None else self.continuation.to_dict(),
            "time_left_h": self.time_left / units.HOUR,
            "notes": list(self.notes),
            "seconds": self.seconds,
        }


def natural_key(name):
    """Sort key of a name with its digit runs as numbers: ``run_2`` before ``run_10``."""
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", os.fspath(name))]


def log_paths(items, suffixes=_SUFFIXES):
    """Raw-log files: files as given, a folder -> its raw logs (entries whose names end in
    ``suffixes`` and do not start with ``.``), sorted by name. An entry that is not a regular
    file (a folder, a FIFO) is kept: the loader refuses it by its kind, naming it, without
    opening it (a FIFO would block), so it is never passed over in silence. ValueError naming
    a missing item or a folder without raw logs (``hse-opt align`` and ``calibrate``). Names sort
    naturally (:func:`natural_key`: run_2 before run_10)."""
    suffixes = tuple(suffixes)
    paths = []
    for item in items:
        item = os.fspath(item)
        if os.path.isdir(item):
            found = sorted((os.path.join(item, f) for f in os.listdir(item)
                            if f.endswith(suffixes) and not f.startswith(".")), key=natural_key)
            if not found:
                raise ValueError(f"{item}: no raw logs ({', '.join(suffixes)}) in the directory; allowed: a "
                                 f"directory of raw logs ({', '.join(suffixes)})")
            paths += found
        elif not os.path.exists(item):
            raise ValueError(f"{item}: no such file or directory; allowed: raw-log files or directories")
        else:
            paths.append(item)
    return paths


def log_signature(path):
    """``(size, mtime_ns)`` of a log and of its ``.json`` sidecar (None when absent): a log is
    read when this is unchanged over one poll interval (module docstring)."""
    st = os.stat(path)
    try:
        sc = os.stat(path + ".json")
        side = (sc.st_size, sc.st_mtime_ns)
    except OSError:
        side = None
    return st.st_size, st.st_mtime_ns, side


def _campaign(runs):
    if runs is None:
        return "none"
    if runs.surveyed is None:
        return "surveyed"
    return "field" if not runs.surveyed.any() else "mixed"


def _align(paths, config, jobs, progress, cache, align_kw, client):
    """Aligned rows and errors for ``paths``, reusing ``cache`` (path -> (signature, row,
    error)) for logs whose signature is unchanged - unless the filter is tuned from the logs'
    pooled noise (``tune_from_data``): every log's tuning then depends on all of them, and all
    are aligned again."""
    from ..align.batch import align_logs
    if align_kw.get("tune_from_data") and cache is not None:
        cache.clear()     # each log's tuning depends on all of them: all are aligned again
    todo, sigs = [], {}
    for p in paths:
        try:
            sigs[p] = log_signature(p)
        except OSError:
            sigs[p] = None
        if cache is None or p not in cache or cache[p][0] != sigs[p]:
            todo.append(p)
    if todo:
        rows, errors = align_logs(todo, config, jobs=jobs, progress=progress, client=client, **align_kw)
        got = {r["log"]: r for r in rows}
        bad = iter(errors)
        results = {}
        for p in todo:
            results[p] = (got[p], None) if p in got else (None, next(bad))
    else:
        results = {}
    rows, errors = [], []
    for p in paths:
        row, err = results[p] if p in results else cache[p][1:]
        if cache is not None:
            cache[p] = (sigs[p], row, err)
        (rows.append(row) if row is not None else errors.append(err))
    return rows, errors


def calibrate(logs, *, config=None, align_kw=None, suffixes=_SUFFIXES, effects=(), time_left_h=DEFAULT_TIME_LEFT_H,
              jobs=1, client=None, target_sigma=None, progress=None, cache=None, costs=None, notes=()):
    """The session on raw logs (module docstring).

    Parameters
    ----------
    logs : sequence of str or os.PathLike
        Raw-log files and folders of them (:mod:`hse_opt.align.rawlog` formats).
    config : hse_opt.align.AlignConfig, optional
        The alignment processor: the system's lab calibration and noise (default, as
        ``hse-opt align``: the orthogonal system with the paper's ideal mount, the filter tuned
        from the logs' own noise, each log's own latitude).
    align_kw : dict, optional
        More arguments of :func:`hse_opt.align.batch.align_logs` (``mapping``,
        ``tune_from_data``, ``pulse_weights``; ``hse-opt align``'s options give them).
    suffixes : tuple of str
        The file names a folder's raw logs end with.
    effects : sequence of str
        Effects to model besides the paper's ``hse`` from the start (the diagnosis may add more).
    time_left_h : float
        Stand time left for the rest of the campaign after the last log, h.
    jobs : int
        Local worker processes for the alignment.
    client : dask.distributed.Client, optional
        Align on this Dask cluster instead (the same rows as ``jobs=1``).
    target_sigma : float, optional
        Target total sigma of lambda2, arcsec: the verdict is ``not yet`` above it, and the
        plan of the rest stops once it is predicted.
    progress : callable, optional
        ``progress(step, done, total)``: ``step`` a short name ("align", "fit and diagnose",
        "systematic risk", "plan"); steps without sub-steps report ``(step, 0, 1)`` as they start.
    cache : dict, optional
        Aligned logs by path, reused while a log's file is unchanged (and filled): what
        :func:`watch` passes so that each update aligns only the new logs.
    costs : hse_opt.design.Costs, optional
        Setup times for the plan of the rest.
    notes : sequence of str
        Notes on the processor (e.g. what it assumed without a lab calibration): first in the
        result's notes (the report, ``summary.json``).

    Returns
    -------
    SessionResult

    Raises
    ------
    ValueError
        No raw log given or found, none could be aligned (each bad log named), or bad
        arguments (named).
    """
    from ..data import DataError
    from ..diagnose import refine
    from ..information import UnidentifiableError
    from ..model import as_model
    from ..align.batch import runs_from_rows

    if not np.isfinite(time_left_h) or time_left_h < 0:
        raise ValueError(f"--time-left-h {time_left_h:g}: allowed: hours >= 0")
    if target_sigma is not None and not (np.isfinite(target_sigma) and target_sigma > 0):
        raise ValueError(f"--target-sigma {target_sigma:g}: allowed: arcsec > 0")
    model = as_model(["hse", *[e for e in effects if e != "hse"]])
    if config is None:
        from ..align import LabCalibration
        config = LabCalibration.orthogonal().align_config()
        align_kw = {"tune_from_data": True, **(align_kw or {})}
    align_kw = dict(align_kw or {})

    def step(name):
        if progress is not None:
            progress(name, 0, 1)

    seconds = {}
    t0 = time.perf_counter()
    paths = log_paths(logs, suffixes)
    if not paths:
        raise ValueError(f"{', '.join(map(os.fspath, logs))}: no raw logs (.npz, .csv); allowed: raw-log files "
                         "or folders of them")
    cb = None if progress is None else (lambda done, total: progress("align", done, total))
    rows, errors = _align(paths, config, jobs, cb, cache, align_kw, client)
    seconds["align"] = time.perf_counter() - t0
    if not rows:
        raise NoRunsError(f"none of the {len(paths)} logs could be aligned (first: {errors[0]})")
    runs, found = runs_from_rows(rows)
    from ..align.batch import NOISE_SOURCE_COLUMN
    notes = [*notes, f"the filter's noise: {rows[0][NOISE_SOURCE_COLUMN]} (data: measured from the logs; file: the "
             "calibration file; truth: TRUTH.toml)", *found]
    time_left = float(time_left_h) * units.HOUR

    t0 = time.perf_counter()
    step("fit and diagnose")
    steps, failure = (), None
    try:
        steps = tuple(refine(runs, model))
    except (UnidentifiableError, DataError, ValueError) as err:   # runs that cannot identify the model yet
        failure = " ".join(str(err).split())
    seconds["fit and diagnose"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    step("systematic risk")
    budget = None
    if steps:   # the diagnosis's own (its test and level), else computed here
        budget = getattr(steps[-1], "budget", None)
        if budget is None:
            from ..aliasing import alias_budget
            budget = alias_budget(steps[-1].fit, runs, tests=steps[-1].n_tests)
    seconds["systematic risk"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    step("plan")
    continuation = _plan(runs, steps, model, time_left, target_sigma, costs, notes)
    seconds["plan"] = time.perf_counter() - t0

    result = SessionResult(tuple(paths), tuple(rows), tuple(errors), runs, _campaign(runs), steps, failure,
                           continuation, "not yet", (), target_sigma, time_left, tuple(notes), seconds, budget)
    reasons = _reasons(result)
    return SessionResult(**{**result.__dict__, "verdict": "not yet" if reasons else "usable",
                            "reasons": tuple(reasons)})


def _plan(runs, steps, model, time_left, target_sigma, costs, notes):
    """The rest of the campaign (:func:`hse_opt.design.sequential.next_runs`, the protected
    continuation ``hse-opt design --field --runs`` plans too) for the final model at its
    estimate (the nominal values without a fit), the runs so far weighted as the fit weighs
    them: the smallest sigma of lambda2 with power >= 0.8 of the diagnosis against each effect
    outside the model that the time left can show - among them those a systematic risk to
    lambda2 now, so the plan takes the runs that would detect them (or names why none can).
    (Estimating the risks too, the old criterion, made the session chase a model that changed
    with every log: the demo's live session then never moved on, its sigma stayed 34 arcsec.)"""
    from ..design.sequential import next_runs
    from ..information import UnidentifiableError
    kw = dict(costs=costs, target_sigma=target_sigma)
    if steps:
        f = steps[-1].fit
        model = f.model
        kw.update(values=dict(zip(f.names, f.values)), tilt_known=f.tilt_known, sigma=f.sigma)
    try:
        return next_runs(runs, model, time_left, **kw)
    except (ValueError, UnidentifiableError, np.linalg.LinAlgError) as err:
        notes.append(f"the rest of the campaign could not be planned: {' '.join(str(err).split())}")
        return None


def _reasons(result):
    """Why the calibration is not usable yet, in words (empty when it is)."""
    r = result
    out = []
    if r.fit is None:
        out.append(f"no calibration yet: {r.failure}")
        return out
    d = r.diagnosis
    if d.verdict == "missing-effect":
        best = d.best.effect if d.best is not None else "?"
        if len(d.ambiguous) > 1:
            out.append(f"the runs show an effect the model lacks but cannot tell {', '.join(d.ambiguous)} apart: "
                       "run the next plan")
        else:
            out.append(f"the runs show an effect the model lacks ({best}) that the refinement did not add")
    elif d.verdict == "inconclusive":
        out.append("the diagnosis is inconclusive: the model fits, but effects this campaign cannot detect "
                   "could move a calibrated parameter by more than its sigma")
    elif d.verdict != "adequate":
        out.append(f"the diagnosis says '{d.verdict}': the residuals follow a pattern no catalogue effect "
                   "explains (see the evidence)")
    if r.budget is not None:
        from ..fit.correction import compensated_parameters
        calibrated = set(compensated_parameters(r.fit))
        values = r.fit.values
        for line, name in zip(r.budget.sentences(values), [n for n, by in zip(r.budget.names, r.budget.systematic_by)
                                                           if by]):
            if name in calibrated:
                out.append(f"systematic risk (what this campaign cannot rule out): {line}")
    from ..fit.correction import compensation_at
    correction, sigma = compensation_at(r.fit.inputs, r.fit)
    rms_c, rms_s = (float(np.sqrt(np.mean(np.square(v)))) / units.ARCSEC for v in (correction, sigma))
    if not rms_s < rms_c:
        out.append(f"the correction is not yet known better than its own size: at the calibration runs it is "
                   f"{rms_c:.3g} arcsec RMS with a 1-sigma of {rms_s:.3g} arcsec RMS (compensating could add as "
                   "much error as it removes)")
    value, std, sys_, total, unit = r.target()
    if value is None or total is None or not np.isfinite(total):
        out.append(f"{TARGET} is not estimated by these runs")
    elif r.target_sigma is not None and total > r.target_sigma:
        out.append(f"sigma({TARGET}) = {total:.3g} {unit} is above the target {r.target_sigma:g} {unit}")
    return out


# -- outputs ---------------------------------------------------------------------------------
def summary(result, shown):
    """The JSON summary (``summary.json``, ``--json``): :meth:`SessionResult.to_dict` with the
    output folder ``shown`` and its report's path."""
    from ..report import REPORT_NAME
    return {**result.to_dict(), "report": os.path.join(os.fspath(shown), REPORT_NAME), "out": os.fspath(shown)}


def write_outputs(result, directory, shown=None):
    """Write the session's report and data into ``directory`` (existing): :data:`OUTPUT_FILES`
    (``FIT.json`` and ``nav/`` only with a fit, ``NEXT_PLAN.csv`` only with a plan; each file
    whole or not at all). ``shown``: the folder's name for the messages, when ``directory`` is a
    temporary folder renamed to it afterwards.

    Returns
    -------
    dict
        The JSON summary (also ``summary.json``).
    """
    from .. import report
    from ..data import save_plan, save_runs
    from ..fit.export import export_calibration
    from ..fit.file import save_fit
    from ..fit.export_vectors import write_test_vectors
    from ..report.session import session_sections, summary_lines

    directory = os.fspath(directory)
    shown = directory if shown is None else os.fspath(shown)
    r = result
    save_runs(r.runs, os.path.join(directory, "RUNS.csv"))
    calibration = None
    if r.fit is not None:
        save_fit(r.fit, os.path.join(directory, "FIT.json"))
        nav = os.path.join(directory, "nav")
        os.makedirs(nav, exist_ok=True)
        calibration = export_calibration(r.fit, nav, source="hse-opt calibrate")
        write_test_vectors(r.fit, nav)
    if r.continuation is not None and r.continuation.plan is not None:
        save_plan(r.continuation.plan, os.path.join(directory, "NEXT_PLAN.csv"))
    report.write_report(directory, session_sections(r, calibration), "hse-opt calibrate", summary_lines(r))
    data = summary(r, shown)
    write_text_atomic(os.path.join(directory, "summary.json"), json.dumps(data, indent=2, allow_nan=False) + "\n")
    return data


# -- the live session --------------------------------------------------------------------------
def watch(folder, *, poll=POLL_S, time_left_h=DEFAULT_TIME_LEFT_H, target_sigma=None, clock=time.monotonic,
          sleep=time.sleep, **kw):
    """The live session: after the logs already in ``folder``, wait for new ones and yield a
    :class:`SessionResult` after each change (module docstring: when a log is read).

    Stops (the generator returns) when the verdict is usable with lambda2's total sigma at or
    below ``target_sigma`` (arcsec), or when ``time_left_h`` hours have passed since the call;
    Ctrl-C raises KeyboardInterrupt out of the generator. The time left passed to
    :func:`calibrate` shrinks with the wall-clock time spent.

    Parameters
    ----------
    folder : str or os.PathLike
        The folder the logs arrive in.
    poll : float
        Poll interval, s (0.05 to 60).
    clock, sleep : callable
        Time source and sleep (tests).
    **kw
        Passed to :func:`calibrate` (``config``, ``align_kw``, ``suffixes``, ``effects``,
        ``jobs``, ``client``, ``costs``, ``progress``).

    Yields
    ------
    SessionResult
    """
    folder = os.fspath(folder)
    if not os.path.isdir(folder):
        raise ValueError(f"{folder}: not a folder; allowed: the folder the logs arrive in (--watch)")
    if not (0.05 <= poll <= 60):
        raise ValueError(f"--poll-s {poll:g}: allowed: 0.05 to 60 s")
    start = clock()
    budget = float(time_left_h) * units.HOUR
    cache, last, seen = {}, None, {}
    while True:
        ready = _stable(folder, seen, kw.get("suffixes", _SUFFIXES))
        key = tuple((p, seen[p]) for p in ready)
        if ready and key != last:
            last = key
            left = max(0.0, budget - (clock() - start))
            try:
                result = calibrate([os.path.join(folder, p) for p in ready], time_left_h=left / units.HOUR,
                                   target_sigma=target_sigma, cache=cache, **kw)
            except NoRunsError:
                result = None      # only bad logs so far: wait for good ones
            if result is not None:
                yield result
                total = result.target()[3]
                if target_sigma is not None and result.verdict == "usable" and total is not None \
                        and total <= target_sigma:
                    return
        if clock() - start >= budget:
            return
        sleep(poll)


def _stable(folder, seen, suffixes=_SUFFIXES):
    """Names of the logs in ``folder`` whose signature is the one ``seen`` recorded at the last
    poll (then unchanged over one interval); ``seen`` is updated to this poll's signatures."""
    ready = []
    now = {}
    for name in sorted(os.listdir(folder)):
        path = os.path.join(folder, name)
        if name.startswith(".") or not name.endswith(tuple(suffixes)) or not os.path.isfile(path):
            continue
        try:
            now[name] = log_signature(path)
        except OSError:
            continue
        if now[name][0] > 0 and seen.get(name) == now[name]:
            ready.append(name)
    seen.clear()
    seen.update(now)
    return ready
