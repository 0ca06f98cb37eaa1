"""FIT.json, the calibration file: :func:`save_fit` writes a :class:`~hse_opt.fit.FitResult`,
:func:`load_fit` reads it back (the model rebuilt from its effect names).

A FIT.json is data from outside (``docs/threats.md``): :func:`load_fit` uses it only when its
numbers agree with each other and with its model, else it raises ValueError naming the field
and what is allowed (the commands exit 2). The checks (:func:`_check_numbers`):

- the effects are known and their names follow :mod:`hse_opt.names`; the parameter names are
  the rebuilt model's;
- ``p_si`` is each ``parameters.<name>.value`` times its unit's SI factor (relative
  :data:`AGREE_RTOL`): a value edited without its SI twin, or the reverse, is refused;
- each free parameter's value lies within the range its effect declares
  (:class:`hse_opt.model.Param` ``lower``/``upper``, e.g. lambda2 +-200 arcsec) and the fit's
  own ``lower``/``upper``, and its std is at most that declared range's width (a std beyond
  it: the calibration does not determine the parameter); a held parameter has std 0;
- ``covariance`` is symmetric and positive semidefinite (eigenvalues down to
  :data:`PSD_RTOL` of the largest), ``std`` is the square root of its diagonal and
  ``correlation`` is it scaled by the stds (:data:`AGREE_RTOL`); rows of held parameters are 0;
- the calibration runs' inputs (``runs.inputs``) are finite, one per run, and the rate,
  azimuth, tilt, latitude, time and duration within :data:`hse_opt.ranges.RANGES`.
"""
import json
import math
import os

import numpy as np

from .. import units
from .result import Constraint, FitResult
from ..information import ConfoundedGroup
from ..model.composition import Model
from ..model.effects import effect as make_effect
from ..model.measurement import RUN_FIELDS
from ..model.symbolic import Geometry

#: relative tolerance of numbers that must agree (p_si with the values, std with the covariance):
#: both are written from one float by hse-opt fit -o, so they agree to rounding
AGREE_RTOL = 1e-9
#: the covariance's smallest eigenvalue may be this fraction of its largest below 0 (rounding)
PSD_RTOL = 1e-9
#: runs.inputs row -> (RANGES key, SI factor of its unit)
_INPUT_RANGES = {"rate": ("rate_dps", units.DEG_PER_S), "azimuth": ("azimuth_deg", units.DEG),
                 "pitch": ("pitch_arcsec", units.ARCSEC), "roll": ("roll_arcsec", units.ARCSEC),
                 "latitude": ("latitude_deg", units.DEG), "t_start": ("t_start_s", 1.0),
                 "duration": ("duration_s", 1.0)}

#: FIT.json format tag
FIT_FORMAT = "hse_opt.fit"
FIT_VERSION = 1


def _fit_json(fit_result):
    g = fit_result.model.geometry
    out = fit_result.to_dict()
    out.update({
        "format": FIT_FORMAT, "version": FIT_VERSION,
        "geometry": {"r_zb_s": g.r_zb_s.tolist(), "K_g": g.K_g.tolist()},
        "names": list(fit_result.names), "p_si": [float(v) for v in fit_result.p],
        "runs": {"run": [int(r) for r in fit_result.run],
                 "residual_arcsec": (fit_result.residuals / units.ARCSEC).tolist(),
                 "sigma_arcsec": (fit_result.sigma / units.ARCSEC).tolist(),
                 "weight": (fit_result.weights if fit_result.weights is not None
                            else np.ones(fit_result.n_runs)).tolist()},
    })
    if fit_result.inputs is not None:  # SI, one list per model input (where the calibration holds)
        mm = fit_result.measurement
        out["runs"]["inputs"] = {name: row.tolist() for name, row in
                                 zip(RUN_FIELDS + tuple(mm.covariates), fit_result.inputs)}
    return out


def _group(g):
    """A :class:`~hse_opt.information.ConfoundedGroup` from its FIT.json form (no direction)."""
    names = tuple(str(n) for n in g["parameters"])
    inflation = tuple(float(x) for x in g["inflation"])
    if len(inflation) != len(names) or not all(math.isfinite(x) and x >= 1.0 for x in inflation):
        raise ValueError(f"\"confounded\" group {list(names)} has inflations {list(inflation)}; allowed: one "
                         "finite number >= 1 per parameter")
    return ConfoundedGroup(names, inflation, float(g["max_abs_correlation"]), None, str(g.get("advice", "")))


def _systematic(par, names, std):
    """``systematic`` and ``systematic_by`` from the parameters' entries (absent in files
    written before the alias budget: not assessed)."""
    values = [par[nm].get("systematic") for nm in names]
    if all(v is None for v in values):
        return {}
    sys = np.array([0.0 if v is None else v for v in values], dtype=float)
    by = tuple({str(e): float(x) for e, x in (par[nm].get("systematic_by") or {}).items()} for nm in names)
    bad = [nm for nm, v, b in zip(names, sys, by) if not (math.isfinite(v) and v >= 0)
           or any(not (math.isfinite(x) and 0 <= x <= v) for x in b.values())]
    if bad:
        raise ValueError(f"\"parameters\" {', '.join(bad)}: systematic must be a finite number >= 0, at least "
                         "each of its systematic_by shifts")
    return {"systematic": sys, "systematic_by": by}


def save_fit(fit_result, path):
    """Write ``fit_result`` as FIT.json: the JSON contract plus what :func:`load_fit` needs to
    rebuild the model by effect names (geometry, full covariance, SI values, per-run residuals).
    Written whole (temporary file, then rename) or not at all."""
    from ..data import write_text_atomic
    write_text_atomic(path, json.dumps(_fit_json(fit_result), indent=1, allow_nan=False) + "\n")


def load_fit(path, model=None):
    """Read FIT.json back into a :class:`FitResult`.

    The model is rebuilt from the file's effect names (catalogue effects and
    ``covariate:<column>``); pass ``model`` for effects of your own with the same names.
    """
    from ..data import read_text
    src = os.fspath(path)
    try:
        d = json.loads(read_text(src, "a FIT.json written by hse-opt fit -o"))
    except json.JSONDecodeError as err:
        raise ValueError(f"{src}: not JSON ({err}); allowed: a FIT.json written by hse-opt fit -o") from None
    except UnicodeDecodeError as err:
        raise ValueError(f"{src}: not UTF-8 text ({err.reason} at byte {err.start}); allowed: a FIT.json "
                         "written by hse-opt fit -o") from None
    except RecursionError:
        raise ValueError(f"{src}: arrays or objects nested too deeply; allowed: a FIT.json written by "
                         "hse-opt fit -o") from None
    if not isinstance(d, dict) or d.get("format") != FIT_FORMAT:
        raise ValueError(f"{src}: not a FIT.json (no \"format\": \"{FIT_FORMAT}\"); allowed: a file "
                         "written by hse-opt fit -o")
    if d.get("version") != FIT_VERSION:
        raise ValueError(f"{src}: FIT.json version {d.get('version')!r}; allowed: {FIT_VERSION}")
    try:
        geometry = Geometry(np.array(d["geometry"]["r_zb_s"]), np.array(d["geometry"]["K_g"]))
        if model is None:
            model = Model([make_effect(e) for e in d["effects"]], geometry)
        elif list(model.effect_names) != list(d["effects"]):
            raise ValueError(f"{src}: the file's effects {d['effects']} differ from the model's "
                             f"{list(model.effect_names)}; allowed: a FIT.json of the same effects")
        tilt_known = d["tilt_known"]
        if not isinstance(tilt_known, bool):
            raise ValueError(f"{src}: \"tilt_known\" is {tilt_known!r}; allowed: true or false")
        mm = model.measurement(tilt_known)
        names = tuple(d["names"])
        if names != mm.names:
            raise ValueError(f"{src}: \"names\" {list(names)} do not match the effects' parameters; "
                             f"allowed: {list(mm.names)}, in this order (as hse-opt fit writes them)")
        par = d["parameters"]
        get = lambda key: np.array([par[nm][key] for nm in names], dtype=float)  # noqa: E731
        bound = lambda key, inf: np.array([inf if par[nm][key] is None else par[nm][key]  # noqa: E731
                                           for nm in names], dtype=float)
        runs = d["runs"]
        residuals = np.array(runs["residual_arcsec"], dtype=float) * units.ARCSEC
        sigma = np.array(runs["sigma_arcsec"], dtype=float) * units.ARCSEC
        constraints = tuple(Constraint(c["coefficients"], -math.inf if c["lower"] is None else c["lower"],
                                       math.inf if c["upper"] is None else c["upper"])
                            for c in d.get("constraints", []))
        n, n_runs = len(names), len(runs["run"])
        for key, value, shape in (("covariance", d["covariance"], (n, n)), ("correlation", d["correlation"], (n, n)),
                                  ("p_si", d["p_si"], (n,)), ("residual_arcsec", residuals, (n_runs,)),
                                  ("sigma_arcsec", sigma, (n_runs,)), ("weight", runs["weight"], (n_runs,))):
            x = np.array(value, dtype=float)
            if x.shape != shape or not np.all(np.isfinite(x)):
                raise ValueError(f"{src}: \"{key}\" has shape {x.shape}{'' if x.shape != shape else ' and values that are not finite'}; "
                                 f"allowed: finite numbers of shape {shape} ({n} parameters, {n_runs} runs), "
                                 "as hse-opt fit -o writes them")
        if not np.all(sigma > 0) or not np.all(np.isfinite(get("value"))) or not np.all(get("std") >= 0):
            raise ValueError(f"{src}: values, sigmas or standard deviations that are not finite or not positive; "
                             "allowed: a FIT.json written by hse-opt fit -o")
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # huge numbers are refused by name
            _check_numbers(src, d, mm, names, n_runs)
        return FitResult(
            model=model, tilt_known=tilt_known, names=names, units=tuple(par[nm]["unit"] for nm in names),
            values=get("value"), std=get("std"), covariance=np.array(d["covariance"], dtype=float),
            correlation=np.array(d["correlation"], dtype=float),
            free=np.array([par[nm]["free"] for nm in names], dtype=bool),
            p=np.array(d["p_si"], dtype=float), run=np.array(runs["run"], dtype=np.int64),
            residuals=residuals, sigma=sigma, standardized=residuals / sigma,
            chi2=float(d["chi2"]), dof=int(d["dof"]), chi2_red=float(d["chi2_red"]),
            aic=float(d["aic"]), bic=float(d["bic"]), condition=float(d["condition"]),
            weighting=d["weighting"], method=d["method"], status=d["status"],
            binding=tuple(d["binding"]), downweighted=tuple(int(r) for r in d["downweighted"]),
            notes=tuple(d["notes"]), lower=bound("lower", -np.inf), upper=bound("upper", np.inf),
            constraints=constraints,
            active=tuple(str(c) for c, cd in zip(constraints, d.get("constraints", [])) if cd.get("active")),
            weights=np.array(runs["weight"], dtype=float), chi2_prior=float(d.get("chi2_prior", 0.0)),
            inputs=(np.array([runs["inputs"][k] for k in RUN_FIELDS + tuple(mm.covariates)], dtype=float)
                    if "inputs" in runs else None),
            confounded=tuple(_group(g) for g in d.get("confounded", [])),
            lack_of_fit=_lack_of_fit(d.get("lack_of_fit")),
            **_systematic(par, names, get("std")))
    except (KeyError, TypeError, IndexError, OverflowError, AttributeError) as err:
        raise ValueError(f"{src}: FIT.json is missing or has a malformed entry {err}; allowed: a file "
                         "written by hse-opt fit -o") from None
    except ValueError as err:  # a value that is no number, an unknown effect: named with the file
        if str(err).startswith(src):
            raise
        allowed = "" if "allowed" in str(err) else "; allowed: a FIT.json written by hse-opt fit -o"
        raise ValueError(f"{src}: {err}{allowed}") from None


def _lack_of_fit(d):
    """The ``lack_of_fit`` entry as a :class:`~hse_opt.fit.weights.LackOfFit` (None: absent)."""
    from .weights import LackOfFit
    if d is None:
        return None
    dof = tuple(int(x) for x in d["dof"])
    value = LackOfFit(float(d["statistic"]), dof, float(d["p_value"]), int(d["groups"]))
    if len(dof) != 2 or min(dof) < 1 or not value.statistic >= 0 or not 0 <= value.p_value <= 1:
        raise ValueError(f"\"lack_of_fit\" {d}: allowed an F >= 0, two degrees of freedom >= 1 and a p-value "
                         "in [0, 1], as hse-opt fit -o writes it")
    return value


def _check_numbers(src, d, mm, names, n_runs):
    """ValueError naming the first field of the FIT.json object ``d`` whose numbers disagree
    with the others or with the model ``mm`` (the module docstring's list)."""
    from ..ranges import RANGES

    def refuse(field, problem, allowed):
        raise ValueError(f"{src}: \"{field}\" {problem}; allowed: {allowed}")

    par = d["parameters"]
    n = len(names)
    value = np.array([par[nm]["value"] for nm in names], dtype=float)
    std = np.array([par[nm]["std"] for nm in names], dtype=float)
    free = [par[nm]["free"] for nm in names]
    p_si = np.array(d["p_si"], dtype=float)
    cov = np.array(d["covariance"], dtype=float)
    corr = np.array(d["correlation"], dtype=float)
    for nm, v, sd in zip(names, value, std):
        if not (np.isfinite(v) and np.isfinite(sd)):
            refuse(f"parameters.{nm}", f"has value {v} and std {sd}", "finite numbers")
    for nm in names:
        if not isinstance(par[nm]["free"], bool):
            refuse(f"parameters.{nm}.free", f"is {par[nm]['free']!r}", "true or false")
    for i, (nm, q) in enumerate(zip(names, mm.params)):
        with np.errstate(over="ignore", invalid="ignore"):
            si = value[i] * q.scale
        if not abs(p_si[i] - si) <= AGREE_RTOL * max(abs(p_si[i]), abs(si)):
            refuse(f"p_si[{i}]", f"= {p_si[i]:.17g} but parameters.{nm}.value {value[i]:.17g} {q.unit} is "
                   f"{si:.17g} in SI", f"p_si = value x {q.scale:.17g} (one {q.unit} in SI), as hse-opt fit -o "
                   "writes them (one of the two was edited)")
        lo, hi = par[nm]["lower"], par[nm]["upper"]
        lo = -math.inf if lo is None else float(lo)
        hi = math.inf if hi is None else float(hi)
        if not lo <= value[i] <= hi:
            refuse(f"parameters.{nm}.value", f"= {value[i]:.6g} {q.unit} is outside the fit's own bounds "
                   f"[{lo:g}, {hi:g}]", "a value within its lower and upper")
        if not free[i]:
            if std[i] != 0 or np.any(cov[i] != 0) or np.any(cov[:, i] != 0):
                refuse(f"parameters.{nm}.std", f"= {std[i]:.6g} (or its covariance row is not 0) for a held "
                       "parameter", "std 0 and a zero covariance row for a parameter with free = false")
            continue
        if not q.lower <= value[i] <= q.upper:
            refuse(f"parameters.{nm}.value", f"= {value[i]:.6g} {q.unit} is outside the range its effect "
                   f"declares", f"{q.lower:g} <= {nm} <= {q.upper:g} {q.unit}")
        if not 0 <= std[i] <= q.upper - q.lower:
            refuse(f"parameters.{nm}.std", f"= {std[i]:.6g} {q.unit}: the calibration does not determine {nm}",
                   f"0 <= std <= {q.upper - q.lower:g} {q.unit} (the width of its declared range "
                   f"[{q.lower:g}, {q.upper:g}])")
    scale = np.sqrt(np.abs(np.diag(cov)))
    tol = AGREE_RTOL * np.maximum(np.outer(scale, scale), np.finfo(float).tiny)
    if np.any(np.abs(cov - cov.T) > tol):
        i, j = np.unravel_index(np.argmax(np.abs(cov - cov.T) - tol), cov.shape)
        refuse(f"covariance[{i}][{j}]", f"= {cov[i, j]:.6g} but covariance[{j}][{i}] = {cov[j, i]:.6g}",
               "a symmetric matrix")
    if not np.allclose(std, scale, rtol=AGREE_RTOL, atol=0.0) or np.any(np.diag(cov) < 0):
        i = int(np.argmax(np.abs(std - scale) - AGREE_RTOL * scale))
        refuse(f"parameters.{names[i]}.std", f"= {std[i]:.6g} but the covariance's diagonal gives "
               f"sqrt({cov[i, i]:.6g})", "std = sqrt(covariance[i][i]), as hse-opt fit -o writes them")
    if n:
        s = np.where(scale > 0, scale, 1.0)  # as a correlation matrix: one scale for every parameter
        eig = np.linalg.eigvalsh(0.5 * (cov + cov.T) / np.outer(s, s))
        if eig.min() < -PSD_RTOL * max(eig.max(), 1.0):
            refuse("covariance", f"is not positive semidefinite (eigenvalue {eig.min():.3g})",
                   "a covariance matrix (symmetric, no negative eigenvalue)")
    with np.errstate(divide="ignore", invalid="ignore"):
        expected = np.where(np.outer(std, std) > 0, cov / np.outer(std, std), 0.0)
    if np.any(np.abs(corr - expected) > 1e-6):
        i, j = np.unravel_index(np.argmax(np.abs(corr - expected)), corr.shape)
        refuse(f"correlation[{i}][{j}]", f"= {corr[i, j]:.6g} but the covariance gives {expected[i, j]:.6g}",
               "correlation = covariance / (std_i std_j), as hse-opt fit -o writes it")
    inputs = d["runs"].get("inputs")
    if inputs is None:
        return
    for name in RUN_FIELDS + tuple(mm.covariates):
        row = np.array(inputs[name], dtype=float)
        if row.shape != (n_runs,) or not np.all(np.isfinite(row)):
            refuse(f"runs.inputs.{name}", f"has shape {row.shape} or numbers that are not finite",
                   f"{n_runs} finite numbers (one per run)")
        if name in _INPUT_RANGES:
            key, factor = _INPUT_RANGES[name]
            bad = ~RANGES[key].contains(row / factor)
            if bad.any():
                k = int(np.argmax(bad))
                refuse(f"runs.inputs.{name}[{k}]", f"= {row[k]:.6g} (SI) is {row[k] / factor:.6g} {key}",
                       RANGES[key].allowed(key))
