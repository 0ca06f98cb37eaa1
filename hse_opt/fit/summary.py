"""A fit as a report shows it: :func:`report_data` (plain data, display units)."""
import numpy as np

from .. import units
from ..model.inputs import RunInputs


def report_data(fit_result, runs):
    """Everything a report shows about a fit, as plain data (display units).

    Returns a dict: ``fit`` (:meth:`FitResult.to_dict`), ``runs`` (columns ``run``,
    ``rate_dps``, ``azimuth_deg``, ``t_start_s``, ``heading_err_arcsec``,
    ``predicted_arcsec``, ``residual_arcsec``, ``standardized``, ``weight``,
    ``sigma_arcsec``) and ``parameters`` (rows of name, value, std, systematic (None when not assessed), unit,
    free, bound state, description).
    """
    mm = fit_result.measurement
    if len(runs) != fit_result.n_runs or not np.array_equal(np.asarray(runs.run), fit_result.run):
        raise ValueError(f"{runs.source}: these runs are not the ones the fit used (run ids differ)")
    predicted = runs.heading_err - fit_result.residuals
    t_start = RunInputs(mm.inputs_from_runs(runs)).t_start  # the model's (run order when absent)
    rows = []
    for i, q in enumerate(mm.params):
        state = ("fixed" if not fit_result.free[i] else "at bound" if q.name in fit_result.binding
                 else "free")
        rows.append({"name": q.name, "value": float(fit_result.values[i]), "std": float(fit_result.std[i]),
                     "systematic": (None if fit_result.systematic is None else float(fit_result.systematic[i])),
                     "unit": q.unit, "state": state, "description": q.description})
    return {
        "fit": fit_result.to_dict(),
        "runs": {"run": fit_result.run.tolist(), "rate_dps": (runs.rate / units.DEG_PER_S).tolist(),
                 "azimuth_deg": (runs.azimuth / units.DEG).tolist(), "t_start_s": t_start.tolist(),
                 "heading_err_arcsec": (runs.heading_err / units.ARCSEC).tolist(),
                 "predicted_arcsec": (predicted / units.ARCSEC).tolist(),
                 "residual_arcsec": (fit_result.residuals / units.ARCSEC).tolist(),
                 "standardized": fit_result.standardized.tolist(),
                 "weight": (fit_result.weights if fit_result.weights is not None
                            else np.ones(fit_result.n_runs)).tolist(),
                 "sigma_arcsec": (fit_result.sigma / units.ARCSEC).tolist()},
        "parameters": rows,
    }
