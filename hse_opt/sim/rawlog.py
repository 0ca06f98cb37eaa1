"""Raw logs: the documented format of 500 Hz RLG / accelerometer / encoder records.

A raw log is what the alignment processor (:mod:`hse_opt.sim.align`) reads; simulated runs
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
``accel_mps``     (n, 3)      accelerometer velocity increments over ``(t_{k-1}, t_k]``, m/s
``encoder_rad``   (n,)        table angle alpha latched at ``t_k``, rad, about z_b (down),
                              zero at the zero-position indicator; multi-turn (unwrapped) or
                              wrapped to one turn -- the loader unwraps it
================  ==========  =============================================================

The first row's increments belong to an interval that has no encoder angle at its start;
the processor does not use them. Metadata (all optional, SI or unit-named): ``latitude_deg``
(required by the processor unless given to it), ``rate_dps`` (nominal), ``azimuth_deg``
(stand reading), ``t_start_s`` (time since power-on at ``t_0``), ``temp_c`` (mean IMU
temperature), ``source``.

Files
    ``.npz`` (numpy, the fast form): the four arrays under the names above plus ``meta_json``
    (a JSON object string). ``.csv``: one header row ``t_s, gyro_x_rad, gyro_y_rad,
    gyro_z_rad, accel_x_mps, accel_y_mps, accel_z_mps, encoder_rad``, one row per sample;
    metadata come from an optional sidecar ``<file>.json`` or the ``meta`` argument.

Checks (:func:`validate_rawlog`): matching shapes, at least 3 samples, every value finite,
timestamps strictly increasing and without gaps (no interval longer than 1.5 times the
median), encoder steps below half a turn. A failure is a ValueError naming the sample index.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

import numpy as np

from hse_opt.data import atomic_path

__all__ = ["RawLog", "validate_rawlog", "load_rawlog", "save_rawlog", "CSV_COLUMNS"]

CSV_COLUMNS = ("t_s", "gyro_x_rad", "gyro_y_rad", "gyro_z_rad", "accel_x_mps", "accel_y_mps",
               "accel_z_mps", "encoder_rad")
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


def validate_rawlog(t, gyro, accel, encoder):
    """Check and normalise raw-log arrays; returns ``(t, gyro, accel, encoder)`` as float64
    (the encoder unwrapped). Raises ValueError naming the first offending sample index."""
    t = np.array(t, dtype=float)
    gyro = np.array(gyro, dtype=float)
    accel = np.array(accel, dtype=float)
    encoder = np.array(encoder, dtype=float)
    if t.ndim != 1:
        raise ValueError(f"raw log t_s must be 1-D, got shape {t.shape}")
    n = t.shape[0]
    if n < 3:
        raise ValueError(f"raw log has {n} samples: at least 3 are required")
    for name, arr, shape in (("gyro_rad", gyro, (n, 3)), ("accel_mps", accel, (n, 3)),
                             ("encoder_rad", encoder, (n,))):
        if arr.shape != shape:
            raise ValueError(f"raw log {name} has shape {arr.shape}; allowed {shape} (one row per timestamp)")
    for name, arr in (("t_s", t), ("gyro_rad", gyro), ("accel_mps", accel), ("encoder_rad", encoder)):
        bad = ~np.isfinite(arr)
        if bad.any():
            idx = int(np.argmax(bad.reshape(n, -1).any(axis=1)))
            raise ValueError(f"raw log {name} is not finite (NaN or inf) at sample index {idx}")
    dt = np.diff(t)
    if (dt <= 0).any():
        idx = int(np.argmax(dt <= 0)) + 1
        raise ValueError(f"raw log timestamps are not strictly increasing at sample index {idx} "
                         f"(t_s[{idx}] = {t[idx]!r} <= t_s[{idx - 1}] = {t[idx - 1]!r})")
    med = float(np.median(dt))
    gap = dt > GAP_FACTOR * med
    if gap.any():
        idx = int(np.argmax(gap)) + 1
        raise ValueError(f"raw log has a gap before sample index {idx}: interval {dt[idx - 1]:.6g} s, "
                         f"median {med:.6g} s (allowed <= {GAP_FACTOR} x median)")
    step = np.diff(encoder)
    if (np.abs(step) > np.pi).any():
        encoder = np.unwrap(encoder)
        step = np.diff(encoder)
    big = np.abs(step) > np.pi / 2
    if big.any():
        idx = int(np.argmax(big)) + 1
        raise ValueError(f"raw log encoder_rad jumps by {step[idx - 1]:.6g} rad at sample index {idx}: "
                         "allowed < pi/2 per sample")
    return t, gyro, accel, encoder


def save_rawlog(log, path):
    """Write ``log`` to ``path`` (``.npz``; or ``.csv`` with a ``.json`` sidecar for meta),
    each file whole or not at all."""
    path = os.fspath(path)
    if path.endswith(".csv"):
        data = np.column_stack([log.t, log.gyro, log.accel, log.encoder])
        with atomic_path(path) as tmp:
            np.savetxt(tmp, data, delimiter=",", header=",".join(CSV_COLUMNS), comments="", fmt="%.17g")
        with atomic_path(path + ".json") as tmp, open(tmp, "w", encoding="utf-8") as fh:
            json.dump(log.meta, fh, indent=1, sort_keys=True)
        return
    if not path.endswith(".npz"):
        raise ValueError(f"{path}: raw log files end in .npz or .csv")
    with atomic_path(path) as tmp:
        np.savez(tmp, t_s=log.t, gyro_rad=log.gyro, accel_mps=log.accel, encoder_rad=log.encoder,
                 meta_json=np.array(json.dumps(log.meta, sort_keys=True)))


def load_rawlog(path, meta=None):
    """Read a raw log (``.npz`` or ``.csv``); ``meta`` entries override the file's metadata.

    Raises
    ------
    ValueError
        The file is malformed or fails :func:`validate_rawlog` (the message names the file
        and the sample index).
    """
    path = os.fspath(path)
    try:
        if path.endswith(".npz"):
            with np.load(path, allow_pickle=False) as z:
                missing = [k for k in ("t_s", "gyro_rad", "accel_mps", "encoder_rad") if k not in z]
                if missing:
                    raise ValueError(f"missing arrays {missing}")
                file_meta = json.loads(str(z["meta_json"])) if "meta_json" in z else {}
                arrays = (z["t_s"], z["gyro_rad"], z["accel_mps"], z["encoder_rad"])
        elif path.endswith(".csv"):
            with open(path, encoding="utf-8") as fh:
                header = [h.strip() for h in fh.readline().split(",")]
            if tuple(header) != CSV_COLUMNS:
                raise ValueError(f"header {header}; required {list(CSV_COLUMNS)}")
            data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
            file_meta = {}
            if os.path.exists(path + ".json"):
                with open(path + ".json", encoding="utf-8") as fh:
                    file_meta = json.load(fh)
            arrays = (data[:, 0], data[:, 1:4], data[:, 4:7], data[:, 7])
        else:
            raise ValueError("raw log files end in .npz or .csv")
        m = dict(file_meta)
        m.update(meta or {})
        return RawLog(*arrays, meta=m)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
