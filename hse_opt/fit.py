"""Weighted least squares of the measurement model to alignment results -> :class:`FitResult`.

``fit(runs, model)`` minimises the sum of squared standardised residuals
``(heading_err - h(p; run)) / sigma`` over the model's free parameters. Models linear in their
parameters converge in one or two Gauss-Newton steps, each solved by QR on the weighted,
column-scaled Jacobian (``method='qr'``).

Weights (reported in ``FitResult.weighting``):

``heading_std``
    the runs' own 1-sigma (``heading_std_arcsec``); the covariance is not rescaled.
``pure-error``
    no sigmas but replicated settings (same rate, azimuth, tilt, duration, latitude): one
    sigma from the scatter within replicate groups, independent of the model.
``residual``
    neither: one sigma from the residuals, ``s^2 = RSS / dof`` (chi2_red is then 1 by
    construction and no goodness-of-fit test is possible).

AIC and BIC are ``chi2 + 2k`` and ``chi2 + k ln n`` when sigma is given or from pure error
(model-independent), and ``n ln(RSS/n) + 2k`` / ``+ k ln n`` when it is from the residuals.
"""
from dataclasses import dataclass, field

import numpy as np

from . import units
from .information import (UnidentifiableError, analyse, describe_runs, fisher, separating_runs,
                          weighted_jacobian)
from .model.measurement import Model, paper_model

__all__ = ["FitResult", "fit", "as_model", "replicate_groups"]


def as_model(model=None):
    """A :class:`Model` from ``None`` (the paper's), a Model, or effect names (``"hse,warmup"``
    or a list; ``hse`` is added when missing)."""
    if model is None:
        return paper_model()
    if isinstance(model, Model):
        return model
    names = [s.strip() for s in model.split(",")] if isinstance(model, str) else list(model)
    names = [n for n in names if n]
    if "hse" not in names:
        names = ["hse"] + names
    return Model(names)


@dataclass(frozen=True, eq=False)
class FitResult:
    """A weighted least-squares calibration. Parameter quantities are in display units
    (``units``); rows of ``covariance``/``correlation`` follow ``names``.

    Attributes
    ----------
    model : Model
    tilt_known : bool
        Whether runs carried pitch/roll (else tilt-coupled terms are free C23 coefficients).
    names, units : tuple of str
        Every parameter of the measurement model, fixed ones included.
    values, std : numpy.ndarray, shape (n_p,)
        Estimates and standard errors (0 for fixed parameters), display units.
    covariance, correlation : numpy.ndarray, shape (n_p, n_p)
    free : numpy.ndarray of bool, shape (n_p,)
    p : numpy.ndarray, shape (n_p,)
        The estimate in SI, for :meth:`MeasurementModel.predict`.
    run : numpy.ndarray of int, shape (n,)
    residuals : numpy.ndarray, shape (n,)
        heading_err - h(p), rad.
    sigma : numpy.ndarray, shape (n,)
        Heading sigma used for each run, rad.
    standardized : numpy.ndarray, shape (n,)
        residuals / sigma.
    chi2, dof, chi2_red, aic, bic, condition : float
    weighting : str
        ``heading_std``, ``pure-error`` or ``residual`` (module docstring).
    method, status : str
        Solver used and its final status.
    binding : tuple of str
        Parameters whose bound binds at the solution.
    downweighted : tuple of int
        Run ids the robust loss down-weighted.
    notes : tuple of str
        What the tool assumed (missing columns, sigma source).
    """

    model: Model
    tilt_known: bool
    names: tuple
    units: tuple
    values: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    free: np.ndarray
    p: np.ndarray
    run: np.ndarray
    residuals: np.ndarray
    sigma: np.ndarray
    standardized: np.ndarray
    chi2: float
    dof: int
    chi2_red: float
    aic: float
    bic: float
    condition: float
    weighting: str
    method: str
    status: str
    binding: tuple = ()
    downweighted: tuple = ()
    notes: tuple = field(default_factory=tuple)

    @property
    def n_runs(self):
        return int(self.run.size)

    @property
    def rms_arcsec(self):
        """RMS of the residuals, arcsec."""
        return float(np.sqrt(np.mean(self.residuals ** 2)) / units.ARCSEC)

    @property
    def measurement(self):
        """The :class:`MeasurementModel` this fit used."""
        return self.model.measurement(self.tilt_known)

    def value(self, name):
        """``(value, std)`` of one parameter, display units."""
        i = self.measurement.parameter_index(name)
        return float(self.values[i]), float(self.std[i])

    def to_dict(self):
        """The JSON form (DESIGN.md contract, plus more keys)."""
        return {
            "effects": list(self.model.effect_names),
            "n_runs": self.n_runs,
            "parameters": {n: {"value": float(v), "std": float(s), "unit": u, "free": bool(f)}
                           for n, v, s, u, f in zip(self.names, self.values, self.std, self.units,
                                                    self.free)},
            "chi2": float(self.chi2), "dof": int(self.dof), "chi2_red": float(self.chi2_red),
            "aic": float(self.aic), "bic": float(self.bic), "rms_arcsec": self.rms_arcsec,
            "condition": float(self.condition), "weighting": self.weighting,
            "method": self.method, "status": self.status, "binding": list(self.binding),
            "downweighted": [int(r) for r in self.downweighted], "notes": list(self.notes),
            "correlation": self.correlation.tolist(),
        }


def replicate_groups(runs):
    """Group label per run: runs with the same settings (rate, azimuth, tilt, duration,
    latitude) share a label. Returns ``(labels, n_groups)``."""
    cols = [runs.rate, runs.azimuth, runs.duration, runs.latitude]
    if runs.pitch is not None:
        cols += [runs.pitch, runs.roll]
    key = np.round(np.column_stack(cols) / 1e-9).astype(np.int64)
    _, labels = np.unique(key, axis=0, return_inverse=True)
    labels = labels.ravel()
    return labels, int(labels.max()) + 1 if labels.size else 0


def pure_error(runs):
    """``(sigma, dof)`` from the scatter within replicate groups (rad), or ``(None, 0)``."""
    labels, g = replicate_groups(runs)
    dof = runs.rate.size - g
    if dof < 2:
        return None, dof
    y = runs.heading_err
    mean = np.bincount(labels, y, g) / np.bincount(labels, minlength=g)
    return float(np.sqrt(np.sum((y - mean[labels]) ** 2) / dof)), dof


def fit(runs, model=None, *, fix=None, tilt_known=None, max_iter=20, start=None):
    """Calibrate ``model`` on ``runs`` by weighted least squares.

    Parameters
    ----------
    runs : hse_opt.data.Runs
    model : Model, str or sequence of str, optional
        Default: the paper's model (``hse``). See :func:`as_model`.
    fix : mapping name -> value (display unit), optional
        Parameters held at a value.
    tilt_known : bool, optional
        Use the runs' pitch/roll (default: when the runs have them).
    start : mapping name -> value (display unit), optional
        Where the iteration starts for free parameters (default: their nominal values); needed
        when a parameter's heading signature vanishes at nominal (a product with another).

    Returns
    -------
    FitResult

    Raises
    ------
    UnidentifiableError
        The runs cannot separate some free parameters (named, with runs that would).
    ValueError
        Bad arguments, too few runs.
    """
    model = as_model(model)
    if tilt_known is None:
        tilt_known = runs.pitch is not None
    if tilt_known and runs.pitch is None:
        raise ValueError(f"{runs.source}: tilt_known=True needs pitch_arcsec/roll_arcsec columns")
    mm = model.measurement(tilt_known)
    X = mm.inputs_from_runs(runs)
    y = np.asarray(runs.heading_err, dtype=float)
    n = y.size
    fix = dict(fix or {})
    p = mm.vector({**(start or {}), **fix})
    free = np.array([name not in fix for name in mm.names])
    k = int(free.sum())
    if n <= k:
        raise ValueError(f"{runs.source}: {n} runs cannot fit {k} free parameters "
                         f"({', '.join(np.array(mm.names)[free])}); need more runs than parameters")

    notes = list(runs.notes)
    if runs.heading_std is not None:
        sigma, weighting = np.asarray(runs.heading_std, dtype=float), "heading_std"
    else:
        s_pe, dof_pe = pure_error(runs)
        if s_pe is not None and s_pe > 0:
            sigma, weighting = np.full(n, s_pe), "pure-error"
            notes.append(f"sigma {s_pe / units.ARCSEC:.3g} arcsec from {dof_pe} replicate degrees "
                         f"of freedom (pure error)")
        else:
            sigma, weighting = np.ones(n), "residual"

    scale = mm.scale
    names_free = [nm for nm, f in zip(mm.names, free) if f]

    def advice(direction):
        shared = describe_runs(X)
        cand = separating_runs(lambda Xc: mm.jacobian(p, Xc)[:, free], X, direction, scale[free])
        text = ("; ".join(shared) + ". ") if shared else ""
        runs_txt = ", ".join(f"{c['rate_dps']:+.4g} deg/s at azimuth {c['azimuth_deg']:.4g} deg"
                             for c in cand)
        return f"{text}Runs that would separate them: {runs_txt}"

    status = "max_iter"
    for it in range(max_iter):
        r = (y - mm.predict(p, X)) / sigma
        A = weighted_jacobian(mm.jacobian(p, X)[:, free], sigma, scale[free])
        if it == 0:
            analyse(A.T @ A, names_free, [q.unit for q, f in zip(mm.params, free) if f],
                    advice=advice)
        Q, R = np.linalg.qr(A)
        step = np.linalg.solve(R, Q.T @ r)  # display units
        p = p.copy()
        p[free] += step * scale[free]
        # converged when the step is a negligible fraction of each parameter's sigma
        if np.all(np.abs(step) <= 1e-6 * np.linalg.norm(np.linalg.inv(R), axis=1)):
            status = "converged"
            break
    if status != "converged":
        raise RuntimeError(f"Gauss-Newton did not converge in {max_iter} iterations "
                           f"(last step {np.abs(step).max():.3g} display units); status {status}")

    res = y - mm.predict(p, X)
    J = mm.jacobian(p, X)
    rss_w = float(np.sum((res / sigma) ** 2))
    dof = n - k
    if weighting == "residual":
        s = np.sqrt(rss_w / dof)
        sigma = np.full(n, s)
        notes.append(f"sigma {s / units.ARCSEC:.3g} arcsec estimated from the residuals")
    info = analyse(fisher(J[:, free], sigma, scale[free]), names_free,
                   [q.unit for q, f in zip(mm.params, free) if f])
    cov = np.zeros((len(mm.names), len(mm.names)))
    cov[np.ix_(free, free)] = info.covariance
    std = np.sqrt(np.diag(cov))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = np.where(np.outer(std, std) > 0, cov / np.outer(std, std), 0.0)
    chi2 = float(np.sum((res / sigma) ** 2))
    if weighting == "residual":
        ll_term = n * np.log(np.sum(res ** 2) / n)
    else:
        ll_term = chi2
    return FitResult(
        model=model, tilt_known=tilt_known, names=mm.names, units=tuple(q.unit for q in mm.params),
        values=p / scale, std=std, covariance=cov, correlation=corr, free=free, p=p,
        run=np.asarray(runs.run), residuals=res, sigma=sigma, standardized=res / sigma,
        chi2=chi2, dof=dof, chi2_red=chi2 / dof, aic=ll_term + 2 * k, bic=ll_term + k * np.log(n),
        condition=info.condition, weighting=weighting, method="qr", status=status,
        notes=tuple(notes))
