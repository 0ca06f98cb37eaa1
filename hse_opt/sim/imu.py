"""Raw 500 Hz data of the constant-rate biased RLG system on a static base (vectorised).

Physics (``PHYSICS.md``; frames n NED, b0 turntable base, b table top, s IMU, g gyro axes):

* Attitude of b0: ``C_b0^n = Rot(tau_n) rot_z(A) rot_y(theta) rot_x(gamma)``: the stand axis
  tilted by ``tau_n = (tau_N, tau_E, 0)`` (fixed in n), the true stand azimuth ``A`` (reading
  plus its offset and periodic error), the base tilt ``(gamma, theta)`` = stand mount tilt +
  the run's deliberate tilt (fixed in b0).
* Table angle ``alpha(t) = alpha0 + W t + W r / (h |W|) (sin(h |W| t + phi) - sin(phi))``
  with ``W = Omega (1 + rate_error)`` (ripple ``r`` at ``h`` cycles per revolution);
  ``C_b^b0 = rot_z(alpha)``.
* Body rate and specific force in b: ``w_ib^b = rot_z(-alpha) w^b0 + alpha_dot e_z`` with
  ``w^b0 = C_n^b0 w_ie^n``; ``f^b = rot_z(-alpha) f^b0``, ``f^b0 = C_n^b0 (0, 0, -g)``.
  Over each sample interval ``(t_{k-1}, t_k]`` the increments are integrated in closed form:
  ``int cos(alpha) dt = (sin alpha_k - sin alpha_{k-1}) / alpha_dot`` (exact for a constant
  rate; with a 1e-4 ripple, alpha deviates from linear inside a 2 ms interval by
  ``alpha_ddot dt^2 / 8`` ~ 1e-10 rad, a periodic relative error of 1e-10 of the horizontal
  rate and specific force),
  ``int alpha_dot dt = alpha_k - alpha_{k-1}`` exactly.
* IMU mount: ``C_b^s(t) = C_b^s(r_zb^s true) rot_z(-xi_w(t))`` with the thermal rotation
  ``xi_w`` (warm-up and temperature) about z_b; its rate adds ``d xi_w`` to the z increment.
  (The lab calibration C~_s^b = (I - [xi x]) C_s^b(r_zb^s calibrated) lives in the processor.)
* Gyros: ``dtheta_g = K_g^-1 C_b^s dtheta_b`` scaled by ``1 + sf + k_nl |w_g|``, plus the bias
  integral (constant + axis bias + warm-up ``b_w exp(-t_on / tau)`` in closed form +
  temperature coefficient, thermal terms by the midpoint rule), angle random walk
  ``N sqrt(dt) n_k``, then RLG pulses: the cumulative angle is floored to whole pulses with a
  random initial counter phase and differenced, so the remainder is carried.
* Accelerometers (axes along s, scale and non-orthogonality ``A_acc``): ``dv_a = A_acc C_b^s
  dv_b`` plus bias, white noise and velocity pulses in the same way.
* Encoder: ``alpha_meas(t_k) = alpha(t_k - dt_sync) + sum a_h sin(h alpha + phi_h)``, rounded
  to the resolution.
"""
from __future__ import annotations

import math

import numpy as np

from hse_opt.frames import (dcm_to_zyx, earth_rate_n, rot_x, rot_y, rot_z, rotvec_to_dcm)
from hse_opt.sim._fastmath import MAX_DEVIATION, PhaseTable, apply3, rotate_small
from hse_opt.sim.rawlog import RawLog
from hse_opt.sim.truth import gyro_matrices, temperature, validate_run

__all__ = ["generate", "true_attitude", "table_angle", "stand_azimuth_true"]


def stand_azimuth_true(truth, reading):
    """True stand azimuth, rad, for a ``reading`` (rad): reading + offset + periodic error."""
    a = reading + truth.stand.azimuth_offset
    for h in truth.stand.azimuth_harmonics:
        a = a + h.value(reading)
    return a


def true_attitude(truth, run):
    """The true attitude of b0 for a run.

    Returns
    -------
    dict
        ``C_b0_n`` (3, 3); ``heading``, ``pitch``, ``roll`` (rad, exact Z-Y-X angles of
        C_b0^n); ``azimuth_true`` (rad, the stand's true azimuth).
    """
    gam = truth.stand.mount_tilt[0] + run.tilt[0]
    the = truth.stand.mount_tilt[1] + run.tilt[1]
    az = stand_azimuth_true(truth, run.azimuth)
    tau_n = np.array([truth.stand.tilt[0], truth.stand.tilt[1], 0.0])
    C = rotvec_to_dcm(tau_n) @ rot_z(az) @ rot_y(the) @ rot_x(gam)
    psi, theta, gamma = dcm_to_zyx(C)
    return {"C_b0_n": C, "heading": float(psi), "pitch": float(theta), "roll": float(gamma),
            "azimuth_true": float(az)}


def table_angle(table, rate, alpha0, tau):
    """True table angle, rad, at times ``tau`` (s since the run start, array_like).

    Parameters
    ----------
    table : TableConfig
    rate : float
        Commanded signed rate Omega, rad/s.
    alpha0 : float
        Angle at tau = 0, rad.
    """
    w = rate * (1.0 + table.rate_error)
    a = alpha0 + w * np.asarray(tau, dtype=float)
    if table.ripple:
        a = a + _ripple(table, rate, np.sin(_ripple_nu(table, rate) * np.asarray(tau) + table.ripple_phase))
    return a


def _ripple_nu(table, rate):
    return table.ripple_order * abs(rate * (1.0 + table.rate_error))


def _ripple(table, rate, sin_phase):
    """Ripple part of the table angle from ``sin(nu tau + phi)``, rad."""
    w = rate * (1.0 + table.rate_error)
    return (w * table.ripple / _ripple_nu(table, rate)) * (sin_phase - math.sin(table.ripple_phase))


def _angle_cos_sin(table, rate, alpha0, i0, m, dt, tabs):
    """alpha, cos(alpha), sin(alpha) at the boundaries ``tau_k = k dt``, ``k = i0 .. i0 + m``;
    ``tabs`` = (PhaseTable of W dt, PhaseTable of the ripple's nu dt or None)."""
    w = rate * (1.0 + table.rate_error)
    lin = alpha0 + w * dt * np.arange(i0, i0 + m + 1, dtype=float)
    c, s = tabs[0].cos_sin(alpha0 + w * dt * i0, m + 1)
    if not table.ripple:
        return lin, c, s
    if tabs[1] is None:                  # ripple too large for the series: plain numpy
        a = table_angle(table, rate, alpha0, dt * np.arange(i0, i0 + m + 1, dtype=float))
        return a, np.cos(a), np.sin(a)
    nu = _ripple_nu(table, rate)
    _, rs = tabs[1].cos_sin(nu * dt * i0 + table.ripple_phase, m + 1)
    d = _ripple(table, rate, rs)
    c, s = rotate_small(c, s, d)
    lin += d
    return lin, c, s


#: samples per generation chunk: the chunks keep the working arrays in cache; the random
#: stream is drawn chunk by chunk (gyro noise, then accelerometer noise), so a seeded run is
#: reproducible for this chunk size.
CHUNK = 16384


class _Counter:
    """A pulse counter: quantizes increments, carrying the fractional remainder.

    ``phase`` (m,) is the initial fractional count in [0, 1) (the counter's unknown phase at
    the start of the record)."""

    def __init__(self, quantum, phase):
        self.q = quantum
        self.rem = np.asarray(phase, dtype=float).copy()

    def __call__(self, incr):
        """Quantize increments (m, k) in place: floor of the running sum, differenced."""
        c = np.cumsum(incr, axis=1, out=incr)
        c /= self.q
        c += self.rem[:, None]
        last = c[:, -1].copy()
        np.floor(c, out=c)
        self.rem = last - c[:, -1]
        c[:, 1:] -= c[:, :-1].copy()
        c *= self.q
        return c


def generate(truth, run, rng=None):
    """Simulate the raw log of one alignment run.

    Parameters
    ----------
    truth : TruthConfig
    run : RunSpec
    rng : numpy.random.Generator or None
        Source of every random draw (noise, counter phases, start angle when
        ``run.alpha0`` is None). May be None only for a noise-free system with a given
        ``run.alpha0``; then the pulse-counter phases are 1/2.

    Returns
    -------
    RawLog
        ``n = round(duration / sample_period)`` samples; timestamps are time since power-on.
        (Arrays are built component-major, so ``log.gyro`` is an F-ordered (n, 3) view.)
    """
    validate_run(truth, run)
    need_rng = (not truth.is_noise_free) or run.alpha0 is None
    if rng is None and need_rng:
        raise ValueError("rng: a numpy.random.Generator is required for a system with noise or "
                         "quantization, or when run.alpha0 is None")
    dt = truth.timing.sample_period
    n = int(round(run.duration / dt))
    alpha0 = float(run.alpha0) if run.alpha0 is not None else float(rng.uniform(0.0, 2 * np.pi))
    mats = gyro_matrices(truth)
    att = true_attitude(truth, run)
    C_n_b0 = att["C_b0_n"].T
    w0 = C_n_b0 @ earth_rate_n(truth.site.latitude)
    f0 = C_n_b0 @ np.array([0.0, 0.0, -truth.site.gravity])
    g, a, enc = truth.gyro, truth.accel, truth.encoder
    mount, thermal = truth.mount, truth.thermal
    G = np.linalg.inv(mats["K_g"]) @ mats["C_b_s"]      # b -> gyro outputs: K_g^-1 C_b^s
    A = mats["A_acc"] @ mats["C_b_s"]                    # b -> accelerometer outputs
    sf = np.asarray(g.sf_error)[:, None]
    nl = np.asarray(g.sf_nonlinearity)[:, None] / dt
    scale = bool(np.any(sf) or np.any(nl))
    gbias = ((np.asarray(g.bias) + g.axis_bias * G[:, 2]) * dt)[:, None]
    abias = (np.asarray(a.bias) * dt)[:, None]
    bw = np.asarray(g.bias_warmup)[:, None]
    tc = np.asarray(g.bias_tempco)[:, None]
    thermal_xi = bool(mount.warmup_xi_z or mount.xi_z_tempco)
    need_temp = bool(mount.xi_z_tempco or np.any(tc))
    g_sigma = g.arw * math.sqrt(dt)
    a_sigma = a.vrw * math.sqrt(dt)
    gcount = acount = None
    if g.pulse:
        gcount = _Counter(g.pulse, rng.uniform(0.0, 1.0, 3) if rng is not None else np.full(3, 0.5))
    if a.pulse:
        acount = _Counter(a.pulse, rng.uniform(0.0, 1.0, 3) if rng is not None else np.full(3, 0.5))

    gyro = np.empty((3, n))
    accel = np.empty((3, n))
    encoder = np.empty(n)
    t_out = np.empty(n)
    # exp(-t_on / tau) on the chunk grid = exp(-t_on[0] / tau) * exp(-k dt / tau): one table
    # per time constant, scaled per chunk (exact to a few 1e-16)
    taus = {}
    if thermal_xi:
        taus["xi"] = mount.warmup_tau
    if bw.any():
        taus["bias"] = g.bias_warmup_tau
    if need_temp:
        taus["temp"] = thermal.tau
    ktab = dt * np.arange(min(n, CHUNK) + 1, dtype=float)
    tables = {name: np.exp(-ktab / tau) for name, tau in taus.items()}
    w_true = run.rate * (1.0 + truth.table.rate_error)
    ripple_ok = 2 * abs(truth.table.ripple / truth.table.ripple_order) <= MAX_DEVIATION
    ptabs = (PhaseTable(w_true * dt, min(n, CHUNK) + 1),
             PhaseTable(_ripple_nu(truth.table, run.rate) * dt, min(n, CHUNK) + 1)
             if truth.table.ripple and ripple_ok else None)
    for i0 in range(0, n, CHUNK):
        i1 = min(n, i0 + CHUNK)
        m = i1 - i0
        t_first = run.t_start + dt * i0
        t_on = t_first + ktab[:m + 1]                 # boundaries, time since power-on
        t_out[i0:i1] = t_on[1:]
        expo = {name: tab[:m + 1] * math.exp(-t_first / taus[name]) for name, tab in tables.items()}
        alpha, ca, sa = _angle_cos_sin(truth.table, run.rate, alpha0, i0, m, dt, ptabs)
        dalpha = np.diff(alpha)
        Ci = np.diff(sa)
        Ci *= dt
        Ci /= dalpha                                  # int cos(alpha) dt over each interval
        Si = np.diff(ca)
        Si *= -dt
        Si /= dalpha                                  # int sin(alpha) dt
        # increments in b, component-major (3, m): rot_z(-alpha) w^b0 + alpha_dot e_z
        dth_b = np.empty((3, m))
        dv_b = np.empty((3, m))
        for out, v, z in ((dth_b, w0, dalpha + w0[2] * dt), (dv_b, f0, f0[2] * dt)):
            np.multiply(Ci, v[0], out=out[0])
            out[0] += v[1] * Si
            np.multiply(Ci, v[1], out=out[1])
            out[1] -= v[0] * Si
            out[2] = z
        temp = None
        if need_temp:
            temp = thermal.ambient_c + thermal.rise_c * (1.0 - expo["temp"])
            if thermal.swing_c:
                temp += thermal.swing_c * np.sin(2 * np.pi * t_on / thermal.swing_period
                                                 + thermal.swing_phase)
        if thermal_xi:
            # thermal rotation xi_w of the IMU about z_b: C_b^s(t) = C_b^s rot_z(-xi_w); it
            # is checked below 1e-3 rad, where cos = 1 - xi^2/2 and sin = xi are exact to
            # < 1e-13 relative
            xi = mount.warmup_xi_z * expo["xi"]
            if mount.xi_z_tempco:
                xi += mount.xi_z_tempco * (temp - thermal.reference_c)
            if np.abs(xi).max() > 1e-3:
                raise ValueError("mount: the thermal mount rotation exceeds 1e-3 rad (206 arcsec); "
                                 "allowed |warmup_xi_z + tempco * dT| <= 206 arcsec")
            s = 0.5 * (xi[1:] + xi[:-1])
            c = 1.0 - 0.5 * s * s
            for arr in (dth_b, dv_b):
                x = arr[0].copy()
                arr[0] *= c
                arr[0] += s * arr[1]
                arr[1] *= c
                arr[1] -= s * x
            dth_b[2] += np.diff(xi)

        dth = apply3(G, dth_b, gyro[:, i0:i1])
        if scale:
            dth *= 1.0 + sf + nl * np.abs(dth)
        dth += gbias
        if bw.any():
            e = np.diff(expo["bias"])
            e *= -g.bias_warmup_tau
            dth += bw * e
        if tc.any():   # thermal terms vary over minutes: midpoint rule, error < 1e-12 relative
            tmid = 0.5 * (temp[1:] + temp[:-1])
            tmid -= thermal.reference_c
            tmid *= dt
            dth += tc * tmid
        if g_sigma:
            noise = rng.standard_normal((3, m), dtype=np.float32)
            noise *= g_sigma
            dth += noise
        if gcount is not None:
            gcount(dth)

        dv = apply3(A, dv_b, accel[:, i0:i1])
        dv += abias
        if a_sigma:
            noise = rng.standard_normal((3, m), dtype=np.float32)
            noise *= a_sigma
            dv += noise
        if acount is not None:
            acount(dv)

        if enc.sync_delay:
            am = table_angle(truth.table, run.rate, alpha0, dt * np.arange(i0 + 1, i1 + 1, dtype=float) - enc.sync_delay)
        else:
            am = alpha[1:]
        if enc.harmonics:
            err = np.zeros(m)
            for h in enc.harmonics:
                err += h.value(am)
            am = am + err
        if enc.resolution:
            am = am / enc.resolution
            np.round(am, out=am)
            am *= enc.resolution
        encoder[i0:i1] = am

    meta = {"latitude_deg": math.degrees(truth.site.latitude),
            "rate_dps": math.degrees(run.rate), "azimuth_deg": math.degrees(run.azimuth),
            "t_start_s": float(run.t_start), "source": "hse_opt.sim",
            "temp_c": float(np.mean(temperature(thermal, run.t_start + np.linspace(0, n * dt, 201))))}
    return RawLog._trusted(t_out, gyro.T, accel.T, encoder, meta)
