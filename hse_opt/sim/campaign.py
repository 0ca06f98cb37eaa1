"""Campaigns: a test plan + the true system -> simulated alignment results, in parallel.

* :func:`run_campaign` -- every run of a :class:`hse_opt.data.Plan` (``PLAN.csv``), in
  parallel on local processes (``jobs``) or on a Dask cluster (``client``); returns a
  :class:`hse_opt.data.Runs` (``RUNS.csv``; save it with :func:`hse_opt.data.save_runs`).
  Results do not depend on ``jobs``, the chunking or the cluster.
* :func:`simulate_run` -- one run: raw data (:mod:`hse_opt.sim.imu`), alignment
  (:mod:`hse_opt.sim.align`), a :class:`RunResult`.
* :func:`simulate_heading_error` -- the noise-free heading error of one configuration,
  the simulator side of the symbolic-vs-numeric comparison.

The command line (``hse-opt simulate``) is :mod:`hse_opt.commands.simulate`; PLAN.csv and
RUNS.csv are read and written by :mod:`hse_opt.data` only.

Seeds. Run ``r`` (its PLAN ``run`` id) draws everything from
``numpy.random.default_rng(numpy.random.SeedSequence([seed, r]))``, so a run's result
depends only on the seed, its id and its row, not on ``jobs``, chunking or the cluster.

Time and temperature carry from run to run through ``t_start_s``, the time since power-on
of each row (the thermal model and the warm-up transients are functions of it).
"""
from __future__ import annotations

import contextlib
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass

import numpy as np

from hse_opt import units
from hse_opt.frames import wrap_angle
from hse_opt.data import DataError, Plan, Runs
from hse_opt.sim.align import AlignConfig, align
from hse_opt.sim.imu import generate, true_attitude
from hse_opt.sim.truth import RunError, RunSpec, TruthConfig, validate_run

__all__ = ["RunResult", "simulate_run", "simulate_alignment", "default_align_config",
           "simulate_heading_error", "run_campaign"]

#: covariate column the simulator adds to RUNS (the run's mean IMU temperature)
TEMP_COLUMN = "temp_c"


def _tuning_truth(truth):
    """The system whose datasheet tunes the processor: ``truth`` itself when it has noise,
    else the default system (a noise-free study keeps a realistic filter)."""
    if truth.gyro.arw > 0 and truth.accel.vrw > 0:
        return truth
    d = TruthConfig.default()
    return truth.updated({"gyro": {"arw_dph_rthz": d.gyro.arw / units.DEG_PER_H,
                                   "pulse_arcsec": d.gyro.pulse / units.ARCSEC},
                          "accel": {"vrw_ug_rthz": d.accel.vrw / units.MICRO_G,
                                    "pulse_mps": d.accel.pulse}})


def default_align_config(truth):
    """The processor for ``truth``: its calibrated parameters and its sensors' specified noise
    (the default system's when ``truth`` is noise-free)."""
    return AlignConfig.from_truth(_tuning_truth(truth))


def simulate_alignment(truth, run, rng=None, align_config=None):
    """Simulate and align one run.

    Returns
    -------
    result : AlignResult
    attitude : dict
        The true attitude (:func:`hse_opt.sim.imu.true_attitude`).
    log_meta : dict
        The raw log's metadata (``temp_c`` ...).
    """
    cfg = default_align_config(truth) if align_config is None else align_config
    log = generate(truth, run, rng)
    return align(log, cfg), true_attitude(truth, run), log.meta


@dataclass(frozen=True)
class RunResult:
    """One simulated alignment (SI).

    Attributes
    ----------
    heading_err : float
        Alignment heading minus the stand azimuth reading, rad (RUNS ``heading_err_arcsec``).
    pitch, roll : float
        The alignment's own leveling of b0, rad.
    heading_std : float
        The filter's 1-sigma heading, rad.
    temp_c : float
        Mean IMU temperature over the run, degC.
    """

    heading_err: float
    pitch: float
    roll: float
    heading_std: float
    temp_c: float


def simulate_run(truth, run, rng, align_config=None):
    """Simulate and align one run.

    Parameters
    ----------
    truth : TruthConfig
    run : RunSpec
    rng : numpy.random.Generator
    align_config : AlignConfig, optional
        Processor (default: :func:`default_align_config`).

    Returns
    -------
    RunResult
    """
    res, _, meta = simulate_alignment(truth, run, rng, align_config)
    return RunResult(heading_err=float(wrap_angle(res.heading - run.azimuth)), pitch=res.pitch,
                     roll=res.roll, heading_std=res.heading_std, temp_c=float(meta["temp_c"]))


def simulate_heading_error(truth, rate, azimuth, latitude=None, duration=600.0, *,
                           t_start=3600.0, tilt=(0.0, 0.0), alpha0=0.0, reference="stand",
                           align_config=None):
    """Heading error of one alignment with noise and quantization off (rad).

    The simulator side of the symbolic-vs-numeric comparison: switch one error source on in
    ``truth`` (e.g. ``TruthConfig.ideal().updated({"gyro": {"eps_arcsec": [2, 0, 0]}})``)
    and compare with the model's prediction for the same run.

    Parameters
    ----------
    truth : TruthConfig
        The system; its noise and quantization are switched off here
        (:meth:`TruthConfig.noise_free`); the processor keeps its datasheet tuning.
    rate : float
        Signed table rate Omega, rad/s.
    azimuth : float
        Stand azimuth reading, rad.
    latitude : float, optional
        rad; default ``truth.site.latitude``.
    duration : float
        s.
    t_start : float
        Time since power-on at the start, s (warm-up and thermal effects).
    tilt : (float, float)
        Deliberate tilt of the table base (x: roll, y: pitch), rad, on top of
        ``stand.mount_tilt``.
    alpha0 : float
        Table angle at the start, rad.
    reference : {"stand", "true"}
        ``"stand"``: alignment heading minus the stand azimuth reading (the RUNS.csv
        ``heading_err_arcsec`` definition, so stand azimuth errors count);
        ``"true"``: minus the true heading of b0.
    align_config : AlignConfig, optional

    Returns
    -------
    float
        Heading error, estimated minus reference, rad.
    """
    if reference not in ("stand", "true"):
        raise ValueError(f"reference = {reference!r} is not allowed: 'stand' or 'true'")
    if latitude is not None:
        truth = truth.updated({"site": {"latitude_deg": latitude / units.DEG}})
    cfg = default_align_config(truth) if align_config is None else align_config
    run = RunSpec(rate=rate, azimuth=azimuth, duration=duration, t_start=t_start,
                  tilt=tuple(tilt), alpha0=alpha0)
    res, att, _ = simulate_alignment(truth.noise_free(), run, None, cfg)
    ref = run.azimuth if reference == "stand" else att["heading"]
    return float(wrap_angle(res.heading - ref))


# -- plans and campaigns -------------------------------------------------------------------------
def _as_plan(plan):
    """A :class:`Plan` from a Plan or a sequence of row mappings (column -> value in the
    column's unit, as in PLAN.csv), validated by :meth:`Plan.from_columns`."""
    if isinstance(plan, Plan):
        return plan
    rows = [dict(r) for r in plan]
    if not rows:
        raise DataError("<plan>", "no rows; allowed: at least one planned run")
    names = list(rows[0])
    for i, r in enumerate(rows, start=1):
        if list(r) != names:
            raise DataError("<plan>", f"has columns {sorted(r)}, row 1 has {sorted(names)}; allowed: "
                                      "the same columns in every row", row=i)
    return Plan.from_columns({k: [r[k] for r in rows] for k in names}, source="<plan>")


def _prepare(plan, truth):
    """Validate every run against the system; returns [(run_id, RunSpec)]."""
    tilt_x = plan.tilt_x if plan.tilt_x is not None else np.zeros(len(plan))
    tilt_y = plan.tilt_y if plan.tilt_y is not None else np.zeros(len(plan))
    out = []
    for i in range(len(plan)):
        spec = RunSpec(rate=float(plan.rate[i]), azimuth=float(plan.azimuth[i]),
                       duration=float(plan.duration[i]), t_start=float(plan.t_start[i]),
                       tilt=(float(tilt_x[i]), float(tilt_y[i])))
        try:
            validate_run(truth, spec)
        except RunError as exc:
            raise DataError(plan.source, f"run {plan.run[i]}: {exc.problem}", row=i + 1,
                            column=exc.column) from None
        out.append((int(plan.run[i]), spec))
    return out


def _single_blas_thread():
    """A context limiting BLAS to one thread (threadpoolctl, if installed): campaign workers
    are already parallel, and idle BLAS threads spinning on a shared machine only steal CPU."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - optional
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


def _simulate_chunk(truth, align_config, seed, items):
    """Worker: simulate a list of (run_id, RunSpec); returns [(run_id, RunResult)]."""
    out = []
    with _single_blas_thread():
        for rid, spec in items:
            rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(rid)]))
            out.append((rid, simulate_run(truth, spec, rng, align_config)))
    return out


def run_campaign(plan, truth, seed, jobs=1, client=None, progress=None, *,
                 align_config=None, chunk_size=None):
    """Simulate every run of a plan.

    Parameters
    ----------
    plan : hse_opt.data.Plan or sequence of mapping
        The plan (``load_plan("PLAN.csv")``), or its rows as mappings of PLAN column name ->
        value in the column's unit, in execution order.
    truth : TruthConfig
    seed : int
        Campaign seed (>= 0); run ``r`` uses ``SeedSequence([seed, r])``.
    jobs : int
        Local worker processes (1: in this process).
    client : dask.distributed.Client, optional
        Run on this Dask cluster instead (``jobs`` is then ignored).
    progress : callable, optional
        ``progress(done, total)`` called in this process as runs complete.
    align_config : AlignConfig, optional
        Processor (default: :func:`default_align_config`).
    chunk_size : int, optional
        Runs per task (default: about 4 tasks per worker, at most 64 runs).

    Returns
    -------
    hse_opt.data.Runs
        One row per planned run, in plan order: the plan's run, rate, azimuth, duration and
        t_start, the site latitude, the alignment's heading error (heading minus the stand
        reading), pitch, roll and 1-sigma; covariates ``temp_c`` (mean IMU temperature), then
        the plan's ``tilt_x_arcsec``, ``tilt_y_arcsec`` and extra columns as written.

    Raises
    ------
    hse_opt.data.DataError
        A run the system cannot make (lock-in, shorter than a revolution, tilt too large),
        naming the plan, row and column; a plan column named ``temp_c``.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed = {seed!r} is not allowed: an integer >= 0 is required")
    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs < 1:
        raise ValueError(f"jobs = {jobs!r} is not allowed: an integer >= 1 is required")
    plan = _as_plan(plan)
    if TEMP_COLUMN in plan.covariates:
        raise DataError(plan.source, "clashes with the simulated mean IMU temperature; allowed: "
                                     "another name for a plan column", column=TEMP_COLUMN)
    items = _prepare(plan, truth)
    cfg = default_align_config(truth) if align_config is None else align_config
    total = len(items)
    workers = jobs if client is None else max(1, len(client.scheduler_info().get("workers", {})) or 1)
    if chunk_size is None:
        chunk_size = max(1, min(64, -(-total // (4 * workers))))
    chunks = [items[i:i + chunk_size] for i in range(0, total, chunk_size)]
    results = {}

    def _collect(part):
        results.update(part)
        if progress is not None:
            progress(len(results), total)

    if client is not None:
        from distributed import as_completed as dask_as_completed
        futures = [client.submit(_simulate_chunk, truth, cfg, int(seed), ch, pure=False)
                   for ch in chunks]
        for fut in dask_as_completed(futures):
            _collect(fut.result())
    elif jobs == 1:
        for item in items:
            _collect(_simulate_chunk(truth, cfg, seed, [item]))
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = [pool.submit(_simulate_chunk, truth, cfg, int(seed), ch) for ch in chunks]
            for fut in as_completed(futures):
                _collect(fut.result())
    res = [results[rid] for rid, _ in items]
    column = lambda name: np.array([getattr(r, name) for r in res])  # noqa: E731
    written = plan.to_columns()              # the plan's values as written, file units
    covariates = {TEMP_COLUMN: column("temp_c")}
    for name in ("tilt_x_arcsec", "tilt_y_arcsec", *plan.covariates):
        if name in written:
            covariates[name] = written[name]
    return Runs(run=plan.run, rate=plan.rate, azimuth=plan.azimuth, heading_err=column("heading_err"),
                latitude=np.full(total, truth.site.latitude), duration=plan.duration,
                t_start=plan.t_start, pitch=column("pitch"), roll=column("roll"),
                heading_std=column("heading_std"), covariates=covariates, source="<simulated>")
