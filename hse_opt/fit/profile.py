"""Fits with nonlinear parameters profiled (the warm-up time constant): a Gauss-Newton start
cannot see them where their heading signature vanishes, so :func:`fit_profiled` first searches
each over its declared range with the other parameters solved linearly, then fits from there."""
import dataclasses
import math

import numpy as np

from .least_squares import fit
from ..information import UnidentifiableError
from ..model.composition import as_model


def fit_profiled(runs, model=None, *, fix=None, tilt_known=None, start=None):
    """:func:`hse_opt.fit.fit` from ``start`` (display units; names outside the model are
    ignored). Free nonlinear parameters (the warm-up time constant) are first profiled - a grid
    and Brent search over the parameter, the model's other parameters solved linearly at each
    value - because a Gauss-Newton start cannot see them where their heading signature
    vanishes; the fit then starts from the profile optimum with every parameter free. When the
    data cannot estimate a nonlinear parameter jointly with the rest (or the iteration leaves
    its bounds), it is held at its profile optimum: the FitResult's dof, AIC and BIC count it as
    fitted and a note says so.

    Parameters and errors as :func:`hse_opt.fit.fit` (``fix``, ``tilt_known``, ``start``)."""
    from scipy import optimize  # here: the plain fit command loads no scipy
    model = as_model(model)
    fix = dict(fix or {})
    tk = runs.pitch is not None if tilt_known is None else bool(tilt_known)
    mm = model.measurement(tk)
    start = {k: v for k, v in (start or {}).items() if k in mm.names and k not in fix}
    nonlinear = [q for q in mm.nonlinear if q not in fix]
    if not nonlinear:
        return fit(runs, model, fix=fix, tilt_known=tk, start=start)
    for name in nonlinear:
        q = mm.params[mm.parameter_index(name)]
        objective = _profile_objective(runs, mm, fix, start, name)
        grid = np.linspace(math.log(q.lower), math.log(q.upper), 13)
        values = [objective(u)[0] for u in grid]
        i = int(np.argmin(values))
        res = optimize.minimize_scalar(lambda u: objective(u)[0], method="bounded",
                                       bounds=(grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]),
                                       options={"xatol": 1e-3})
        start = objective(res.x if res.fun <= values[i] else grid[i])[1]
    held = {n: start[n] for n in nonlinear}
    f_held = fit(runs, model, fix={**fix, **held}, tilt_known=tk, start=start)
    f = None
    # a profile optimum at a bound is set by the bound, not the data: no joint fit from there
    # (IPOPT would spend its iterations on a direction the data do not see)
    if all(_inside(mm, n, start[n], margin=1e-3) for n in nonlinear):
        try:
            f = fit(runs, model, fix=fix, tilt_known=tk, start=start)
        except (UnidentifiableError, RuntimeError, np.linalg.LinAlgError, ValueError):
            # the held fit validated the inputs: failing here means the data cannot estimate
            # the nonlinear parameters jointly with the rest (or the iteration diverged)
            pass
    if f is not None and all(_inside(mm, n, f.value(n)[0], margin=1e-3) for n in nonlinear) \
            and f.chi2 <= f_held.chi2 * (1 + 1e-9):
        return f
    dof = f_held.dof - len(held)
    if dof < 1:
        raise ValueError(f"{runs.source}: {f_held.n_runs} runs cannot fit the model's free parameters and "
                         f"{', '.join(held)}; allowed: more runs, or some parameters held with --fix")
    text = ", ".join(f"{n} = {v:.4g} {mm.params[mm.parameter_index(n)].unit}"
                     + (" (at its bound)" if not _inside(mm, n, v, margin=1e-3) else "")
                     for n, v in held.items())
    return dataclasses.replace(
        f_held, dof=dof, chi2_red=f_held.chi2 / dof, aic=f_held.aic + 2 * len(held),
        bic=f_held.bic + len(held) * math.log(f_held.n_runs),
        notes=f_held.notes + (f"{text} from a profile search (these runs cannot estimate it jointly "
                              f"with the rest): counted as fitted in dof and BIC, its uncertainty not in "
                              f"the covariance",))


def _inside(mm, name, value, margin=0.0):
    """Whether ``value`` lies inside the bounds of ``name`` (by ``margin``, relative)."""
    q = mm.params[mm.parameter_index(name)]
    if q.lower > 0:  # a scale parameter: relative margin
        return q.lower * (1 + margin) <= value <= q.upper * (1 - margin)
    span = q.upper - q.lower
    return q.lower + margin * span <= value <= q.upper - margin * span


def _profile_objective(runs, mm, fix, start, name):
    """``u -> (weighted RSS, parameters)`` with ``name`` at ``exp(u)`` (display unit) and the
    other free parameters solved by one linearised step from ``start``: exact for models linear
    in them."""
    X = mm.inputs_from_runs(runs)
    y = np.asarray(runs.heading_err, float)
    w = 1.0 / (np.asarray(runs.heading_std, float) if runs.heading_std is not None else np.ones(y.size))
    free = np.array([q not in fix and q != name for q in mm.names])

    def objective(u):
        values = {**start, **fix, name: math.exp(u)}
        p = mm.vector(values)
        r = (y - mm.predict(p, X)) * w
        A = mm.jacobian(p, X)[:, free] * mm.scale[free] * w[:, None]
        step, *_ = np.linalg.lstsq(A, r, rcond=None)
        p_disp = p / mm.scale
        p_disp[free] += step
        return float(np.sum((r - A @ step) ** 2)), dict(zip(mm.names, p_disp.tolist()))

    return objective
