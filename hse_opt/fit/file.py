"""FIT.json, the calibration file: :func:`save_fit` writes a :class:`~hse_opt.fit.FitResult`,
:func:`load_fit` reads it back (the model rebuilt from its effect names)."""
import json
import math
import os

import numpy as np

from .. import units
from .result import Constraint, FitResult
from ..model.composition import Model
from ..model.effects import effect as make_effect
from ..model.measurement import RUN_FIELDS
from ..model.symbolic import Geometry

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
                             f"{list(model.effect_names)}")
        tilt_known = bool(d["tilt_known"])
        mm = model.measurement(tilt_known)
        names = tuple(d["names"])
        if names != mm.names:
            raise ValueError(f"{src}: parameters {list(names)} do not match the model's "
                             f"{list(mm.names)}")
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
                    if "inputs" in runs else None))
    except (KeyError, TypeError, IndexError, OverflowError, AttributeError) as err:
        raise ValueError(f"{src}: FIT.json is missing or has a malformed entry {err}; allowed: a file "
                         "written by hse-opt fit -o") from None
    except ValueError as err:  # a value that is no number, an unknown effect: named with the file
        if str(err).startswith(src):
            raise
        allowed = "" if "allowed" in str(err) else "; allowed: a FIT.json written by hse-opt fit -o"
        raise ValueError(f"{src}: {err}{allowed}") from None
