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
    pitch theta, roll gamma; the paper's Eq. 3 is its first-order form. A tilt of b0 is
    ``Tilt(roll, pitch)`` and C23 is ``c23()`` (:mod:`hse_opt.model.inputs`).
Signs
    Heading error is *estimated minus true* everywhere (RUNS.csv ``heading_err_arcsec``,
    model predictions, fits, plots). The paper's delta-psi (Eqs. 12, 14-16) is true minus
    estimated; a function that implements one of the paper's closed forms says which sign it
    returns. lambda2 = eps1 + eps2 + eps3 keeps the paper's meaning.
Units
    SI inside (rad, rad/s, s). arcsec, deg, deg/s, deg/h and microseconds appear only at the
    edges (files, command line, reports, parameter display units), converted through
    :mod:`hse_opt.units`; a non-SI name carries its unit (``rate_dps``).

The long form: ``docs/conventions.md``; file formats ``docs/formats.md``; packages and data
flow ``docs/architecture.md`` (in the repository).
"""
import sys
import types

from . import _moved

__version__ = "0.1.0"

_moved.install()

#: the public API, imported on first use (``import hse_opt.sim`` loads neither the model's
#: CasADi stack nor the design's cvxpy): name -> (module, attribute); attribute None gives the
#: module itself (``hse_opt.diagnose`` is a callable module: ``hse_opt.diagnose(runs)`` and
#: ``hse_opt.diagnose.refine(runs)`` both work)
_API = {
    # calibration (issue 4)
    **{name: ("fit", name) for name in ("Constraint", "FitResult", "SolverError", "fit")},
    **{name: ("fit.correction", name) for name in ("compensate", "compensation")},
    **{name: ("fit.file", name) for name in ("load_fit", "save_fit")},
    **{name: ("information", name) for name in ("Prior", "UnidentifiableError", "heading_sigma")},
    **{name: ("fit.paper_procedure", name) for name in ("PaperCalibration", "compensate_eq14",
                                                   "paper_procedure")},
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


__all__ = list(_API)


def __getattr__(name):
    import importlib

    try:
        module, attr = _API[name]
    except KeyError:
        raise AttributeError(f"module 'hse_opt' has no attribute {name!r}") from None
    mod = importlib.import_module(f".{module}", __name__)
    value = mod if attr is None else getattr(mod, attr)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_API))


class _Package(types.ModuleType):
    """The package keeps its API names: importing a submodule binds it as an attribute of the
    package, which would turn ``hse_opt.fit`` (the function) into the module ``hse_opt.fit``
    once anything imports that module; such a binding is left to ``sys.modules``."""

    def __setattr__(self, name, value):
        if isinstance(value, types.ModuleType) and _API.get(name, (None, None))[1] is not None:
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
