"""Raw logs -> RUNS rows (``hse-opt align``): each log through the alignment processor, in
parallel; a bad log is reported and does not stop the others.

* :func:`align_logs` -- load, check and align logs (local worker processes), one RUNS row
  per good log and one line per bad one;
* :func:`runs_from_rows` -- those rows as a :class:`hse_opt.data.Runs`.
"""
from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor, as_completed

import numpy as np

from hse_opt import units
from hse_opt.align._blas import one_thread
from hse_opt.align.blocks import block_sums
from hse_opt.align.noise import NOISE_COLUMNS, combine_noise, noise_from_log
from hse_opt.align.processor import align, latitude_of
from hse_opt.align.mapping import read_mapped
from hse_opt.align.quality import assess
from hse_opt.align.rawlog import load_rawlog
from hse_opt.data import DataError, Runs

__all__ = ["align_logs", "runs_from_rows", "single_blas_thread", "LOG_META_COLUMNS", "NOISE_FIGURES",
           "NOISE_SOURCE_COLUMN"]

#: the filter tuned from the data pools the Allan figures of at most this many logs, spread
#: evenly over the campaign (the noise is the system's: eight ten-minute logs pin its terms to
#: a few per cent, and a first pass over every log would read each twice)
TUNING_LOGS = 8
#: metadata keys of a raw log that become RUNS.csv columns (file units)
LOG_META_COLUMNS = ("azimuth_deg", "t_start_s", "temp_c")
#: the filter's noise figures (``AlignConfig`` fields) -> their names in the RUNS.csv column
#: :data:`NOISE_SOURCE_COLUMN` and in messages
NOISE_FIGURES = {"arw": "gyro ARW", "vrw": "accel VRW", "gyro_pulse": "gyro quantum",
                 "accel_pulse": "accel quantum"}
#: RUNS.csv text column: where each of the filter's noise figures came from, e.g. ``gyro ARW:
#: file; accel VRW: data; gyro quantum: data; accel quantum: data`` (``data``: the Allan
#: analysis of the logs; otherwise ``align_logs``'s ``given_by``: ``file``, ``truth``)
NOISE_SOURCE_COLUMN = "noise_source"


def single_blas_thread():
    """A context limiting BLAS to one thread (:func:`hse_opt.align._blas.one_thread`): the
    workers (of a campaign or a batch of logs) are already parallel, and idle BLAS threads
    spinning on a shared machine only steal CPU."""
    return one_thread()


def _checked_log(path, mapping=None, pulse_weights=None, counts=None):
    """Load ``path`` (through ``mapping`` when given; ``pulse_weights`` for a pulse-count log
    whose sidecar gives none) and run the quality checks (``counts``: the encoder's counts per
    revolution when the calibration gives them): the (repaired) log, its Quality and the block
    sums its checks and its Allan analysis share (None for a log too short for that analysis,
    which then names the log)."""
    if mapping is None:
        log, temperature = load_rawlog(path, pulse_weights=pulse_weights), None
    else:
        mapped = read_mapped(path, mapping)
        log, temperature = mapped.log, mapped.temperature
    try:
        sums = block_sums(log)
    except ValueError:
        sums = None
    quality = assess(log, temperature=temperature, encoder_counts_per_rev=counts, sums=sums)
    quality.raise_if_refused(path)
    return quality.log, quality, sums


def _error_line(path, exc):
    """The one-line error of a bad log, naming the file."""
    if isinstance(exc, OSError):
        return f"{path}: cannot read: {exc.strerror or exc}"
    text = str(exc)
    return text if text.startswith(path) else f"{path}: {text}"


def _noise_one(path, config, mapping=None, noise=None, pulse_weights=None):
    """Worker: the noise figures of one raw log; ``(path, figures, error)``."""
    try:
        log, _, sums = _checked_log(path, mapping, pulse_weights, config.encoder_counts_per_rev)
        return path, noise_from_log(log, sums=sums), None
    except (ValueError, OSError) as exc:
        return path, None, _error_line(path, exc)


def _align_one(path, config, mapping=None, noise=None, pulse_weights=None):
    """Worker: load, check, characterise the noise of and align one raw log; returns ``(path,
    row, error)``: the RUNS row (column -> value in file units, plus ``run`` and ``position``
    from the metadata when given, and ``noise``: the log's :class:`NoiseFigures`) or the
    one-line error (the file named). ``noise``: the log's figures when already computed."""
    from hse_opt.data import DEFAULT_MIN_RATE_DPS

    try:
        log, quality, sums = _checked_log(path, mapping, pulse_weights, config.encoder_counts_per_rev)
        noise = noise_from_log(log, sums=sums) if noise is None else noise
        res = align(log, config)
        lat = latitude_of(log, config)
        if abs(res.rate) < DEFAULT_MIN_RATE_DPS * units.DEG_PER_S:
            raise ValueError(f"the encoder's mean rate is {res.rate / units.DEG_PER_S:.4g} deg/s; allowed: "
                             f"|rate| >= {DEFAULT_MIN_RATE_DPS:g} deg/s (outside the gyros' lock-in zone)")
    except (ValueError, OSError) as exc:
        return path, None, _error_line(path, exc)
    row = {"rate_dps": res.rate / units.DEG_PER_S,
           "heading_deg": float(np.mod(res.heading, 2 * np.pi)) / units.DEG,
           "latitude_deg": lat / units.DEG, "duration_s": round(float(log.t[-1] - log.t[0]), 6),
           "pitch_arcsec": res.pitch / units.ARCSEC, "roll_arcsec": res.roll / units.ARCSEC,
           "heading_std_arcsec": res.heading_std / units.ARCSEC, "quality": quality.summary(),
           **noise.columns(), "noise": noise}
    for key in ("run", "position", *LOG_META_COLUMNS):
        if log.meta.get(key) is not None:
            row[key] = log.meta[key]
    try:        # the row alone as RUNS.csv takes it (a metadata value out of its range names this log)
        Runs.from_columns(_columns([row])[0], source=path, min_rate_dps=0.0)
    except DataError as exc:
        return path, None, _error_line(path, DataError(path, exc.problem, column=exc.column))
    n = len(log)     # the same samples under two names: a few of them, the encoder's sum and the repairs
    row["_samples"] = (n, float(log.t[0]), float(log.t[-1]), *log.gyro[n // 2].tolist(),
                       *log.accel[n // 3].tolist(), float(log.encoder.sum()), quality.summary())
    return path, row, None


def _chunk(worker, paths, config, mapping, noise, pulse_weights=None):
    """Worker: ``worker`` on each path, BLAS on one thread (the workers are parallel)."""
    with single_blas_thread():
        return [worker(path, config, mapping, noise.get(path), pulse_weights) for path in paths]


def _map(worker, paths, config, jobs, progress, client, mapping, noise=None, pulse_weights=None):
    """``worker(path, config, mapping, noise, pulse_weights)`` on every path, in ``jobs`` local
    processes or on a Dask ``client``'s workers; results by path."""
    noise = noise or {}
    done = {}

    def _collect(item):
        done[item[0]] = item
        if progress is not None:
            progress(len(done), len(paths))

    def _chunks(workers):
        size = max(1, min(8, len(paths) // (4 * workers)))
        return [(paths[i:i + size], {p: noise[p] for p in paths[i:i + size] if p in noise})
                for i in range(0, len(paths), size)]

    if client is not None:
        from distributed import as_completed as dask_as_completed
        workers = max(1, len(client.scheduler_info().get("workers", {})))
        futures = [client.submit(_chunk, worker, part, config, mapping, known, pulse_weights, pure=False)
                   for part, known in _chunks(workers)]
        for fut in dask_as_completed(futures):
            for item in fut.result():
                _collect(item)
    elif jobs == 1 or len(paths) <= 1:
        for path in paths:
            _collect(worker(path, config, mapping, noise.get(path), pulse_weights))
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = [pool.submit(_chunk, worker, part, config, mapping, known, pulse_weights)
                       for part, known in _chunks(jobs)]
            for fut in as_completed(futures):
                for item in fut.result():
                    _collect(item)
    return done


def align_logs(paths, config, jobs=1, progress=None, client=None, *, mapping=None, tune_from_data=False,
               pulse_weights=None, given_by="given"):
    """Align raw logs (:mod:`hse_opt.align.rawlog`), in parallel; a bad log does not stop the others.

    Parameters
    ----------
    paths : sequence of str
        Raw-log files (``.npz``, ``.csv`` in either form).
    config : AlignConfig
        The processor: the system's lab calibration and noise; its ``latitude`` serves logs
        without ``latitude_deg`` (:func:`hse_opt.align.latitude_of`).
    jobs : int
        Local worker processes (1: in this process).
    progress : callable, optional
        ``progress(done, total)``, called as logs complete.
    client : dask.distributed.Client, optional
        Align on this Dask cluster instead (``jobs`` is then ignored; the workers must see the
        paths). The rows are the same as with ``jobs=1``: each log is aligned alone, by the same
        code, and collected in path order.
    mapping : hse_opt.align.mapping.Mapping, optional
        Read every log as a test stand's CSV through it (:func:`hse_opt.align.mapping.read_mapped`).
    tune_from_data : bool or collection of str
        Tune the filter from the logs' own noise instead of ``config``'s ``arw``, ``vrw``,
        ``gyro_pulse``, ``accel_pulse`` (True: all four, for a system whose noise no
        calibration file gives; a collection: those of :data:`NOISE_FIGURES` named, the others
        kept from ``config``, for a file that gives only some): a first pass takes the Allan
        analysis (:func:`hse_opt.align.noise.noise_from_log`) of up to :data:`TUNING_LOGS` logs
        spread evenly over ``paths``, pooled (:func:`hse_opt.align.noise.combine_noise`: one
        system, so one noise; a single log's long-cluster points are few), and every log is
        aligned with :meth:`~hse_opt.align.noise.NoiseFigures.tuning` of the pooled figures
        (per sensor axis).
    given_by : str
        Where ``config``'s noise figures come from, for the rows' :data:`NOISE_SOURCE_COLUMN`
        (``file``: a calibration file; ``truth``: a simulated system's).
    pulse_weights : (gyro, accel), optional
        Pulse weights (rad, m/s; one number or three each) for pulse-count CSV logs whose
        sidecar gives none (:func:`hse_opt.align.load_rawlog`): the lab calibration's.

    Returns
    -------
    rows : list of dict
        One RUNS row per good log, in the order of ``paths``: ``rate_dps`` (the encoder's mean
        rate), ``heading_deg``, ``latitude_deg`` (the log's, else the config's), ``duration_s``
        (``t_{n-1} - t_0``, to the microsecond: the span the processor aligns; the first
        row's increments have no encoder angle at their start),
        ``pitch_arcsec``, ``roll_arcsec``, ``heading_std_arcsec`` (the filter's 1-sigma),
        ``quality`` (:meth:`hse_opt.align.findings.Quality.summary`: ``ok``, or what was
        repaired or noted before alignment), ``noise_source`` (:data:`NOISE_SOURCE_COLUMN`:
        where each of the filter's noise figures came from), the noise columns
        (:data:`hse_opt.align.noise.NOISE_COLUMNS`: ``gyro_arw_dph_rthz``, ...) and ``noise``
        (the log's :class:`hse_opt.align.noise.NoiseFigures`, for reports), and
        from the log's metadata, when present: ``run``, ``position``, ``azimuth_deg``,
        ``t_start_s``, ``temp_c``. Each row also has ``log`` (its path).
    errors : list of str
        One line per bad log (the file and, where it applies, the sample), in path order: a
        log that cannot be read, is refused by its checks, has a metadata value out of its
        RUNS.csv range, or repeats an earlier log's samples (the same file given twice, or a
        copy: the first is kept).
    """
    import dataclasses

    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs < 1:
        raise ValueError(f"jobs = {jobs!r} is not allowed: an integer >= 1 is required")
    paths = [str(p) for p in paths]
    tuned = _tuned(tune_from_data)
    noise = None
    if tuned:      # a first pass over up to TUNING_LOGS logs spread over the campaign
        sample = [paths[i] for i in sorted(set(np.linspace(0, len(paths) - 1, min(TUNING_LOGS, len(paths)))
                                                .round().astype(int).tolist()))]
        first = _map(_noise_one, sample, config, jobs, None, client, mapping, pulse_weights=pulse_weights)
        noise = {p: first[p][1] for p in sample if first[p][1] is not None}   # in path order: pooled alike
        if noise:
            tuning = combine_noise(noise.values()).tuning()
            config = dataclasses.replace(config, **{k: tuning[k] for k in tuned})
        else:       # no log could be read: they are all bad logs below; nothing was measured
            tuned = ()
    source = "; ".join(f"{name}: {'data' if key in tuned else given_by}" for key, name in NOISE_FIGURES.items())
    done = _map(_align_one, paths, config, jobs, progress, client, mapping, noise, pulse_weights)
    rows, errors, seen = [], [], {}
    for path in paths:
        _, row, err = done[path]
        if err is None:
            first = seen.setdefault(row["_samples"], path)
            if first != path or any(r["log"] == path for r in rows):
                err = (f"{path}: the same log as {first} (given twice, or a copy); allowed: each log once"
                       if first != path else f"{path}: given twice; allowed: each log once")
        if err is None:
            rows.append({**{k: v for k, v in row.items() if k != "_samples"}, NOISE_SOURCE_COLUMN: source,
                         "log": path})
        else:
            errors.append(err)
    return rows, errors


def _tuned(tune_from_data):
    """The figures of :data:`NOISE_FIGURES` to measure from the data (a tuple, in its order)."""
    if isinstance(tune_from_data, (bool, np.bool_)):
        return tuple(NOISE_FIGURES) if tune_from_data else ()
    names = set(tune_from_data)
    unknown = names - set(NOISE_FIGURES)
    if unknown:
        raise ValueError(f"tune_from_data names {sorted(unknown)}; allowed: True, False or some of "
                         + ", ".join(NOISE_FIGURES))
    return tuple(k for k in NOISE_FIGURES if k in names)


def runs_from_rows(rows, source="<aligned logs>"):
    """A :class:`hse_opt.data.Runs` from :func:`align_logs` rows.

    Rows are ordered by ``t_start_s`` when every log gives it (else as given); ``run`` is
    the logs' own id when every log gives one, else 1, 2, ... in that order. Metadata that
    only some logs give is an error naming the first log without it (``position``), or is
    left out (``t_start_s``, ``temp_c``: the returned notes say so). A log without
    ``azimuth_deg`` has no heading reference (an unsurveyed position: RUNS.csv keeps its
    ``heading_deg`` and leaves ``azimuth_deg`` empty).

    Returns
    -------
    runs : hse_opt.data.Runs
    notes : list of str

    Raises
    ------
    hse_opt.data.DataError
        Naming the log (its row's ``log``) and the column.
    """
    rows = list(rows)
    if all("t_start_s" in r for r in rows):
        rows.sort(key=lambda r: float(r["t_start_s"]))
    columns, notes = _columns(rows)
    try:
        runs = Runs.from_columns(columns, source=source, min_rate_dps=0.0)
    except DataError as exc:
        if exc.row is None or not 1 <= exc.row <= len(rows) or "log" not in rows[exc.row - 1]:
            raise
        raise DataError(rows[exc.row - 1]["log"], exc.problem, column=exc.column) from None
    return runs, notes


def _columns(rows):
    """The RUNS columns of ``rows`` (in their order) and the notes on what was left out."""
    notes = []
    ids = [r.get("run") for r in rows]
    if not (all(isinstance(i, (int, np.integer)) and not isinstance(i, bool) for i in ids)
            and len(set(ids)) == len(ids)):
        if any(i is not None for i in ids):
            notes.append("not every log has a unique integer 'run' in its metadata: runs numbered 1, 2, ...")
        ids = list(range(1, len(rows) + 1))
    columns = {"run": ids}
    for name in ("rate_dps", "heading_deg", "latitude_deg", "duration_s", "pitch_arcsec", "roll_arcsec",
                 "heading_std_arcsec"):
        columns[name] = [r[name] for r in rows]
    if any("azimuth_deg" in r for r in rows):
        columns["azimuth_deg"] = [r.get("azimuth_deg") for r in rows]
    if any("position" in r for r in rows):
        for r in rows:
            if "position" not in r:
                raise DataError(r.get("log", "<log>"), "has no 'position' in its metadata while other logs have one; "
                                          "allowed: a position in every log's metadata or in none")
        columns["position"] = [str(r["position"]) for r in rows]
    for name in ("quality", NOISE_SOURCE_COLUMN):
        if any(name in r for r in rows):
            columns[name] = [r.get(name, "") for r in rows]
    for name in NOISE_COLUMNS:
        if all(name in r for r in rows):
            columns[name] = [r[name] for r in rows]
    for name in ("t_start_s", "temp_c"):
        have = sum(name in r for r in rows)
        if have == len(rows):
            columns[name] = [r[name] for r in rows]
        elif have:
            notes.append(f"'{name}' left out: only {have} of {len(rows)} logs give it")
    return columns, notes
