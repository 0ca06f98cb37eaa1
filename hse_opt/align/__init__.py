"""The user's data path: raw logs of a rotating RLG system -> headings (``hse-opt align``).

Real recordings and the simulator's logs go through the same code; the simulator
(:mod:`hse_opt.sim`) calls this package to process what it generates, and this package
imports neither the simulator nor the symbolic model (it loads neither CasADi nor cvxpy).

Modules
-------
rawlog
    :class:`RawLog` -- the documented raw-log format (``.npz`` / ``.csv``), load/validate/save.
processor
    :func:`align` -- the alignment processor (coarse TRIAD + Kalman filter + whole-revolution
    smoothing); :class:`AlignConfig` (the lab calibration it applies and its tuning),
    :class:`AlignResult`.
calibration
    :class:`LabCalibration` -- the system's lab calibration (``CALIBRATION.toml``: K~_g, the
    accelerometer matrix, C~_s^b, optional pulse weights, noise and latitude),
    :func:`load_calibration`, :func:`save_calibration`.
batch
    :func:`align_logs`, :func:`runs_from_rows` -- many logs in parallel into a RUNS table; a
    bad log is reported and does not stop the others.
noise
    :func:`noise_from_log` -- the sensors' noise from a log itself: overlapping Allan deviation
    of the six channels (the table's turn, Earth rate and gravity fitted out) and the IEEE
    Std 952 terms (:class:`NoiseFigures`); :func:`combine_noise` for a campaign.
quality
    :func:`assess` -- a log's quality before alignment (encoder samples against the rate and
    the gyros, the table's rate, stuck / saturated / spiking channels, temperature drift,
    metadata types): repaired by a documented rule or refused, each finding with its sample
    and time (:class:`Quality`).
steps
    check 3b of the quality checks: a step in one gyro's angle below the window test (a
    sample's error of 0.2 arcsec moves a 10-minute heading by half its sigma).
metadata
    a raw log's metadata keys and the values each allows (check 5), the encoder's resolution.
mapping
    :func:`load_mapping`, :func:`read_mapped` -- a test stand's own CSV read through a
    mapping file (TOML: columns, units, time base, pulse weights, counts per revolution,
    signs, axis order; ``docs/rawlogs.md``).
rotations
    rotation matrices, Euler angles, rotation vectors, Earth rate (numpy only; the simulator
    uses them too).
"""
from hse_opt.align.batch import align_logs, runs_from_rows
from hse_opt.align.calibration import LabCalibration, load_calibration, save_calibration
from hse_opt.align.mapping import load_mapping, read_mapped
from hse_opt.align.noise import NoiseFigures, combine_noise, noise_from_log
from hse_opt.align.processor import (AlignConfig, AlignHistory, AlignResult, align, latitude_of, quantization_arw,
                                     triad)
from hse_opt.align.quality import Quality, assess
from hse_opt.align.rawlog import RawLog, check_rawlog, load_rawlog, save_rawlog, validate_rawlog

__all__ = [
    "AlignConfig", "AlignHistory", "AlignResult", "align", "latitude_of", "quantization_arw", "triad",
    "LabCalibration", "load_calibration", "save_calibration", "align_logs", "runs_from_rows", "NoiseFigures",
    "combine_noise", "noise_from_log", "RawLog", "check_rawlog", "load_rawlog", "save_rawlog", "validate_rawlog",
    "Quality", "assess", "load_mapping", "read_mapped",
]
