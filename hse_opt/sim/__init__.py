"""The numeric alignment simulator: the independent reference for :mod:`hse_opt.model`.

Built from the paper's physics (``docs/conventions.md``); it imports only :mod:`hse_opt.units` and
:mod:`hse_opt.data` (file formats) from the rest of the package, has its own rotations
(:mod:`hse_opt.sim.rotations`) and loads neither CasADi nor cvxpy.

Modules
-------
rotations
    rotation matrices, Euler angles, rotation vectors, Earth rate (numpy).
truth
    :class:`TruthConfig` -- the true system (frozen, TOML in and out, units in key names);
    :class:`RunSpec` -- one run of a plan.
imu
    :func:`generate` -- raw 500 Hz gyro/accelerometer increments and encoder angles.
rawlog
    :class:`RawLog` -- the documented raw-log format (``.npz`` / ``.csv``), load/validate/save.
align
    :func:`align` -- the alignment processor (coarse TRIAD + Kalman filter + whole-revolution
    smoothing) for simulated or real logs; :class:`AlignConfig`, :class:`AlignResult`.
campaign
    :func:`run_campaign` (Plan -> Runs of :mod:`hse_opt.data`, parallel, Dask),
    :func:`simulate_run`, :func:`simulate_heading_error` (noise-free, one error source at a
    time). The command ``hse-opt simulate`` is :mod:`hse_opt.commands.simulate`.
"""
from hse_opt.sim.align import AlignConfig, AlignHistory, AlignResult, align, triad
from hse_opt.sim.campaign import (RunResult, default_align_config, run_campaign, simulate_alignment,
                                  simulate_heading_error, simulate_run)
from hse_opt.sim.imu import generate, true_attitude
from hse_opt.sim.rawlog import RawLog, check_rawlog, load_rawlog, save_rawlog, validate_rawlog
from hse_opt.sim.truth import Harmonic, RunSpec, TruthConfig, load_truth, save_truth

__all__ = [
    "AlignConfig", "AlignHistory", "AlignResult", "align", "triad", "RunResult",
    "default_align_config", "run_campaign", "simulate_alignment", "simulate_heading_error",
    "simulate_run", "generate",
    "true_attitude", "RawLog", "check_rawlog", "load_rawlog", "save_rawlog", "validate_rawlog",
    "Harmonic", "RunSpec", "TruthConfig", "load_truth", "save_truth",
]
