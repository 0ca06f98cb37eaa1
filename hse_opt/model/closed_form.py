"""The paper's closed forms (Eqs. 13-16) and the first-order result they approximate.

Sign: the paper's delta-psi is *true minus estimated*; functions here say which sign they
return. ``heading_error_*`` functions return the project's sign (estimated - true).
"""
import numpy as np

from ..frames import EARTH_RATE
from . import inputs


def lambda1(rate, latitude):
    """lambda1 = Omega - w_ie sin L (rad/s), Eq. 13."""
    return rate - EARTH_RATE * np.sin(latitude)


def c23(psi, theta, gamma):
    """C23 = -gamma cos psi + theta sin psi: east component of the rotation axis (Eq. 3;
    :func:`hse_opt.model.inputs.c23` with pitch theta and roll gamma)."""
    return inputs.c23(psi, inputs.Tilt(roll=gamma, pitch=theta))


def mean_d_omega_east(rate, latitude, lambda2, C23):
    """Eq. 13: revolution mean of the east rate error, lambda1 lambda2 C23 / 3 (rad/s)."""
    return lambda1(rate, latitude) * lambda2 * C23 / 3.0


def hse_paper(rate, latitude, lambda2, psi, theta, gamma):
    """Eq. 14 as printed: the paper's delta-psi (true - estimated), rad."""
    return lambda1(rate, latitude) * lambda2 * c23(psi, theta, gamma) / (3.0 * EARTH_RATE * np.cos(latitude))


def heading_error_eq14(rate, latitude, lambda2, psi, theta, gamma):
    """Eq. 14 with the project's sign: heading error estimated - true, rad."""
    return -hse_paper(rate, latitude, lambda2, psi, theta, gamma)


def k_hse(lambda2, C23, latitude):
    """Eq. 16: K_HSE = lambda2 C23 / (3 w_ie cos L), s (rad of heading per rad/s of rate);
    paper's sign (true - estimated)."""
    return lambda2 * C23 / (3.0 * EARTH_RATE * np.cos(latitude))


def hse_eq15(rate, K_HSE):
    """Eq. 15: the paper's delta-psi = K_HSE Omega (true - estimated), rad; K_HSE in s."""
    return K_HSE * rate


def lambda2_from_k_hse(K_HSE, C23, latitude):
    """Invert Eq. 16: lambda2 = 3 w_ie cos L K_HSE / C23 (rad); K_HSE in s, paper's sign."""
    return 3.0 * EARTH_RATE * np.cos(latitude) * K_HSE / C23


def lambda2_c23_from_k_hse(K_HSE, latitude):
    """The product lambda2 * C23 (rad^2) implied by K_HSE (s, paper's sign) at latitude L."""
    return 3.0 * EARTH_RATE * np.cos(latitude) * K_HSE


def heading_error_first_order(rate, latitude, eps, xi, r_zb_s, psi, theta, gamma):
    """The heading error (rad, estimated - true) to first order in eps and xi, derived here.

    With ``M = C_s^b Lambda C_b^s - [xi x]`` (Lambda of Eq. 1; C_b^s from the axis r_zb^s),
    the revolution average of ``C_b^b0 M C_b0^b`` keeps ``M33`` on the axis, ``a = (M11 +
    M22)/2`` across it and the turn ``c = (M21 - M12)/2`` about it; the axis rate Omega
    picks up ``M33``. Since ``trace(Lambda) = 0``, ``a = -M33/2`` for the Lambda part. With
    ``z = C_b0^n e_z = (C13, C23, C33)``, the east rate error is
    ``C23 M33 (Omega + 3/2 w_ie (C13 cos L - C33 sin L)) + c w_ie (C33 cos L + C13 sin L)``,
    and the heading error is minus it over ``w_ie cos L`` (Eq. 12, our sign).

    Its heading-dependent part is Eq. 14 with ``lambda2 -> 3 r_zb^s' Lambda r_zb^s`` (the
    paper's lambda2 for the ideal axis) and ``lambda1 -> Omega - 3/2 w_ie sin L`` (the paper
    has 1 for 3/2: Lambda also shrinks the horizontal Earth rate by M33/2, which leaks into
    east through the tilt; a relative change of w_ie sin L / (2 Omega), below 1e-4 at the
    paper's rates). The heading-independent remainder is ``-c (C33 + C13 tan L)``, i.e. to
    first order ``xi_z - (M21 - M12)/2``: a turn of the IMU mount or of the Lambda error
    about the rotation axis is a heading offset.

    Parameters
    ----------
    rate : float or ndarray
        Omega, rad/s (signed).
    latitude : float
        L, rad.
    eps, xi : array_like, shape (3,)
        eps1..eps3 of Lambda and the C_s^b error angles (in b), rad.
    r_zb_s : array_like, shape (3,)
        Rotation axis in s (unit vector).
    psi, theta, gamma : float or ndarray
        Heading, pitch, roll of b0 (rad, exact Z-Y-X).
    """
    from ..frames import c_b_s, dcm_zyx, skew

    eps = np.asarray(eps, dtype=float)
    C_s_b = c_b_s(np.asarray(r_zb_s, dtype=float)).T
    Lam = np.array([[0, 0, 0], [eps[0], 0, 0], [eps[1], eps[2], 0]])
    M = C_s_b @ Lam @ C_s_b.T - skew(np.asarray(xi, dtype=float))
    M33, c = M[2, 2], (M[1, 0] - M[0, 1]) / 2
    C = dcm_zyx(psi, theta, gamma)
    C13, C23, C33 = C[..., 0, 2], C[..., 1, 2], C[..., 2, 2]
    w, cL, sL = EARTH_RATE, np.cos(latitude), np.sin(latitude)
    d_omega_e = C23 * M33 * (rate + 1.5 * w * (C13 * cL - C33 * sL)) + c * w * (C33 * cL + C13 * sL)
    return -d_omega_e / (w * cL)


def heading_error_encoder_mount(rate, latitude, psi, enc_c1, enc_s1, xi_x, xi_y):
    """Heading error (rad, estimated - true) of the encoder's 1st harmonic meeting a horizontal
    mount error, to first order in each (level base), derived here.

    The calibrated ``C~_s^b = (I - [xi x]) C_s^b`` (Eq. 2) leaks the table rate into the
    horizontal of b: ``-Omega xi x e_z = Omega (-xi_y, xi_x)``, as a complex number
    ``i Omega z`` with ``z = xi_x + i xi_y``. The processor turns it into b0 with the encoder
    angle ``alpha + delta``, ``delta = c1 cos(alpha) + s1 sin(alpha)``:
    ``exp(i alpha) (1 + i delta) i Omega z``, whose revolution mean is
    ``-Omega D z / 2`` with ``D = c1 + i s1`` (the mean of ``delta exp(i alpha)`` is ``D / 2``).
    In n (``C_b0^n = rot_z(psi)``) its east part is ``Im(exp(i psi) (-Omega D z / 2))``, and
    Eq. 12 gives ``Omega Im(exp(i psi) D z) / (2 w_ie cos L)``. Angles in rad, rate rad/s.
    """
    D = enc_c1 + 1j * enc_s1
    z = xi_x + 1j * xi_y
    return rate * np.imag(np.exp(1j * psi) * D * z) / (2.0 * EARTH_RATE * np.cos(latitude))
