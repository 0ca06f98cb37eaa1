"""The numeric alignment simulator: the independent reference for :mod:`hse_opt.model`.

Built from the paper's physics (``docs/conventions.md``); it imports only :mod:`hse_opt.units`,
:mod:`hse_opt.data` (file formats) and the user's data path :mod:`hse_opt.align` (raw logs, the
alignment processor, the numpy rotations :mod:`hse_opt.align.rotations`) from the rest of the
package, and loads neither CasADi nor cvxpy. The raw-log and processor names below are
re-exported from :mod:`hse_opt.align`.

Modules
-------
truth
    :class:`TruthConfig` -- the true system (frozen, TOML in and out, units in key names);
    :class:`RunSpec` -- one run of a plan.
imu
    :func:`generate` -- raw 500 Hz gyro/accelerometer increments and encoder angles.
campaign
    :func:`run_campaign` (Plan -> Runs of :mod:`hse_opt.data`, parallel, Dask),
    :func:`simulate_run`, :func:`simulate_heading_error` (noise-free, one error source at a
    time), :func:`lab_calibration` and :func:`align_config_from_truth` (the lab calibration
    and the processor of a simulated system). The command ``hse-opt simulate`` is
    :mod:`hse_opt.app.commands.simulate`.
"""
import sys
import types

from hse_opt.align import (AlignConfig, AlignHistory, AlignResult, RawLog, align, check_rawlog, load_rawlog,
                           save_rawlog, triad, validate_rawlog)
from hse_opt.sim.campaign import (RunResult, align_config_from_truth, default_align_config, lab_calibration,
                                  run_campaign, simulate_alignment, simulate_heading_error, simulate_run)
from hse_opt.sim.imu import generate, true_attitude
from hse_opt.sim.truth import Harmonic, RunSpec, TruthConfig, load_truth, save_truth

__all__ = [
    "AlignConfig", "AlignHistory", "AlignResult", "align", "triad", "RunResult",
    "align_config_from_truth", "default_align_config", "lab_calibration", "run_campaign", "simulate_alignment",
    "simulate_heading_error", "simulate_run", "generate",
    "true_attitude", "RawLog", "check_rawlog", "load_rawlog", "save_rawlog", "validate_rawlog",
    "Harmonic", "RunSpec", "TruthConfig", "load_truth", "save_truth",
]


class _Package(types.ModuleType):
    """``hse_opt.sim.align`` stays the function: the old module name ``hse_opt.sim.align`` (now
    :mod:`hse_opt.align.processor`, kept as an alias by :mod:`hse_opt._moved`) would rebind the
    package's attribute to the module when a script imports it."""

    def __setattr__(self, name, value):
        if name == "align" and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
