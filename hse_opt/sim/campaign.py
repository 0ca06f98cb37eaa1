"""Campaigns: a test plan + the true system -> simulated alignment results, in parallel.

* :func:`run_campaign` -- every run of a :class:`hse_opt.data.Plan` (``PLAN.csv``), in
  parallel on local processes (``jobs``) or on a Dask cluster (``client``); returns a
  :class:`hse_opt.data.Runs` (``RUNS.csv``; save it with :func:`hse_opt.data.save_runs`).
  Results do not depend on ``jobs``, the chunking or the cluster.
* :func:`simulate_run` -- one run: raw data (:mod:`hse_opt.sim.imu`), alignment
  (:mod:`hse_opt.align.processor`), a :class:`RunResult`.
* :func:`simulate_heading_error` -- the noise-free heading error of one configuration,
  the simulator side of the symbolic-vs-numeric comparison.
* :func:`lab_calibration`, :func:`align_config_from_truth`, :func:`default_align_config` --
  the lab calibration of a simulated system and the processor's settings for it.

The command line (``hse-opt simulate``) is :mod:`hse_opt.app.commands.simulate`; PLAN.csv and
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
from hse_opt.align.rotations import wrap_angle
from hse_opt.data import DataError, Plan, Runs
from hse_opt.align import LabCalibration, align
from hse_opt.align.batch import single_blas_thread
from hse_opt.sim.imu import generate, true_attitude
from hse_opt.sim.truth import RunError, RunSpec, TruthConfig, gyro_matrices, validate_run

__all__ = ["RunResult", "simulate_run", "simulate_alignment", "lab_calibration", "align_config_from_truth",
           "default_align_config", "simulate_heading_error", "run_campaign"]

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


def lab_calibration(truth):
    """The lab calibration of a simulated system (what ``CALIBRATION.toml`` would hold for it).

    The lab estimates, not the truth: the calibrated K~_g = (I + Lambda) K_g (Eq. 1) and
    C~_s^b = (I - [xi x]) C_s^b(r_zb_s_calibrated) (Eq. 2), whose errors eps, xi are what the
    HSE calibration finds; the accelerometers as ideal (K_a = I: the truth's accelerometer
    scale factors and misalignments are residuals the lab left); the nominal pulse weights
    (where the truth quantizes), the encoder's counts per revolution (where it quantizes), the
    sensors' specified noise and the site latitude.

    Returns
    -------
    hse_opt.align.LabCalibration
    """
    mats = gyro_matrices(truth)
    res = truth.encoder.resolution
    counts = 2.0 * np.pi / res if res else None
    if counts is not None and abs(counts - round(counts)) < 1e-6 * counts:
        counts = float(round(counts))          # 0.18 arcsec: 7,200,000 counts, not 7199999.999999999
    return LabCalibration(K_g=mats["K_g_cal"], K_a=np.eye(3), C_s_b=mats["C_s_b_cal"],
                          gyro_pulse=truth.gyro.pulse or None, accel_pulse=truth.accel.pulse or None,
                          arw=truth.gyro.arw, vrw=truth.accel.vrw, latitude=truth.site.latitude,
                          encoder_counts_per_rev=counts, source="<lab calibration of the simulated system>")


def align_config_from_truth(truth, **overrides):
    """The processor of a simulated system (:class:`hse_opt.align.AlignConfig`): its lab
    calibration (:func:`lab_calibration`) with the truth's pulse weights (0: none) as tuning,
    and no latitude of its own (each log's ``latitude_deg``, which :func:`generate` writes);
    ``overrides`` replace any field."""
    kw = dict(gyro_pulse=truth.gyro.pulse, accel_pulse=truth.accel.pulse, latitude=None)
    kw.update(overrides)
    return lab_calibration(truth).align_config(**kw)


def default_align_config(truth):
    """The processor for ``truth``: its calibrated parameters and its sensors' specified noise
    (the default system's when ``truth`` is noise-free)."""
    return align_config_from_truth(_tuning_truth(truth))


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
    heading : float
        The alignment's own heading, rad in [0, 2 pi).
    """

    heading_err: float
    pitch: float
    roll: float
    heading_std: float
    temp_c: float
    heading: float = float("nan")


def simulate_run(truth, run, rng, align_config=None, *, log_path=None, log_meta=None):
    """Simulate and align one run.

    Parameters
    ----------
    truth : TruthConfig
    run : RunSpec
    rng : numpy.random.Generator
    align_config : AlignConfig, optional
        Processor (default: :func:`default_align_config`).
    log_path : str, optional
        Also write the raw log there (:func:`hse_opt.sim.save_rawlog`), its metadata updated
        with ``log_meta`` (a None value removes the key).

    Returns
    -------
    RunResult
    """
    cfg = default_align_config(truth) if align_config is None else align_config
    log = generate(truth, run, rng)
    res = align(log, cfg)
    if log_path is not None:
        from hse_opt.align.rawlog import RawLog, save_rawlog
        meta = {**log.meta, **(log_meta or {})}
        meta = {k: v for k, v in meta.items() if v is not None}
        save_rawlog(RawLog._trusted(log.t, log.gyro, log.accel, log.encoder, meta), log_path)
    return RunResult(heading_err=float(wrap_angle(res.heading - run.azimuth)), pitch=res.pitch,
                     roll=res.roll, heading_std=res.heading_std, temp_c=float(log.meta["temp_c"]),
                     heading=float(np.mod(res.heading, 2 * np.pi)))


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


def _simulate_chunk(truth, align_config, seed, items, logs=None):
    """Worker: simulate a list of (run_id, RunSpec); returns [(run_id, RunResult)]. ``logs``:
    run_id -> (path, meta) of the raw logs to write."""
    out = []
    with single_blas_thread():
        for rid, spec in items:
            rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(rid)]))
            path, meta = (logs or {}).get(rid, (None, None))
            out.append((rid, simulate_run(truth, spec, rng, align_config, log_path=path, log_meta=meta)))
    return out


def _positions(plan):
    """Position labels of a plan: its ``position`` column, else ``P1``, ``P2``, ... by stand
    azimuth in order of first appearance (labels that do not give the azimuth away)."""
    if plan.position is not None:
        return plan.position
    keys = list(dict.fromkeys(plan.azimuth.tolist()))
    return np.array([f"P{keys.index(a) + 1}" for a in plan.azimuth.tolist()])


def _worker_signals():
    """In a worker process: Ctrl-C is the parent's to handle (it stops the workers), SIGTERM ends
    the worker (not a handler inherited from the parent)."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def run_campaign(plan, truth, seed, jobs=1, client=None, progress=None, *,
                 align_config=None, chunk_size=None, field=False, surveyed=(), raw_logs=None):
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
    field : bool
        A field campaign: each position (the plan's ``position`` labels, else ``P1``, ``P2``,
        ... by stand azimuth) keeps its true heading to itself. The runs carry ``position`` and
        the alignment's own ``heading_deg``; ``azimuth_deg`` and ``heading_err_arcsec`` only at
        the positions named in ``surveyed`` (a mixed campaign), empty elsewhere.
    surveyed : collection of str
        Positions of a field campaign whose stand azimuth is known.
    raw_logs : str or os.PathLike, optional
        Also write each run's raw log to this existing directory as ``run_<id>.npz`` (the
        metadata: ``run``, ``position``, ``t_start_s``, ``latitude_deg``, ``temp_c``, and
        ``azimuth_deg`` unless the position's heading is hidden), ready for ``hse-opt align``.

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
    positions = _positions(plan)
    surveyed = {str(p) for p in surveyed}
    if not field and surveyed:
        raise ValueError("surveyed positions are a field-campaign option; allowed: field=True (--field)")
    if surveyed - set(positions.tolist()):
        raise ValueError(f"surveyed positions {sorted(surveyed - set(positions.tolist()))} are not in the plan; "
                         f"allowed: {sorted(set(positions.tolist()))}")
    known = np.array([not field or p in surveyed for p in positions.tolist()])
    logs = None
    if raw_logs is not None:
        import os
        directory = os.fspath(raw_logs)
        if not os.path.isdir(directory):
            raise ValueError(f"{directory}: the raw-log directory does not exist; allowed: an existing directory")
        logs = {rid: (os.path.join(directory, f"run_{rid}.npz"),
                      {"run": rid, "position": str(positions[i]),
                       "azimuth_deg": None if not known[i] else float(plan.azimuth[i] / units.DEG)})
                for i, (rid, _) in enumerate(items)}
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
        futures = [client.submit(_simulate_chunk, truth, cfg, int(seed), ch, _part(logs, ch), pure=False)
                   for ch in chunks]
        for fut in dask_as_completed(futures):
            _collect(fut.result())
    elif jobs == 1:
        for item in items:
            _collect(_simulate_chunk(truth, cfg, seed, [item], logs))
    else:
        pool = ProcessPoolExecutor(max_workers=jobs, initializer=_worker_signals)
        try:
            futures = [pool.submit(_simulate_chunk, truth, cfg, int(seed), ch, _part(logs, ch)) for ch in chunks]
            for fut in as_completed(futures):
                _collect(fut.result())
        except BaseException:  # an error, Ctrl-C or SIGTERM: stop now, not after the queued runs
            for proc in list((getattr(pool, "_processes", None) or {}).values()):
                proc.terminate()
            pool.shutdown(wait=False, cancel_futures=True)
            raise
        pool.shutdown()
    res = [results[rid] for rid, _ in items]
    column = lambda name: np.array([getattr(r, name) for r in res])  # noqa: E731
    written = plan.to_columns()              # the plan's values as written, file units
    covariates = {TEMP_COLUMN: column("temp_c")}
    for name in ("tilt_x_arcsec", "tilt_y_arcsec", *plan.covariates):
        if name in written:
            covariates[name] = written[name]
    if field:
        return _field_runs(plan, truth, column, covariates, positions, known)
    return Runs(run=plan.run, rate=plan.rate, azimuth=plan.azimuth, heading_err=column("heading_err"),
                latitude=np.full(total, truth.site.latitude), duration=plan.duration,
                t_start=plan.t_start, pitch=column("pitch"), roll=column("roll"),
                heading_std=column("heading_std"), position=plan.position, covariates=covariates,
                metadata=plan.metadata, source="<simulated>")


def _part(logs, chunk):
    return None if logs is None else {rid: logs[rid] for rid, _ in chunk}


def _field_runs(plan, truth, column, covariates, positions, known):
    """The RUNS table of a field campaign: the plan's azimuth only where it is known."""
    written = plan.to_columns()
    heading_err = column("heading_err") / units.ARCSEC
    cols = {"run": plan.run, "rate_dps": written["rate_dps"],
            "azimuth_deg": np.where(known, written["azimuth_deg"], np.nan),
            "heading_err_arcsec": np.where(known, heading_err, np.nan),
            "heading_deg": column("heading") / units.DEG,
            "latitude_deg": np.full(len(plan), truth.site.latitude / units.DEG),
            "duration_s": written["duration_s"], "t_start_s": written["t_start_s"],
            "pitch_arcsec": column("pitch") / units.ARCSEC, "roll_arcsec": column("roll") / units.ARCSEC,
            "heading_std_arcsec": column("heading_std") / units.ARCSEC, "position": positions, **covariates,
            **{k: v.tolist() for k, v in plan.metadata.items()}}
    cols = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in cols.items()}
    return Runs.from_columns(cols, source="<simulated field campaign>", min_rate_dps=0.0,
                             allow_small_azimuths=True)
