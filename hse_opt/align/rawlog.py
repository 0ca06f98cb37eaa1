"""Raw logs: the documented format of 500 Hz RLG / accelerometer / encoder records.

A raw log is what the alignment processor (:mod:`hse_opt.align.processor`) reads; simulated runs
(:func:`hse_opt.sim.imu.generate`) and real recordings use the same format.

Format
------
One row per sample ``k = 0 .. n-1`` at timestamp ``t_k``:

================  ==========  =============================================================
column / array    shape       meaning
================  ==========  =============================================================
``t_s``           (n,)        timestamp, s: strictly increasing, uniform up to jitter
                              (any epoch; simulated logs use time since power-on)
``gyro_rad``      (n, 3)      RLG angle increments over ``(t_{k-1}, t_k]``, rad, one per gyro
                              (x_g, y_g, z_g order): pulse counts times the nominal pulse
                              weight, *before* any calibration (the processor applies K~_g)
``accel_mps``     (n, 3)      accelerometer velocity increments over ``(t_{k-1}, t_k]``, m/s,
                              along the IMU axes x_s, y_s, z_s (specific force: on a static
                              base their sum points up), *before* calibration (the processor
                              applies the accelerometer matrix K_a, then C~_s^b)
``encoder_rad``   (n,)        table angle alpha latched at ``t_k``, rad, about z_b (down),
                              zero at the zero-position indicator; multi-turn (unwrapped) or
                              wrapped to one turn -- the loader unwraps it
================  ==========  =============================================================

Frames (``docs/conventions.md``, ``docs/rawlogs.md``): the IMU is fixed to the table top b
(z_b down along the rotation axis, x_b at the encoder's zero), so s (the IMU's orthogonal
frame) and g (the gyro sensing axes) turn with the table; C~_s^b (the lab calibration,
``CALIBRATION.toml``) places s in b -- in the paper's triad every gyro axis is 54.74 deg from
z_b (the rotation axis in s near ``-(1, 1, 1)/sqrt(3)``). b turns relative to the base b0 by
alpha; b0 is fixed on the stand (its attitude in n is what the alignment finds).

The first row's increments belong to an interval that has no encoder angle at its start;
the processor does not use them, and the record's length is ``t_{n-1} - t_0``. Metadata (all optional, SI or unit-named): ``latitude_deg``
(required by the processor unless given to it), ``rate_dps`` (nominal), ``azimuth_deg``
(stand reading), ``t_start_s`` (time since power-on at ``t_0``), ``temp_c`` (mean IMU
temperature), ``source``.

Files
    ``.npz`` (numpy, the fast form): the four arrays under the names above plus ``meta_json``
    (a JSON object string). ``.csv``: one header row ``t_s, gyro_x_rad, gyro_y_rad,
    gyro_z_rad, accel_x_mps, accel_y_mps, accel_z_mps, encoder_rad``, one row per sample;
    metadata come from an optional sidecar ``<file>.json`` or the ``meta`` argument.
    ``.csv`` with pulse counts (as test stands record them): the header ``t_s,
    gyro_x_pulses, gyro_y_pulses, gyro_z_pulses, accel_x_pulses, accel_y_pulses,
    accel_z_pulses, encoder_rad``, whole-number counts per sample, and the pulse weights in
    the sidecar (or ``meta``): ``gyro_pulse_arcsec`` and ``accel_pulse_mps``, each one number
    or three (x, y, z). The loader multiplies counts by weights; the log is then the same as
    the ``_rad`` / ``_mps`` form. Either CSV form may give the table angle as
    ``encoder_deg`` instead of ``encoder_rad``.

Metadata keys the alignment command (``hse-opt align``) reads into RUNS.csv: ``run`` (integer
id), ``position`` (stand-position label), ``azimuth_deg`` (the stand reading; without it the
run has no heading reference), ``latitude_deg``, ``t_start_s``, ``temp_c``.

Checks (:func:`validate_rawlog`): matching shapes, at least 3 samples, every value finite,
timestamps strictly increasing and without gaps (no interval longer than 1.5 times the
median), encoder steps below half a turn. A failure is a ValueError naming the sample index.
:func:`check_rawlog` adds what a real recording can get wrong: a channel that is zero in
every sample (dead or unconnected), and units (the gyros' rate against the encoder's, the
accelerometers' specific force against gravity). :func:`load_rawlog` runs both, and names
the file; a truncated file names the sample where it ends.
"""
from __future__ import annotations

import json
import os
import stat
from dataclasses import dataclass, field

import numpy as np

from hse_opt import units
from hse_opt.data import DataError, atomic_path

__all__ = ["RawLog", "validate_rawlog", "check_rawlog", "load_rawlog", "save_rawlog", "CSV_COLUMNS",
           "PULSE_COLUMNS"]

CSV_COLUMNS = ("t_s", "gyro_x_rad", "gyro_y_rad", "gyro_z_rad", "accel_x_mps", "accel_y_mps",
               "accel_z_mps", "encoder_rad")
#: header of the pulse-count CSV form (weights ``gyro_pulse_arcsec``, ``accel_pulse_mps`` in meta)
PULSE_COLUMNS = ("t_s", "gyro_x_pulses", "gyro_y_pulses", "gyro_z_pulses", "accel_x_pulses",
                 "accel_y_pulses", "accel_z_pulses", "encoder_rad")
_CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
#: specific force on a static base, m/s^2: the accelerometer units check allows [G_MIN, G_MAX]
G_MIN, G_MAX = 5.0, 15.0
#: the gyros' rate over the encoder's must lie in [1 / RATE_RATIO_MAX, RATE_RATIO_MAX]
RATE_RATIO_MAX = 1.25
#: an interval longer than this times the median interval is a gap
GAP_FACTOR = 1.5


@dataclass(frozen=True, eq=False)
class RawLog:
    """A raw log (see the module docstring). Arrays are float64 and read-only.

    Attributes
    ----------
    t : numpy.ndarray, shape (n,)
        Timestamps, s.
    gyro : numpy.ndarray, shape (n, 3)
        Gyro angle increments, rad.
    accel : numpy.ndarray, shape (n, 3)
        Velocity increments, m/s.
    encoder : numpy.ndarray, shape (n,)
        Table angle at each timestamp, rad, unwrapped.
    meta : dict
        Metadata (see the module docstring).
    """

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    encoder: np.ndarray
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        arrays = validate_rawlog(self.t, self.gyro, self.accel, self.encoder)
        for name, arr in zip(("t", "gyro", "accel", "encoder"), arrays):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "meta", dict(self.meta))

    @classmethod
    def _trusted(cls, t, gyro, accel, encoder, meta):
        """Build without the O(n) checks, for arrays the simulator made itself."""
        obj = object.__new__(cls)
        for name, arr in (("t", t), ("gyro", gyro), ("accel", accel), ("encoder", encoder)):
            arr = np.asarray(arr, dtype=float)
            arr.setflags(write=False)
            object.__setattr__(obj, name, arr)
        object.__setattr__(obj, "meta", dict(meta))
        return obj

    def __len__(self):
        return self.t.shape[0]

    @property
    def sample_period(self):
        """Median sample period, s."""
        return float(np.median(np.diff(self.t)))


def validate_rawlog(t, gyro, accel, encoder, *, copy=True):
    """Check and normalise raw-log arrays; returns ``(t, gyro, accel, encoder)`` as float64
    (the encoder unwrapped), copies unless ``copy=False``. Raises ValueError naming the first
    offending sample index."""
    asarray = np.array if copy else np.asarray
    t = asarray(t, dtype=float)
    gyro = asarray(gyro, dtype=float)
    accel = asarray(accel, dtype=float)
    encoder = asarray(encoder, dtype=float)
    if t.ndim != 1:
        raise ValueError(f"raw log t_s has shape {t.shape}; allowed: 1-D, one timestamp per sample")
    n = t.shape[0]
    if n < 3:
        raise ValueError(f"raw log has {n} samples; allowed: at least 3")
    for name, arr, shape in (("gyro_rad", gyro, (n, 3)), ("accel_mps", accel, (n, 3)),
                             ("encoder_rad", encoder, (n,))):
        if arr.shape != shape:
            raise ValueError(f"raw log {name} has shape {arr.shape}; allowed {shape} (one row per timestamp)")
    for name, arr in (("t_s", t), ("gyro_rad", gyro), ("accel_mps", accel), ("encoder_rad", encoder)):
        bad = ~np.isfinite(arr)
        if bad.any():
            idx = int(np.argmax(bad.reshape(n, -1).any(axis=1)))
            raise ValueError(f"raw log {name} is not finite (NaN or inf) at sample index {idx}; allowed: finite "
                             "numbers")
    dt = np.diff(t)
    if (dt <= 0).any():
        idx = int(np.argmax(dt <= 0)) + 1
        raise ValueError(f"raw log timestamps are not strictly increasing at sample index {idx} "
                         f"(t_s[{idx}] = {float(t[idx])!r} <= t_s[{idx - 1}] = {float(t[idx - 1])!r}); allowed: "
                         "increasing times, one sample each")
    med = float(np.median(dt))
    gap = dt > GAP_FACTOR * med
    if gap.any():
        idx = int(np.argmax(gap)) + 1
        raise ValueError(f"raw log has a gap before sample index {idx} (t_s = {t[idx]:.6f}): interval "
                         f"{dt[idx - 1]:.6g} s, median {med:.6g} s (allowed <= {GAP_FACTOR} x median)")
    step = np.diff(encoder)
    if (np.abs(step) > np.pi).any():
        encoder = np.unwrap(encoder)
        step = np.diff(encoder)
    big = np.abs(step) > np.pi / 2
    if big.any():
        idx = int(np.argmax(big)) + 1
        raise ValueError(f"raw log encoder_rad jumps by {step[idx - 1]:.6g} rad at sample index {idx} "
                         f"(t_s = {t[idx]:.6f}): allowed < pi/2 per sample")
    return t, gyro, accel, encoder


def check_rawlog(log):
    """What a real recording can get wrong beyond :func:`validate_rawlog`; ValueError naming
    the channel, the samples and what is allowed.

    * A gyro or accelerometer channel that is zero in every sample (dead or unconnected).
    * Units. On a static base each sample's specific force has the magnitude of gravity
      whatever the attitude: the median of ``|accel_k| / dt`` must lie in [5, 15] m/s^2
      (velocity increments in m/s, not g or cm/s). The gyros turn with the table: the median
      of ``|gyro_k| / dt`` (rad/s; Earth rate aside) must match the encoder's mean rate within
      a factor 1.25 (increments in rad, not deg, arcsec or raw pulses; an encoder in rad).

    Parameters
    ----------
    log : RawLog
    """
    n = len(log)
    for j, name in enumerate(_CHANNELS):
        x = (log.gyro if j < 3 else log.accel)[:, j % 3]
        if not x[1:].any():
            raise ValueError(f"raw log {name} is zero in every sample (sample index 1 to {n - 1}): a dead or "
                             "unconnected channel; allowed: a recorded channel")
    # medians over every 7th sample: the units are off by factors of 10 and more, when at all
    sub = slice(1, None, 7)
    dt = (log.t[1:] - log.t[:-1])[::7]
    acc, gyr = log.accel[sub], log.gyro[sub]
    f = np.median(np.sqrt(np.einsum("ij,ij->i", acc, acc)) / dt)
    if not G_MIN <= f <= G_MAX:
        raise ValueError(f"raw log accel_mps: the specific force is {f:.4g} m/s^2 (median over sample index 1 "
                         f"to {n - 1}); allowed: {G_MIN:g}-{G_MAX:g} m/s^2 on a static base (velocity "
                         "increments in m/s: about 1 is g s, 981 cm/s)")
    span = log.encoder[-1] - log.encoder[0]
    table = abs(span) / (log.t[-1] - log.t[0])
    if table > 0.1 * units.DEG_PER_S:   # a table at rest: the alignment itself says so
        w = np.median(np.sqrt(np.einsum("ij,ij->i", gyr, gyr)) / dt)
        ratio = w / table
        if not 1 / RATE_RATIO_MAX <= ratio <= RATE_RATIO_MAX:
            raise ValueError(f"raw log gyro_rad and encoder_rad disagree: the gyros turn at {w:.4g} rad/s, the "
                             f"encoder at {table:.4g} rad/s (median over sample index 1 to {n - 1}; ratio "
                             f"{ratio:.4g}: 57.3 is degrees, 206265 arcsec, 1/57.3 an encoder in degrees); "
                             "allowed: both in rad, ratio within 1.25")


def save_rawlog(log, path, *, pulse_weights=None):
    """Write ``log`` to ``path`` (``.npz``; or ``.csv`` with a ``.json`` sidecar for meta),
    each file whole or not at all.

    ``pulse_weights = (gyro_pulse, accel_pulse)`` (rad, m/s; one number or three each)
    writes the pulse-count CSV form: the increments divided by the weights, which must give
    whole numbers (the log's own quanta), and the weights in the sidecar.
    """
    path = os.fspath(path)
    if path.endswith(".csv"):
        meta, header, inc = dict(log.meta), CSV_COLUMNS, np.column_stack([log.gyro, log.accel])
        if pulse_weights is not None:
            wg, wa = (np.broadcast_to(np.asarray(w, dtype=float), (3,)) for w in pulse_weights)
            counts = inc / np.concatenate([wg, wa])
            whole = np.round(counts)
            if not np.all(np.abs(counts - whole) <= 1e-6 * np.maximum(1.0, np.abs(whole))):
                raise ValueError(f"{path}: the increments are not whole multiples of the pulse weights; allowed: pulse "
                         "counts times the weights given")
            inc = whole
            header = PULSE_COLUMNS
            meta["gyro_pulse_arcsec"] = (wg / units.ARCSEC).tolist()
            meta["accel_pulse_mps"] = wa.tolist()
        data = np.column_stack([log.t, inc, log.encoder])
        with atomic_path(path) as tmp:
            np.savetxt(tmp, data, delimiter=",", header=",".join(header), comments="", fmt="%.17g")
        with atomic_path(path + ".json") as tmp, open(tmp, "w", encoding="utf-8") as fh:
            json.dump(meta, fh, indent=1, sort_keys=True)
        return
    if pulse_weights is not None:
        raise ValueError(f"{path}: pulse counts are a CSV form; allowed: a .csv path with pulse_weights")
    if not path.endswith(".npz"):
        raise ValueError(f"{path}: not a raw log; allowed: files ending in .npz or .csv")
    with atomic_path(path) as tmp:
        np.savez(tmp, t_s=log.t, gyro_rad=log.gyro, accel_mps=log.accel, encoder_rad=log.encoder,
                 meta_json=np.array(json.dumps(log.meta, sort_keys=True)))


def _weights(meta, key, factor, given=None):
    """A pulse weight from meta: one positive number or three -> (3,) in SI; ``given`` (SI,
    one or three: the lab calibration's) serves when meta has none, and must agree with it
    (relative 1e-9) when both do."""
    if key not in meta:
        if given is not None:
            return np.broadcast_to(np.asarray(given, dtype=float), (3,))
        raise ValueError(f"pulse counts need the pulse weight '{key}' in the .json sidecar (or meta, or the "
                         "calibration file); allowed: one positive number or three")
    try:
        w = np.asarray(meta[key], dtype=float) * factor
    except (TypeError, ValueError):
        w = np.array(np.nan)
    if w.shape not in ((), (3,)) or not np.all(np.isfinite(w) & (w > 0)):
        raise ValueError(f"meta '{key}' = {meta[key]!r}; allowed: one positive number or three")
    w = np.broadcast_to(w, (3,))
    if given is not None and not np.allclose(w, given, rtol=1e-9, atol=0):
        cal = ", ".join(f"{x:.10g}" for x in np.broadcast_to(np.asarray(given, dtype=float), (3,)) / factor)
        raise ValueError(f"meta '{key}' = {meta[key]!r} and the calibration file's pulse weight [{cal}] differ; "
                         "allowed: one pulse weight (or only one of them)")
    return w


def _read_csv(path):
    """(header, data (n, 8)) of a raw-log CSV, column-major (each channel contiguous, as the
    quality checks' compiled passes read them: :mod:`hse_opt.align._compiled`); a short or
    malformed line names its sample."""
    with open(path, encoding="utf-8") as fh:
        header = [h.strip() for h in fh.readline().split(",")]
        text = fh.read()
    lines = text.splitlines()
    if not any(line.strip() for line in lines):  # (np.loadtxt would warn and give one column)
        raise ValueError(f"no samples below the header; allowed: the header, then one row of {len(header)} "
                         "values per sample")
    try:
        data = np.loadtxt(lines, delimiter=",", ndmin=2, dtype=float)
    except ValueError as exc:
        for k, line in enumerate(lines):
            fields = line.split(",")
            if len(fields) != len(header):
                end = " (the file is truncated)" if k == len(lines) - 1 else ""
                raise ValueError(f"sample index {k} (line {k + 2}) has {len(fields)} fields, the header "
                                 f"{len(header)}{end}; allowed: one value per column") from None
            for name, v in zip(header, fields):
                try:
                    if not v.strip().isascii():  # float() reads '１２': numpy does not
                        raise ValueError(v)
                    float(v)
                except ValueError:
                    raise ValueError(f"sample index {k} (line {k + 2}), column {name}: {v.strip()!r} is not a "
                                     "number; allowed: decimal numbers, comma-separated") from None
        raise ValueError(f"{' '.join(str(exc).split())}; allowed: decimal numbers, comma-separated") from None
    if data.shape[1] != len(header):
        raise ValueError(f"{data.shape[1]} values per row, the header {len(header)}; allowed: one value per "
                         "column")
    if text and not text.endswith("\n"):
        raise ValueError(f"the file is truncated: its last line (sample index {data.shape[0] - 1}) has no line "
                         "end; allowed: whole lines")
    return header, np.asfortranarray(data)


def _read_npz(path):
    """The arrays of a ``.npz`` file, name -> array.

    Stored (uncompressed) members, as :func:`save_rawlog` writes them, are read into one
    buffer, each at a 64-byte boundary (one read each, without the CRC checks of
    :func:`numpy.load`): a member's data sits at any byte of the file, and a view of it there
    would be unaligned, which makes every later operation go through numpy's buffered copies
    (the checks and the alignment of a 10-minute log: 2.5 and 1.4 times the instructions). A
    truncated file still fails: the zip directory sits at its end, and a member must fit before
    it. Compressed members go through :func:`numpy.load`.
    """
    import io
    import struct
    import zipfile

    with open(path, "rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        try:
            infos = zipfile.ZipFile(fh).infolist()
        except zipfile.BadZipFile as exc:
            raise ValueError(f"is truncated or not a numpy .npz archive ({exc}); allowed: a whole .npz raw "
                             "log") from None
        if any(i.compress_type != zipfile.ZIP_STORED for i in infos):
            with np.load(path, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        # one buffer for all members, each at a 64-byte boundary in it (one allocation, as a
        # whole-file read: separate arrays cost twice the page faults of a fresh allocation)
        buf, out = np.empty(size + 64 * (len(infos) + 1), dtype=np.uint8), {}
        pos = -buf.ctypes.data % 64
        for info in infos:
            fh.seek(info.header_offset + 26)
            name_len, extra_len = struct.unpack("<HH", fh.read(4))
            start = info.header_offset + 30 + name_len + extra_len
            fh.seek(start)
            member = io.BytesIO(fh.read(min(info.file_size, 65536)))
            version = np.lib.format.read_magic(member)
            read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                           else np.lib.format.read_array_header_2_0)
            shape, fortran, dtype = read_header(member)
            count = int(np.prod(shape, dtype=np.int64))
            if start + member.tell() + count * dtype.itemsize > size or dtype.hasobject:
                raise ValueError(f"array {info.filename} is truncated; allowed: a whole .npz raw log")
            nbytes = count * dtype.itemsize
            fh.seek(start + member.tell())
            if fh.readinto(memoryview(buf[pos:pos + nbytes])) != nbytes:
                raise ValueError(f"array {info.filename} is truncated; allowed: a whole .npz raw log")
            arr = buf[pos:pos + nbytes].view(dtype)
            pos += nbytes + -(buf.ctypes.data + pos + nbytes) % 64
            out[info.filename.removesuffix(".npy")] = arr.reshape(shape, order="F" if fortran else "C")
    return out


def load_rawlog(path, meta=None, *, check=True, pulse_weights=None):
    """Read a raw log (``.npz`` or ``.csv``, either CSV form); ``meta`` entries override the
    file's metadata.

    ``check`` also runs :func:`check_rawlog` (dead channels, units). ``pulse_weights =
    (gyro, accel)`` (rad, m/s; one number or three each; the lab calibration's) convert a
    pulse-count CSV whose sidecar gives no weights; a sidecar weight that differs is an error.

    Raises
    ------
    hse_opt.data.DataError
        (a ValueError) The file is missing, not a regular file (a directory, a FIFO), not
        readable, malformed, truncated, its metadata no JSON object, or it fails
        :func:`validate_rawlog` / :func:`check_rawlog` (the message names the file, and the
        sample index where one applies).
    """
    path = os.fspath(path)
    if meta is not None and not isinstance(meta, dict):
        raise DataError(path, f"meta is a {type(meta).__name__}; allowed: a dict (key -> value)")
    try:
        _regular_file(path)
        if path.endswith(".npz"):
            z = _read_npz(path)
            missing = [k for k in ("t_s", "gyro_rad", "accel_mps", "encoder_rad") if k not in z]
            if missing:
                raise ValueError(f"missing arrays {missing}; allowed: an .npz with t_s, gyro_rad, accel_mps and "
                                 "encoder_rad")
            file_meta = _meta_object(path, "meta_json", str(z["meta_json"])) if "meta_json" in z else {}
            arrays = (z["t_s"], z["gyro_rad"], z["accel_mps"], z["encoder_rad"])
        elif path.endswith(".csv"):
            header, data = _read_csv(path)
            file_meta = {}
            if os.path.lexists(path + ".json"):
                _regular_file(path + ".json")
                with open(path + ".json", encoding="utf-8") as fh:
                    file_meta = _meta_object(path + ".json", "the sidecar", fh.read())
            file_meta.update(meta or {})
            enc = header[-1:]
            enc_factor = {"encoder_rad": 1.0, "encoder_deg": units.DEG}.get(enc[0] if enc else "")
            if tuple(header[:-1]) == CSV_COLUMNS[:-1] and enc_factor:
                gyro, accel = data[:, 1:4], data[:, 4:7]
            elif tuple(header[:-1]) == PULSE_COLUMNS[:-1] and enc_factor:
                counts = data[:, 1:7]
                frac = np.abs(counts - np.round(counts)) > 1e-9
                if frac.any():
                    k, j = np.argwhere(frac)[0]
                    raise ValueError(f"sample index {k}, column {PULSE_COLUMNS[1 + j]}: {counts[k, j]!r} is not a "
                                     "whole number; allowed: pulse counts")
                wg, wa = (None, None) if pulse_weights is None else pulse_weights
                gyro = counts[:, :3] * _weights(file_meta, "gyro_pulse_arcsec", units.ARCSEC, wg)
                accel = counts[:, 3:] * _weights(file_meta, "accel_pulse_mps", 1.0, wa)
            else:
                raise ValueError(f"header {header}; allowed: {list(CSV_COLUMNS)} or {list(PULSE_COLUMNS)} (the "
                                 "encoder as encoder_rad or encoder_deg)")
            arrays = (data[:, 0], gyro, accel, data[:, 7] * enc_factor)
        else:
            raise ValueError("not a raw log; allowed: files ending in .npz or .csv")
        m = dict(file_meta)
        m.update(meta or {})
        t, gyro, accel, encoder = validate_rawlog(*arrays, copy=False)  # the arrays are the loader's own
        log = RawLog._trusted(t, gyro, accel, encoder, m)
        if check:
            check_rawlog(log)
        return log
    except DataError:
        raise
    except ValueError as exc:
        raise DataError(path, str(exc)) from None
    except OSError as exc:
        raise DataError(path, f"cannot read: {exc.strerror or exc}; allowed: a readable raw-log file") from None


def _regular_file(path):
    """DataError unless ``path`` is a regular file (a FIFO would block the reader, a directory or
    device is no log); OSError (no such file) as :func:`os.stat` raises it."""
    mode = os.stat(path).st_mode
    if not stat.S_ISREG(mode):
        kind = "a directory" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode) else "not a regular file"
        raise DataError(path, f"is {kind}; allowed: a regular raw-log file (.npz, .csv, .csv.json)")


def _meta_object(source, what, text):
    """The metadata dict of a JSON text; DataError naming ``source`` if it is no JSON object."""
    try:
        meta = json.loads(text)
    except ValueError as exc:
        raise DataError(source, f"{what} is not valid JSON ({exc}); allowed: a JSON object") from None
    if not isinstance(meta, dict):
        raise DataError(source, f"{what} is a JSON {type(meta).__name__}; allowed: a JSON object "
                                "(key -> value)")
    return meta
