"""The symbolic error model of the paper (Eqs. 1-12) in CasADi SX.

Every quantity is named as in the paper. The chain, for one operating point:

1. truth: ``C_b0^n(psi, theta, gamma)`` (Eq. 3, exact Z-Y-X or first order), the table angle
   ``alpha`` with ``C_b^b0 = rot_z(alpha)``, the body rate
   ``omega_ib_b = C_n^b omega_ie_n + omega_nb_b`` with ``omega_nb_b = (0, 0, Omega)``, and the
   static-base gyro outputs ``omega_ig_g = K_g^-1 C_b^s omega_ib_b`` (paper Eq. 5);
2. processing with the lab-calibrated parameters ``K~_g = (I + Lambda) K_g`` (Eq. 1) and
   ``C~_s^b = (I - [xi x]) C_s^b`` (Eq. 2), then the navigation solution
   ``omega~_ie_n = C_b^n (C~_s^b K~_g omega_ig_g - omega_nb_b)`` (Eq. 6);
3. the error ``d_omega = omega~_ie_n - omega_ie_n`` and its parts (Eqs. 8-11);
4. the revolution average (exact, see :func:`revolution_average`) and the heading error,
   linear (Eq. 12), from the full nonlinear gyrocompass, or as the alignment processor
   forms it (:func:`alignment_rates_b0`, :func:`heading_error_alignment`: the same to first
   order; they differ by products of errors when encoder harmonics meet a table-fixed rate).

The model's effects (:mod:`hse_opt.model.effects`) act on this chain through an
:class:`ErrorModel`: where the physics acts (gyro outputs, calibration, encoder, heading
reference), never on the heading directly unless the effect *is* a heading-reference error.

Heading errors returned here are *estimated minus true* (the project's sign).
"""
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .. import frames
from ..frames import EARTH_RATE

E_Z = ca.DM([0.0, 0.0, 1.0])
SKEW_Z = ca.DM(frames.skew([0.0, 0.0, 1.0]))


def lambda_matrix(eps):
    """Lambda of Eq. 1 from eps = (eps1, eps2, eps3): ``[[0,0,0],[eps1,0,0],[eps2,eps3,0]]``."""
    z = 0 * eps[0]
    return frames.matrix3([[z, z, z], [eps[0], z, z], [eps[1], eps[2], z]])


def k_g_tilde(K_g, eps):
    """K~_g = (I + Lambda) K_g (Eq. 1)."""
    return ca.mtimes(ca.SX.eye(3) + lambda_matrix(eps), K_g)


def c_s_b_tilde(C_s_b, xi):
    """C~_s^b = (I - [xi x]) C_s^b (Eq. 2); xi in rad, components in b."""
    return ca.mtimes(ca.SX.eye(3) - frames.skew(xi), C_s_b)


def c_b0_n(psi, theta, gamma, form="exact"):
    """C_b0^n: ``form='exact'`` Z-Y-X, ``'first_order'`` the paper's Eq. 3."""
    if form == "exact":
        return frames.dcm_zyx(psi, theta, gamma)
    if form == "first_order":
        return frames.dcm_first_order(psi, theta, gamma)
    raise ValueError(f"form={form!r} is not allowed; use 'exact' or 'first_order'")


def gyro_outputs(K_g, C_b_s, omega_ib_b):
    """Static-base gyro outputs ``omega_ig_g = K_g^-1 C_b^s omega_ib_b`` (rad/s, g frame)."""
    return ca.mtimes(ca.solve(K_g, C_b_s), omega_ib_b)


def navigation_rate(C_b_n, C_s_b_est, K_g_est, omega_ig_g, omega_nb_b):
    """Eq. 6: ``omega~_ie_n = C_b^n (C~_s^b K~_g omega_ig_g - omega_nb_b)``."""
    return ca.mtimes(C_b_n, ca.mtimes([C_s_b_est, K_g_est, omega_ig_g]) - omega_nb_b)


def d_omega_parts(C_b_n, C_s_b, Lambda, xi, omega_ib_b):
    """The three parts of d_omega (Eqs. 9, 10, 11) for a perfect gyro and exact C_s^b, K_g.

    Returns ``(d_omega_xi, d_omega_Lambda, O_d_omega)``; their sum is the exact d_omega of
    Eq. 6 in that case.
    """
    C_b_s = C_s_b.T
    M = ca.mtimes([C_s_b, Lambda, C_b_s])
    d_xi = -ca.mtimes([C_b_n, frames.skew(xi), omega_ib_b])
    d_lambda = ca.mtimes([C_b_n, M, omega_ib_b])
    second = -ca.mtimes([C_b_n, frames.skew(xi), M, omega_ib_b])
    return d_xi, d_lambda, second


def revolution_average(f, alpha, degree):
    """Exact mean over one revolution of a trigonometric polynomial in ``alpha``.

    The mean of a trigonometric polynomial of degree D over N equally spaced angles is
    its exact revolution mean once N > D: a harmonic m aliases onto the mean only when m is
    a multiple of N. We use N = D + 1.

    Parameters
    ----------
    f : casadi.SX
        Expression in the scalar symbol ``alpha`` (any shape).
    alpha : casadi.SX
        The table angle symbol (rad).
    degree : int
        The trigonometric degree of ``f`` in ``alpha`` (an upper bound is fine).
    """
    n = int(degree) + 1
    return sum(ca.substitute(f, alpha, 2 * np.pi * k / n) for k in range(n)) / n


@dataclass
class ErrorModel:
    """Where the error sources act on the chain; effects add to these fields.

    All values are SI CasADi expressions. An effect's ``act`` adds its contribution with the
    ``add_*`` methods; the model then carries every contribution to the heading error.
    """

    #: eps1..eps3 of Lambda (Eq. 1), rad
    eps: ca.SX = field(default_factory=lambda: ca.SX.zeros(3))
    #: xi of Eq. 2, rad, components in b
    xi: ca.SX = field(default_factory=lambda: ca.SX.zeros(3))
    #: true rotation axis in s minus the calibrated one (first order), unitless
    d_r_zb_s: ca.SX = field(default_factory=lambda: ca.SX.zeros(3))
    #: gyro bias fixed in b (rad/s), added to the true rate before the gyros
    gyro_bias_b: ca.SX = field(default_factory=lambda: ca.SX.zeros(3))
    #: gyro output maps ``f(omega_ig_g, sign_g) -> added output`` with their degree factor
    gyro_output_terms: list = field(default_factory=list)
    #: encoder angle late by this time, s
    encoder_delay: ca.SX = field(default_factory=lambda: ca.SX(0))
    #: encoder angle errors ``f(alpha) -> rad`` with their harmonic order
    encoder_terms: list = field(default_factory=list)
    #: stand azimuth reading minus true heading, rad
    reference_error: ca.SX = field(default_factory=lambda: ca.SX(0))

    def add_lambda(self, eps):
        """Add non-orthogonality errors eps1..eps3 (rad) of K_g (Eq. 1)."""
        self.eps = self.eps + eps

    def add_xi(self, xi):
        """Add a small rotation error xi (rad, in b) of the calibrated C_s^b (Eq. 2)."""
        self.xi = self.xi + xi

    def add_axis_error(self, d_r_zb_s):
        """The true axis r_zb^s differs from the calibrated one by ``d_r_zb_s``."""
        self.d_r_zb_s = self.d_r_zb_s + d_r_zb_s

    def add_gyro_bias_b(self, bias_b):
        """Add a gyro bias (rad/s) fixed in the turntable-top frame b."""
        self.gyro_bias_b = self.gyro_bias_b + bias_b

    def add_gyro_output_term(self, fun, degree_factor=1):
        """Add ``fun(omega_ig_g, sign_g)`` to the gyro outputs.

        ``sign_g`` is the sign of each gyro's input rate (constant for a biased gyro: the
        table rate dominates). ``degree_factor`` is the polynomial degree of ``fun`` in
        ``omega_ig_g`` (it sets the exact averaging).
        """
        self.gyro_output_terms.append((fun, int(degree_factor)))

    def add_encoder_delay(self, delay):
        """The encoder angle used by the processor is late by ``delay`` (s)."""
        self.encoder_delay = self.encoder_delay + delay

    def add_encoder_error(self, fun, order):
        """Add a periodic encoder angle error ``fun(alpha)`` (rad) of harmonic order ``order``."""
        self.encoder_terms.append((fun, int(order)))

    def add_reference_error(self, error):
        """The heading reference (stand azimuth reading) exceeds the true heading by ``error``
        (rad); the recorded heading error (alignment minus reading) falls by it."""
        self.reference_error = self.reference_error + error


@dataclass(frozen=True)
class Geometry:
    """The nominal geometry of the system the model is built for.

    Attributes
    ----------
    r_zb_s : ndarray, shape (3,)
        The calibrated rotation axis in s (unit vector; ideal: every component -1/sqrt(3)).
    K_g : ndarray, shape (3, 3)
        Gyro-to-s matrix (Eq. 1). It cancels from the heading error; it shapes the gyro
        outputs that effects such as the scale-factor nonlinearity act on.
    """

    r_zb_s: np.ndarray = field(default_factory=lambda: frames.R_ZB_S_IDEAL.copy())
    K_g: np.ndarray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self):
        r = np.asarray(self.r_zb_s, dtype=float)
        K = np.asarray(self.K_g, dtype=float)
        if r.shape != (3,) or not np.all(np.isfinite(r)):
            raise ValueError(f"r_zb_s must be 3 finite numbers, got {self.r_zb_s!r}")
        if abs(np.linalg.norm(r) - 1) > 1e-9:
            raise ValueError(f"r_zb_s must be a unit vector; |r_zb_s| = {np.linalg.norm(r):.12g}")
        if abs(r[0]) >= 1 - 1e-6:
            raise ValueError(f"r_zb_s = {r} is along x_g: C_b^s is undefined; allowed: |e_x| < 1")
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or abs(np.linalg.det(K)) < 1e-6:
            raise ValueError("K_g must be a finite, invertible 3x3 matrix")
        object.__setattr__(self, "r_zb_s", r)
        object.__setattr__(self, "K_g", K)


@dataclass
class Operating:
    """Symbols (or values) of one operating point, SI: rate ``Omega`` (rad/s, signed),
    heading ``psi``, pitch ``theta``, roll ``gamma`` (rad), latitude ``L`` (rad),
    ``t_start`` and ``duration`` (s) and named covariates."""

    Omega: ca.SX
    psi: ca.SX
    theta: ca.SX
    gamma: ca.SX
    L: ca.SX
    t_start: ca.SX = 0
    duration: ca.SX = 600.0
    covariates: dict = field(default_factory=dict)


def averaged_rate_b0(op, errors, geometry=Geometry(), form="exact", omega_ie_b0=None):
    """Revolution-averaged computed Earth rate in b0 and the averaging degree.

    See :func:`rate_b0` for the arguments; returns ``(omega_b0, degree)`` with ``omega_b0``
    the exact revolution mean (:func:`revolution_average`).
    """
    integrand, alpha, degree = rate_b0(op, errors, geometry, form, omega_ie_b0)
    return revolution_average(integrand, alpha, degree), degree


def rate_b0(op, errors, geometry=Geometry(), form="exact", omega_ie_b0=None):
    """Computed Earth rate in b0 at table angle alpha, before averaging.

    Parameters
    ----------
    op : Operating
    errors : ErrorModel
    geometry : Geometry or tuple
        A :class:`Geometry`, or ``(r_zb_s, K_g)`` where either may be a CasADi expression.
    form : {'exact', 'first_order'}
        Form of C_b0^n.
    omega_ie_b0 : casadi.SX, shape (3, 1), optional
        Stand-in for the true Earth rate in b0 (default ``C_n^b0 omega_ie_n``); a symbol here
        lets the constant chain from it to the averaged rate be folded (the compiled
        compensation, :mod:`hse_opt.fit.export`).

    Returns
    -------
    omega_b0 : casadi.SX, shape (3, 1)
        ``C_b^b0 (C~_s^b K~_g omega_ig_g - omega_nb_b)`` at the symbol ``alpha``, rad/s,
        with C_b^b0 from the (delayed, erroneous) encoder angle.
    alpha : casadi.SX
        The table-angle symbol.
    degree : int
        Trigonometric degree in alpha of the averaged quantity (averaged exactly with
        degree + 1 samples): 1 for the body rate, times the largest gyro-output degree,
        plus 1 + the largest encoder harmonic for the encoder-angle projection.
    """
    C_b_b0_enc, rate_b, alpha, degree = _projected(op, errors, geometry, form, omega_ie_b0)
    return ca.mtimes(C_b_b0_enc, rate_b), alpha, degree


def _projected(op, errors, geometry, form, omega_ie_b0=None):
    """The two factors of :func:`rate_b0`: the processor's ``C_b^b0`` (encoder angle) and the
    processed rate in b, ``C~_s^b K~_g omega_ig_g - omega_nb_b``, at the symbol alpha; then
    alpha and the degree."""
    r_cal, K_g = (geometry.r_zb_s, geometry.K_g) if isinstance(geometry, Geometry) else geometry
    alpha = ca.SX.sym("alpha")
    C_n_b0 = c_b0_n(op.psi, op.theta, op.gamma, form).T
    if omega_ie_b0 is None:
        omega_ie_b0 = ca.mtimes(C_n_b0, frames.earth_rate_n(op.L))
    omega_nb_b = op.Omega * E_Z
    omega_ib_b = ca.mtimes(frames.rot_z(alpha).T, omega_ie_b0) + omega_nb_b

    r_cal = r_cal if frames.is_symbolic(r_cal) else ca.DM(r_cal)
    r_true = r_cal + errors.d_r_zb_s
    r_true = r_true / ca.norm_2(r_true)
    C_b_s_true = frames.c_b_s(r_true)
    C_s_b = frames.c_b_s(r_cal if frames.is_symbolic(r_cal) else np.array(r_cal).ravel()).T
    C_s_b = C_s_b if frames.is_symbolic(C_s_b) else ca.DM(C_s_b)
    K_g = K_g if frames.is_symbolic(K_g) else ca.DM(K_g)

    omega_ig_g = gyro_outputs(K_g, C_b_s_true, omega_ib_b + errors.gyro_bias_b)
    sign_g = ca.sign(op.Omega * ca.solve(K_g, ca.mtimes(C_b_s_true, E_Z)))
    degree_body = 1
    out_g = omega_ig_g
    for fun, deg in errors.gyro_output_terms:
        out_g = out_g + fun(omega_ig_g, sign_g)
        degree_body = max(degree_body, deg)

    omega_b_est = ca.mtimes([c_s_b_tilde(C_s_b, errors.xi), k_g_tilde(K_g, errors.eps), out_g])

    C_b_b0_enc, omega_nb_b_enc, order = encoder_projection(op, errors, alpha)
    return C_b_b0_enc, omega_b_est - omega_nb_b_enc, alpha, degree_body + 1 + order


def encoder_projection(op, errors, alpha):
    """What the processor takes from the encoder at the true table angle ``alpha``.

    The encoder angle is ``alpha_enc = alpha - Omega*delay + delta(alpha)``, ``delta`` the sum
    of the encoder terms, linearised (``|delta|`` ~ 1e-4 rad). Returns ``C_b^b0`` built from
    it, the table rate it removes, ``Omega (1 + d delta / d alpha) e_z``, and the largest
    harmonic order of ``delta``.
    """
    delta = ca.SX(0)
    order = 0
    for fun, k in errors.encoder_terms:
        delta = delta + fun(alpha)
        order = max(order, k)
    d_delta = ca.jacobian(delta, alpha)
    C_b_b0_enc = ca.mtimes([frames.rot_z(alpha), frames.rot_z(-op.Omega * errors.encoder_delay),
                            ca.SX.eye(3) + delta * SKEW_Z])
    return C_b_b0_enc, op.Omega * (1 + d_delta) * E_Z, order


def alignment_rates_b0(op, errors, geometry=Geometry(), form="exact"):
    """The revolution-averaged rate in b0 as the alignment processor splits it.

    The alignment processor (``hse-opt align``, :mod:`hse_opt.align.processor`: simulated and real
    logs) levels and gyrocompasses (TRIAD) on the mean rate with the parts fixed in the table
    top fitted out: a vector ``v`` fixed in b reaches b0 as ``g(alpha) v``, ``g`` the turn by
    the *encoder* angle (complex form, horizontal), and the horizontal mean is fitted as
    ``w + g v`` over the revolution, which gives ``w = mean - mu v`` with ``mu`` the
    revolution mean of ``g``. Its fine alignment (Kalman filter, table-fixed parts turning
    at the nominal rate) then sees the remainder, ``mu v``, as an east rate error, linearly
    (Eq. 12). ``mu`` is nonzero only when the encoder angle is not uniform in time (encoder
    harmonics: ``mu = i (c1 + i s1) / 2``), and ``v`` is large when a mount misalignment
    leaks the table rate into b.

    Returns ``(omega_coarse, omega_mean, degree)``: the coarse mean ``w`` (vertical: the
    plain mean), the plain revolution mean (:func:`averaged_rate_b0`) and its degree.
    """
    C_b_b0_enc, rate_b, alpha, degree = _projected(op, errors, geometry, form)
    integrand = ca.mtimes(C_b_b0_enc, rate_b)
    if not errors.encoder_terms:       # g = exp(i (alpha - Omega delay)): mu = 0
        mean = revolution_average(integrand, alpha, degree)
        return mean, mean, degree
    # one set of angles for the mean and the table-fixed part v (the b-frame mean)
    both = revolution_average(ca.vertcat(integrand, rate_b[0:2]), alpha, degree)
    mean, v = both[0:3], both[3:5]
    order = max(k for _, k in errors.encoder_terms)
    mu = revolution_average(C_b_b0_enc[0:2, 0], alpha, 1 + order)
    w = mean[0:2] - ca.vertcat(mu[0] * v[0] - mu[1] * v[1], mu[0] * v[1] + mu[1] * v[0])
    return ca.vertcat(w, mean[2]), mean, degree


def heading_error_alignment(op, omega_coarse, omega_mean, form="exact"):
    """Heading error (rad, estimated - true) of the alignment processor: the full nonlinear
    gyrocompass on the coarse mean (:func:`heading_error_gyrocompass`) plus the fine
    alignment's linear response to the rest, ``-d_omega_E / (w_ie cos L)`` (Eq. 12); see
    :func:`alignment_rates_b0`. Equal to the gyrocompass on the plain mean to first order."""
    rest_n = ca.mtimes(c_b0_n(op.psi, op.theta, op.gamma, form), omega_mean - omega_coarse)
    return heading_error_gyrocompass(op, omega_coarse, form) - rest_n[1] / (EARTH_RATE * ca.cos(op.L))


def heading_error_linear(op, omega_b0, form="exact"):
    """Eq. 12 with the project's sign: ``-d_omega_E / (w_ie cos L)`` (rad, estimated - true)."""
    C_b0_n = c_b0_n(op.psi, op.theta, op.gamma, form)
    d_omega_n = ca.mtimes(C_b0_n, omega_b0) - frames.earth_rate_n(op.L)
    return -d_omega_n[1] / (EARTH_RATE * ca.cos(op.L))


def heading_error_gyrocompass(op, omega_b0, form="exact"):
    """Heading error (rad, estimated - true) of the full nonlinear gyrocompass.

    With the vertical known from leveling (perfect accelerometers), the estimated east in b0
    is ``down x omega``, the estimated north ``east x down``; the error is the angle from the
    true north to the estimated one, measured toward east, with the sign flipped (a north
    turned toward east makes every heading read small). No small-angle step.
    """
    C_n_b0 = c_b0_n(op.psi, op.theta, op.gamma, form).T
    north, east, down = C_n_b0[:, 0], C_n_b0[:, 1], C_n_b0[:, 2]
    east_est = ca.cross(down, omega_b0)
    north_est = ca.cross(east_est, down)
    return -ca.atan2(ca.dot(north_est, east), ca.dot(north_est, north))


def error_function(form="exact", heading="gyrocompass"):
    """The paper's model as a CasADi Function of its named quantities, for studies and tests.

    Inputs: ``Omega`` (rad/s), ``psi``, ``theta``, ``gamma``, ``L`` (rad), ``eps`` (3, rad),
    ``xi`` (3, rad), ``r_zb_s`` (3, the calibrated axis, unit), ``d_r_zb_s`` (3, true axis
    minus calibrated). Outputs: ``heading_err`` (rad, estimated - true), ``omega_b0``
    (revolution-averaged computed Earth rate in b0, rad/s) and ``d_omega_n`` (its error in n).
    ``heading`` is ``'gyrocompass'`` (full nonlinear) or ``'linear'`` (Eq. 12).
    """
    names = ("Omega", "psi", "theta", "gamma", "L")
    Omega, psi, theta, gamma, L = (ca.SX.sym(n) for n in names)
    eps, xi, r, dr = (ca.SX.sym(n, 3) for n in ("eps", "xi", "r_zb_s", "d_r_zb_s"))
    op = Operating(Omega=Omega, psi=psi, theta=theta, gamma=gamma, L=L)
    errors = ErrorModel()
    errors.add_lambda(eps)
    errors.add_xi(xi)
    errors.add_axis_error(dr)
    omega_b0, _ = averaged_rate_b0(op, errors, (r, ca.DM.eye(3)), form)
    if heading == "gyrocompass":
        h = heading_error_gyrocompass(op, omega_b0, form)
    elif heading == "linear":
        h = heading_error_linear(op, omega_b0, form)
    else:
        raise ValueError(f"heading={heading!r} is not allowed; use 'gyrocompass' or 'linear'")
    d_omega_n = ca.mtimes(c_b0_n(psi, theta, gamma, form), omega_b0) - frames.earth_rate_n(L)
    return ca.Function("hse_model", [Omega, psi, theta, gamma, L, eps, xi, r, dr],
                       [h, omega_b0, d_omega_n],
                       list(names) + ["eps", "xi", "r_zb_s", "d_r_zb_s"],
                       ["heading_err", "omega_b0", "d_omega_n"])
