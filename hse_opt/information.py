"""Jacobian -> Fisher information -> covariance, and identifiability.

Shared by the fit, the experiment design and the diagnosis, so that a parameter's predicted
sigma, its fitted standard error and the diagnosis' score tests all come from one place.

Parameters are handled in their *display units* here (arcsec, deg/h, us, ...: the units of
:class:`~hse_opt.model.Param`), which keeps the information matrix well scaled; ``scale``
converts (``value_si = value * scale``). Jacobians come in SI (rad per SI unit) from
:meth:`hse_opt.model.MeasurementModel.jacobian`.
"""
from dataclasses import dataclass

import numpy as np

from . import units
from .frames import EARTH_RATE

#: Angle random walk of the default simulated system (``arw_dph_rthz = 0.0120``), rad/sqrt(s).
DEFAULT_ARW = 0.0120 * units.DEG_PER_H
#: A column-normalised Jacobian with a condition number above this cannot be trusted to
#: separate parameters: the fit, the design and the diagnosis raise.
MAX_CONDITION = 1e6


def heading_sigma(duration, latitude, arw=DEFAULT_ARW, floor=0.0):
    """1-sigma heading error of one gyrocompass alignment (rad).

    White rate noise of density ``arw`` averaged over ``duration`` gives an east-rate error
    ``arw / sqrt(T)``, read as heading through the horizontal Earth rate ``w_ie cos L``;
    ``floor`` (rad) adds in quadrature (run-to-run effects the noise does not cover).

    Parameters
    ----------
    duration : array_like
        Alignment length, s.
    latitude : array_like
        Latitude, rad.
    arw : float
        Angle random walk, rad/sqrt(s) (default: the default simulated system, whose
        10-minute scatter matches the paper's Table 1).
    floor : float
        Run-to-run heading scatter not from the gyro noise, rad.
    """
    duration = np.asarray(duration, dtype=float)
    latitude = np.asarray(latitude, dtype=float)
    if np.any(duration <= 0):
        raise ValueError("duration must be > 0 s")
    if np.any(np.abs(latitude) >= np.pi / 2):
        raise ValueError("|latitude| must be < 90 deg: the gyrocompass needs a horizontal Earth rate")
    if arw < 0 or floor < 0:
        raise ValueError(f"arw and floor must be >= 0, got arw={arw}, floor={floor}")
    white = arw / (EARTH_RATE * np.cos(latitude) * np.sqrt(duration))
    return np.hypot(white, floor)


class UnidentifiableError(ValueError):
    """The data cannot separate some parameters.

    Attributes
    ----------
    names : tuple of str
        The confounded parameters (those in the near-null direction of the information).
    direction : numpy.ndarray
        That direction, in display units, normalised.
    condition : float
        Condition number of the column-normalised Jacobian.
    """

    def __init__(self, message, names, direction=None, condition=np.inf):
        super().__init__(message)
        self.names = tuple(names)
        self.direction = direction
        self.condition = condition


@dataclass(frozen=True)
class Information:
    """The Fisher information of a set of runs and what follows from it.

    Attributes
    ----------
    names, units : tuple of str
        Parameters and their display units, in the model's order.
    fisher : numpy.ndarray, shape (n_p, n_p)
        Information matrix, per display unit squared.
    covariance, correlation : numpy.ndarray, shape (n_p, n_p)
        Inverse of ``fisher`` (display units) and its correlation form.
    std : numpy.ndarray, shape (n_p,)
        Predicted standard deviations, display units.
    condition : float
        Condition number of the column-normalised weighted Jacobian.
    """

    names: tuple
    units: tuple
    fisher: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    std: np.ndarray
    condition: float

    def std_of(self, name):
        """Predicted standard deviation of one parameter (display unit)."""
        return float(self.std[_index(self.names, name)])


def _index(names, name):
    try:
        return list(names).index(name)
    except ValueError:
        raise ValueError(f"unknown parameter {name!r}; allowed: {', '.join(names)}") from None


def weighted_jacobian(J, sigma, scale):
    """``J`` (n, n_p, rad per SI unit) -> rows divided by ``sigma`` (rad), columns per display
    unit: the Jacobian of the standardised residuals in display units."""
    J = np.asarray(J, dtype=float)
    sigma = np.broadcast_to(np.asarray(sigma, dtype=float), (J.shape[0],))
    if np.any(~np.isfinite(sigma)) or np.any(sigma <= 0):
        raise ValueError("heading sigmas must be finite and > 0")
    return J * np.asarray(scale, dtype=float)[None, :] / sigma[:, None]


def fisher(J, sigma, scale, weights=None):
    """Fisher information (display units) of runs with Jacobian ``J`` and heading sigma.

    ``weights`` (n,), optional, multiplies each run's information: repeats in a design, or
    the approximate design's candidate weights.
    """
    A = weighted_jacobian(J, sigma, scale)
    if weights is not None:
        A = A * np.sqrt(np.asarray(weights, dtype=float))[:, None]
    return A.T @ A


def condition_number(F):
    """Condition number of the column-normalised information's square root (that of the
    column-normalised weighted Jacobian); ``inf`` when a parameter has no information."""
    d = np.sqrt(np.clip(np.diag(F), 0.0, None))
    if np.any(d == 0):
        return np.inf
    lam = np.linalg.eigvalsh(F / np.outer(d, d))
    if lam[0] <= 0:
        return np.inf
    return float(np.sqrt(lam[-1] / lam[0]))


def check_identifiable(F, names, max_condition=MAX_CONDITION, advice=None):
    """Raise :class:`UnidentifiableError` naming the confounded parameters when the
    information ``F`` (display units) cannot separate them; return the condition number.

    ``advice(direction)``, optional, returns a sentence on which runs would separate them.
    """
    names = tuple(names)
    d = np.sqrt(np.clip(np.diag(F), 0.0, None))
    blind = [n for n, v in zip(names, d) if v == 0 or not np.isfinite(v)]
    if blind:
        v = np.array([1.0 if n in blind else 0.0 for n in names])
        raise UnidentifiableError(
            f"the data carry no information on {', '.join(blind)}: these runs do not move the "
            f"heading through them" + _advice(advice, v), blind, v)
    lam, vec = np.linalg.eigh(F / np.outer(d, d))
    cond = np.inf if lam[0] <= 0 else float(np.sqrt(lam[-1] / lam[0]))
    if cond > max_condition:
        v = vec[:, 0] / d  # back to display units
        v_n = vec[:, 0]
        conf = [n for n, c in zip(names, v_n) if abs(c) > 0.1 * np.abs(v_n).max()]
        combo = " ".join(f"{'-' if c < 0 else '+'} {abs(c):.3g}*{n}"
                         for n, c in zip(names, v / np.abs(v).max()) if n in conf).lstrip("+ ")
        raise UnidentifiableError(
            f"parameters {', '.join(conf)} cannot be told apart by these runs (condition number "
            f"{cond:.3g} > {max_condition:.3g}; the combination {combo} is not observed)"
            + _advice(advice, v), conf, v / np.linalg.norm(v), cond)
    return cond


def _advice(advice, direction):
    if advice is None:
        return ""
    text = advice(direction)
    return f". {text[:1].upper()}{text[1:]}" if text else ""


def analyse(F, names, units_, max_condition=MAX_CONDITION, advice=None):
    """:class:`Information` from a Fisher matrix, after the identifiability check."""
    cond = check_identifiable(F, names, max_condition, advice)
    d = np.sqrt(np.diag(F))
    # invert the normalised matrix (well scaled), then undo the scaling
    cov = np.linalg.inv(F / np.outer(d, d)) / np.outer(d, d)
    cov = 0.5 * (cov + cov.T)
    var = np.diag(cov)
    if np.any(var <= 0):
        bad = [n for n, v in zip(names, var) if v <= 0]
        raise UnidentifiableError(f"covariance of {', '.join(bad)} is not positive: the information "
                                  f"matrix is numerically singular", bad)
    std = np.sqrt(var)
    return Information(tuple(names), tuple(units_), F, cov, cov / np.outer(std, std), std, cond)


def describe_runs(X):
    """Sentences on what every run in ``X`` (measurement-model inputs) shares: the factors the
    runs do not vary, which is usually why parameters cannot be separated."""
    rate, az, pitch, roll = X[0], X[1], X[2], X[3]
    out = []
    if np.ptp(np.abs(rate)) < 1e-9:
        out.append(f"every run is at |rate| {abs(rate[0]) / units.DEG_PER_S:.4g} deg/s")
    if np.all(rate > 0) or np.all(rate < 0):
        out.append("every run turns the same sense")
    if np.ptp(np.angle(np.exp(1j * (az - az[0])))) < 1e-6:
        out.append(f"every run is at azimuth {np.rad2deg(az[0]) % 360:.4g} deg")
    elif np.unique(np.round(np.rad2deg(az) % 360, 3)).size < 3:
        out.append("the runs use fewer than 3 azimuths")
    if np.ptp(X[6]) < 1e-9:
        out.append(f"every run lasts {X[6][0]:.4g} s")
    return out


def separating_runs(jacobian, X, direction, scale, k=3):
    """Candidate runs that best observe ``direction`` (display units) in parameter space.

    Candidates vary each factor of the existing runs ``X``: both rotation senses at the
    smallest and largest |rate|, azimuths every 45 deg, the existing durations, start times
    and tilts. ``jacobian(X_c)`` returns dh/dp (n_c, n_p, SI). Returns up to ``k`` dicts
    (``rate_dps``, ``azimuth_deg``) best first, and their normalised signal on ``direction``.
    """
    r = np.abs(X[0])
    rates = np.unique(np.concatenate([[r.min(), r.max()], [-r.min(), -r.max()]]))
    az = np.deg2rad(np.arange(0, 360, 45.0))
    R, A = np.meshgrid(rates, az, indexing="ij")
    n = R.size
    Xc = np.repeat(X[:, :1], n, axis=1).copy()
    Xc[0], Xc[1] = R.ravel(), A.ravel()
    Jc = jacobian(Xc) * np.asarray(scale)[None, :]
    signal = np.abs(Jc @ direction) / np.maximum(np.linalg.norm(Jc, axis=1), 1e-300)
    best = np.argsort(-signal)[:k]
    return [{"rate_dps": float(Xc[0, i] / units.DEG_PER_S), "azimuth_deg": float(np.rad2deg(Xc[1, i])),
             "signal": float(signal[i])} for i in best]


def prior_fisher(prior, names):
    """Prior information (display units) on ``names`` from an earlier calibration.

    ``prior`` is a :class:`~hse_opt.fit.FitResult`, or a mapping in the fit's JSON form
    (``parameters``: name -> ``std`` (and ``free``), optional ``correlation`` in the same
    order; without it the estimates are taken as uncorrelated). The covariance of the
    parameters both share is inverted (the prior's other parameters are marginalised out);
    parameters the prior does not have get no prior information.

    Returns
    -------
    numpy.ndarray, shape (len(names), len(names))
    """
    names = tuple(names)
    if hasattr(prior, "covariance") and hasattr(prior, "names"):
        p_names = tuple(prior.names)
        cov = np.asarray(prior.covariance, dtype=float)
        free = np.asarray(getattr(prior, "free", np.ones(len(p_names), bool)), dtype=bool)
    elif isinstance(prior, dict) and isinstance(prior.get("parameters"), dict):
        params = prior["parameters"]
        p_names = tuple(params)
        try:
            std = np.array([float(params[n]["std"]) for n in p_names])
        except (KeyError, TypeError, ValueError):
            raise ValueError("prior: every entry of 'parameters' needs a numeric 'std' (display units)") from None
        corr = np.asarray(prior.get("correlation", np.eye(len(p_names))), dtype=float)
        if corr.shape != (len(p_names), len(p_names)):
            raise ValueError(f"prior: 'correlation' has shape {corr.shape}; allowed: ({len(p_names)}, "
                             f"{len(p_names)}) in the order of 'parameters'")
        cov = corr * np.outer(std, std)
        free = np.array([bool(params[n].get("free", True)) and std[i] > 0 for i, n in enumerate(p_names)])
    else:
        raise ValueError(f"prior: a FitResult or the fit's JSON mapping is required, got {type(prior).__name__}")
    if not np.all(np.isfinite(cov)):
        raise ValueError("prior: the covariance is not finite")
    shared = [n for n, f in zip(p_names, free) if f and n in names]
    F = np.zeros((len(names), len(names)))
    if not shared:
        return F
    i = [p_names.index(n) for n in shared]
    sub = cov[np.ix_(i, i)]
    try:
        info = np.linalg.inv(np.linalg.cholesky(sub))
    except np.linalg.LinAlgError:
        raise ValueError(f"prior: the covariance of {', '.join(shared)} is not positive definite") from None
    info = info.T @ info
    j = [names.index(n) for n in shared]
    F[np.ix_(j, j)] = info
    return F
