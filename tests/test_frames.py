import casadi as ca
import numpy as np
import pytest

from hse_opt import frames, units


def test_rotations_are_proper_and_match_symbolic(rng):
    a = rng.uniform(-np.pi, np.pi, 50)
    for rot in (frames.rot_x, frames.rot_y, frames.rot_z):
        R = rot(a)
        assert R.shape == (50, 3, 3)
        np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-15)
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-14)
        s = ca.SX.sym("s")
        f = ca.Function("f", [s], [rot(s)])
        np.testing.assert_allclose(np.array(f(a[3])), R[3], atol=1e-15)


def test_rot_z_is_c_b_b0_of_the_paper():
    # C_b^b0 = [[cos a, -sin a, 0], [sin a, cos a, 0], [0, 0, 1]]: x_b at alpha is seen in b0
    a = 0.3
    np.testing.assert_allclose(frames.rot_z(a) @ [1, 0, 0], [np.cos(a), np.sin(a), 0], atol=1e-15)


def test_heading_is_clockwise_from_north():
    # heading 90 deg: x_b0 points east in NED
    C = frames.dcm_zyx(np.pi / 2, 0.0, 0.0)
    np.testing.assert_allclose(C @ [1, 0, 0], [0, 1, 0], atol=1e-15)


def test_first_order_dcm_agrees_to_second_order_in_tilt(rng):
    psi = rng.uniform(0, 2 * np.pi, 100)
    u, v = rng.uniform(-1, 1, (2, 100))
    ratio = []
    for tilt in (2e-3, 1e-3, 5e-4, 2.5e-4):
        d = np.abs(frames.dcm_zyx(psi, u * tilt, v * tilt) - frames.dcm_first_order(psi, u * tilt, v * tilt))
        assert d.max() <= 2 * tilt ** 2  # |theta gamma| + (theta^2 + gamma^2)/2
        ratio.append(d.max() / tilt ** 2)
    # the difference is second order: halving the tilt quarters it
    np.testing.assert_allclose(ratio, ratio[-1], rtol=1e-2)


def test_c_b_s_matches_cross_product_construction(rng):
    for _ in range(20):
        r = frames.R_ZB_S_IDEAL + rng.uniform(-1e-2, 1e-2, 3)
        r /= np.linalg.norm(r)
        y = np.cross(r, [1, 0, 0]); y /= np.linalg.norm(y)
        x = np.cross(y, r); x /= np.linalg.norm(x)
        np.testing.assert_allclose(frames.c_b_s(r), np.column_stack([x, y, r]), atol=1e-14)
        assert np.linalg.det(frames.c_b_s(r)) == pytest.approx(1.0)


def test_skew_is_cross_product(rng):
    v, u = rng.normal(size=(2, 3))
    np.testing.assert_allclose(frames.skew(v) @ u, np.cross(v, u), atol=1e-15)


def test_earth_rate_and_units():
    np.testing.assert_allclose(frames.earth_rate_n(0.0), [frames.EARTH_RATE, 0, 0])
    assert units.to_si(3600.0, "arcsec") == pytest.approx(units.DEG)
    assert units.from_si(units.DEG_PER_H, "deg/h") == pytest.approx(1.0)
    assert units.factor("arcsec/deg") == pytest.approx(1 / 3600)
    with pytest.raises(ValueError, match="furlong"):
        units.factor("furlong")
