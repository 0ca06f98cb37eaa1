"""Campaigns: PLAN rows + the true system -> RUNS rows (simulated alignments), in parallel.

* :func:`simulate_run` -- one run: raw data (:mod:`hse_opt.sim.imu`), alignment
  (:mod:`hse_opt.sim.align`), one RUNS.csv row.
* :func:`run_campaign` -- every row of a plan, in parallel on local processes
  (``jobs``) or on a Dask cluster (``client``); results do not depend on either.
* :func:`simulate_heading_error` -- the noise-free heading error of one configuration,
  the simulator side of the symbolic-vs-numeric comparison.
* :func:`simulate_main` / :func:`add_simulate_arguments` -- ``hse-opt simulate``.

Seeds. Run ``r`` (its PLAN ``run`` id) draws everything from
``numpy.random.default_rng(numpy.random.SeedSequence([seed, r]))``, so a run's result
depends only on the seed, its id and its row, not on ``jobs``, chunking or the cluster.

Time and temperature carry from run to run through ``t_start_s``, the time since power-on
of each row (the thermal model and the warm-up transients are functions of it); a plan
without ``t_start_s`` runs back to back from power-on.
"""
from __future__ import annotations

import contextlib
import csv
import math
import os
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor, as_completed

import numpy as np

from hse_opt import units
from hse_opt.sim.align import AlignConfig, align
from hse_opt.sim.imu import generate, true_attitude
from hse_opt.sim.truth import RunSpec, TruthConfig, validate_run

__all__ = ["simulate_run", "simulate_alignment", "default_align_config", "simulate_heading_error", "run_campaign",
           "read_plan_csv", "write_runs_csv", "RUNS_COLUMNS", "PLAN_COLUMNS",
           "add_simulate_arguments", "simulate_main"]

#: RUNS.csv columns written by the simulator, in order (DESIGN.md contract + temp_c);
#: extra PLAN columns follow them.
RUNS_COLUMNS = ("run", "rate_dps", "azimuth_deg", "heading_err_arcsec", "latitude_deg",
                "duration_s", "t_start_s", "pitch_arcsec", "roll_arcsec", "heading_std_arcsec",
                "temp_c")
#: required PLAN.csv columns (``t_start_s`` may be missing: runs then follow back to back)
PLAN_COLUMNS = ("run", "rate_dps", "azimuth_deg", "t_start_s", "duration_s")
_PLAN_OPTIONAL = ("tilt_x_arcsec", "tilt_y_arcsec")


def _wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


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


def simulate_run(truth, run, rng, align_config=None, run_id=0, extra=None):
    """One simulated alignment as a RUNS.csv row.

    Parameters
    ----------
    truth : TruthConfig
    run : RunSpec
    rng : numpy.random.Generator
    align_config : AlignConfig, optional
    run_id : int
    extra : dict, optional
        Extra (PLAN) columns copied to the row.

    Returns
    -------
    dict
        Column name -> value in the column's unit (:data:`RUNS_COLUMNS`, then ``extra``).
        ``heading_err_arcsec`` is the alignment heading minus the stand azimuth reading.
    """
    res, att, meta = simulate_alignment(truth, run, rng, align_config)
    row = {
        "run": int(run_id),
        "rate_dps": run.rate / units.DEG_PER_S,
        "azimuth_deg": run.azimuth / units.DEG,
        "heading_err_arcsec": _wrap(res.heading - run.azimuth) / units.ARCSEC,
        "latitude_deg": truth.site.latitude / units.DEG,
        "duration_s": run.duration,
        "t_start_s": run.t_start,
        "pitch_arcsec": res.pitch / units.ARCSEC,
        "roll_arcsec": res.roll / units.ARCSEC,
        "heading_std_arcsec": res.heading_std / units.ARCSEC,
        "temp_c": meta["temp_c"],
    }
    for k, v in (extra or {}).items():
        row.setdefault(k, v)
    return row


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
    return _wrap(res.heading - ref)


# -- plans and campaigns -------------------------------------------------------------------------
def _plan_to_rows(plan_rows):
    """Rows (list of dict, file units) from a sequence of mappings or an object with
    ``to_columns()`` (e.g. hse_opt.data.Plan)."""
    if hasattr(plan_rows, "to_columns"):
        cols = plan_rows.to_columns()
        n = len(next(iter(cols.values()))) if cols else 0
        return [{k: (int(v[i]) if k == "run" else float(v[i])) for k, v in cols.items()}
                for i in range(n)]
    return [dict(r) for r in plan_rows]


def _prepare(plan_rows, truth):
    """Validate the plan against the system; returns [(run_id, RunSpec, extra)]."""
    rows = _plan_to_rows(plan_rows)
    if not rows:
        raise ValueError("PLAN: no rows")
    out, seen = [], set()
    t_next = 0.0
    for i, row in enumerate(rows, start=1):
        where = f"PLAN row {i}"
        try:
            missing = [c for c in PLAN_COLUMNS if c != "t_start_s" and c not in row]
            if missing:
                raise ValueError(f"missing column(s) {missing}; required {list(PLAN_COLUMNS)}")
            try:
                rid = float(row["run"])
            except (TypeError, ValueError):
                raise ValueError(f"run = {row['run']!r}: an integer >= 0 is required") from None
            if not (math.isfinite(rid) and rid.is_integer() and rid >= 0):
                raise ValueError(f"run = {row['run']!r}: an integer >= 0 is required")
            rid = int(rid)
            if rid in seen:
                raise ValueError(f"run = {rid} is not unique")
            seen.add(rid)
            r = dict(row)
            if r.get("t_start_s") in (None, ""):
                r["t_start_s"] = t_next
            spec = RunSpec.from_plan_row(r)
            validate_run(truth, spec)
        except ValueError as exc:
            raise ValueError(f"{where} (run {row.get('run', '?')}): {exc}") from None
        t_next = spec.t_start + spec.duration
        extra = {}
        for k, v in row.items():
            if k in PLAN_COLUMNS or k in RUNS_COLUMNS:
                continue
            try:
                extra[k] = float(v)
            except (TypeError, ValueError):
                raise ValueError(f"{where}: column {k} = {v!r}: extra columns must be numeric") from None
        out.append((rid, spec, extra))
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
    """Worker: simulate a list of (run_id, RunSpec, extra); returns [(run_id, row)]."""
    out = []
    with _single_blas_thread():
        for rid, spec, extra in items:
            rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(rid)]))
            out.append((rid, simulate_run(truth, spec, rng, align_config, rid, extra)))
    return out


def run_campaign(plan_rows, truth, seed, jobs=1, client=None, progress=None, *,
                 align_config=None, chunk_size=None):
    """Simulate every run of a plan.

    Parameters
    ----------
    plan_rows : sequence of mapping, or hse_opt.data.Plan
        PLAN.csv rows (column name -> value in the column's unit), in execution order.
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
    list of dict
        RUNS rows in plan order (:data:`RUNS_COLUMNS`, then the plan's extra columns).
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed = {seed!r} is not allowed: an integer >= 0 is required")
    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs < 1:
        raise ValueError(f"jobs = {jobs!r} is not allowed: an integer >= 1 is required")
    items = _prepare(plan_rows, truth)
    cfg = default_align_config(truth) if align_config is None else align_config
    total = len(items)
    workers = jobs if client is None else max(1, len(client.scheduler_info().get("workers", {})) or 1)
    if chunk_size is None:
        chunk_size = max(1, min(64, -(-total // (4 * workers))))
    chunks = [items[i:i + chunk_size] for i in range(0, total, chunk_size)]
    results = {}
    done = 0

    def _collect(part):
        nonlocal done
        for rid, row in part:
            results[rid] = row
        done += len(part)
        if progress is not None:
            progress(done, total)

    if client is not None:
        from distributed import as_completed as dask_as_completed
        futures = [client.submit(_simulate_chunk, truth, cfg, int(seed), ch, pure=False)
                   for ch in chunks]
        for fut in dask_as_completed(futures):
            _collect(fut.result())
    elif jobs == 1:
        for ch in chunks:
            for item in ch:
                _collect(_simulate_chunk(truth, cfg, seed, [item]))
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = [pool.submit(_simulate_chunk, truth, cfg, int(seed), ch) for ch in chunks]
            for fut in as_completed(futures):
                _collect(fut.result())
    return [results[rid] for rid, _, _ in items]


# -- CSV (local until hse_opt.data is merged into this branch) -----------------------------------
def read_plan_csv(path):
    """Read PLAN.csv into rows (dict of column -> float; ``run`` int).

    Raises ValueError naming the file, the 1-based data row and the column."""
    path = os.fspath(path)
    rows = []
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        header = [h.strip() for h in (reader.fieldnames or [])]
        missing = [c for c in PLAN_COLUMNS if c not in header]
        if missing:
            raise ValueError(f"{path}: missing column(s) {missing}; required {list(PLAN_COLUMNS)}")
        if len(set(header)) != len(header):
            raise ValueError(f"{path}: duplicate column names in {header}")
        for i, raw in enumerate(reader, start=1):
            row = {}
            for k, v in raw.items():
                k = (k or "").strip()
                v = (v or "").strip() if isinstance(v, str) else v
                if k == "" or v is None:
                    raise ValueError(f"{path}: data row {i}: wrong number of fields")
                try:
                    x = float(v)
                except ValueError:
                    raise ValueError(f"{path}: data row {i}, column {k} = {v!r}: a number is required") from None
                if not math.isfinite(x):
                    raise ValueError(f"{path}: data row {i}, column {k} = {v!r}: a finite number is required")
                row[k] = int(x) if k == "run" and x.is_integer() else x
            rows.append(row)
    return rows


def _fmt(v):
    if isinstance(v, (int, np.integer)) and not isinstance(v, bool):
        return str(int(v))
    return repr(float(v))


def write_runs_csv(rows, path):
    """Write RUNS rows (dicts, file units) to ``path`` atomically (temporary file, then
    rename): :data:`RUNS_COLUMNS` first, then any extra columns in first-seen order."""
    path = os.fspath(path)
    cols = list(RUNS_COLUMNS)
    for r in rows:
        for k in r:
            if k not in cols:
                cols.append(k)
    d = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=".runs-", suffix=".csv", dir=d)
    try:
        with os.fdopen(fd, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh, lineterminator="\n")
            w.writerow(cols)
            for r in rows:
                w.writerow(["" if r.get(c) is None else _fmt(r[c]) for c in cols])
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


# -- command line helper --------------------------------------------------------------------------
def add_simulate_arguments(parser):
    """Add the ``hse-opt simulate`` arguments to an argparse (sub)parser."""
    parser.add_argument("plan", help="PLAN.csv")
    parser.add_argument("--truth", help="TRUTH.toml (default: the paper-like system)")
    parser.add_argument("-o", "--output", required=True, help="RUNS.csv to write")
    parser.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    parser.add_argument("--jobs", type=int, default=1, help="local worker processes (default 1)")
    parser.add_argument("--dask", metavar="ADDRESS", default=None,
                        help="run on the Dask scheduler at ADDRESS (e.g. tcp://host:8786)")
    parser.add_argument("--no-progress", dest="progress", action="store_false",
                        help="no progress bar on stderr")
    parser.add_argument("--write-truth", metavar="FILE", default=None,
                        help="also write the truth used, every key, to FILE (TOML)")
    return parser


def simulate_main(args):
    """Run ``hse-opt simulate`` for parsed ``args`` (see :func:`add_simulate_arguments`).

    Returns the exit status: 0 success, 2 bad input (message on stderr naming the file, row,
    column or key), 1 anything else.
    """
    bar = None
    try:
        truth = TruthConfig.from_toml(args.truth) if args.truth else TruthConfig.default()
        plan = read_plan_csv(args.plan)
        client = None
        if getattr(args, "dask", None):
            from distributed import Client
            client = Client(args.dask)
        progress = None
        if getattr(args, "progress", True):
            from tqdm import tqdm
            bar = tqdm(total=len(plan), unit="run", file=sys.stderr, desc="simulate")

            def progress(done, total):
                bar.update(done - bar.n)
        try:
            rows = run_campaign(plan, truth, args.seed, jobs=args.jobs, client=client,
                                progress=progress)
        finally:
            if client is not None:
                client.close()
        write_runs_csv(rows, args.output)
        if getattr(args, "write_truth", None):
            truth.to_toml(args.write_truth)
        return 0
    except (ValueError, OSError) as exc:
        print(f"hse-opt simulate: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - the exit-status contract: 1 for anything else
        print(f"hse-opt simulate: unexpected error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    finally:
        if bar is not None:
            bar.close()
