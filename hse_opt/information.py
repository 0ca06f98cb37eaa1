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
from .model.inputs import RunInputs, Tilt

#: Angle random walk of the default simulated system (``arw_dph_rthz = 0.0120``), rad/sqrt(s).
DEFAULT_ARW = 0.0120 * units.DEG_PER_H
#: A column-normalised Jacobian with a condition number above this cannot be trusted to
#: separate parameters: the fit, the design and the diagnosis raise.
MAX_CONDITION = 1e6


#: a parameter that moves no run's heading by this much across its whole declared range
#: (``Param.upper - Param.lower``) has no information in the runs: what it leaves in the
#: Jacobian is rounding, which column normalisation would otherwise blow up
SENSITIVITY_FLOOR = 1e-6 * units.ARCSEC


def invisible(J, ranges, floor=SENSITIVITY_FLOOR):
    """Mask (n_p,) of parameters whose heading signature is below ``floor`` (rad) in every run
    across their whole range. ``J`` (n, n_p): dh/dp, rad per display unit; ``ranges`` (n_p,),
    display units."""
    J = np.asarray(J, dtype=float)
    reach = np.abs(J).max(axis=0, initial=0.0) * np.asarray(ranges, dtype=float)
    return reach < floor


def blind_out(F, mask):
    """``F`` with the rows and columns of ``mask`` set to zero (they carry only rounding)."""
    F = np.array(F, dtype=float)
    F[mask, :] = 0.0
    F[:, mask] = 0.0
    return F


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


def null_space(C, k):
    """Orthonormal basis (k, k - rank) of the directions ``dz`` with ``C dz = 0``; the identity
    when ``C`` has no rows. ``C`` (m, k): active linear constraints on k parameters."""
    C = np.asarray(C, dtype=float).reshape(-1, k)
    if C.shape[0] == 0:
        return np.eye(k)
    u, s, vt = np.linalg.svd(C)
    rank = int(np.sum(s > 1e-12 * max(s.max(), 1e-300)))
    return vt[rank:].T.copy()


def _reduce(F, Z):
    """Information on the reduced coordinates ``u`` of ``z = Z u`` and its diagonal scaling."""
    Fr = Z.T @ F @ Z
    return Fr, np.sqrt(np.clip(np.diag(Fr), 0.0, None))


def check_identifiable(F, names, max_condition=MAX_CONDITION, advice=None, Z=None):
    """Raise :class:`UnidentifiableError` naming the confounded parameters when the
    information ``F`` (display units) cannot separate them; return the condition number.

    ``Z`` (n_p, r), optional: the directions the parameters may still move in (the null space
    of active equality constraints, :func:`null_space`); the check is on ``Z' F Z``.
    ``advice(direction)``, optional, returns a sentence on which runs would separate them.
    """
    names = tuple(names)
    F = np.asarray(F, dtype=float)
    d_full = np.sqrt(np.clip(np.diag(F), 0.0, None))
    Z = np.eye(len(names)) if Z is None else np.asarray(Z, dtype=float)
    if Z.shape[1] == 0:
        return 1.0
    Fr, d = _reduce(F, Z)

    def weight(v):  # how much each parameter takes part in direction v (display units)
        w = np.abs(v) * np.where(d_full > 0, d_full, d_full.max(initial=0.0) or 1.0)
        return w / max(w.max(), 1e-300)

    blind = np.flatnonzero((d == 0) | ~np.isfinite(d))
    if blind.size:
        v = Z[:, blind].sum(axis=1)
        w = np.max([weight(Z[:, j]) for j in blind], axis=0)
        conf = [n for n, c in zip(names, w) if c > 0.1]
        raise UnidentifiableError(
            f"the data carry no information on {', '.join(conf)}: these runs do not move the "
            f"heading through {'it' if len(conf) == 1 else 'them'}" + _advice(advice, v), conf, v)
    lam, vec = np.linalg.eigh(Fr / np.outer(d, d))
    cond = np.inf if lam[0] <= 0 else float(np.sqrt(lam[-1] / lam[0]))
    if cond > max_condition:
        v = Z @ (vec[:, 0] / d)  # back to display units
        w = weight(v)
        conf = [n for n, c in zip(names, w) if c > 0.1]
        vmax = np.abs(v[w > 0.1]).max()
        combo = " ".join(f"{'-' if c < 0 else '+'} {abs(c) / vmax:.3g}*{n}"
                         for n, c, wi in zip(names, v, w) if wi > 0.1).lstrip("+ ")
        raise UnidentifiableError(
            f"parameters {', '.join(conf)} cannot be told apart by these runs (condition number "
            f"{cond:.3g} > {max_condition:.3g}; the combination {combo} is not observed)"
            + _advice(advice, v), conf, v / np.linalg.norm(v), cond)
    return cond


#: parameters whose estimates correlate beyond this cannot be separated by the runs in
#: practice: a 0.99 correlation inflates both sigmas at least 7-fold (1 / sqrt(1 - r^2))
CONFOUNDED_CORRELATION = 0.99
#: a variance inflation above this (sigma 10 times what the parameter would have alone, the
#: others known) names a parameter as confounded (the usual collinearity rule of thumb is 10;
#: 100 flags only what the campaign really cannot separate)
CONFOUNDED_INFLATION = 100.0


@dataclass(frozen=True)
class ConfoundedGroup:
    """Parameters a campaign cannot separate (:func:`confounded`).

    Attributes
    ----------
    names : tuple of str
        The parameters of the group.
    inflation : tuple of float
        Each one's sigma inflation, ``sqrt(VIF)``: its sigma over the sigma it would have if
        the other parameters were known (1 = orthogonal), same order as ``names``.
    correlation : float
        The largest |correlation| between two parameters of the group.
    direction : numpy.ndarray, shape (n_p,)
        The least-observed combination of the parameters (display units, unit norm; zero
        outside the group).
    advice : str
        What the runs share and which runs would separate the group ("" when not asked).
    """

    names: tuple
    inflation: tuple
    correlation: float
    direction: np.ndarray
    advice: str = ""

    def text(self):
        """One sentence: the group, its inflation and correlation, and the advice."""
        infl = ", ".join(f"{n} x{i:.3g}" for n, i in zip(self.names, self.inflation))
        out = (f"{', '.join(self.names)} are confounded by these runs (|r| up to {self.correlation:.4f}; "
               f"sigma inflated {infl})")
        return out + (f": {self.advice}" if self.advice else "")

    def to_dict(self):
        return {"parameters": list(self.names), "inflation": [float(i) for i in self.inflation],
                "max_abs_correlation": float(self.correlation), "advice": self.advice, "text": self.text()}


def confounded(F, covariance, names, advice=None, max_correlation=CONFOUNDED_CORRELATION,
               max_inflation=CONFOUNDED_INFLATION):
    """Groups of parameters the runs cannot separate: near-collinear columns of the weighted
    Jacobian.

    A parameter's variance inflation is ``VIF_j = C_jj F_jj``: its variance over the variance
    it would have with every other parameter known (``1/F_jj``). In the scaled covariance
    ``S = D C D`` (``D = sqrt(diag F)``; ``S = R^-1`` for the correlation form ``R`` of the
    information without constraints), ``diag S`` are the VIFs and every eigenvector of ``S``
    with eigenvalue above ``max_inflation`` is a combination of parameters the runs barely
    observe; its parameters (those with at least a tenth of the largest component) form a
    group, as does every pair with ``|r| > max_correlation``; overlapping groups merge.

    Parameters
    ----------
    F : array_like, shape (k, k)
        Information of the free parameters, display units.
    covariance : array_like, shape (k, k)
        Their covariance (the inverse of ``F``, or the constrained covariance).
    names : sequence of str
    advice : callable, optional
        ``advice(direction)`` -> sentence on the runs that would separate a group
        (:func:`separation_advice`).
    max_correlation, max_inflation : float
        The thresholds (:data:`CONFOUNDED_CORRELATION`, :data:`CONFOUNDED_INFLATION`).

    Returns
    -------
    tuple of ConfoundedGroup
        Largest inflation first; empty when the runs separate every parameter.
    """
    names = tuple(names)
    F = np.asarray(F, dtype=float)
    C = np.asarray(covariance, dtype=float)
    k = len(names)
    if k < 2:
        return ()
    d = np.sqrt(np.clip(np.diag(F), 0.0, None))
    S = C * np.outer(d, d)
    S = 0.5 * (S + S.T)
    vif = np.diag(S).copy()
    sd = np.sqrt(np.clip(np.diag(C), 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        R = np.where(np.outer(sd, sd) > 0, C / np.outer(sd, sd), 0.0)
    np.fill_diagonal(R, 0.0)
    parent = list(range(k))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    def join(members):
        root = find(members[0])
        for j in members[1:]:
            parent[find(j)] = root

    flagged = np.zeros(k, bool)
    lam, V = np.linalg.eigh(S)
    for e in np.flatnonzero(lam > max_inflation):
        u = np.abs(V[:, e])
        members = list(np.flatnonzero(u > 0.1 * u.max()))
        if len(members) > 1:
            join(members)
            flagged[members] = True
    pairs = np.argwhere(np.triu(np.abs(R) > max_correlation, 1))
    for i, j in pairs:
        join([int(i), int(j)])
        flagged[[i, j]] = True
    groups = {}
    for i in np.flatnonzero(flagged):
        groups.setdefault(find(i), []).append(int(i))
    out = []
    for members in groups.values():
        # the least-observed direction within the group (display units)
        sub = np.ix_(members, members)
        _, V_g = np.linalg.eigh(S[sub])
        u = np.zeros(k)
        u[members] = V_g[:, -1]
        z = np.where(d > 0, u / np.where(d > 0, d, 1.0), 0.0)
        z = z / max(np.linalg.norm(z), 1e-300)
        r_max = float(np.abs(R[sub]).max())
        text = advice(z) if advice is not None else ""
        out.append(ConfoundedGroup(tuple(names[i] for i in members),
                                   tuple(float(np.sqrt(max(vif[i], 1.0))) for i in members), r_max, z, text))
    return tuple(sorted(out, key=lambda g: -max(g.inflation)))


def _advice(advice, direction):
    if advice is None:
        return ""
    text = advice(direction)
    return f". {text[:1].upper()}{text[1:]}" if text else ""


def analyse(F, names, units_, max_condition=MAX_CONDITION, advice=None, Z=None):
    """:class:`Information` from a Fisher matrix, after the identifiability check.

    With ``Z`` (see :func:`check_identifiable`) the covariance is that of the constrained
    estimate, ``Z (Z' F Z)^-1 Z'``: parameters the constraints pin have zero variance.
    """
    F = np.asarray(F, dtype=float)
    k = len(names)
    cond = check_identifiable(F, names, max_condition, advice, Z)
    Z = np.eye(k) if Z is None else np.asarray(Z, dtype=float)
    if Z.shape[1]:
        Fr, d = _reduce(F, Z)
        # invert the normalised matrix (well scaled), then undo the scaling
        cov_r = np.linalg.inv(Fr / np.outer(d, d)) / np.outer(d, d)
        cov = Z @ cov_r @ Z.T
    else:
        cov = np.zeros((k, k))
    cov = 0.5 * (cov + cov.T)
    var = np.diag(cov).copy()
    pinned = np.linalg.norm(Z, axis=1) < 1e-9
    var[pinned] = 0.0
    if np.any(var[~pinned] <= 0):
        bad = [n for n, v, p in zip(names, var, pinned) if v <= 0 and not p]
        raise UnidentifiableError(f"covariance of {', '.join(bad)} is not positive: the information "
                                  f"matrix is numerically singular", bad)
    std = np.sqrt(var)
    cov[pinned, :] = 0.0
    cov[:, pinned] = 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = np.where(np.outer(std, std) > 0, cov / np.outer(std, std), 0.0)
    np.fill_diagonal(corr, np.where(std > 0, 1.0, 0.0))
    return Information(tuple(names), tuple(units_), F, cov, corr, std, cond)


def propagated_std(J, covariance, names=None, tol=1e-9):
    """1-sigma of each row of ``J x`` for ``x`` with covariance ``C``: ``sqrt(diag(J C J'))``,
    computed as the row norms of ``J L`` with ``C = L L'`` (:func:`covariance_factor`), so it
    is real and >= 0 by construction - no clipping or ``abs()`` of a negative variance.

    Parameters
    ----------
    J : array_like, shape (n, k)
        Sensitivities of n quantities to k parameters (per display unit).
    covariance : array_like, shape (k, k)
        The parameters' covariance (display units); symmetric positive semidefinite.
    names, tol
        As :func:`covariance_factor`.

    Returns
    -------
    numpy.ndarray, shape (n,)
    """
    J = np.atleast_2d(np.asarray(J, dtype=float))
    return np.linalg.norm(J @ covariance_factor(covariance, names, tol, k=J.shape[1]), axis=1)


def covariance_factor(covariance, names=None, tol=1e-9, k=None):
    """``L`` with ``C = L L'`` (up to rounding) from the eigen-decomposition of ``C``'s
    correlation form.

    Parameters
    ----------
    covariance : array_like, shape (k, k)
        Symmetric positive semidefinite.
    names : sequence of str, optional
        The parameters, for messages.
    tol : float
        Eigenvalues of the correlation matrix above ``-tol`` (rounding of a singular PSD
        matrix, e.g. under equality constraints) count as zero; below, ``C`` is not a
        covariance and ``ValueError`` says along which parameters.
    k : int, optional
        The size ``C`` must have (default its own).

    Returns
    -------
    numpy.ndarray, shape (k, k)
    """
    C = np.asarray(covariance, dtype=float)
    k = C.shape[0] if k is None and C.ndim == 2 else (k or 0)
    names = tuple(names) if names is not None else tuple(f"parameter {i}" for i in range(k))
    if C.shape != (k, k) or not np.all(np.isfinite(C)):
        raise ValueError(f"the covariance of {', '.join(names)} must be a finite {k} x {k} matrix, got "
                         f"shape {C.shape}")
    var = np.diag(C)
    if np.any(var < 0):
        bad = [n for n, v in zip(names, var) if v < 0]
        raise ValueError(f"the covariance gives {', '.join(bad)} a negative variance; allowed: a "
                         "positive semidefinite covariance")
    d = np.sqrt(var)
    s = np.where(d > 0, d, 1.0)
    R = C / np.outer(s, s)  # correlation form; rows of zero-variance parameters must be zero
    if k and np.abs(R - R.T).max() > tol:
        raise ValueError(f"the covariance of {', '.join(names)} is not symmetric")
    lam, V = np.linalg.eigh(0.5 * (R + R.T))
    if k and lam[0] < -tol * max(lam[-1], 1.0):
        w = np.abs(V[:, 0])
        bad = [n for n, c in zip(names, w) if c > 0.1 * w.max()]
        raise ValueError(f"the covariance is not positive semidefinite (eigenvalue {lam[0]:.3g} of its "
                         f"correlation form along {', '.join(bad)})")
    L = (s[:, None] * V) * np.sqrt(np.maximum(lam, 0.0))[None, :]  # C = L L' (up to rounding)
    return L


def describe_runs(X, tilt_known=False):
    """Sentences on what every run in ``X`` (measurement-model inputs) shares: the factors the
    runs do not vary, which is usually why parameters cannot be separated."""
    v = RunInputs(X)
    rate, az = v.rate, v.azimuth
    out = []
    if np.ptp(np.abs(rate)) < 1e-9:
        out.append(f"every run is at |rate| {abs(rate[0]) / units.DEG_PER_S:.4g} deg/s")
    if np.all(rate > 0) or np.all(rate < 0):
        out.append("every run turns the same sense")
    if np.ptp(np.angle(np.exp(1j * (az - az[0])))) < 1e-6:
        out.append(f"every run is at azimuth {np.rad2deg(az[0]) % 360:.4g} deg")
    elif np.unique(np.round(np.rad2deg(az) % 360, 3)).size < 3:
        out.append("the runs use fewer than 3 azimuths")
    if tilt_known:
        c23 = v.c23
        if np.all(np.abs(v.tilt) < units.ARCSEC):
            out.append("every run is level (|pitch|, |roll| < 1 arcsec), so tilt-coupled terms do "
                       "not reach the heading")
        elif np.ptp(c23) < 1e-9:
            out.append(f"the rotation axis has the same east tilt C23 = {c23[0] / units.ARCSEC:.4g} "
                       "arcsec in every run")
    if np.ptp(v.t_start) < 1e-9:
        out.append(f"every run starts {v.t_start[0]:.4g} s after power-on")
    if np.ptp(v.duration) < 1e-9:
        out.append(f"every run lasts {v.duration[0]:.4g} s")
    return out


def separating_runs(jacobian, X, direction, scale, k=3, tilt_known=False):
    """Candidate runs that best observe ``direction`` (display units) in parameter space.

    Candidates vary each factor of the existing runs ``X``: both rotation senses at the
    smallest and largest |rate|, azimuths every 45 deg, start times from power-on (0 s and
    the existing range), and, when every run is level and ``tilt_known``, a 1-mrad pitch or
    roll. ``jacobian(X_c)`` returns dh/dp (n_c, n_p, SI). Returns up to ``k`` dicts best
    first: ``rate_dps``, ``azimuth_deg``, ``t_start_s``, ``pitch_arcsec``, ``roll_arcsec``,
    ``signal`` (normalised signal on ``direction``) and ``text`` (the factors that vary).
    """
    v = RunInputs(X)
    r = np.abs(v.rate)
    rates = np.unique(np.concatenate([[r.min(), r.max()], [-r.min(), -r.max()]]))
    az = np.deg2rad(np.arange(0, 360, 45.0))
    starts = np.unique([0.0, v.t_start.min(), v.t_start.max()])
    tilts = [Tilt(roll=v.roll[0], pitch=v.pitch[0])]
    if tilt_known and np.all(np.abs(v.tilt) < units.ARCSEC):
        tilts += ([Tilt(roll=0.0, pitch=s * units.MRAD) for s in (1, -1)]
                  + [Tilt(roll=s * units.MRAD, pitch=0.0) for s in (1, -1)])
    grid = np.array(np.meshgrid(rates, az, starts, np.arange(len(tilts)), indexing="ij")).reshape(4, -1)
    n = grid.shape[1]
    Xc = np.repeat(X[:, :1], n, axis=1).copy()
    cand = RunInputs(Xc)
    cand.rate, cand.azimuth, cand.t_start = grid[0], grid[1], grid[2]
    cand.tilt = Tilt(*np.array(tilts).T[:, grid[3].astype(int)])
    Jc = jacobian(Xc) * np.asarray(scale)[None, :]
    signal = np.abs(Jc @ direction) / np.maximum(np.linalg.norm(Jc, axis=1), 1e-300)
    # a factor the signal does not depend on is left out of the advice
    grid_signal = signal.reshape(rates.size, az.size, starts.size, len(tilts))
    tol = 1e-9 * max(signal.max(), 1e-300)
    by_az, by_start, by_tilt = (np.ptp(grid_signal, axis=a).max() > tol for a in (1, 2, 3))
    order = np.argsort(-np.round(signal, 12), kind="stable")
    out, seen = [], set()
    for i in order:
        c = {"rate_dps": float(cand.rate[i] / units.DEG_PER_S),
             "azimuth_deg": float(np.rad2deg(cand.azimuth[i])), "t_start_s": float(cand.t_start[i]),
             "pitch_arcsec": float(cand.pitch[i] / units.ARCSEC),
             "roll_arcsec": float(cand.roll[i] / units.ARCSEC), "signal": float(signal[i])}
        text = f"{c['rate_dps']:+.4g} deg/s " + (f"at azimuth {c['azimuth_deg']:.4g} deg" if by_az
                                                  else "at any azimuth")
        if by_start:
            text += f", starting {c['t_start_s']:.4g} s after power-on"
        if by_tilt:
            text += f", pitch {c['pitch_arcsec']:.4g} arcsec, roll {c['roll_arcsec']:.4g} arcsec"
        if text in seen:
            continue
        seen.add(text)
        out.append({**c, "text": text})
        if len(out) == k:
            break
    return out


def separation_advice(measurement, p, X, free, direction):
    """A sentence for :class:`UnidentifiableError`: what the runs ``X`` share and which runs
    would observe ``direction`` (display units, over the ``free`` parameters of
    ``measurement`` at SI values ``p``)."""
    free = np.asarray(free, dtype=bool)
    shared = describe_runs(X, measurement.tilt_known)
    cand = separating_runs(lambda Xc: measurement.jacobian(p, Xc)[:, free], X, direction,
                           measurement.scale[free], tilt_known=measurement.tilt_known)
    text = ("; ".join(shared) + ". ") if shared else ""
    useful = [c["text"] for c in cand if c["signal"] > 1e-6]
    if not useful:
        return text + "No run that varies rate, azimuth, start time or tilt would separate them"
    return f"{text}Runs that would separate them: {'; '.join(useful)}"


@dataclass(frozen=True)
class Prior:
    """Gaussian prior information on parameters, display units.

    Attributes
    ----------
    names : tuple of str
    mean : numpy.ndarray, shape (m,)
    covariance : numpy.ndarray, shape (m, m)
        Symmetric positive definite.
    source : str
        Where the prior comes from (a file, ``'fit'``), for messages.
    """

    names: tuple
    mean: np.ndarray
    covariance: np.ndarray
    source: str = "prior"

    def __post_init__(self):
        names = tuple(self.names)
        mean = np.array(self.mean, dtype=float).reshape(-1)
        cov = np.array(self.covariance, dtype=float)
        m = len(names)
        if len(set(names)) != m:
            raise ValueError(f"{self.source}: prior names repeat: {names}")
        if mean.shape != (m,) or cov.shape != (m, m):
            raise ValueError(f"{self.source}: prior mean {mean.shape} and covariance {cov.shape} do "
                             f"not match {m} names")
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
            raise ValueError(f"{self.source}: prior mean and covariance must be finite")
        if m and (np.abs(cov - cov.T).max() > 1e-9 * np.abs(cov).max()
                  or np.linalg.eigvalsh(0.5 * (cov + cov.T))[0] <= 0):
            bad = [n for n, v in zip(names, np.diag(cov)) if v <= 0] or list(names)
            raise ValueError(f"{self.source}: prior covariance must be symmetric positive definite "
                             f"(check {', '.join(bad)}; a parameter known exactly is fixed, not a prior)")
        for k, v in (("names", names), ("mean", mean), ("covariance", 0.5 * (cov + cov.T))):
            object.__setattr__(self, k, v)

    @classmethod
    def from_fit(cls, fit, source="previous fit"):
        """The estimate and covariance of a :class:`~hse_opt.fit.FitResult`'s free
        parameters (fixed ones and those held at a bound carry no prior)."""
        keep = np.asarray(fit.free, dtype=bool) & (np.asarray(fit.std) > 0)
        return cls(tuple(np.array(fit.names)[keep]), np.asarray(fit.values)[keep],
                   np.asarray(fit.covariance)[np.ix_(keep, keep)], source)

    @classmethod
    def independent(cls, mean, std, source="prior"):
        """Independent priors: ``mean`` and ``std`` map name -> display value."""
        if set(mean) != set(std):
            raise ValueError(f"{source}: prior mean and std must name the same parameters, got "
                             f"{sorted(mean)} and {sorted(std)}")
        names = tuple(mean)
        s = np.array([float(std[n]) for n in names])
        if np.any(~np.isfinite(s)) or np.any(s <= 0):
            bad = [n for n, v in zip(names, s) if not (v > 0 and np.isfinite(v))]
            raise ValueError(f"{source}: prior std of {', '.join(bad)} must be finite and > 0 "
                             "(a parameter known exactly is fixed, not a prior)")
        return cls(names, [float(mean[n]) for n in names], np.diag(s ** 2), source)

    def restrict(self, names):
        """The prior on the parameters of ``names`` it knows (marginalised over the others);
        returns ``(prior, dropped)`` with ``dropped`` the names it had and ``names`` lacks."""
        keep = [i for i, n in enumerate(self.names) if n in set(names)]
        dropped = tuple(n for n in self.names if n not in set(names))
        return (Prior(tuple(self.names[i] for i in keep), self.mean[keep],
                      self.covariance[np.ix_(keep, keep)], self.source), dropped)

    def fisher(self, names):
        """``(F, F @ mean)`` over ``names`` (display units; zero where the prior is silent).
        Names the prior has and ``names`` lacks are marginalised out."""
        names = list(names)
        prior, _ = self.restrict(names)
        k = len(names)
        F, b = np.zeros((k, k)), np.zeros(k)
        if prior.names:
            idx = [names.index(n) for n in prior.names]
            Fp = np.linalg.inv(prior.covariance)
            F[np.ix_(idx, idx)] = 0.5 * (Fp + Fp.T)
            b[idx] = Fp @ prior.mean
        return F, b
