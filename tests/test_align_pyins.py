"""The user's data path on data nobody here wrote (issue 25, item 7): raw logs made by an
independent third-party INS generator, ``python-ins`` (``pyins``; a test extra in pyproject's
``[test]``): its ``sim.generate_imu`` integrates gyro and accelerometer increments from an
attitude history on the WGS84 Earth (its own Earth rate, gravity and coning/sculling
integration), and its ``inertial_sensor.Parameters`` applies a sensor triad's errors (a
transform matrix, white noise, bias random walk) with its own random numbers.

The turntable is described only by its attitude: ``C_s^n(t) = C_b0^n rot_z(Omega t) C_s^b``
(``docs/conventions.md``), the generator's body frame being the IMU frame s; the encoder
reads ``Omega t`` exactly. References: the attitude the logs were made with, the paper's
closed form to first order (``hse_opt.model.closed_form.heading_error_first_order``) for a
known lab-calibration error, and the generator's own noise parameters.
"""
import math

import numpy as np
import pytest

pyins_sim = pytest.importorskip("pyins.sim", reason="python-ins (pyins) is a test extra: pip install '.[test]'")
from pyins import inertial_sensor  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from hse_opt import units  # noqa: E402
from hse_opt.align import AlignConfig, RawLog, align  # noqa: E402
from hse_opt.align.noise import combine_noise, noise_from_log  # noqa: E402
from hse_opt.frames import c_b_s  # noqa: E402
from hse_opt.model.closed_form import heading_error_first_order  # noqa: E402

DT = 0.002
LAT_DEG = 45.0
R_ZB_S = np.array([-0.5772, -0.578, -0.57685020585937])
R_ZB_S = R_ZB_S / np.linalg.norm(R_ZB_S)
C_S_B = c_b_s(R_ZB_S).T                       # s -> b: the lab calibration the processor applies
PITCH, ROLL = -120.0 * units.ARCSEC, -55.0 * units.ARCSEC


def _kinematics(duration, rate_dps, psi):
    """Noise-free increments from the generator: ``(t, alpha, gyro, accel)``."""
    t = np.arange(int(round(duration / DT)) + 1) * DT
    alpha = rate_dps * units.DEG_PER_S * t
    C_b0_n = Rotation.from_euler("xyz", [ROLL, PITCH, psi]).as_matrix()
    C_s_n = C_b0_n @ Rotation.from_euler("z", alpha[:, None]).as_matrix() @ C_S_B
    rph = Rotation.from_matrix(C_s_n).as_euler("xyz", degrees=True)
    _, imu = pyins_sim.generate_imu(t, np.array([LAT_DEG, 0.0, 0.0]), rph, np.zeros((t.size, 3)),
                                    sensor_type="increment")
    return t, alpha, imu


def _log(t, alpha, imu, gyro=None, accel=None):
    """A RawLog of the generator's increments, errors applied by the generator's own sensor
    model when given (``inertial_sensor.Parameters``)."""
    g = imu[["gyro_x", "gyro_y", "gyro_z"]]
    a = imu[["accel_x", "accel_y", "accel_z"]]
    g = g if gyro is None else gyro.apply(g, "increment")
    a = a if accel is None else accel.apply(a, "increment")
    return RawLog(t, g.to_numpy(), a.to_numpy(), alpha, {"latitude_deg": LAT_DEG})


def _config(**kw):
    """The processor with the lab calibration (identity K~_g, the mount's C~_s^b) and a
    noise-free tuning unless given."""
    base = dict(C_s_b_cal=C_S_B, latitude=LAT_DEG * units.DEG, arw=0.0, vrw=0.0, gyro_pulse=0.0,
                accel_pulse=0.0)
    base.update(kw)
    return AlignConfig(**base)


@pytest.mark.parametrize("rate_dps, psi_deg", [(60.0, 40.0), (-40.0, 200.0)])
def test_noise_free_logs_give_the_true_attitude(rate_dps, psi_deg):
    t, alpha, imu = _kinematics(60.0 if abs(rate_dps) == 60 else 63.0, rate_dps, math.radians(psi_deg))
    res = align(_log(t, alpha, imu), _config())
    err = math.remainder(res.heading - math.radians(psi_deg), 2 * math.pi)
    assert abs(err) < 0.01 * units.ARCSEC
    assert abs(res.pitch - PITCH) < 0.01 * units.ARCSEC and abs(res.roll - ROLL) < 0.01 * units.ARCSEC


@pytest.mark.parametrize("rate_dps, psi_deg", [(60.0, 40.0), (-40.0, 200.0), (40.0, 110.0)])
def test_a_known_lab_calibration_error_moves_the_heading_by_the_closed_form(rate_dps, psi_deg):
    # the gyros' true non-orthogonality left by the lab calibration: K~_g = (I + Lambda) K_g
    # (Eq. 1); the processor applies K~_g = I, so the generator's gyro transform is I + Lambda
    eps = np.array([4.0, 2.0, 3.0]) * units.ARCSEC     # lambda2 = 9 arcsec, twice the paper's
    lam = np.array([[0, 0, 0], [eps[0], 0, 0], [eps[1], eps[2], 0]])
    t, alpha, imu = _kinematics(60.0 if abs(rate_dps) == 60 else 63.0, rate_dps, math.radians(psi_deg))
    log = _log(t, alpha, imu, gyro=inertial_sensor.Parameters(transform=np.eye(3) + lam))
    res = align(log, _config())
    err = math.remainder(res.heading - math.radians(psi_deg), 2 * math.pi)
    expected = heading_error_first_order(rate_dps * units.DEG_PER_S, LAT_DEG * units.DEG, eps, np.zeros(3), R_ZB_S,
                                         math.radians(psi_deg), PITCH, ROLL)
    assert abs(expected) > 0.5 * units.ARCSEC            # a heading-sensitive error 50 x the tolerance
    assert abs(err - expected) < 0.01 * units.ARCSEC


@pytest.fixture(scope="module")
def noisy():
    """One 63-second record at 40 deg/s (7 revolutions) and the generator's noise on it, 100
    draws: gyro ARW, accelerometer VRW (white noise of each sensor, its own seed per log)."""
    t, alpha, imu = _kinematics(63.0, 40.0, math.radians(70.0))
    arw = 0.02 * units.DEG_PER_H                        # rad/sqrt(s): 0.02 deg/h/sqrt(Hz)
    vrw = 5.0 * units.MICRO_G                           # m/s/sqrt(s): 5 ug/sqrt(Hz)
    logs = [_log(t, alpha, imu, gyro=inertial_sensor.Parameters(noise=arw, rng=2 * k),
                 accel=inertial_sensor.Parameters(noise=vrw, rng=2 * k + 1)) for k in range(100)]
    return _log(t, alpha, imu), logs, arw, vrw


def test_allan_terms_are_the_generators(noisy):
    _, logs, arw, vrw = noisy
    pooled = combine_noise(noise_from_log(log) for log in logs[:10])
    assert np.allclose(pooled.random_walk[:3], arw, rtol=0.1)
    assert np.allclose(pooled.random_walk[3:], vrw, rtol=0.1)
    # white noise only: the quantization term holds under 10 % of the variance at the shortest
    # cluster (its point scatters by 1 % in variance; the fit trades it against N's 1 %)
    assert np.all(pooled.coefficients[:3, 0] / pooled.tau[0] ** 2 < 0.1 * arw ** 2 / pooled.tau[0])


def test_a_rate_random_walk_of_the_generator_is_recovered():
    # the generator's bias random walk (rad/s/sqrt(s)) strong enough to dominate from 5 s
    t, alpha, imu = _kinematics(126.0, 40.0, math.radians(70.0))
    arw, rrw = 0.02 * units.DEG_PER_H, 0.2 * units.DEG_PER_H
    figs = [noise_from_log(_log(t, alpha, imu, gyro=inertial_sensor.Parameters(noise=arw, bias_walk=rrw, rng=50 + k)))
            for k in range(8)]
    pooled = combine_noise(figs)
    assert np.allclose(pooled.random_walk[:3], arw, rtol=0.1)
    assert np.allclose(pooled.rate_random_walk[:3].mean(), rrw, rtol=0.1)


def test_heading_z_scores_with_the_filter_tuned_from_the_data(noisy):
    import dataclasses
    clean, logs, _, _ = noisy
    figs = [noise_from_log(log) for log in logs]
    config = dataclasses.replace(_config(), **combine_noise(figs).tuning())
    ref = align(clean, config).heading                  # the noise-free log's heading, same filter
    res = [align(log, config) for log in logs]
    z = np.array([math.remainder(r.heading - ref, 2 * math.pi) / r.heading_std for r in res])
    rms = float(np.sqrt(np.mean(z ** 2)))
    # 100 z-scores: the RMS of unit normals scatters by 1 / sqrt(200) = 0.07
    assert 0.85 <= rms <= 1.15, rms
    assert abs(np.mean(z)) < 3 / math.sqrt(len(z))
