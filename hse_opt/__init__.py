"""hse_opt: calibration and compensation of the heading-sensitive error (HSE) of a
constant-rate biased ring-laser-gyro (RLG) system, after Yu, Wu, Cao, Zhao and Liu,
J. National University of Defense Technology 35(4), 2013.

Conventions (the contract every module keeps)
---------------------------------------------
Frames
    n   local level North-East-Down.
    b0  turntable base; b is b0 turned by the table angle alpha about z (down, the
        rotation axis): ``C_b^b0 = rot_z(alpha)``.
    b   turntable top, rotating with the table.
    s   IMU reference: x_s along gyro x, y_s in the x_g-y_g plane.
    g   the three gyro sensing axes (non-orthogonal).
Names
    ``C_ab`` maps frame b to frame a (``v_a = C_ab @ v_b``); a vector carries its frame in
    its name (``omega_ib_b``). Paper symbols keep their names: ``eps`` (eps1..eps3 of
    Lambda, Eq. 1), ``xi`` (Eq. 2), ``r_zb_s``, ``lambda1``, ``lambda2``, ``C23``.
Attitude
    C_b0^n = rot_z(psi) rot_y(theta) rot_x(gamma): heading psi clockwise from north,
    pitch theta, roll gamma; the paper's Eq. 3 is its first-order form.
Signs
    Heading error is *estimated minus true* everywhere (RUNS.csv ``heading_err_arcsec``,
    model predictions, fits, plots). The paper's delta-psi (Eqs. 12, 14-16) is true minus
    estimated; a function that implements one of the paper's closed forms says which sign it
    returns. lambda2 = eps1 + eps2 + eps3 keeps the paper's meaning.
Units
    SI inside (rad, rad/s, s). arcsec, deg, deg/s, deg/h and microseconds appear only at the
    edges (files, command line, reports, parameter display units), converted through
    :mod:`hse_opt.units`; a non-SI name carries its unit (``rate_dps``).
"""
__version__ = "0.1.0"

# -- public API (calibration: issue 4) --------------------------------------------------------
from .compensation import compensate, compensation  # noqa: E402
from .fit import Constraint, FitResult, SolverError, fit  # noqa: E402
from .fit_file import load_fit, save_fit  # noqa: E402
from .information import Prior, UnidentifiableError, heading_sigma  # noqa: E402
from .paper_procedure import PaperCalibration, compensate_eq14, paper_procedure  # noqa: E402

#: more of the public API, imported on first use: name -> (module, attribute); attribute None
#: gives the module itself (``hse_opt.diagnose`` is a callable module: ``hse_opt.diagnose(runs)``
#: and ``hse_opt.diagnose.refine(runs)`` both work)
_API = {
    "diagnose": ("diagnose", None),
    "Diagnosis": ("diagnose", "Diagnosis"),
    # experiment design (issue 5): hse_opt.design(model, criterion, budget=...) designs a plan
    "design": ("design", None),
    "DesignSpace": ("design", "DesignSpace"),
    "Costs": ("design", "Costs"),
    "Stand": ("design", "Stand"),
    "DesignResult": ("design", "DesignResult"),
    "Discrimination": ("design", "Discrimination"),
    "monte_carlo": ("validation.monte_carlo", "monte_carlo"),
}


__all__ = ["Constraint", "FitResult", "SolverError", "compensate", "compensation", "fit", "load_fit",
           "save_fit", "Prior", "UnidentifiableError", "heading_sigma", "PaperCalibration",
           "compensate_eq14", "paper_procedure", *_API]


def __getattr__(name):
    import importlib

    try:
        module, attr = _API[name]
    except KeyError:
        raise AttributeError(f"module 'hse_opt' has no attribute {name!r}") from None
    mod = importlib.import_module(f".{module}", __name__)
    return mod if attr is None else getattr(mod, attr)


def __dir__():
    return sorted(set(globals()) | set(_API))
