"""The true system of the simulator: a frozen configuration, loaded from and saved to TOML.

Everything is SI inside (rad, rad/s, s, m/s, m/s^2); the TOML file carries the unit in every
key name (``latitude_deg``, ``arw_dph_rthz``, ...). A key that is not in the schema, in any
section, is an error naming it and suggesting the closest valid key; it is never ignored.

Sections and keys (``TRUTH.toml``; defaults are the paper-like system of
:meth:`TruthConfig.default`, written out in ``hse_opt/datasets/truth_default.toml``; a file
may give any subset of keys, the rest keep their default values)

``[site]``
    ``latitude_deg``, ``gravity_mps2`` (local gravity).
``[timing]``
    ``sample_period_ms`` (2 ms in the paper).
``[table]`` (single-axis bias turntable; the signed rate itself is a run parameter, PLAN.csv)
    ``rate_error_ppm`` (true rate = commanded rate * (1 + error)), ``ripple_ppm`` (relative
    amplitude of a periodic rate ripple), ``ripple_order`` (its frequency in cycles per
    revolution), ``ripple_phase_deg``, ``jitter_arcsec`` (1-sigma of the table angle about
    the commanded turn, independent from sample to sample: the servo's position noise; the
    gyros and the encoder see the same angle, so it reaches the heading only through the
    quantizers, which it dithers).
``[encoder]``
    ``resolution_arcsec`` (0 = no quantization), ``sync_delay_us`` (the encoder angle is
    latched ``sync_delay_us`` *after* the gyro sample it is used with, i.e. it is late:
    ``alpha_meas(t) = alpha(t - dt)``), ``[[encoder.harmonics]]`` (periodic angle error
    ``sum a_h sin(h alpha + phi_h)``, each with ``order``, ``amplitude_arcsec``, ``phase_deg``).
``[gyro]``
    ``axes_nonorth_arcsec`` (true non-orthogonality of the gyro axes in s: y_g turned toward
    x_s, z_g turned toward x_s, z_g turned toward y_s; gives the true K_g),
    ``eps_arcsec`` (eps1..eps3 of Lambda: the lab-calibrated K~_g = (I + Lambda) K_g, Eq. 1),
    ``bias_dph`` (per gyro), ``axis_bias_dph`` (an extra bias vector along the rotation axis
    z_b, spread over the gyros), ``bias_warmup_dph`` with ``bias_warmup_tau_s`` (per-gyro bias
    transient ``b_w exp(-t_on / tau)`` after power-on), ``bias_tempco_dph_per_c`` (per gyro,
    against ``thermal.reference_c``), ``sf_error_ppm`` (per gyro), ``sf_nonlinearity_ppm_per_dps``
    (scale-factor error growing with the gyro's own input rate ``|w_i|``), ``arw_dph_rthz``
    (angle random walk, deg/h/sqrt(Hz) = deg/h * sqrt(s); 1 deg/sqrt(h) = 60 deg/h/sqrt(Hz)),
    ``pulse_arcsec`` (RLG pulse quantum; 0 = no quantization), ``lockin_dps`` (lock-in
    threshold on a gyro's input rate).
``[mount]`` (IMU on the table top)
    ``r_zb_s_true``, ``r_zb_s_calibrated`` (unit rotation axis in s, ideally all
    -1/sqrt(3)), ``xi_arcsec`` (the small-angle error of the calibrated C~_s^b, Eq. 2),
    ``warmup_xi_z_arcsec`` with ``warmup_tau_s`` (thermal rotation of the IMU mount about the
    rotation axis after power-on, ``xi_z(t_on) = a exp(-t_on / tau)``, added to the xi_z of
    Eq. 2), ``xi_z_tempco_arcsec_per_c`` (the same rotation following the temperature).
``[accel]``
    ``bias_ug``, ``sf_error_ppm``, ``nonorth_arcsec`` (y toward x, z toward x, z toward y),
    ``vrw_ug_rthz`` (white noise density), ``pulse_mps`` (velocity quantum; 0 = off).
``[stand]`` (the test stand carrying the turntable base; its azimuth is the heading reference)
    ``tilt_arcsec`` ([north, east] small rotation of the stand's axis, fixed in n),
    ``mount_tilt_arcsec`` ([x, y]: roll about x_b0 and pitch about y_b0 of the turntable base
    on the stand top, fixed in b0, so it turns with the stand azimuth; a plan's deliberate
    ``tilt_x_arcsec, tilt_y_arcsec`` add to it), ``azimuth_offset_arcsec`` and
    ``[[stand.azimuth_harmonics]]`` (true stand azimuth = reading + offset
    + ``sum a_h sin(h * reading + phi_h)``).
``[thermal]`` (IMU temperature against time since power-on ``t_on``)
    ``temp = ambient_c + rise_c (1 - exp(-t_on / tau_s)) + swing_c sin(2 pi t_on / swing_period_s + swing_phase_deg)``;
    ``reference_c`` is the temperature of the lab calibration.

The catalogue effects of the symbolic model and the keys that switch them on here are
:mod:`hse_opt.validation.twins` (the simulator does not know the model's effects).

The default system (:meth:`TruthConfig.default`)
------------------------------------------------
Chosen to resemble the paper's prototype and Table 1 (``paper_table1.csv``):

* latitude 28.07 deg (0.49 rad, the paper's worked example), 2 ms sampling, encoder
  resolution 0.18 arcsec, table rate ripple 100 ppm once per revolution (the paper's rate
  stability 1e-4), table-angle jitter 0.5 arcsec (a servo holding the table to a few
  encoder counts; it also dithers the pulse counters, see below).
* HSE: eps = (1.6, 1.2, 1.4) arcsec, lambda2 = 4.2 arcsec (the paper's calibrated value; the
  paper does not give the split). The base of the turntable is tilted on the stand top by
  roll -55 arcsec, pitch -120 arcsec (fixed in b0): with Eq. 14 at 40 deg/s this gives the
  heading-sensitive error that the paper compensated in Table 1 (the differences
  before - after compensation, -3.8, +8.5, +4.2, -9.0 arcsec at stand azimuths 0, 92, 181,
  273 deg, fit ``a cos(psi) + b sin(psi)`` with a = -4.0 and b = +8.8 arcsec).
* Warm-up (the paper's cold-start first position): mount rotation xi_z of -12 arcsec
  decaying with tau = 600 s after power-on, gyro bias transients of a few 1e-3 deg/h.
* Noise. The within-position (repeat) scatter of Table 1, pooled over positions 2-4 (the
  cold-start position 1 is left out: it also holds the warm-up drift), is 7.90 arcsec
  (6 degrees of freedom; 9.52 arcsec with position 1). For a gyrocompass the 10-minute
  heading scatter is ``sigma = N / (w_ie cos L sqrt(T))``, N the angle random walk, which
  gives N = 0.0124 deg/h/sqrt(Hz) for 7.90 arcsec. The accelerometer noise adds to it
  (it limits how well the filter sees the tilt drift: 10 ug/sqrt(Hz) would add 50 %), so
  the default accelerometer is quiet, 1 ug/sqrt(Hz), with 1e-4 m/s velocity pulses.
  RLG pulses add a random walk of their own, ``q |Omega| sqrt(dt / 12)``
  (:func:`hse_opt.align.quantization_arw`), once the table jitter dithers the counters;
  without it, at rates where a gyro's pulses per sample sit close to a simple fraction, the
  counter's remainder locks to the table angle and biases the heading (tens of arcsec at
  -40 deg/s for 0.5 arcsec pulses, ``tests/test_sim_imu.py``). The default readout
  resolves 0.1 arcsec (an interpolating fringe counter): 0.0009 deg/h/sqrt(Hz) at 40 deg/s,
  0.0014 at 60 deg/s, so the heading noise is the gyros' own. With those the processor's
  Kalman filter gives a 1-sigma of 7.92 arcsec for ``arw_dph_rthz = 0.0120``
  (2.0e-4 deg/sqrt(h)) at 40 deg/s, and 200 seeds scatter by the same
  (``studies/simulator_noise.py``). That is a very quiet gyro: the paper's repeat scatter
  is small.
* Realistic residuals that do not reach heading at first order: gyro biases of a few
  1e-3 deg/h, non-orthogonal true K_g (tens of arcsec; it cancels), r_zb^s 1e-3 away from
  ideal and calibrated to about 2 arcsec, xi = (3, -2, 0) arcsec, accelerometer biases of
  tens of ug, scale factors of tens of ppm, misalignments of 10 arcsec.
"""
from __future__ import annotations

import dataclasses
import difflib
import functools
import math
from dataclasses import dataclass, field
from decimal import Decimal

import numpy as np

from hse_opt import units
# the exact decimal <-> SI conversions and the atomic writer of the file formats (one
# implementation each, in hse_opt.data)
from hse_opt.data import atomic_path
from hse_opt.data.decimals import _to_si, _to_text
from hse_opt.align.rotations import R_ZB_S_IDEAL, c_b_s, skew

__all__ = [
    "Harmonic", "SiteConfig", "TimingConfig", "TableConfig", "EncoderConfig", "GyroConfig",
    "MountConfig", "AccelConfig", "StandConfig", "ThermalConfig", "TruthConfig", "RunSpec",
    "MAX_TILT", "RunError", "load_truth", "save_truth", "validate_run", "temperature",
    "gyro_matrices",
]

#: Largest tilt component accepted (stand, mount, plan), rad: 1 deg. The simulator itself is
#: exact at any tilt; the limit keeps runs inside the small-tilt domain of the paper's model
#: (first order in the tilt, Eq. 3) and catches tilts given in the wrong unit.
MAX_TILT = 3600.0 * units.ARCSEC

# Unit labels used in the TOML schema -> factor to SI (all factors from hse_opt.units).
_UNIT = {
    "1": 1.0, "deg": units.DEG, "arcsec": units.ARCSEC, "ms": units.MILLISECOND,
    "us": units.MICROSECOND, "ppm": units.PPM, "s": 1.0, "m/s": 1.0, "m/s^2": 1.0, "C": 1.0,
    "deg/h": units.DEG_PER_H, "deg/s": units.DEG_PER_S, "deg/h/rtHz": units.DEG_PER_H,
    "deg/h/C": units.DEG_PER_H, "ppm/(deg/s)": units.PPM / units.DEG_PER_S,
    "ug": units.MICRO_G, "ug/rtHz": units.MICRO_G, "arcsec/C": units.ARCSEC,
}


def _p(key, unit, default, *, n=None, lo=None, hi=None, integer=False, doc=""):
    """A schema field: TOML ``key`` in ``unit``; ``default`` given in that unit; bounds in it."""
    if n is None:
        dflt = int(default) if integer else _to_si(default, _UNIT[unit])
    else:
        dflt = tuple(_to_si(v, _UNIT[unit]) for v in default)
    return field(default=dflt, metadata=dict(key=key, unit=unit, n=n, lo=lo, hi=hi,
                                            integer=integer, doc=doc))


@dataclass(frozen=True)
class Harmonic:
    """One periodic error term ``amplitude * sin(order * angle + phase)``.

    Attributes
    ----------
    order : int
        Harmonic number, >= 1.
    amplitude : float
        rad.
    phase : float
        rad.
    """

    order: int
    amplitude: float
    phase: float = 0.0

    def value(self, angle):
        """The error at ``angle`` (rad, array_like), rad."""
        return self.amplitude * np.sin(self.order * np.asarray(angle) + self.phase)


_HARMONIC_KEYS = {"order": "1", "amplitude_arcsec": "arcsec", "phase_deg": "deg"}


@dataclass(frozen=True)
class SiteConfig:
    """The site. ``latitude`` rad, ``gravity`` m/s^2 (local)."""

    latitude: float = _p("latitude_deg", "deg", 28.07, lo=-89.0, hi=89.0, doc="geodetic latitude")
    gravity: float = _p("gravity_mps2", "m/s^2", 9.7925, lo=9.7, hi=9.9, doc="local gravity")


@dataclass(frozen=True)
class TimingConfig:
    """Sampling. ``sample_period`` s."""

    sample_period: float = _p("sample_period_ms", "ms", 2.0, lo=0.1, hi=100.0,
                              doc="gyro/accelerometer/encoder sampling period")


@dataclass(frozen=True)
class TableConfig:
    """Bias turntable errors (the signed rate is a run parameter). Relative values are
    dimensionless, ``ripple_phase`` rad."""

    rate_error: float = _p("rate_error_ppm", "ppm", 0.0, lo=-1e4, hi=1e4,
                           doc="true rate = commanded * (1 + rate_error)")
    ripple: float = _p("ripple_ppm", "ppm", 100.0, lo=0.0, hi=1e4,
                       doc="relative amplitude of the periodic rate ripple")
    ripple_order: int = _p("ripple_order", "1", 1, lo=1, hi=1000, integer=True,
                           doc="ripple frequency, cycles per revolution")
    ripple_phase: float = _p("ripple_phase_deg", "deg", 0.0, doc="ripple phase")
    jitter: float = _p("jitter_arcsec", "arcsec", 0.5, lo=0.0, hi=60.0,
                       doc="table-angle jitter about the commanded turn (servo position noise), "
                           "white at the sample rate")


@dataclass(frozen=True)
class EncoderConfig:
    """Table angle encoder: ``resolution`` rad, ``sync_delay`` s (encoder late by it),
    periodic angle error ``harmonics``."""

    resolution: float = _p("resolution_arcsec", "arcsec", 0.18, lo=0.0, hi=3600.0,
                           doc="angle quantum (0: no quantization)")
    sync_delay: float = _p("sync_delay_us", "us", 0.0, lo=-1e4, hi=1e4,
                           doc="encoder latched this long after the gyro sample (late > 0)")
    harmonics: tuple = ()


@dataclass(frozen=True)
class GyroConfig:
    """The three RLGs. Angles rad, rates rad/s, ``arw`` rad/sqrt(s), ``pulse`` rad,
    ``sf_error`` dimensionless, ``sf_nonlinearity`` 1/(rad/s), ``bias_tempco`` rad/s/degC."""

    axes_nonorth: tuple = _p("axes_nonorth_arcsec", "arcsec", (25.0, -40.0, 30.0), n=3,
                             lo=-3600.0, hi=3600.0, doc="true gyro-axis non-orthogonality")
    eps: tuple = _p("eps_arcsec", "arcsec", (1.6, 1.2, 1.4), n=3, lo=-3600.0, hi=3600.0,
                    doc="eps1..eps3 of Lambda (Eq. 1)")
    bias: tuple = _p("bias_dph", "deg/h", (0.004, -0.003, 0.005), n=3, lo=-10.0, hi=10.0,
                     doc="constant bias per gyro")
    axis_bias: float = _p("axis_bias_dph", "deg/h", 0.0, lo=-10.0, hi=10.0,
                          doc="extra bias vector along the rotation axis")
    bias_warmup: tuple = _p("bias_warmup_dph", "deg/h", (0.003, -0.002, 0.002), n=3,
                            lo=-10.0, hi=10.0, doc="bias transient amplitude after power-on")
    bias_warmup_tau: float = _p("bias_warmup_tau_s", "s", 900.0, lo=1.0, hi=1e6,
                                doc="bias transient time constant")
    bias_tempco: tuple = _p("bias_tempco_dph_per_c", "deg/h/C", (0.0002, -0.0001, 0.0001), n=3,
                            lo=-1.0, hi=1.0, doc="bias temperature coefficient")
    sf_error: tuple = _p("sf_error_ppm", "ppm", (0.0, 0.0, 0.0), n=3, lo=-1e4, hi=1e4,
                         doc="scale-factor error")
    sf_nonlinearity: tuple = _p("sf_nonlinearity_ppm_per_dps", "ppm/(deg/s)", (0.0, 0.0, 0.0),
                                n=3, lo=-1e3, hi=1e3, doc="scale-factor error per deg/s of input")
    arw: float = _p("arw_dph_rthz", "deg/h/rtHz", 0.0120, lo=0.0, hi=100.0,
                    doc="angle random walk")
    pulse: float = _p("pulse_arcsec", "arcsec", 0.1, lo=0.0, hi=100.0,
                      doc="RLG pulse quantum (0: no quantization)")
    lockin: float = _p("lockin_dps", "deg/s", 1.0, lo=0.0, hi=100.0,
                       doc="lock-in threshold on a gyro's input rate")


@dataclass(frozen=True)
class MountConfig:
    """IMU on the table top: rotation axis in s (unit vectors), ``xi`` rad (Eq. 2),
    warm-up/thermal rotation about the rotation axis (rad, s, rad/degC)."""

    r_zb_s_true: tuple = _p("r_zb_s_true", "1", (-0.5772, -0.578, -0.57685020585937), n=3,
                            lo=-1.0, hi=1.0, doc="true rotation axis in s (unit)")
    r_zb_s_calibrated: tuple = _p("r_zb_s_calibrated", "1", (-0.57719440665505, -0.57799580499129, -0.57686000584075), n=3,
                                  lo=-1.0, hi=1.0, doc="lab-calibrated rotation axis in s (unit)")
    xi: tuple = _p("xi_arcsec", "arcsec", (3.0, -2.0, 0.0), n=3, lo=-3600.0, hi=3600.0,
                   doc="small-angle error of the calibrated C~_s^b (Eq. 2)")
    warmup_xi_z: float = _p("warmup_xi_z_arcsec", "arcsec", -12.0, lo=-3600.0, hi=3600.0,
                            doc="mount rotation about z_b right after power-on")
    warmup_tau: float = _p("warmup_tau_s", "s", 600.0, lo=1.0, hi=1e6,
                           doc="its time constant")
    xi_z_tempco: float = _p("xi_z_tempco_arcsec_per_c", "arcsec/C", 0.0, lo=-3600.0, hi=3600.0,
                            doc="mount rotation about z_b per degC from reference_c")


@dataclass(frozen=True)
class AccelConfig:
    """Accelerometers (axes along s up to ``nonorth``): ``bias`` m/s^2, ``vrw`` m/s/sqrt(s),
    ``pulse`` m/s."""

    bias: tuple = _p("bias_ug", "ug", (50.0, -30.0, 80.0), n=3, lo=-1e5, hi=1e5, doc="bias")
    sf_error: tuple = _p("sf_error_ppm", "ppm", (50.0, -40.0, 30.0), n=3, lo=-1e5, hi=1e5,
                         doc="scale-factor error")
    nonorth: tuple = _p("nonorth_arcsec", "arcsec", (10.0, -8.0, 5.0), n=3, lo=-3600.0, hi=3600.0,
                        doc="axis non-orthogonality")
    vrw: float = _p("vrw_ug_rthz", "ug/rtHz", 1.0, lo=0.0, hi=1e5, doc="white noise density")
    pulse: float = _p("pulse_mps", "m/s", 1e-4, lo=0.0, hi=1.0,
                      doc="velocity quantum (0: no quantization)")


@dataclass(frozen=True)
class StandConfig:
    """Test stand: tilts rad, azimuth reading error rad."""

    tilt: tuple = _p("tilt_arcsec", "arcsec", (0.0, 0.0), n=2, lo=-3600.0, hi=3600.0,
                     doc="[north, east] tilt of the stand axis, fixed in n")
    mount_tilt: tuple = _p("mount_tilt_arcsec", "arcsec", (-55.0, -120.0), n=2, lo=-3600.0,
                           hi=3600.0, doc="[x (roll), y (pitch)] tilt of the turntable base, fixed in b0")
    azimuth_offset: float = _p("azimuth_offset_arcsec", "arcsec", 0.0, lo=-1296000.0,
                               hi=1296000.0, doc="true azimuth - reading, constant part")
    azimuth_harmonics: tuple = ()


@dataclass(frozen=True)
class ThermalConfig:
    """IMU temperature model (degC, s, rad)."""

    ambient_c: float = _p("ambient_c", "C", 20.0, lo=-60.0, hi=100.0, doc="ambient temperature")
    rise_c: float = _p("rise_c", "C", 8.0, lo=-50.0, hi=100.0, doc="self-heating after power-on")
    tau: float = _p("tau_s", "s", 1800.0, lo=1.0, hi=1e7, doc="self-heating time constant")
    swing_c: float = _p("swing_c", "C", 0.0, lo=0.0, hi=100.0, doc="ambient swing amplitude")
    swing_period: float = _p("swing_period_s", "s", 86400.0, lo=1.0, hi=1e8, doc="ambient swing period")
    swing_phase: float = _p("swing_phase_deg", "deg", 0.0, doc="ambient swing phase")
    reference_c: float = _p("reference_c", "C", 28.0, lo=-60.0, hi=100.0,
                            doc="temperature of the lab calibration")


_SECTIONS = {
    "site": SiteConfig, "timing": TimingConfig, "table": TableConfig, "encoder": EncoderConfig,
    "gyro": GyroConfig, "mount": MountConfig, "accel": AccelConfig, "stand": StandConfig,
    "thermal": ThermalConfig,
}
_HARMONIC_FIELDS = {("encoder", "harmonics"), ("stand", "azimuth_harmonics")}

def _key_of(cls, fld):
    if (cls, fld.name) in _HARMONIC_CLS_FIELDS:
        return fld.name
    return fld.metadata["key"]


def _schema_keys(section):
    cls = _SECTIONS[section]
    return [_key_of(cls, f) for f in dataclasses.fields(cls)]


_HARMONIC_CLS_FIELDS = {(EncoderConfig, "harmonics"), (StandConfig, "azimuth_harmonics")}


def _unknown(name, valid, where):
    close = difflib.get_close_matches(name, valid, n=1, cutoff=0.5)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return ValueError(f"unknown key {name!r} in {where}{hint} allowed: {', '.join(sorted(valid))}")


def _is_number(v):
    return isinstance(v, (int, float, Decimal)) and not isinstance(v, bool)


def _shown(raw):
    """A value as the user wrote it, for messages (TOML floats are read as Decimal)."""
    if isinstance(raw, (list, tuple)):
        return [_shown(v) for v in raw]
    return float(raw) if isinstance(raw, Decimal) else raw


def _si(value, unit):
    """A value in ``unit`` (TOML Decimal, float or int) -> SI float: the decimal as written
    times the unit factor, rounded once (as :mod:`hse_opt.data` reads CSV files)."""
    return _to_si(str(value) if isinstance(value, Decimal) else value, _UNIT[unit])


def _display(x, unit, decimals):
    """SI float -> the shortest decimal in ``unit`` that :func:`_si` reads back exactly;
    a Decimal for the TOML file, else its float."""
    text = _to_text(x, _UNIT[unit])
    return Decimal(text) if decimals else float(text)


def _finite(v):
    """Whether a TOML number is a finite float (a 400-digit integer is not)."""
    try:
        return math.isfinite(float(v))
    except OverflowError:
        return False


def _check_bounds(where, value, meta):
    lo, hi = meta["lo"], meta["hi"]
    vals = value if isinstance(value, (list, tuple)) else [value]
    for v in vals:
        if not _finite(v) or (lo is not None and v < lo) or (hi is not None and v > hi):
            rng = f"[{lo}, {hi}]" if lo is not None and hi is not None else (
                f">= {lo}" if lo is not None else f"<= {hi}" if hi is not None else "finite")
            raise ValueError(f"{where} = {_shown(value)!r} is not allowed: each value must be finite "
                             f"and in {rng} {meta['unit']}")


def _parse_value(where, raw, meta):
    n = meta["n"]
    if n is None:
        if not _is_number(raw):
            raise ValueError(f"{where} = {_shown(raw)!r} is not allowed: a number in {meta['unit']} is required")
        if meta["integer"] and (not _finite(raw) or not float(raw).is_integer()):
            raise ValueError(f"{where} = {_shown(raw)!r} is not allowed: an integer is required")
        _check_bounds(where, raw, meta)
        return int(raw) if meta["integer"] else _si(raw, meta["unit"])
    if not isinstance(raw, (list, tuple)) or len(raw) != n or not all(_is_number(v) for v in raw):
        raise ValueError(f"{where} = {_shown(raw)!r} is not allowed: a list of {n} numbers in "
                         f"{meta['unit']} is required")
    _check_bounds(where, list(raw), meta)
    return tuple(_si(v, meta["unit"]) for v in raw)


def _parse_harmonics(where, raw):
    if not isinstance(raw, list):
        raise ValueError(f"{where} must be an array of tables [[{where}]] with keys "
                         f"{sorted(_HARMONIC_KEYS)}")
    out = []
    for i, h in enumerate(raw):
        w = f"{where}[{i}]"
        if not isinstance(h, dict):
            raise ValueError(f"{w} must be a table with keys {sorted(_HARMONIC_KEYS)}")
        for k in h:
            if k not in _HARMONIC_KEYS:
                raise _unknown(k, list(_HARMONIC_KEYS), w)
        for k in ("order", "amplitude_arcsec"):
            if k not in h:
                raise ValueError(f"{w}.{k} is missing; required keys: order, amplitude_arcsec")
        order = h["order"]
        if isinstance(order, bool) or not isinstance(order, int) or not 1 <= order <= 1000:
            raise ValueError(f"{w}.order = {_shown(order)!r} is not allowed: an integer in [1, 1000] is required")
        amp, ph = h["amplitude_arcsec"], h.get("phase_deg", 0.0)
        for k, v in (("amplitude_arcsec", amp), ("phase_deg", ph)):
            if not _is_number(v) or not _finite(v):
                raise ValueError(f"{w}.{k} = {_shown(v)!r} is not allowed: a finite number is required")
        if abs(amp) > 3600.0:
            raise ValueError(f"{w}.amplitude_arcsec = {_shown(amp)!r} is not allowed: |amplitude| <= 3600 arcsec")
        out.append(Harmonic(order, _si(amp, "arcsec"), _si(ph, "deg")))
    return tuple(out)


def _harmonics_to_toml(hs, decimals):
    return [{"order": h.order, "amplitude_arcsec": _display(h.amplitude, "arcsec", decimals),
             "phase_deg": _display(h.phase, "deg", decimals)} for h in hs]


@dataclass(frozen=True)
class TruthConfig:
    """The true system (frozen, nested, SI inside). Build with :meth:`default`,
    :meth:`ideal`, :meth:`from_dict` or :func:`load_truth`; change with :meth:`updated`.

    Attributes
    ----------
    site, timing, table, encoder, gyro, mount, accel, stand, thermal
        The sections (see the module docstring for every key and unit).
    """

    site: SiteConfig = SiteConfig()
    timing: TimingConfig = TimingConfig()
    table: TableConfig = TableConfig()
    encoder: EncoderConfig = EncoderConfig()
    gyro: GyroConfig = GyroConfig()
    mount: MountConfig = MountConfig()
    accel: AccelConfig = AccelConfig()
    stand: StandConfig = StandConfig()
    thermal: ThermalConfig = ThermalConfig()

    def __hash__(self):
        """The sections' hash, computed once: a frozen configuration keys the simulator's
        caches of its matrices and tables, looked up on every run."""
        h = self.__dict__.get("_hash")
        if h is None:
            h = hash(tuple(getattr(self, f.name) for f in dataclasses.fields(self)))
            object.__setattr__(self, "_hash", h)
        return h

    def __getstate__(self):          # the hash is not carried to another process
        return {k: v for k, v in self.__dict__.items() if k != "_hash"}

    def __post_init__(self):
        for name in ("r_zb_s_true", "r_zb_s_calibrated"):
            r = np.asarray(getattr(self.mount, name))
            if abs(np.linalg.norm(r) - 1.0) > 1e-6:
                raise ValueError(f"mount.{name} = {tuple(r)} is not allowed: a unit vector is "
                                 f"required (|r| = {np.linalg.norm(r):.9f}, allowed 1 +- 1e-6)")
            if abs(r[0]) > 0.99:
                raise ValueError(f"mount.{name} = {tuple(r)} is not allowed: the rotation axis "
                                 "must not be along x_g (|e_x| <= 0.99)")
        for key in ("tilt", "mount_tilt"):
            for v in getattr(self.stand, key):
                if abs(v) > MAX_TILT:
                    raise ValueError(f"stand.{key}_arcsec: |tilt| = {abs(v) / units.ARCSEC:.1f} "
                                     f"arcsec is too large; allowed |tilt| <= {MAX_TILT / units.ARCSEC:.0f} arcsec")
        for sec, fld in (("gyro", "arw"), ("accel", "vrw"), ("gyro", "pulse"), ("accel", "pulse"),
                         ("encoder", "resolution")):
            if getattr(getattr(self, sec), fld) < 0:
                key = getattr(type(getattr(self, sec)), "__dataclass_fields__")[fld].metadata["key"]
                raise ValueError(f"{sec}.{key} = {getattr(getattr(self, sec), fld)!r} (SI) is not "
                                 "allowed: noise and quanta must be >= 0")

    # -- construction ------------------------------------------------------------------------
    @classmethod
    def default(cls):
        """The paper-like default system (see the module docstring for how it was chosen)."""
        return cls()

    @classmethod
    def ideal(cls):
        """A perfect system: every error, noise and quantization off (latitude, gravity,
        sampling kept), ideal rotation axis; the start for one-error-at-a-time studies."""
        d = cls().to_dict(decimals=True)
        zero3 = [0.0, 0.0, 0.0]
        ideal_r = [float(v) for v in R_ZB_S_IDEAL]
        d["table"].update(rate_error_ppm=0.0, ripple_ppm=0.0, jitter_arcsec=0.0)
        d["encoder"].update(resolution_arcsec=0.0, sync_delay_us=0.0, harmonics=[])
        d["gyro"].update(axes_nonorth_arcsec=[25.0, -40.0, 30.0], eps_arcsec=zero3, bias_dph=zero3,
                         axis_bias_dph=0.0, bias_warmup_dph=zero3, bias_tempco_dph_per_c=zero3,
                         sf_error_ppm=zero3, sf_nonlinearity_ppm_per_dps=zero3, arw_dph_rthz=0.0,
                         pulse_arcsec=0.0)
        d["mount"].update(r_zb_s_true=ideal_r, r_zb_s_calibrated=ideal_r, xi_arcsec=zero3,
                          warmup_xi_z_arcsec=0.0, xi_z_tempco_arcsec_per_c=0.0)
        d["accel"].update(bias_ug=zero3, sf_error_ppm=zero3, nonorth_arcsec=zero3,
                          vrw_ug_rthz=0.0, pulse_mps=0.0)
        d["stand"].update(tilt_arcsec=[0.0, 0.0], mount_tilt_arcsec=[0.0, 0.0],
                          azimuth_offset_arcsec=0.0, azimuth_harmonics=[])
        return cls.from_dict(d)

    def noise_free(self):
        """A copy with every random and quantization effect off (ARW, accelerometer noise,
        RLG and velocity pulses, encoder resolution); deterministic errors kept."""
        return self.updated({"gyro": {"arw_dph_rthz": 0.0, "pulse_arcsec": 0.0},
                             "accel": {"vrw_ug_rthz": 0.0, "pulse_mps": 0.0},
                             "encoder": {"resolution_arcsec": 0.0}, "table": {"jitter_arcsec": 0.0}})

    @property
    def is_noise_free(self):
        """True when no random draw is needed to simulate a run (except the start angle)."""
        return (self.gyro.arw == 0 and self.accel.vrw == 0 and self.gyro.pulse == 0
                and self.accel.pulse == 0 and self.table.jitter == 0)

    @classmethod
    def from_dict(cls, d, base=None):
        """Build from a TOML-shaped dict (sections of unit-named keys); missing keys keep the
        values of ``base`` (default: :meth:`default`). Unknown sections or keys raise
        ValueError naming them."""
        if not isinstance(d, dict):
            raise ValueError("a truth configuration must be a table of sections")
        base = cls() if base is None else base
        sections = {}
        for sname in d:
            if sname not in _SECTIONS:
                raise _unknown(sname, list(_SECTIONS), "the truth configuration (section)")
        for sname, scls in _SECTIONS.items():
            current = getattr(base, sname)
            raw = d.get(sname, {})
            if not isinstance(raw, dict):
                raise ValueError(f"[{sname}] must be a table of keys")
            valid = _schema_keys(sname)
            for k in raw:
                if k not in valid:
                    raise _unknown(k, valid, f"[{sname}]")
            changes = {}
            for f in dataclasses.fields(scls):
                key = _key_of(scls, f)
                if key not in raw:
                    continue
                where = f"{sname}.{key}"
                if (scls, f.name) in _HARMONIC_CLS_FIELDS:
                    changes[f.name] = _parse_harmonics(where, raw[key])
                else:
                    changes[f.name] = _parse_value(where, raw[key], f.metadata)
            sections[sname] = dataclasses.replace(current, **changes)
        return cls(**sections)

    def to_dict(self, decimals=False):
        """The TOML-shaped dict (unit-named keys, values in those units): each value the
        shortest decimal that reads back to exactly the same SI float, as ``decimal.Decimal``
        with ``decimals=True`` (what :meth:`to_toml` writes), else as float."""
        out = {}
        for sname, scls in _SECTIONS.items():
            sec = getattr(self, sname)
            sd = {}
            for f in dataclasses.fields(scls):
                v = getattr(sec, f.name)
                if (scls, f.name) in _HARMONIC_CLS_FIELDS:
                    sd[f.name] = _harmonics_to_toml(v, decimals)
                    continue
                m = f.metadata
                if m["integer"]:
                    sd[m["key"]] = int(v)
                elif m["n"] is None:
                    sd[m["key"]] = _display(v, m["unit"], decimals)
                else:
                    sd[m["key"]] = [_display(x, m["unit"], decimals) for x in v]
            out[sname] = sd
        return out

    def updated(self, changes):
        """A copy with ``changes`` (a TOML-shaped dict, e.g. ``{"gyro": {"eps_arcsec":
        [1, 2, 3]}}``) applied, validated like a file."""
        return TruthConfig.from_dict(changes, base=self)

    @classmethod
    def from_toml(cls, path):
        """Load ``TRUTH.toml``; missing keys take the default system's values."""
        from hse_opt.data import read_toml
        d = read_toml(path, "a UTF-8 TOML file (the sections of TRUTH.toml)", parse_float=Decimal)  # exact: see _si
        try:
            return cls.from_dict(d)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None

    def to_toml(self, path=None):
        """Write (or, with ``path=None``, return) the TOML text; every key is written, and
        reading it back gives exactly this configuration."""
        import tomli_w
        text = tomli_w.dumps(self.to_dict(decimals=True))
        if path is not None:
            with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
                fh.write(text)
        return text


def load_truth(path):
    """:meth:`TruthConfig.from_toml`."""
    return TruthConfig.from_toml(path)


def save_truth(truth, path):
    """:meth:`TruthConfig.to_toml`."""
    truth.to_toml(path)


# -- derived quantities -------------------------------------------------------------------------
def per_configuration(maxsize):
    """``functools.lru_cache`` for functions of a frozen configuration (and other hashable
    arguments); with an unhashable argument the function runs uncached."""
    def decorate(fn):
        cached = functools.lru_cache(maxsize=maxsize)(fn)

        @functools.wraps(fn)
        def wrapper(*args):
            try:
                return cached(*args)
            except TypeError:                # an unhashable argument: not cached
                return fn(*args)
        wrapper.cache_clear = cached.cache_clear
        return wrapper
    return decorate


def gyro_matrices(truth):
    """The true and calibrated matrices of the gyro chain.

    Returns
    -------
    dict of numpy.ndarray, shape (3, 3)
        ``K_g`` true (g -> s), ``K_g_inv`` its inverse (rows: the gyro sensing axes in s),
        ``K_g_cal`` = (I + Lambda) K_g (Eq. 1), ``C_b_s`` true (from
        ``r_zb_s_true``), ``C_s_b_cal`` = (I - [xi x]) C_s^b(r_zb_s_calibrated) (Eq. 2),
        ``A_acc`` true accelerometer matrix (s -> accelerometer outputs, scale and
        non-orthogonality), ``Lambda``. The arrays are read-only: they are computed once
        per configuration (a frozen :class:`TruthConfig`) and shared.
    """
    return dict(_gyro_matrices(truth))


@per_configuration(maxsize=16)
def _gyro_matrices(truth):
    g, m, a = truth.gyro, truth.mount, truth.accel
    d_yx, d_zx, d_zy = g.axes_nonorth
    u_y = np.array([math.sin(d_yx), math.cos(d_yx), 0.0])
    u_z = np.array([math.sin(d_zx), math.sin(d_zy), 0.0])
    u_z[2] = math.sqrt(1.0 - u_z[0] ** 2 - u_z[1] ** 2)
    K_g_inv = np.array([[1.0, 0.0, 0.0], u_y, u_z])   # rows: gyro sensing axes in s
    K_g = np.linalg.inv(K_g_inv)
    e1, e2, e3 = g.eps
    Lam = np.array([[0.0, 0.0, 0.0], [e1, 0.0, 0.0], [e2, e3, 0.0]])
    K_g_cal = (np.eye(3) + Lam) @ K_g
    C_b_s = c_b_s(np.asarray(m.r_zb_s_true))
    C_s_b_cal = (np.eye(3) - skew(np.asarray(m.xi))) @ c_b_s(np.asarray(m.r_zb_s_calibrated)).T
    n_yx, n_zx, n_zy = a.nonorth
    A_acc = np.diag(1.0 + np.asarray(a.sf_error)) @ np.array(
        [[1.0, 0.0, 0.0], [n_yx, 1.0, 0.0], [n_zx, n_zy, 1.0]])
    mats = {"K_g": K_g, "K_g_inv": K_g_inv, "K_g_cal": K_g_cal, "C_b_s": C_b_s,
            "C_s_b_cal": C_s_b_cal, "A_acc": A_acc, "Lambda": Lam}
    for m in mats.values():
        m.setflags(write=False)
    return mats


def temperature(thermal, t_on):
    """IMU temperature, degC, at times since power-on ``t_on`` (s, array_like)."""
    t_on = np.asarray(t_on, dtype=float)
    temp = thermal.ambient_c + thermal.rise_c * (1.0 - np.exp(-t_on / thermal.tau))
    if thermal.swing_c:
        temp = temp + thermal.swing_c * np.sin(2 * np.pi * t_on / thermal.swing_period
                                               + thermal.swing_phase)
    return temp


# -- one run ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RunSpec:
    """One alignment run (a PLAN.csv row), SI.

    Attributes
    ----------
    rate : float
        Signed commanded table rate Omega about z_b (down), rad/s.
    azimuth : float
        Test-stand azimuth reading, rad.
    duration : float
        Alignment length, s.
    t_start : float
        Time since power-on at the start, s.
    tilt : tuple of 2 float
        Deliberate tilt of the table base (x: roll, y: pitch), rad, added to the mount tilt.
    alpha0 : float or None
        Table angle at the start, rad; None draws it uniformly from the run's Generator.
    """

    rate: float
    azimuth: float = 0.0
    duration: float = 600.0
    t_start: float = 3600.0
    tilt: tuple = (0.0, 0.0)
    alpha0: float | None = None


class RunError(ValueError):
    """A run the system cannot make. ``column`` is the PLAN column at fault, ``problem`` the
    message (what is wrong and what is allowed)."""

    def __init__(self, column, problem):
        self.column, self.problem = column, problem
        super().__init__(problem)

    def __reduce__(self):
        return type(self), (self.column, self.problem)


def validate_run(truth, run, mats=None):
    """Check a run against the system; :class:`RunError` naming the PLAN column and what is
    allowed. ``mats`` is :func:`gyro_matrices` of ``truth`` when the caller has it.

    Checks: a finite non-zero rate outside the gyros' lock-in zone (each gyro's input rate
    ``|Omega r_g . r_zb^s|``, less the Earth rate, must exceed ``gyro.lockin_dps``) and below what
    the sampling represents (the highest periodic error of the table angle, ``ripple_order`` or
    an encoder harmonic's order per revolution, under the Nyquist rate), a duration
    of at least one table revolution plus one sample (and at most one day), ``t_start >= 0`` and each
    total tilt component within :data:`MAX_TILT`.
    """
    for name, v in (("rate_dps", run.rate), ("azimuth_deg", run.azimuth),
                    ("duration_s", run.duration), ("t_start_s", run.t_start)):
        if not math.isfinite(v):
            raise RunError(name, f"{name} = {v!r} is not allowed: a finite number is required")
    mats = gyro_matrices(truth) if mats is None else mats
    proj = np.abs(mats["K_g_inv"] @ mats["C_b_s"][:, 2])      # |cos| between gyro axis and z_b
    from hse_opt.align.rotations import EARTH_RATE
    min_rate = (truth.gyro.lockin + EARTH_RATE) / proj.min()
    if not abs(run.rate) > min_rate:
        raise RunError(
            "rate_dps", f"rate_dps = {run.rate / units.DEG_PER_S:g} is inside the gyros' lock-in zone "
            f"(gyro.lockin_dps = {truth.gyro.lockin / units.DEG_PER_S:g} on each gyro's input "
            f"rate): allowed |rate_dps| > {min_rate / units.DEG_PER_S:.4g}")
    # the sampling must represent the table's periodic errors: the highest order per revolution
    # (rate ripple, encoder harmonics; the turn itself) below the Nyquist rate of the samples
    order = max([1, truth.table.ripple_order, *(h.order for h in truth.encoder.harmonics)])
    max_rate = math.pi / (order * truth.timing.sample_period)
    if abs(run.rate) >= max_rate:
        raise RunError("rate_dps", f"rate_dps = {run.rate / units.DEG_PER_S:g} turns the table too far per "
                       f"sample for {1 / truth.timing.sample_period:g} Hz sampling (periodic errors up to "
                       f"order {order} per revolution); allowed |rate_dps| < {max_rate / units.DEG_PER_S:.6g}")
    # one revolution of encoder span: the first sample's increment has no angle at its start
    t_min = 2 * math.pi / abs(run.rate) + truth.timing.sample_period
    if run.duration < t_min:
        raise RunError("duration_s", f"duration_s = {run.duration:g} is shorter than one table "
                       f"revolution plus one sample: allowed duration_s >= {t_min:.6g} s at "
                       f"rate_dps = {run.rate / units.DEG_PER_S:g}")
    if run.duration > 86400.0:
        raise RunError("duration_s", f"duration_s = {run.duration:g} is not allowed: at most 86400 s")
    if run.t_start < 0:
        raise RunError("t_start_s", f"t_start_s = {run.t_start:g} is not allowed: time since power-on >= 0")
    for i, name in enumerate(("tilt_x_arcsec", "tilt_y_arcsec")):
        total = run.tilt[i] + truth.stand.mount_tilt[i]
        if abs(total) > MAX_TILT:
            raise RunError(name, f"{name} = {run.tilt[i] / units.ARCSEC:g}: |tilt| too large (with "
                             f"stand.mount_tilt_arcsec {truth.stand.mount_tilt[i] / units.ARCSEC:g}); "
                             f"allowed |total tilt| <= {MAX_TILT / units.ARCSEC:.0f} arcsec")
