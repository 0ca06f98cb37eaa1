"""The simulator's own rotations (numpy only), independent of the model's :mod:`hse_opt.frames`.

The simulator is the independent reference for the symbolic model, so it does not share the
model's frame code; ``tests/test_sim_rotations.py`` checks these functions against
``scipy.spatial.transform.Rotation``. Conventions are those of the package (:mod:`hse_opt`):
``C_ab`` maps frame b to frame a, NED navigation frame, ``C_b0^n = rot_z(psi) rot_y(theta)
rot_x(gamma)``. Angles of shape ``(...)`` give matrices of shape ``(..., 3, 3)``.
"""
import math

import numpy as np

#: Earth rotation rate, rad/s (WGS-84)
EARTH_RATE = 7.292115e-5
#: the ideal rotation axis in s: every component -1/sqrt(3) (each gyro axis at 54.74 deg)
R_ZB_S_IDEAL = np.full(3, -1.0 / math.sqrt(3.0))


def _matrix(rows):
    """``(..., 3, 3)`` from nested rows of broadcastable scalars/arrays."""
    if all(getattr(e, "ndim", 0) == 0 for row in rows for e in row):   # one matrix: the common case
        return np.array(rows, dtype=float)
    flat = np.broadcast_arrays(*[np.asarray(e, dtype=float) for row in rows for e in row])
    return np.stack(flat, axis=-1).reshape(flat[0].shape + (3, 3))


def skew(v):
    """The cross-product matrix ``[v x]`` of ``v`` (..., 3): ``skew(v) @ u == cross(v, u)``."""
    v = np.asarray(v, dtype=float)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    zero = np.zeros_like(x)
    return _matrix([[zero, -z, y], [z, zero, -x], [-y, x, zero]])


def rot_x(a):
    """Active rotation by ``a`` (rad) about x."""
    c, s = np.cos(a), np.sin(a)
    return _matrix([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a):
    """Active rotation by ``a`` (rad) about y."""
    c, s = np.cos(a), np.sin(a)
    return _matrix([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a):
    """Active rotation by ``a`` (rad) about z (``rot_z(alpha)`` is C_b^b0)."""
    c, s = np.cos(a), np.sin(a)
    return _matrix([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotvec_to_dcm(phi):
    """Rotation matrix of the rotation vector ``phi`` (..., 3), rad (Rodrigues; exact at any
    angle, the Taylor series of its coefficients below 1e-4 rad)."""
    phi = np.asarray(phi, dtype=float)
    a2 = np.einsum("...i,...i->...", phi, phi)
    small = a2 < 1e-8
    a = np.sqrt(np.where(small, 1.0, a2))
    s = np.where(small, 1.0 - a2 / 6.0 + a2 * a2 / 120.0, np.sin(a) / a)
    c = np.where(small, 0.5 - a2 / 24.0 + a2 * a2 / 720.0, (1.0 - np.cos(a)) / (a * a))
    k = skew(phi)
    return np.eye(3) + s[..., None, None] * k + c[..., None, None] * (k @ k)


def dcm_to_zyx(C):
    """``(psi, theta, gamma)``, rad, of ``C = rot_z(psi) rot_y(theta) rot_x(gamma)`` (..., 3, 3):
    heading in (-pi, pi], pitch in [-pi/2, pi/2], roll in (-pi, pi]."""
    C = np.asarray(C, dtype=float)
    return (np.arctan2(C[..., 1, 0], C[..., 0, 0]), -np.arcsin(np.clip(C[..., 2, 0], -1.0, 1.0)),
            np.arctan2(C[..., 2, 1], C[..., 2, 2]))


def earth_rate_n(latitude):
    """Earth rate in NED, rad/s: ``EARTH_RATE (cos L, 0, -sin L)`` (..., 3)."""
    if isinstance(latitude, float):                  # one latitude: the common case
        return np.array([EARTH_RATE * math.cos(latitude), 0.0, -EARTH_RATE * math.sin(latitude)])
    c, s = np.cos(latitude), np.sin(latitude)
    return EARTH_RATE * np.stack(np.broadcast_arrays(c, np.zeros_like(c), -s), axis=-1)


def c_b_s(r_zb_s):
    """C_b^s from the unit rotation axis in s (3,): columns ``r_xb^s, r_yb^s, r_zb^s`` with
    ``r_yb^s`` along ``r_zb^s x (1, 0, 0)`` (normal to gyro x) and ``r_xb^s = r_yb^s x r_zb^s``."""
    x, y, z = (float(v) for v in r_zb_s)
    k = math.hypot(y, z)                     # |r_zb^s x (1, 0, 0)|
    return np.array([[k, 0.0, x], [-x * y / k, z / k, y], [-x * z / k, -y / k, z]])


def wrap_angle(a):
    """``a`` (rad) wrapped to [-pi, pi)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi
