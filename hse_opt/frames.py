"""Rotations, skew matrices and the frame constructions of the paper (section 1.1).

Conventions (see :mod:`hse_opt` for the whole contract):

- ``C_ab`` maps vectors from frame b to frame a: ``v_a = C_ab @ v_b``.
- Frames: n (North-East-Down), b0 (turntable base), b (turntable top, z_b down along the
  rotation axis), s (IMU reference), g (gyro sensing axes, non-orthogonal).
- ``rot_x``, ``rot_y``, ``rot_z`` are the active rotations by an angle about a coordinate
  axis; ``rot_z(alpha)`` is C_b^b0 of the paper, ``rot_z(psi) @ rot_y(theta) @ rot_x(gamma)``
  is the exact Z-Y-X form of C_b0^n (heading psi clockwise from north seen from above,
  pitch theta, roll gamma).

Every function takes either numbers / numpy arrays (broadcast: angles of shape ``(...)``
give matrices of shape ``(..., 3, 3)``) or CasADi ``SX`` scalars (giving a 3x3
CasADi matrix). This is the one module the symbolic model and the simulator share.
"""
import math

import casadi as ca
import numpy as np

#: Earth rotation rate, rad/s (WGS-84)
EARTH_RATE = 7.292115e-5
#: Normal gravity used by the simulator's default system, m/s^2
GRAVITY = 9.7925
#: The ideal rotation axis in s: every component -1/sqrt(3) (each gyro axis at 54.74 deg)
R_ZB_S_IDEAL = np.full(3, -1.0 / math.sqrt(3.0))

_SYM = (ca.SX,)


def is_symbolic(*xs):
    """True when any argument is a CasADi SX expression."""
    return any(isinstance(x, _SYM) for x in xs)


def _sin(x):
    return ca.sin(x) if is_symbolic(x) else np.sin(x)


def _cos(x):
    return ca.cos(x) if is_symbolic(x) else np.cos(x)


def matrix3(rows):
    """Assemble a 3x3 matrix from nested rows of scalars, arrays or CasADi expressions.

    Numeric entries broadcast: the result has shape ``(..., 3, 3)``.
    """
    flat = [e for row in rows for e in row]
    if is_symbolic(*flat):
        return ca.blockcat([[ca.SX(e) if not is_symbolic(e) else e for e in row] for row in rows])
    arrays = np.broadcast_arrays(*[np.asarray(e, dtype=float) for e in flat])
    return np.stack(arrays, axis=-1).reshape(arrays[0].shape + (3, 3))


def skew(v):
    """The cross-product matrix ``[v x]``: ``skew(v) @ u == cross(v, u)``.

    Parameters
    ----------
    v : array_like, shape (..., 3), or CasADi 3-vector
    """
    if is_symbolic(v) or isinstance(v, ca.DM):
        return ca.skew(v)
    v = np.asarray(v, dtype=float)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    zero = np.zeros_like(x)
    return matrix3([[zero, -z, y], [z, zero, -x], [-y, x, zero]])


def rot_x(a):
    """Active rotation by angle ``a`` (rad) about x."""
    c, s = _cos(a), _sin(a)
    return matrix3([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a):
    """Active rotation by angle ``a`` (rad) about y."""
    c, s = _cos(a), _sin(a)
    return matrix3([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a):
    """Active rotation by angle ``a`` (rad) about z; ``rot_z(alpha)`` is C_b^b0."""
    c, s = _cos(a), _sin(a)
    return matrix3([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def dcm_zyx(psi, theta, gamma):
    """C_b0^n, exact Z-Y-X form ``rot_z(psi) @ rot_y(theta) @ rot_x(gamma)`` (rad)."""
    if is_symbolic(psi, theta, gamma):
        return ca.mtimes([rot_z(psi), rot_y(theta), rot_x(gamma)])
    return rot_z(psi) @ rot_y(theta) @ rot_x(gamma)


def dcm_first_order(psi, theta, gamma):
    """C_b0^n to first order in the tilts, the paper's Eq. 3: ``rot_z(psi) (I + [phi x])``,
    phi = (gamma, theta, 0) rad."""
    c, s = _cos(psi), _sin(psi)
    return matrix3([
        [c, -s, gamma * s + theta * c],
        [s, c, -gamma * c + theta * s],
        [-theta, gamma, 1.0],
    ])


def earth_rate_n(latitude):
    """Earth rate in NED, rad/s: ``EARTH_RATE * (cos L, 0, -sin L)``; latitude in rad."""
    c, s = _cos(latitude), _sin(latitude)
    if is_symbolic(latitude):
        return EARTH_RATE * ca.vertcat(c, 0, -s)
    return EARTH_RATE * np.stack(np.broadcast_arrays(c, np.zeros_like(c), -s), axis=-1)


def c_b_s(r_zb_s):
    """C_b^s from the rotation axis in s (paper, after Eq. 1): columns r_xb^s, r_yb^s, r_zb^s.

    ``r_yb^s = (r_zb^s x r_xg^s)/|.|`` with ``r_xg^s = (1, 0, 0)`` and
    ``r_xb^s = (r_yb^s x r_zb^s)/|.|``. ``r_zb_s`` must be a unit vector.
    """
    if is_symbolic(r_zb_s):
        ex, ey, ez = r_zb_s[0], r_zb_s[1], r_zb_s[2]
        sqrt = ca.sqrt
    else:
        r_zb_s = np.asarray(r_zb_s, dtype=float)
        ex, ey, ez = r_zb_s[..., 0], r_zb_s[..., 1], r_zb_s[..., 2]
        sqrt = np.sqrt
    k = sqrt(1 - ex * ex)
    return matrix3([
        [k, 0.0 * ex, ex],
        [-ex * ey / k, ez / k, ey],
        [-ex * ez / k, -ey / k, ez],
    ])


def wrap_angle(a):
    """Wrap an angle (rad) to [-pi, pi)."""
    if is_symbolic(a):
        return ca.atan2(ca.sin(a), ca.cos(a))
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


# -- additions (numeric helpers used by the simulator; additive only) --------------------------
def rotvec_to_dcm(phi):
    """Rotation matrix of a rotation vector (Rodrigues), exact for any angle; numeric only.

    ``rotvec_to_dcm(a * e)`` is the active rotation by angle ``a`` (rad) about the unit axis
    ``e``; to first order it is ``I + [phi x]``.

    Parameters
    ----------
    phi : array_like, shape (..., 3)
        Rotation vector, rad.

    Returns
    -------
    numpy.ndarray, shape (..., 3, 3)
    """
    phi = np.asarray(phi, dtype=float)
    a2 = np.einsum("...i,...i->...", phi, phi)
    a = np.sqrt(a2)
    small = a2 < 1e-8
    safe = np.where(small, 1.0, a)
    # sin(a)/a and (1 - cos(a))/a^2, with their Taylor series for small a
    s = np.where(small, 1.0 - a2 / 6.0 + a2 * a2 / 120.0, np.sin(safe) / safe)
    c = np.where(small, 0.5 - a2 / 24.0 + a2 * a2 / 720.0, (1.0 - np.cos(safe)) / (safe * safe))
    k = skew(phi)
    eye = np.broadcast_to(np.eye(3), k.shape)
    return eye + s[..., None, None] * k + c[..., None, None] * (k @ k)


def dcm_to_zyx(C):
    """Angles (psi, theta, gamma), rad, of ``C = rot_z(psi) @ rot_y(theta) @ rot_x(gamma)``.

    The inverse of :func:`dcm_zyx` for |theta| < pi/2; numeric only.

    Parameters
    ----------
    C : array_like, shape (..., 3, 3)

    Returns
    -------
    psi, theta, gamma : numpy.ndarray, shape (...)
        Heading in (-pi, pi], pitch in [-pi/2, pi/2], roll in (-pi, pi].
    """
    C = np.asarray(C, dtype=float)
    psi = np.arctan2(C[..., 1, 0], C[..., 0, 0])
    theta = -np.arcsin(np.clip(C[..., 2, 0], -1.0, 1.0))
    gamma = np.arctan2(C[..., 2, 1], C[..., 2, 2])
    return psi, theta, gamma
