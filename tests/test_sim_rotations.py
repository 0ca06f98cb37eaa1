"""The simulator's own rotations (hse_opt.align.rotations) against scipy.spatial.transform and
against the definitions (orthonormal frames, the axis they are built from)."""
import numpy as np
from scipy.spatial.transform import Rotation

from hse_opt.align import rotations as r


def test_euler_and_axis_rotations_match_scipy(rng):
    psi, theta, gamma = rng.uniform(-np.pi, np.pi, 50), rng.uniform(-1.5, 1.5, 50), rng.uniform(-np.pi, np.pi, 50)
    C = r.rot_z(psi) @ r.rot_y(theta) @ r.rot_x(gamma)
    ref = Rotation.from_euler("ZYX", np.column_stack([psi, theta, gamma])).as_matrix()  # intrinsic z-y'-x''
    np.testing.assert_allclose(C, ref, atol=1e-15)
    back = np.column_stack(r.dcm_to_zyx(C))
    np.testing.assert_allclose(back, np.column_stack([psi, theta, gamma]), atol=1e-12)
    for axis, f in zip("xyz", (r.rot_x, r.rot_y, r.rot_z)):
        np.testing.assert_allclose(f(psi), Rotation.from_euler(axis, psi[:, None]).as_matrix(), atol=1e-15)


def test_rotation_vectors_match_scipy_at_every_size(rng):
    axes = rng.normal(size=(40, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    for angle in (0.0, 1e-9, 3e-5, 1e-2, 1.0, 3.1):
        phi = angle * axes
        np.testing.assert_allclose(r.rotvec_to_dcm(phi), Rotation.from_rotvec(phi).as_matrix(), atol=1e-15)


def test_skew_earth_rate_wrap_and_mount_frame(rng):
    v, u = rng.normal(size=(10, 3)), rng.normal(size=(10, 3))
    np.testing.assert_allclose(np.einsum("kij,kj->ki", r.skew(v), u), np.cross(v, u), atol=1e-14)
    lat = 0.49
    w = r.earth_rate_n(lat)
    # the Earth's axis in NED at latitude L: north turned up (towards -D) by L about east
    ref = Rotation.from_euler("y", lat).apply([r.EARTH_RATE, 0.0, 0.0])
    np.testing.assert_allclose(w, ref, atol=1e-20)
    a = rng.uniform(-20, 20, 100)
    wrapped = r.wrap_angle(a)
    assert np.all((wrapped >= -np.pi) & (wrapped < np.pi))
    np.testing.assert_allclose(np.exp(1j * wrapped), np.exp(1j * a), atol=1e-12)
    z = r.R_ZB_S_IDEAL + rng.uniform(-1e-3, 1e-3, 3)
    z /= np.linalg.norm(z)
    C = r.c_b_s(z)
    np.testing.assert_allclose(C.T @ C, np.eye(3), atol=1e-15)
    assert np.isclose(np.linalg.det(C), 1.0)
    np.testing.assert_allclose(C[:, 2], z)                   # z_b is the rotation axis
    assert abs(C[0, 1]) < 1e-16                              # y_b is normal to gyro x
    assert C[0, 0] > 0                                       # x_b leans towards gyro x
