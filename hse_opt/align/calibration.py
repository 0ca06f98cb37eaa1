"""The system's lab calibration (``CALIBRATION.toml``): what the alignment processor applies to
a raw log before it aligns it.

A lab calibration is the maker's estimate of the system's geometry, made once in the lab
(``docs/conventions.md``): the gyro matrix K~_g (Eq. 1), the accelerometer matrix, and the mount C~_s^b
(Eq. 2; or the rotation axis r_zb^s it is built from). The processor applies these estimates;
whatever they miss (the eps of Eq. 1, the xi of Eq. 2, the accelerometers' residual scale
factors and misalignments) is the system's residual error, which the heading-sensitive-error
calibration (``hse-opt fit``) deals with. ``hse-opt simulate --write-calibration`` writes the
lab calibration of a simulated system: its *calibrated* matrices, not its true ones.

File format (TOML; the unit is in every key that has one; matrices are dimensionless, rows
``[[r0], [r1], [r2]]``; ``docs/calibration.md`` documents every key):

``[gyro]``
    ``K_g`` (3x3, required) gyro outputs (the log's ``gyro_rad`` columns, x_g y_g z_g) -> s;
    ``pulse_arcsec`` (optional, one number or three) the RLG pulse weight: read only for
    pulse-count logs whose sidecar gives none, and it tunes the filter's quantization noise.
``[accel]``
    ``K_a`` (3x3, required) accelerometer outputs (the log's ``accel_mps`` columns) -> s;
    ``pulse_mps`` (optional, one number or three) the velocity pulse weight (as the gyro's).
``[mount]``
    ``C_s_b`` (3x3) s -> b, or ``r_zb_s`` (3, a unit vector) the rotation axis z_b in s as the
    paper calibrates it (forward and backward turns), C_s^b then by the paper's closed form
    (:func:`hse_opt.align.rotations.c_b_s`); exactly one of the two.
``[noise]`` (optional: a figure it leaves out is measured from the logs)
    ``gyro_arw_dph_rthz`` (one number or three: x_g, y_g, z_g) the gyros' angle random walk,
    deg/h/sqrt(Hz) (TRUTH.toml's unit; 1 deg/sqrt(h) = 60 deg/h/sqrt(Hz));
    ``accel_vrw_ug_rthz`` (one number or three) the accelerometers' white noise, ug/sqrt(Hz).
``[encoder]`` (optional)
    ``counts_per_rev`` the table encoder's counts per revolution: the quality checks' encoder
    quantum (:func:`hse_opt.align.quality.assess`).
``[site]`` (optional)
    ``latitude_deg`` for logs whose metadata gives none; a log whose ``latitude_deg`` differs
    is an error naming both.

A file with just ``gyro.K_g``, ``accel.K_a`` and ``mount.C_s_b`` (or ``mount.r_zb_s``) is
complete; an example ships in the package
(:func:`hse_opt.datasets.calibration_example_path`). Without a file the processor assumes the orthogonal system of
:meth:`LabCalibration.orthogonal`: orthogonal gyro and accelerometer axes along s and the
paper's ideal mount (every gyro axis at 54.74 deg from the rotation axis).
"""
from __future__ import annotations

import difflib
import math
import sys
from dataclasses import dataclass
from decimal import Decimal

import numpy as np

from hse_opt import units
from hse_opt.align.processor import AlignConfig, _mat
from hse_opt.align.rotations import R_ZB_S_IDEAL, c_b_s
from hse_opt.data import DataError, read_text, write_text_atomic
from hse_opt.data.decimals import _to_si, _to_text

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["LabCalibration", "load_calibration", "save_calibration", "calibration_from_dict"]

#: singular values of K_g and K_a allowed: outputs in the log's units within a factor 1.25 of s
#: (a matrix in deg or arcsec, or a singular one, is refused)
GAIN_MIN, GAIN_MAX = 0.8, 1.25
#: largest |C C^T - I| of C_s_b, and |1 - |r_zb_s|| (the small angles of Eq. 2 are ~1e-5)
ORTHO_TOL = 1e-3

_SCHEMA = {
    "gyro": ("K_g", "pulse_arcsec"),
    "accel": ("K_a", "pulse_mps"),
    "mount": ("C_s_b", "r_zb_s"),
    "noise": ("gyro_arw_dph_rthz", "accel_vrw_ug_rthz"),
    "encoder": ("counts_per_rev",),
    "site": ("latitude_deg",),
}


@dataclass(frozen=True)
class LabCalibration:
    """A system's lab calibration (SI).

    Attributes
    ----------
    K_g : 3x3 nested tuple
        Calibrated gyro matrix K~_g, gyro outputs (rad) -> s.
    K_a : 3x3 nested tuple
        Calibrated accelerometer matrix, outputs (m/s) -> s.
    C_s_b : 3x3 nested tuple
        Calibrated mount C~_s^b, s -> b.
    gyro_pulse, accel_pulse : tuple of 3 float or None
        Pulse weights, rad and m/s (x, y, z); None: not given.
    arw : float, tuple of 3 float, or None
        Gyro angle random walk, rad/sqrt(s): one for all three gyros or one each (x_g, y_g,
        z_g); None: measured from the data.
    vrw : float, tuple of 3 float, or None
        Accelerometer white noise, m/s/sqrt(s), one or one each; None: measured from the data.
    latitude : float or None
        rad; used for logs whose metadata gives none.
    encoder_counts_per_rev : float or None
        The table encoder's counts per revolution (the quality checks' encoder quantum);
        None: not given.
    source : str
        Where it came from (a file name), for messages.
    """

    K_g: tuple
    K_a: tuple
    C_s_b: tuple
    gyro_pulse: tuple | None = None
    accel_pulse: tuple | None = None
    arw: float | None = None
    vrw: float | None = None
    latitude: float | None = None
    encoder_counts_per_rev: float | None = None
    source: str = "<calibration>"

    def __post_init__(self):
        for name in ("K_g", "K_a"):
            m = _matrix(self.source, name, getattr(self, name))
            sv = np.linalg.svd(m, compute_uv=False)
            if not (GAIN_MIN <= sv.min() and sv.max() <= GAIN_MAX):
                raise DataError(self.source, f"{name} has gains {sv.min():.6g}..{sv.max():.6g}; allowed: "
                                f"{GAIN_MIN:g}-{GAIN_MAX:g} (outputs in rad and m/s mapped to s: a matrix near a "
                                "rotation, not in deg or arcsec, not singular)")
            object.__setattr__(self, name, _mat(m))
        m = _matrix(self.source, "C_s_b", self.C_s_b)
        off = float(np.abs(m @ m.T - np.eye(3)).max())
        if off > ORTHO_TOL or np.linalg.det(m) <= 0:
            raise DataError(self.source, f"C_s_b is not a rotation (|C C^T - I| = {off:.3g}, det "
                            f"{np.linalg.det(m):.6g}); allowed: a proper rotation within {ORTHO_TOL:g}")
        object.__setattr__(self, "C_s_b", _mat(m))
        for name in ("gyro_pulse", "accel_pulse"):
            v = getattr(self, name)
            if v is not None:
                w = np.broadcast_to(np.asarray(v, dtype=float), (3,))
                if not np.all(np.isfinite(w) & (w > 0)):
                    raise DataError(self.source, f"{name} = {v!r}; allowed: one positive number or three")
                object.__setattr__(self, name, tuple(float(x) for x in w))
        for name in ("arw", "vrw"):
            v = getattr(self, name)
            if v is not None:
                w = np.asarray(v, dtype=float) if _numbers(v, ()) or _numbers(v, (3,)) else None
                if w is None or not np.all(np.isfinite(w) & (w >= 0)):
                    raise DataError(self.source, f"{name} = {v!r}; allowed: one number >= 0 or three")
                object.__setattr__(self, name, float(w) if w.ndim == 0 else tuple(float(x) for x in w))
        c = self.encoder_counts_per_rev
        if c is not None and not (_numbers(c, ()) and math.isfinite(c) and c >= 1):
            raise DataError(self.source, f"encoder.counts_per_rev = {c!r}; allowed: a number >= 1")
        if self.latitude is not None and not abs(self.latitude) < math.radians(89.0):
            raise DataError(self.source, f"latitude_deg = {self.latitude / units.DEG:g}; allowed: |latitude| < 89")

    @classmethod
    def orthogonal(cls):
        """The processor's default: orthogonal gyro and accelerometer axes along s (K_g = K_a
        = I) and the paper's ideal mount, r_zb^s = -(1, 1, 1)/sqrt(3); no noise, no latitude."""
        return cls(K_g=_mat(np.eye(3)), K_a=_mat(np.eye(3)), C_s_b=_mat(c_b_s(R_ZB_S_IDEAL).T),
                   source="<orthogonal calibration>")

    @property
    def pulse_weights(self):
        """``(gyro_pulse, accel_pulse)`` for :func:`hse_opt.align.load_rawlog` when both are
        given, else None."""
        if self.gyro_pulse is None or self.accel_pulse is None:
            return None
        return self.gyro_pulse, self.accel_pulse

    @property
    def has_noise(self):
        """Whether the calibration gives every noise figure the filter needs (:meth:`noise_given`)."""
        return all(self.noise_given().values())

    def noise_given(self):
        """Which of the filter's noise figures (:data:`hse_opt.align.batch.NOISE_FIGURES`: the
        gyros' ARW, the accelerometers' VRW, the two quanta) this calibration gives, name ->
        bool; the others are measured from the logs (``align_logs(..., tune_from_data=...)``)."""
        return {"arw": self.arw is not None, "vrw": self.vrw is not None,
                "gyro_pulse": self.gyro_pulse is not None, "accel_pulse": self.accel_pulse is not None}

    def align_config(self, **overrides):
        """The processor's settings (:class:`hse_opt.align.AlignConfig`): these matrices, the
        latitude, the encoder's counts, the noise and the pulse weights where given (one per
        axis when three differ), the :class:`~hse_opt.align.AlignConfig` defaults elsewhere
        (the figures a calibration leaves out are measured from the logs by
        :func:`hse_opt.align.align_logs`); ``overrides`` replace any field."""
        kw = dict(K_g_cal=self.K_g, C_s_b_cal=self.C_s_b, A_acc_cal=self.K_a, latitude=self.latitude,
                  encoder_counts_per_rev=self.encoder_counts_per_rev)
        for field_, value in (("arw", self.arw), ("vrw", self.vrw), ("gyro_pulse", self.gyro_pulse),
                              ("accel_pulse", self.accel_pulse)):
            if value is not None:
                kw[field_] = _one_or_three(value)
        kw.update(overrides)
        return AlignConfig(**kw)

    def to_toml(self):
        """The ``CALIBRATION.toml`` text: every given key, with a comment line per key; reading
        it back (:func:`load_calibration`) gives exactly this calibration."""
        def num(x, factor=1.0):
            return _to_text(x, factor)

        def mat(m):
            return "[" + ", ".join("[" + ", ".join(num(x) for x in row) + "]" for row in m) + "]"

        def vec(v, factor):
            return "[" + ", ".join(num(x, factor) for x in v) + "]"

        out = ["# Lab calibration of one rotating RLG system (hse-opt align --calibration); keys: "
               "docs/calibration.md", "", "[gyro]",
               "# K~_g: gyro outputs (gyro_rad columns x_g, y_g, z_g) -> s, dimensionless",
               f"K_g = {mat(self.K_g)}"]
        if self.gyro_pulse is not None:
            out += ["# RLG pulse weight, arcsec (x, y, z): for pulse-count logs without weights",
                    f"pulse_arcsec = {vec(self.gyro_pulse, units.ARCSEC)}"]
        out += ["", "[accel]", "# accelerometer outputs (accel_mps columns) -> s, dimensionless",
                f"K_a = {mat(self.K_a)}"]
        if self.accel_pulse is not None:
            out += ["# velocity pulse weight, m/s (x, y, z)", f"pulse_mps = {vec(self.accel_pulse, 1.0)}"]
        out += ["", "[mount]", "# C~_s^b: s -> b (b: the table top, z_b down along the rotation axis)",
                f"C_s_b = {mat(self.C_s_b)}"]
        def one_or_vec(v, factor):
            return num(v, factor) if isinstance(v, float) else vec(v, factor)

        if self.arw is not None or self.vrw is not None:
            out += ["", "[noise]", "# the filter's tuning, one number or three (x, y, z); a figure left out is "
                    "measured from the logs"]
            if self.arw is not None:
                out.append(f"gyro_arw_dph_rthz = {one_or_vec(self.arw, units.DEG_PER_H)}")
            if self.vrw is not None:
                out.append(f"accel_vrw_ug_rthz = {one_or_vec(self.vrw, units.MICRO_G)}")
        if self.encoder_counts_per_rev is not None:
            out += ["", "[encoder]", "# the table encoder's counts per revolution (the quality checks' quantum)",
                    f"counts_per_rev = {num(self.encoder_counts_per_rev)}"]
        if self.latitude is not None:
            out += ["", "[site]", "# for logs without latitude_deg in their metadata",
                    f"latitude_deg = {num(self.latitude, units.DEG)}"]
        return "\n".join(out) + "\n"


def _one_or_three(v):
    """A float for one number or three equal ones, else the tuple of three."""
    if isinstance(v, tuple):
        return v[0] if v[0] == v[1] == v[2] else v
    return v


def _matrix(source, name, value):
    m = np.asarray(value, dtype=float) if _numbers(value, (3, 3)) else None
    if m is None or m.shape != (3, 3) or not np.isfinite(m).all():
        raise DataError(source, f"{name} = {_shown(value)!r}; allowed: a 3x3 matrix of finite numbers "
                        "[[r0], [r1], [r2]]")
    return m


def _numbers(value, shape):
    """Whether ``value`` is a nested list of real numbers (no bools, no text) of ``shape``."""
    if not shape:
        return isinstance(value, (int, float, Decimal, np.floating, np.integer)) and not isinstance(value, bool)
    if isinstance(value, np.ndarray):
        return value.shape == shape and value.dtype.kind in "fiu"
    return (isinstance(value, (list, tuple)) and len(value) == shape[0]
            and all(_numbers(v, shape[1:]) for v in value))


def _shown(raw):
    if isinstance(raw, (list, tuple)):
        return [_shown(v) for v in raw]
    return float(raw) if isinstance(raw, Decimal) else raw


def _si(source, where, raw, factor, n=None):
    """A number (n None) or one-or-n numbers (n given) in file units -> SI float / tuple."""
    try:
        if n is not None and _numbers(raw, (n,)):
            return tuple(_to_si(str(v), factor) for v in raw)
        if _numbers(raw, ()):
            v = _to_si(str(raw), factor)
            return v if n is None else (v,) * n
    except ValueError as exc:  # NaN, inf, 1e999
        raise DataError(source, f"{where} {' '.join(str(exc).split())[:80]}; allowed: finite numbers") from None
    allowed = "a number" if n is None else f"one number or {n}"
    raise DataError(source, f"{where} = {_shown(raw)!r}; allowed: {allowed}")


def _section(source, d, name):
    sec = d.get(name, {})
    if not isinstance(sec, dict):
        raise DataError(source, f"'{name}' must be a table [{name}]; allowed sections: "
                        + ", ".join(f"[{s}]" for s in _SCHEMA))
    for key in sec:
        if key not in _SCHEMA[name]:
            close = difflib.get_close_matches(key, _SCHEMA[name], n=1, cutoff=0.5)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise DataError(source, f"unknown key '{name}.{key}'{hint}; allowed in [{name}]: "
                            + ", ".join(_SCHEMA[name]))
    return sec


def calibration_from_dict(d, source="<calibration>"):
    """A :class:`LabCalibration` from a TOML-shaped dict (file units; see the module docstring)."""
    if not isinstance(d, dict):
        raise DataError(source, f"is {type(d).__name__}; allowed: the tables of CALIBRATION.toml")
    for name in d:
        if name not in _SCHEMA:
            close = difflib.get_close_matches(name, list(_SCHEMA), n=1, cutoff=0.5)
            hint = f" (did you mean [{close[0]}]?)" if close else ""
            raise DataError(source, f"unknown section [{name}]{hint}; allowed: "
                            + ", ".join(f"[{s}]" for s in _SCHEMA))
    gyro, accel, mount, noise, encoder, site = (_section(source, d, s) for s in _SCHEMA)
    for sec, key in (("gyro", "K_g"), ("accel", "K_a")):
        if key not in d.get(sec, {}):
            raise DataError(source, f"has no '{sec}.{key}'; allowed: a complete file gives gyro.K_g, accel.K_a "
                            "and mount.C_s_b (or mount.r_zb_s)")
    if ("C_s_b" in mount) == ("r_zb_s" in mount):
        raise DataError(source, "gives " + ("both 'mount.C_s_b' and 'mount.r_zb_s'" if mount else "no mount")
                        + "; allowed: exactly one of mount.C_s_b (3x3, s -> b) and mount.r_zb_s (3)")
    if "r_zb_s" in mount:
        r = mount["r_zb_s"]
        if not _numbers(r, (3,)) or not np.isfinite(np.asarray(r, dtype=float)).all():
            raise DataError(source, f"mount.r_zb_s = {_shown(r)!r}; allowed: 3 finite numbers (a unit vector)")
        r = np.asarray(r, dtype=float)
        norm = float(np.linalg.norm(r))
        if abs(norm - 1.0) > ORTHO_TOL:
            raise DataError(source, f"mount.r_zb_s has length {norm:.6g}; allowed: a unit vector "
                            f"(within {ORTHO_TOL:g})")
        C_s_b = c_b_s(r / norm).T
    else:
        C_s_b = mount["C_s_b"]
    kw = {}
    if "pulse_arcsec" in gyro:
        kw["gyro_pulse"] = _si(source, "gyro.pulse_arcsec", gyro["pulse_arcsec"], units.ARCSEC, 3)
    if "pulse_mps" in accel:
        kw["accel_pulse"] = _si(source, "accel.pulse_mps", accel["pulse_mps"], 1.0, 3)
    for key, field_, factor in (("gyro_arw_dph_rthz", "arw", units.DEG_PER_H),
                                ("accel_vrw_ug_rthz", "vrw", units.MICRO_G)):
        if key in noise:    # one number stays one (a file read back writes it as it was)
            v = _si(source, f"noise.{key}", noise[key], factor, 3)
            kw[field_] = v[0] if _numbers(noise[key], ()) else v
    if "counts_per_rev" in encoder:
        kw["encoder_counts_per_rev"] = _si(source, "encoder.counts_per_rev", encoder["counts_per_rev"], 1.0)
    if "latitude_deg" in site:
        kw["latitude"] = _si(source, "site.latitude_deg", site["latitude_deg"], units.DEG)
    return LabCalibration(K_g=_matrix(source, "gyro.K_g", gyro["K_g"]),
                          K_a=_matrix(source, "accel.K_a", accel["K_a"]),
                          C_s_b=_matrix(source, "mount.C_s_b", C_s_b), source=source, **kw)


def load_calibration(path):
    """Read ``CALIBRATION.toml`` (the file is only read).

    Raises
    ------
    hse_opt.data.DataError
        Not readable, not TOML, an unknown section or key (the closest valid one suggested), a
        missing matrix, a value outside what is allowed; the message names the file and key.
    """
    import os
    src = os.fspath(path)
    try:
        text = read_text(src, "a UTF-8 TOML file")
    except OSError as exc:
        raise DataError(src, f"cannot read the calibration: {exc.strerror or exc}; allowed: a CALIBRATION.toml "
                        "you can read") from None
    except UnicodeDecodeError as exc:
        raise DataError(src, f"is not UTF-8 text ({exc.reason} at byte {exc.start}); allowed: a UTF-8 "
                        "TOML file") from None
    try:
        d = tomllib.loads(text, parse_float=Decimal)
    except tomllib.TOMLDecodeError as exc:
        raise DataError(src, f"not valid TOML: {exc}; allowed: the sections of CALIBRATION.toml "
                        "(docs/calibration.md)") from None
    except RecursionError:
        raise DataError(src, "arrays or tables nested too deeply; allowed: the sections of "
                        "CALIBRATION.toml") from None
    return calibration_from_dict(d, source=src)


def save_calibration(calibration, path):
    """Write ``calibration`` as ``CALIBRATION.toml`` at ``path``, whole or not at all."""
    write_text_atomic(path, calibration.to_toml())
