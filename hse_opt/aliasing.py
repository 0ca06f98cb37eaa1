"""What a campaign cannot rule out: the alias budget of the effects missing from a model.

A fitted model is only as good as what the runs could have told apart from it. For every
catalogue effect *not* in the model, at the edge of its plausible range
(:data:`hse_opt.model.plausible.RANGES`), on *these* runs:

Detectability
    the power of the diagnosis's own test of that effect (:mod:`hse_opt.diagnose`: the score /
    nested-model F test of the effect's weighted Jacobian columns against the fit's residual,
    at the diagnosis's level ``alpha / m``, Bonferroni over its ``m`` tests). For Gaussian
    noise the statistic is noncentral F with noncentrality ``lambda = ||(I - P_M) A_E delta||^2``
    (``A_E`` the effect's columns weighted by the runs' sigmas, ``P_M`` the projection on the
    model's columns and, in a field campaign, the positions' unknown constants): the power is
    ``P(F'(q, dof, lambda) > F_crit)``, closed form (:func:`f_sf`, numpy only). The effect is
    *detectable* at a size when the power is at least :data:`POWER_LIMIT` (0.8, the usual
    design target); ``lambda`` grows with the size squared, so the size below which it goes
    undetected (the *threshold*) follows from the noncentrality that gives power 0.8.
Alias shift
    the shift the effect causes in every fitted parameter when present but not modelled: the
    alias matrix ``B = (J_M' W J_M)^-1 J_M' W J_E`` (with a prior, its information inside the
    inverse: ``B = C J_M' W J_E`` with ``C`` the fit's covariance), linearised at the fit;
    shift ``= B delta``.
Worst direction of a multi-parameter effect
    over the vertices of its plausible box (each parameter at +- its edge; the maximum of
    ``|B_i delta|`` over a box is at a vertex). Each vertex is scaled down to the largest size
    the test would miss (power 0.8) when the full vertex would be detected; the parameter's
    shift is the largest over the vertices so scaled. The effect's power is that of its least
    detectable vertex, and its threshold is stated along that vertex (as a fraction of the
    plausible edge, or in the parameter's unit for a one-parameter effect).
Systematic risk
    an effect whose largest *undetectable* shift of a parameter exceeds that parameter's
    statistical 1-sigma: the data would not show it, yet it would move the estimate by more
    than the estimate's own error. ``systematic`` (per parameter, its unit) is the largest such
    shift over the effects; ``systematic_by`` names each effect's. A parameter without risk
    has ``systematic`` 0.

Nonlinear parameters of a missing effect (``warmup_tau``) stay at their nominal value; a
missing effect that acts only in a product with another missing one (``mount_xi`` without
``encoder_harmonic``) and covariate effects (no plausible range) are not assessed, with the
reason. :func:`effect_power` is the detectability alone, for a candidate plan (the design).
"""
from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass

import numpy as np

from .information import weighted_jacobian
from .model import CATALOGUE, as_model
from .model.composition import Model
from .model.effects import effect as make_effect
from .model.plausible import RANGES

#: default family-wise level of the diagnosis's verdict (:data:`hse_opt.diagnose.ALPHA`)
ALPHA = 0.05
#: an effect is detectable when the diagnosis's test rejects with at least this probability
#: (the usual 80 % power of experiment design)
POWER_LIMIT = 0.8
#: without the diagnosis at hand, the size of its test family (goodness of fit, lack of fit,
#: about ten factors, run order, every candidate): 20 is typical for a campaign with tilts,
#: covariates add more; the level is then ``alpha / 20``
DEFAULT_TESTS = 20
#: a projected direction (unit columns) shorter than this is in the model's span (the
#: diagnosis's tolerance, :mod:`hse_opt.diagnose.statistics`)
_TOL = 1e-6


@dataclass(frozen=True, eq=False)
class EffectRisk:
    """One missing effect's detectability and alias shifts on one campaign.

    Attributes
    ----------
    effect : str
    parameters : tuple of str
        The effect's parameters assessed; ``edge`` their plausible edge (display units,
        ``units``).
    edge : tuple of float
    units : tuple of str
    assessed : bool
        False when the effect could not be assessed (``reason`` says why).
    reason : str
    power : float
        Power of the diagnosis's test against the effect at the edge of its plausible range
        (its least detectable vertex); 0 when the runs cannot test it at all.
    threshold : float
        The fraction of the plausible edge (along that vertex) below which the test misses the
        effect (power < :data:`POWER_LIMIT`); ``inf`` when no size is detectable here.
    shift : numpy.ndarray, shape (n_p,)
        Largest undetectable shift of every parameter of the fit (display units; 0 for fixed
        parameters), as the module docstring defines it.
    full_shift : numpy.ndarray, shape (n_p,)
        Largest shift at the plausible edge, detectable or not.
    dof : tuple of int
        The test's degrees of freedom (q, dof).
    level : float
        The test's level.
    worst : numpy.ndarray, shape (n_p, q)
        Per fitted parameter, the effect's values (display units) behind its ``shift``.
    alias : numpy.ndarray, shape (n_p, q)
        The alias matrix ``B``: shift of every fitted parameter per display unit of each of the
        effect's parameters (0 rows for fixed parameters).
    """

    effect: str
    parameters: tuple
    edge: tuple
    units: tuple
    assessed: bool
    reason: str = ""
    power: float = 0.0
    threshold: float = math.inf
    shift: np.ndarray = None
    full_shift: np.ndarray = None
    dof: tuple = ()
    level: float = 0.0
    worst: np.ndarray = None
    alias: np.ndarray = None

    @property
    def detectable(self):
        """Whether the test has power >= :data:`POWER_LIMIT` at the plausible edge."""
        return self.assessed and self.power >= POWER_LIMIT

    def threshold_text(self):
        """``'undetectable here below 340 us'`` (or the fraction of the plausible edge)."""
        if not self.assessed:
            return f"not assessed ({self.reason})"
        if not math.isfinite(self.threshold):
            return "undetectable here at any size"
        if self.threshold >= 1.0:
            what = ", ".join(f"{p} {e:g} {u}" for p, e, u in zip(self.parameters, self.edge, self.units))
            return f"undetectable here within its plausible range ({what})"
        if len(self.parameters) == 1:
            return (f"undetectable here below {self.threshold * self.edge[0]:.3g} {self.units[0]} "
                    f"({self.parameters[0]})")
        what = ", ".join(f"{p} {e:g}" for p, e in zip(self.parameters, self.edge))
        return (f"undetectable here below {self.threshold:.2g} of its plausible size ({what} "
                f"{self.units[0] if len(set(self.units)) == 1 else ''})").replace(" )", ")")

    def to_dict(self, names=None):
        d = {"effect": self.effect, "parameters": list(self.parameters), "edge": list(self.edge),
             "units": list(self.units), "assessed": self.assessed, "reason": self.reason,
             "power": float(self.power), "detectable": self.detectable,
             "threshold_fraction": float(self.threshold) if math.isfinite(self.threshold) else None,
             "threshold": self.threshold_text(), "level": float(self.level), "dof": list(self.dof)}
        if names is not None and self.shift is not None:
            d["shift"] = {n: float(s) for n, s in zip(names, self.shift)}
            d["full_shift"] = {n: float(s) for n, s in zip(names, self.full_shift)}
        return d


@dataclass(frozen=True, eq=False)
class AliasBudget:
    """The alias budget of a fit (module docstring).

    Attributes
    ----------
    names, units : tuple of str
        The fit's parameters (every one, fixed included).
    std : numpy.ndarray, shape (n_p,)
        Their statistical 1-sigma (display units).
    effects : tuple of EffectRisk
    systematic : numpy.ndarray, shape (n_p,)
        Per parameter the largest undetectable shift that exceeds its sigma (0 when none).
    systematic_by : tuple of dict
        Per parameter ``{effect: shift}`` of the effects that are risks to it.
    alpha, level, power_limit : float
        Family-wise alpha, the test's level (``alpha / m``) and the power limit.
    """

    names: tuple
    units: tuple
    std: np.ndarray
    effects: tuple
    systematic: np.ndarray
    systematic_by: tuple
    alpha: float
    level: float
    power_limit: float = POWER_LIMIT

    @property
    def risks(self):
        """The effects that are a systematic risk to at least one parameter, worst first."""
        worst = {}
        for by in self.systematic_by:
            for e, s in by.items():
                worst[e] = max(worst.get(e, 0.0), s)
        order = sorted(worst, key=lambda e: -max(self._ratio(e)))
        return tuple(r for name in order for r in self.effects if r.effect == name)

    def _ratio(self, effect):
        return [s / sd for by, sd in zip(self.systematic_by, self.std) for e, s in by.items()
                if e == effect and sd > 0] or [0.0]

    def effect(self, name):
        for r in self.effects:
            if r.effect == name:
                return r
        raise ValueError(f"{name!r} was not assessed; assessed: {', '.join(r.effect for r in self.effects)}")

    def sentences(self, values=None):
        """Lines a user reads: per parameter at risk, its value (``values``: display units, in
        ``names`` order) with the statistical sigma and each effect that could move it."""
        out = []
        for i, (name, unit, sd, by) in enumerate(zip(self.names, self.units, self.std, self.systematic_by)):
            if not by:
                continue
            head = f"{name} = {values[i]:.4g} +- {sd:.3g} {unit} statistical" if values is not None \
                else f"{name} (+- {sd:.3g} {unit} statistical)"
            parts = [f"{e}, {self.effect(e).threshold_text()}, could move it by up to {s:.3g} {unit}"
                     for e, s in sorted(by.items(), key=lambda kv: -kv[1])]
            out.append(f"{head}; " + "; ".join(parts))
        return out

    def to_dict(self):
        return {"alpha": self.alpha, "level": self.level, "power_limit": self.power_limit,
                "effects": [r.to_dict(self.names) for r in self.effects],
                "risks": [r.effect for r in self.risks]}


def _vertices(edge):
    """The plausible box's vertices up to sign (q, 2^(q-1)): each parameter at +- its edge."""
    q = len(edge)
    signs = np.array([[1.0] + list(v) for v in itertools.product((1.0, -1.0), repeat=q - 1)]).T if q else \
        np.zeros((0, 1))
    return np.asarray(edge, float)[:, None] * signs


def _betacf(a, b, x):
    """The continued fraction of the regularised incomplete beta function (modified Lentz;
    Press et al., *Numerical Recipes*, 3rd ed., Sec. 6.4), scalars."""
    tiny = 1e-300
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 100000):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        step = d * c
        h *= step
        if abs(step - 1.0) < 1e-16:
            break
    return h


def _log_front(a, b, x):
    """``log(x^a (1 - x)^b / B(a, b))``."""
    return math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)


def betainc(a, b, x):
    """Regularised incomplete beta function ``I_x(a, b)`` of scalars (numpy-free: the fit
    command does not import scipy, as :func:`hse_opt.fit.result.chi2_sf`)."""
    a, b, x = float(a), float(b), float(x)
    if x <= 0.0 or x >= 1.0:
        return 0.0 if x <= 0.0 else 1.0
    front = math.exp(_log_front(a, b, x))
    if x < (a + 1.0) / (a + b + 2.0):
        return min(max(front * _betacf(a, b, x) / a, 0.0), 1.0)
    return min(max(1.0 - front * _betacf(b, a, 1.0 - x) / b, 0.0), 1.0)


def f_sf(f, d1, d2, lam=0.0):
    """``P(F > f)`` for F (noncentral with noncentrality ``lam``) with ``(d1, d2)`` degrees of
    freedom: the Poisson mixture ``sum_j Pois(j; lam/2) I_x(d2/2, d1/2 + j)``,
    ``x = d2 / (d2 + d1 f)`` (Johnson, Kotz & Balakrishnan, *Continuous Univariate
    Distributions* vol. 2, Eq. 30.6), over the Poisson weights' +-12 sigma window; the beta
    functions from one continued fraction and the recurrence
    ``I_x(a, b + 1) = I_x(a, b) + x^a (1 - x)^b / (b B(a, b))`` (positive terms, no
    cancellation)."""
    x = d2 / (d2 + d1 * float(f))
    a, b0 = 0.5 * d2, 0.5 * d1
    mu = 0.5 * float(lam)
    if mu <= 0.0:
        return betainc(a, b0, x)
    sd = math.sqrt(mu)
    j0 = max(0, math.floor(mu - 12.0 * sd - 12.0))
    j = np.arange(j0, math.ceil(mu + 12.0 * sd + 12.0) + 1, dtype=float)
    b = b0 + j
    # log(x^a (1-x)^b / (b B(a, b))) for b = b0 + j: lgamma(a + b) - lgamma(b) by cumulative sums
    step = np.log(a + b[:-1]) - np.log(b[:-1])          # lgamma(a+b+1) - lgamma(b+1) - (same at b)
    lg = (math.lgamma(a + b[0]) - math.lgamma(b[0])) + np.concatenate([[0.0], np.cumsum(step)])
    log_term = lg - math.lgamma(a) + a * math.log(x) + b * math.log1p(-x) - np.log(b)
    inc = np.concatenate([[betainc(a, b[0], x)], np.exp(log_term[:-1])])
    I = np.minimum(np.cumsum(inc), 1.0)
    log_w = -mu + j * math.log(mu) - (math.lgamma(j0 + 1.0) + np.concatenate(
        [[0.0], np.cumsum(np.log(j[1:]))]))
    return float(np.clip(np.sum(np.exp(log_w) * I), 0.0, 1.0))


def _solve(fun, target, lo, hi, rel=1e-9):
    """The ``t`` in [lo, hi] with increasing ``fun(t) = target`` (Illinois regula falsi)."""
    f_lo, f_hi = fun(lo) - target, fun(hi) - target
    side = 0
    for _ in range(200):
        t = (lo * f_hi - hi * f_lo) / (f_hi - f_lo) if f_hi != f_lo else 0.5 * (lo + hi)
        f_t = fun(t) - target
        if f_t == 0.0 or hi - lo <= rel * max(abs(t), 1e-300):
            return t
        if (f_t > 0) == (f_hi > 0):
            hi, f_hi = t, f_t
            if side == -1:
                f_lo *= 0.5
            side = -1
        else:
            lo, f_lo = t, f_t
            if side == 1:
                f_hi *= 0.5
            side = 1
    return 0.5 * (lo + hi)


@functools.lru_cache(maxsize=256)
def _critical(q, dof, level):
    """``(F_crit, lam80)``: the F(q, dof) value rejected at ``level`` and the noncentrality at
    which the test's power is :data:`POWER_LIMIT`."""
    # F_crit through x = dof / (dof + q F): I_x(dof/2, q/2) = level, increasing in x
    x = _solve(lambda t: betainc(0.5 * dof, 0.5 * q, t), level, 0.0, 1.0, rel=1e-13)
    crit = dof * (1.0 - x) / (q * x)
    hi = 10.0
    while f_sf(crit, q, dof, hi) < POWER_LIMIT:
        hi *= 4.0
    return crit, _solve(lambda lam: f_sf(crit, q, dof, lam), POWER_LIMIT, 0.0, hi, rel=1e-9)


class _Mixture:
    """The power ``f_sf(crit, d1, d2, lam)`` of one test (fixed ``crit``, ``d1``, ``d2``) for
    any ``lam``, its beta factors ``I_x(d2/2, d1/2 + j)``, ``j = 0, 1, ...`` computed once.

    :func:`f_sf`'s Poisson mixture evaluates a continued fraction and the recurrence of the
    beta factors on every call; they do not depend on ``lam``, so they are kept in a table
    (the same recurrence, the same cumulative sums: the factors of a window starting at
    ``j = 0`` are :func:`f_sf`'s to the last bit), extended on demand. The factors increase
    to a limit: once a recurrence term past the terms' peak underflows to 0, or their sum
    reaches 1, every later factor equals the last (the table is then complete). A window past
    a complete table has power equal to the last factor: the Poisson mass below the window
    (``mu - 12 sqrt(mu) - 12``) is below 1e-30. A table that would exceed :attr:`MAX` entries
    (few runs and a huge noncentrality) leaves the window to :func:`f_sf`.
    """

    #: entries of the largest table (512 kB)
    MAX = 1 << 16

    def __init__(self, crit, d1, d2):
        self.crit, self.d1, self.d2 = float(crit), d1, d2
        self.x = d2 / (d2 + d1 * self.crit)
        self.a, self.b0 = 0.5 * d2, 0.5 * d1
        i0 = betainc(self.a, self.b0, self.x)
        # (factors so far, their unclipped running sum, the running sum of the steps of
        # lgamma(a + b) - lgamma(b) at the next term, the index from which every factor equals
        # the last once the table is complete, else None): replaced whole, so that a thread
        # reading it never sees half an extension
        self._state = (np.array([min(i0, 1.0)]), i0, 0.0, None)

    def _extend(self, size):
        """Grow the table toward ``size`` entries, doubling, until it is complete."""
        factors, total, steps, flat = self._state
        a, x = self.a, self.x
        while flat is None and factors.size < min(size, self.MAX):
            m = factors.size
            b = self.b0 + np.arange(m - 1, min(self.MAX, max(2 * m, 64)), dtype=float)  # terms m-1 .. give factors m ..
            s = np.cumsum(np.concatenate([[steps], np.log(a + b[:-1]) - np.log(b[:-1])]))
            lg = (math.lgamma(a + self.b0) - math.lgamma(self.b0)) + s[:-1]
            log_term = lg - math.lgamma(a) + a * math.log(x) + b[:-1] * math.log1p(-x) - np.log(b[:-1])
            sums = np.cumsum(np.concatenate([[total], np.exp(log_term)]))[1:]
            factors = np.concatenate([factors, np.minimum(sums, 1.0)])
            total, steps = float(sums[-1]), float(s[-1])
            past_peak = log_term.size < 2 or log_term[-1] < log_term[-2]
            if sums[-1] >= 1.0 or (math.exp(log_term[-1]) == 0.0 and past_peak):
                flat = int(np.argmax(factors == factors[-1]))   # the factors do not decrease
        self._state = (factors, total, steps, flat)

    def sf(self, lam):
        """``f_sf(crit, d1, d2, lam)`` (``lam > 0``)."""
        mu = 0.5 * float(lam)
        sd = math.sqrt(mu)
        j0 = max(0, math.floor(mu - 12.0 * sd - 12.0))
        j1 = math.ceil(mu + 12.0 * sd + 12.0)
        self._extend(j1 + 1)
        factors, _, _, flat = self._state
        if flat is None and factors.size <= j1:
            return f_sf(self.crit, self.d1, self.d2, lam)
        if flat is not None and j0 >= flat:
            return float(min(max(factors[-1], 0.0), 1.0))
        I = factors[j0:j1 + 1]
        if I.size <= j1 - j0:
            I = np.concatenate([I, np.full(j1 - j0 + 1 - I.size, factors[-1])])
        if j0 == 0:
            j, log_factorial = _log_factorials(j1)
            log_w = -mu + j * math.log(mu) - log_factorial
        else:
            j = np.arange(j0, j1 + 1, dtype=float)
            log_w = -mu + j * math.log(mu) - (math.lgamma(j0 + 1.0) + np.concatenate(
                [[0.0], np.cumsum(np.log(j[1:]))]))
        return min(max(float(np.dot(np.exp(log_w), I)), 0.0), 1.0)


def _log_factorials(n):
    """``(j, log(j!))`` for ``j = 0 .. n`` (float arrays): :func:`f_sf`'s cumulative sums of
    ``log j`` for a window from 0, from a table of the next power of two kept."""
    j, lf = _factorial_table(1 << max(6, n.bit_length()))
    return j[:n + 1], lf[:n + 1]


@functools.lru_cache(maxsize=32)
def _factorial_table(size):
    j = np.arange(size, dtype=float)
    return j, np.concatenate([[0.0], np.cumsum(np.log(j[1:]))])


@functools.lru_cache(maxsize=64)
def _mixture(q, dof, level):
    """``(_Mixture, lam80)`` of the F(q, dof) test at ``level`` (:func:`_critical`)."""
    crit, lam80 = _critical(q, dof, level)
    return _Mixture(crit, q, dof), lam80


def _test_power(lam, q, dof, level):
    """Power of the F(q, dof) test at ``level`` for the noncentrality ``lam``, and the
    noncentrality at which it is :data:`POWER_LIMIT` (0 and ``inf`` when no test is possible)."""
    if q < 1 or dof < 1:
        return 0.0, math.inf
    mixture, lam80 = _mixture(int(q), int(dof), float(level))
    return (mixture.sf(lam) if lam > 0 else level), lam80


def noncentrality_for_power(q, dof, level):
    """The noncentrality at which the diagnosis's F(q, dof) test at ``level`` has power
    :data:`POWER_LIMIT` (``inf`` when no test is possible): what a plan must give a missing
    effect for the diagnosis to detect it (the design's power floors,
    :mod:`hse_opt.design.protection`)."""
    return _test_power(0.0, q, dof, level)[1]


def _factor(C, g, k):
    """The triangular factor of one Householder QR of a campaign's weighted columns
    ``C = [G, A, Z]`` (n, g + k + Q): the unsurveyed positions' constants ``G`` (n, g), the
    model's free parameters ``A`` (n, k) and the effects' ``Z`` (n, Q).

    With ``[G, A, Z] = [Q_g, Q_a, Q_z] T`` every projection the budget needs is a block of
    ``T``: the effects' part orthogonal to the model's span (positions included) is
    ``Q_z T_zz``, so its norms and noncentralities are those of ``T_zz``; the model's columns
    within the positions are ``Q_a T_aa`` and ``A' (I - P_G) Z = T_aa' T_az``, the alias
    matrix's product. Householder's backward error is columnwise, so the columns' very
    different scales need no equilibration.

    Returns
    -------
    tuple
        ``(T_z, m, T_aa, T_az)``: ``T_z`` the effects' columns of ``T`` (whole: their norms
        are the effects' columns'), ``m = g + k`` the row where ``T_zz`` starts, ``T_aa``
        (k, k) and ``T_az`` (k, Q).
    """
    m = g + k
    T = np.linalg.qr(C, mode="r") if C.size else np.zeros((0, C.shape[1]))
    return T[:, m:], m, T[g:m, g:m], T[g:m, m:]


@dataclass(frozen=True, eq=False)
class _Stack:
    """Effects side by side: effect ``e``'s columns ``cols[e]`` of the stacked matrix ``Z``
    and its sizes ``V[e]`` (q_e, m_e), the ``verts[e]`` columns of the vertices (``first``:
    each effect's first); ``block`` (Q, m) the sizes on the effect's own rows, 0 elsewhere
    (``Z @ block`` is every effect's ``Z_e @ V_e``)."""

    cols: tuple
    verts: tuple
    V: tuple
    block: np.ndarray
    first: np.ndarray

    @classmethod
    def of(cls, sizes):
        """From each effect's sizes (q_e, m_e), in order."""
        q = np.cumsum([0] + [v.shape[0] for v in sizes])
        m = np.cumsum([0] + [v.shape[1] for v in sizes])
        block = np.zeros((q[-1], m[-1]))
        for i, v in enumerate(sizes):
            block[q[i]:q[i + 1], m[i]:m[i + 1]] = v
        return cls(tuple(slice(int(a), int(b)) for a, b in zip(q[:-1], q[1:])),
                   tuple(slice(int(a), int(b)) for a, b in zip(m[:-1], m[1:])), tuple(sizes), block, m[:-1])


def _ranks(T_zz, cols, d2, r2):
    """Per effect (its columns ``cols``) the rank of its columns orthogonal to the model's:
    the singular values of its unit columns of ``T_zz`` above :data:`_TOL` (one column:
    ``r / d``, ``d2``, ``r2`` the columns' squared norms before and after the projection). The
    effects of several columns share one batched SVD, zero columns padding them to one width
    (a zero column adds a singular value 0)."""
    ranks, multi = [], []
    for e, c in enumerate(cols):
        if c.stop - c.start == 1:
            ranks.append(int(d2[c.start] > 0.0 and r2[c.start] > _TOL ** 2 * d2[c.start]))
            continue
        ranks.append(0)
        keep = [i for i in range(c.start, c.stop) if d2[i] > 0.0]
        if keep and T_zz.shape[0]:
            multi.append((e, keep))
    if multi:
        M = np.zeros((len(multi), T_zz.shape[0], max(len(keep) for _, keep in multi)))
        for j, (_, keep) in enumerate(multi):
            M[j, :, :len(keep)] = T_zz[:, keep] / np.sqrt(np.take(d2, keep))
        for (e, _), s in zip(multi, np.linalg.svd(M, compute_uv=False)):
            ranks[e] = int(np.sum(s > _TOL))
    return ranks


@dataclass(frozen=True, eq=False)
class _Assessed:
    """:func:`_assess`'s answer for E effects against k fitted parameters: ``power``,
    ``threshold`` and ``q`` (lists, per effect); ``shift`` and ``full`` (k, E) or None;
    ``worst`` per effect (k, q_e) or None."""

    power: list
    threshold: list
    q: list
    shift: np.ndarray = None
    full: np.ndarray = None
    worst: list = None


def _assess(factor, stack, dof_fit, level, B=None):
    """Every effect of ``stack`` at once: power at the edge, threshold fraction, the test's
    numerator dof ``q``; with the alias matrix ``B`` (k, Q) of every effect's columns, the
    undetectable and the edge shifts (k,) and the effect's values behind each undetectable
    shift (k, q) (:class:`_Assessed`).

    ``factor``: :func:`_factor` of the campaign with the effects' columns side by side
    (:class:`_Stack`: their sizes to assess, the plausible box's vertices, :func:`_vertices`),
    ``dof_fit`` the fit's residual degrees of freedom. ``q`` is the rank of the effect's
    columns orthogonal to the model's (singular values of the unit columns above
    :data:`_TOL`)."""
    T, m = factor[0], factor[1]
    T_zz = T[m:]
    TV = T_zz @ stack.block
    lam = np.einsum("ij,ij->j", TV, TV)         # every vertex's noncentrality
    d2, r2 = np.einsum("ij,ij->j", T, T).tolist(), np.einsum("ij,ij->j", T_zz, T_zz).tolist()
    lam_v = lam.tolist()
    lam80, powers, ranks = [], [], []
    for verts, q in zip(stack.verts, _ranks(T_zz, stack.cols, d2, r2)):
        # the least detectable vertex (power grows with lambda)
        power, need = _test_power(min(lam_v[verts]), q, dof_fit - q, level)
        powers.append(float(power))
        ranks.append(q)
        lam80 += [need] * (verts.stop - verts.start)
    # each vertex scaled to the largest size the test misses; the threshold is the least
    # detectable vertex's
    reach = np.sqrt(np.array(lam80) / np.where(lam > 0, lam, 1.0))
    reach[lam <= 0] = math.inf
    threshold = np.maximum.reduceat(reach, stack.first).tolist() if lam.size else []
    if B is None:
        return _Assessed(powers, threshold, ranks)
    scale = np.minimum(1.0, reach)
    BV = np.abs(B @ stack.block)
    scaled = BV * scale
    worst = []
    for verts, V in zip(stack.verts, stack.V):
        if V.shape[1] == 1:
            worst.append(np.repeat(V.T * scale[verts.start], BV.shape[0], axis=0))
        else:
            worst.append((V * scale[verts])[:, np.argmax(scaled[:, verts], axis=1)].T)
    return _Assessed(powers, threshold, ranks, np.maximum.reduceat(scaled, stack.first, axis=1),
                     np.maximum.reduceat(BV, stack.first, axis=1), worst)


@dataclass(frozen=True, eq=False)
class _Layout:
    """What :func:`alias_budget` knows of a fit's model before it sees the runs (built once
    per model, tilt mode, parameter names and effects asked, :func:`_layout`).

    ``skipped``: ``(effect, parameters, units, reason)`` of each effect not assessed;
    ``assessed``: ``(effect, parameters, edge, units)`` of each effect assessed, in order;
    ``mm``: the measurement model of the model with every assessable effect;
    ``known``: which fit parameters ``mm`` has; ``jacobian``: the Jacobian of ``mm`` at those
    parameters, the effects' at nominal (:meth:`~hse_opt.model.measurement.MeasurementModel.held_jacobian`),
    its columns the known fit parameters' then the assessed effects' side by side (``stack``:
    their vertices), ``scale`` the columns' SI scales; ``column``: each fit parameter's column
    (-1 when ``mm`` lacks it)."""

    skipped: tuple
    assessed: tuple = ()
    mm: object = None
    known: np.ndarray = None
    jacobian: object = None
    scale: np.ndarray = None
    column: np.ndarray = None
    stack: _Stack = None


@functools.lru_cache(maxsize=64)
def _layout(model, tilt_known, names, wanted):
    """The :class:`_Layout` of a fit's ``model`` (parameter ``names``) for the effects
    ``wanted``; raises for an effect already in the model."""
    have = set(model.effect_names)
    skipped, extra = [], []
    for name in wanted:
        eff = make_effect(name)
        params = [q for q in eff.params if q.name not in eff.nonlinear]
        missing = [n for n in eff.needs if n not in have]
        no_range = [q.name for q in params if q.name not in RANGES]
        if name in have:
            raise ValueError(f"effect {name!r} is already in the model ({', '.join(sorted(have))})")
        if missing or no_range:
            why = (f"it acts only in a product with {', '.join(missing)}, which the model lacks" if missing
                   else f"no plausible range for {', '.join(no_range)}")
            skipped.append((name, tuple(q.name for q in params), tuple(q.unit for q in params), why))
            continue
        extra.append(eff)
    if not extra:
        return _Layout(tuple(skipped))
    mm = Model(model.effects + tuple(extra), model.geometry).measurement(tilt_known)
    assessed, columns, sizes = [], [], []
    for eff in extra:
        params = [q for q in eff.params if q.name not in eff.nonlinear]
        tilted = [n for n in mm.names if any(n.startswith(q.name + "*") for q in params)]
        if tilted:
            skipped.append((eff.name, tuple(q.name for q in params), tuple(q.unit for q in params),
                            "it acts through the tilt, which these runs do not carry "
                            f"({', '.join(tilted)}): its size here depends on the unknown tilt"))
            continue
        edge = tuple(max(abs(RANGES[q.name][0]), abs(RANGES[q.name][1])) for q in params)
        assessed.append((eff.name, tuple(q.name for q in params), edge, tuple(q.unit for q in params)))
        columns += [mm.parameter_index(q.name) for q in params]
        sizes.append(_vertices(edge))
    order = {name: i for i, name in enumerate(wanted)}
    skipped.sort(key=lambda s: order[s[0]])
    if not assessed:
        return _Layout(tuple(skipped))
    known = np.array([n in mm.names for n in names], dtype=bool)
    at = tuple(mm.names.index(n) for n in np.array(names)[known]) if known.any() else ()
    column = np.full(len(names), -1, dtype=np.intp)
    column[known] = np.arange(len(at))
    jacobian = mm.held_jacobian(at, at + tuple(columns))
    return _Layout(tuple(skipped), tuple(assessed), mm, known, jacobian, mm.scale[list(at + tuple(columns))],
                   column, _Stack.of(sizes))


def alias_budget(fit_result, runs, effects=None, *, alpha=ALPHA, level=None, tests=None, jit=None):
    """The alias budget of ``fit_result`` on ``runs`` (module docstring).

    Parameters
    ----------
    fit_result : hse_opt.fit.FitResult
        A fit of ``runs``.
    runs : hse_opt.data.Runs
        The runs it was fitted to.
    effects : sequence of str, optional
        Catalogue effects to assess (default: every catalogue effect not in the model).
    alpha : float
        Family-wise level of the diagnosis's verdict.
    level : float, optional
        The level of each test (default ``alpha / tests``).
    tests : int, optional
        The size of the diagnosis's test family (default :data:`DEFAULT_TESTS`); the
        diagnosis passes its own.
    jit : bool, optional
        Passed to the model's Jacobian.

    Returns
    -------
    AliasBudget
        Systematic per parameter in the parameter's display unit.

    Notes
    -----
    The effects' bookkeeping (which can be assessed, their columns and vertices, the
    extended model's Jacobian with the effects held at their nominal 0) is built once per
    model and kept; a call evaluates that Jacobian on the runs once and assesses every effect
    from one Householder QR of the model's and the effects' columns (:func:`_factor`,
    :func:`_assess`).
    """
    f = fit_result
    level = alpha / (tests or DEFAULT_TESTS) if level is None else float(level)
    if not 0.0 < level < 1.0:
        raise ValueError(f"level {level!r}; allowed: a significance level in (0, 1)")
    names = tuple(f.names)
    have = f.model.effect_names
    wanted = tuple(e for e in CATALOGUE if e not in have) if effects is None else tuple(effects)
    layout = _layout(f.model, bool(f.tilt_known), names, wanted)
    n_p = len(names)
    std = np.asarray(f.std, float)
    out, systematic, by = [], np.zeros(n_p), [dict() for _ in names]
    if layout.assessed:
        mm = layout.mm
        # catalogue effects add no covariate: the fit's own inputs are the extended model's
        X = f.inputs if f.inputs is not None and f.inputs.shape[0] == mm.n_x else mm.inputs_from_runs(runs)
        free = np.asarray(f.free, bool)
        cols = layout.column[free]
        if cols.size and cols.min() < 0:        # a free parameter the extended model lacks
            mm.parameter_index(names[int(np.flatnonzero(free & (layout.column < 0))[0])])
        A = weighted_jacobian(layout.jacobian(np.asarray(f.p, float)[layout.known], X, jit), f.sigma,
                              layout.scale)
        group, positions = runs.reference_groups()
        k, g, n_known = cols.size, len(positions), len(layout.column) - int(np.sum(layout.column < 0))
        if g:
            C = np.column_stack([(group[:, None] == np.arange(g)[None, :]) / np.asarray(f.sigma)[:, None],
                                 A[:, cols], A[:, n_known:]])
        else:   # every known parameter free: the Jacobian's columns are already in place
            C = A if k == n_known else np.column_stack([A[:, cols], A[:, n_known:]])
        factor = _factor(C, g, k)
        cov = np.asarray(f.covariance, float)
        B = np.zeros((n_p, factor[0].shape[1]))
        B[free] = (cov if free.all() else cov[np.ix_(free, free)]) @ (factor[2].T @ factor[3])
        dof = int(f.dof)
        a = _assess(factor, layout.stack, dof, level, B)
        for e, ((name, params, edge, units), cols) in enumerate(zip(layout.assessed, layout.stack.cols)):
            out.append(EffectRisk(name, params, edge, units, True, "", a.power[e], a.threshold[e], a.shift[:, e],
                                  a.full[:, e], (a.q[e], dof - a.q[e]), level, a.worst[e], B[:, cols].copy()))
        risky = (a.shift.T > std) & (std > 0)  # (effects, parameters)
        systematic = np.where(risky, a.shift.T, 0.0).max(axis=0, initial=0.0)
        for e, i in zip(*np.nonzero(risky)):
            by[i][layout.assessed[e][0]] = float(a.shift[i, e])
    out += [EffectRisk(name, params, (), units, False, why, shift=np.zeros(n_p), full_shift=np.zeros(n_p),
                       level=level) for name, params, units, why in layout.skipped]
    return AliasBudget(names, tuple(f.units), std, tuple(out), systematic, tuple(by), alpha, level)


def effect_test(model, X, effect, size=1.0, *, sigma, p=None, tilt_known=True, positions=None,
                alpha=ALPHA, level=None, tests=None, dof=None, jit=None):
    """The diagnosis's test against a catalogue ``effect`` missing from ``model`` on the runs
    ``X`` (a candidate plan), as :func:`alias_budget` defines it: its power and degrees of
    freedom.

    Parameters
    ----------
    model : Model, str or sequence of str
        The model that would be fitted (``effect`` must not be in it).
    X : numpy.ndarray, shape (n_x, n), or hse_opt.data.Runs
        The runs' measurement-model inputs (``model.measurement(tilt_known).inputs(...)``,
        SI; a run repeated k times appears k times), or runs.
    effect : str
        A catalogue effect name.
    size : float or mapping name -> value
        The effect's size: a fraction of its plausible edge (1: the edge,
        :data:`hse_opt.model.plausible.RANGES`; the least detectable vertex of the box), or
        its parameters' values in their display units (one direction).
    sigma : float or array_like, shape (n,)
        Heading 1-sigma of each run, rad (e.g. :func:`hse_opt.information.heading_sigma`).
    p : mapping name -> value (display unit), optional
        The model's parameter values where the test is linearised (default nominal).
    tilt_known : bool
        Whether the runs carry pitch/roll.
    positions : array_like of int, shape (n,), optional
        For a field plan: each run's position without a heading reference (0 .. P-1), -1 for a
        surveyed run; each position's unknown constant is part of the model (and a model
        parameter constant within every position, the ``offset`` without a surveyed run, is
        held fixed, as the fit holds it).
    alpha, level, tests
        As :func:`alias_budget`.
    dof : int, optional
        Residual degrees of freedom of the fit (default n - free parameters - positions).
    jit : bool, optional

    Returns
    -------
    EffectTest
        ``power``: the probability that the diagnosis's test rejects (0 .. 1; the test's
        level itself when the effect's signature beyond the model is zero at ``size``, 0 when
        it has no direction beyond the model or too few runs are left for the test).

    Raises
    ------
    ValueError
        Unknown effect, an effect already in the model or without a plausible range.
    """
    base = as_model(model)
    eff = make_effect(effect)
    if eff.name in base.effect_names:
        raise ValueError(f"effect {eff.name!r} is already in the model ({', '.join(base.effect_names)})")
    params = [q for q in eff.params if q.name not in eff.nonlinear]
    no_range = [q.name for q in params if q.name not in RANGES]
    if no_range:
        raise ValueError(f"effect {eff.name!r}: no plausible range for {', '.join(no_range)}; allowed: "
                         f"{', '.join(e for e in CATALOGUE if all(q.name in RANGES for q in CATALOGUE[e].params if q.name not in CATALOGUE[e].nonlinear))}")
    level = alpha / (tests or DEFAULT_TESTS) if level is None else float(level)
    mm = Model(base.effects + (eff,), base.geometry).measurement(tilt_known)
    if not isinstance(X, np.ndarray):
        X = mm.inputs_from_runs(X)
    n = X.shape[1]
    sig = np.broadcast_to(np.asarray(sigma, float), (n,))
    p_si = mm.vector({k: v for k, v in (p or {}).items()})
    A_all = weighted_jacobian(mm.jacobian(p_si, X, jit), sig, mm.scale)
    mine = {q.name for q in eff.params}
    cols = [i for i, nm in enumerate(mm.names) if nm.split("*")[0] not in mine and nm not in mm.nonlinear]
    G = None
    n_pos = 0
    if positions is not None:
        pos = np.asarray(positions, int)
        n_pos = int(pos.max()) + 1 if pos.size and pos.max() >= 0 else 0
        if n_pos:
            G = (pos[:, None] == np.arange(n_pos)[None, :]) / sig[:, None]
            # a column constant within every position (the offset of a campaign without a
            # reference) is in the constants' span: the fit holds it fixed, so must the test
            Gq = np.linalg.qr(G)[0]
            A_M = A_all[:, cols]
            inside = np.linalg.norm(A_M - Gq @ (Gq.T @ A_M), axis=0) <= 1e-9 * np.linalg.norm(A_M, axis=0)
            cols = [c for c, drop in zip(cols, inside) if not drop]
    idx = [mm.parameter_index(q.name) for q in params]
    edge = np.array([max(abs(RANGES[q.name][0]), abs(RANGES[q.name][1])) for q in params])
    if isinstance(size, dict):
        unknown = sorted(set(size) - {q.name for q in params})
        if unknown:
            raise ValueError(f"size names {unknown}; allowed: {', '.join(q.name for q in params)}")
        V = np.array([[float(size.get(q.name, 0.0))] for q in params])
    else:
        V = _vertices(float(size) * edge)
    dof_fit = n - len(cols) - n_pos if dof is None else int(dof)
    C = np.column_stack(([G] if n_pos else []) + [A_all[:, cols], A_all[:, idx]])
    a = _assess(_factor(C, n_pos, len(cols)), _Stack.of([V]), dof_fit, level)
    return EffectTest(a.power[0], a.q[0], dof_fit - a.q[0])


@dataclass(frozen=True)
class EffectTest:
    """The diagnosis's test of one missing effect on a plan (:func:`effect_test`).

    Attributes
    ----------
    power : float
        Probability that it rejects (:func:`effect_power`).
    q : int
        Its numerator degrees of freedom: the effect's directions beyond the model's span
        (0: the effect has no signature the model and the positions' constants do not have).
    dof : int
        Its denominator degrees of freedom (< 1: too few runs for the test).
    """

    power: float
    q: int
    dof: int


def effect_power(model, X, effect, size=1.0, **kw):
    """Power of the diagnosis's test against a catalogue ``effect`` missing from ``model`` on
    the runs ``X``: :func:`effect_test` (same arguments) without its degrees of freedom."""
    return effect_test(model, X, effect, size, **kw).power


def describe(budget, values=None):
    """The budget in words for a fit's text output: the sentences of
    :meth:`AliasBudget.sentences`, or one line saying that no effect is a risk."""
    lines = budget.sentences(values)
    if lines:
        return lines
    undetectable = [r.effect for r in budget.effects if r.assessed and not r.detectable]
    if undetectable:
        return [f"no systematic risk: {', '.join(undetectable)} would go undetected here, but move no "
                "parameter by more than its 1-sigma"]
    return ["no systematic risk: every assessed effect would be detected at its plausible size"]


__all__ = ["ALPHA", "AliasBudget", "DEFAULT_TESTS", "EffectRisk", "EffectTest", "POWER_LIMIT", "alias_budget",
           "describe", "effect_power", "effect_test", "noncentrality_for_power"]
