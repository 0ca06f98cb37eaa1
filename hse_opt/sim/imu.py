"""Raw 500 Hz data of the constant-rate biased RLG system on a static base (vectorised).

Physics (``docs/conventions.md``; frames n NED, b0 turntable base, b table top, s IMU, g gyro axes):

* Attitude of b0: ``C_b0^n = Rot(tau_n) rot_z(A) rot_y(theta) rot_x(gamma)``: the stand axis
  tilted by ``tau_n = (tau_N, tau_E, 0)`` (fixed in n), the true stand azimuth ``A`` (reading
  plus its offset and periodic error), the base tilt ``(gamma, theta)`` = stand mount tilt +
  the run's deliberate tilt (fixed in b0).
* Table angle ``alpha(t) = alpha0 + W t + W r / (h |W|) (sin(h |W| t + phi) - sin(phi))
  + j(t)`` with ``W = Omega (1 + rate_error)`` (ripple ``r`` at ``h`` cycles per revolution)
  and the servo jitter ``j``, white at the samples and linear between them;
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

from hse_opt.sim.rotations import dcm_to_zyx, earth_rate_n, rot_x, rot_y, rot_z, rotvec_to_dcm
from hse_opt.sim._fastmath import MAX_DEVIATION, PhaseTable, exp_linear, normal_f32, rotate_small
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


#: samples per generation chunk: the chunks keep the working arrays in cache; the random
#: stream is drawn chunk by chunk (gyro noise, then accelerometer noise), so a seeded run is
#: reproducible for this chunk size.
CHUNK = 16384


class _Sensor:
    """One sensor triad of the generator: outputs ``M @ v_b`` plus per-row terms, white noise
    and a pulse counter per row.

    Work is done in counts when the quantum ``q`` is set: everything is pre-scaled by 1/q,
    the running sum is floored and differenced (remainder carried from chunk to chunk), and
    the pulses are scaled back by q.
    """

    def __init__(self, M, v0, bias_dt, sigma, q, phase, extra=(), z=None):
        self.k = 1.0 / q if q else 1.0
        self.q = q
        M = np.asarray(M, dtype=float)
        bias = np.asarray(bias_dt, dtype=float)
        # outputs = M @ (x, y, z) with x = Ci v0x + Si v0y, y = Ci v0y - Si v0x: one column
        # per basis row (Ci, Si, z, *extra); ``extra`` are the coefficient vectors of further
        # basis rows (time-varying biases). A constant z increment ``z`` goes into the bias.
        cols = [M[:, 0] * v0[0] + M[:, 1] * v0[1], M[:, 0] * v0[1] - M[:, 1] * v0[0]]
        if z is None:
            cols += [M[:, 2], *extra]
        else:
            bias = bias + M[:, 2] * z
        self.B = np.column_stack(cols) * self.k
        self.bias = (bias * self.k)[:, None]
        self.sigma = sigma * self.k
        self.rem = None if not q else np.asarray(phase, dtype=float).copy()

    def rows(self, V, out):
        """Signal rows ``B @ V + bias`` into ``out`` (3, m), in counts when quantized; ``V``
        (k, m) holds the basis rows (the first columns of B are used)."""
        # a (3 x k) by (k x m) product, k <= 5, m <= CHUNK: BLAS stays on one thread below
        # its threading threshold (m n k < 262144 in OpenBLAS)
        np.dot(self.B, V[:self.B.shape[1]], out=out)
        out += self.bias
        return out

    def finish(self, out, rng, dest):
        """Noise, quantization; SI increments into ``dest`` (3, m)."""
        if self.sigma:
            out += normal_f32(rng, out.shape, self.sigma)
        if self.rem is None:
            dest[...] = out
            return
        out[:, 0] += self.rem
        np.cumsum(out, axis=1, out=out)
        last = out[:, -1].copy()
        np.floor(out, out=out)
        self.rem = last - out[:, -1]
        np.subtract(out[:, 1:], out[:, :-1], out=dest[:, 1:])
        dest[:, 0] = out[:, 0]
        dest *= self.q


def generate(truth, run, rng=None):
    """Simulate the raw log of one alignment run.

    Parameters
    ----------
    truth : TruthConfig
    run : RunSpec
    rng : numpy.random.Generator or None
        Source of every random draw (noise, counter phases, start angle when
        ``run.alpha0`` is None). May be None only for a noise-free system (no noise, no
        quantization) with a given ``run.alpha0``.

    Returns
    -------
    RawLog
        ``n = round(duration / sample_period)`` samples; timestamps are time since power-on.
        (Arrays are built component-major, so ``log.gyro`` is an F-ordered (n, 3) view.)

    Notes
    -----
    Generated in chunks of :data:`CHUNK` samples; the random stream is drawn chunk by chunk
    (gyro noise, then accelerometer noise).
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
    nl = np.asarray(g.sf_nonlinearity)[:, None]
    scale = bool(np.any(sf) or np.any(nl))
    bw = np.asarray(g.bias_warmup)
    tc = np.asarray(g.bias_tempco)
    thermal_xi = bool(mount.warmup_xi_z or mount.xi_z_tempco)
    need_temp = bool(mount.xi_z_tempco or tc.any())
    gq = 0.0 if scale else g.pulse      # with a scale-factor error, quantize after scaling
    # time-varying gyro biases as extra basis rows: the warm-up transient's integral over
    # each interval, -tau d(exp(-t_on / tau)), and the temperature term dt (temp_mid - ref)
    extra = ([bw * -g.bias_warmup_tau] if bw.any() else []) + ([tc * dt] if tc.any() else [])
    gyro_s = _Sensor(G, w0, (np.asarray(g.bias) + g.axis_bias * G[:, 2]) * dt,
                     g.arw * math.sqrt(dt), gq,
                     rng.uniform(0.0, 1.0, 3) if (gq and rng is not None) else np.full(3, 0.5), extra)
    gcount = None
    if scale and g.pulse:
        gcount = _Sensor(np.eye(3), np.zeros(3), np.zeros(3), 0.0, g.pulse,
                         rng.uniform(0.0, 1.0, 3) if rng is not None else np.full(3, 0.5))
    acc_s = _Sensor(A, f0, np.asarray(a.bias) * dt, a.vrw * math.sqrt(dt), a.pulse,
                    rng.uniform(0.0, 1.0, 3) if (a.pulse and rng is not None) else np.full(3, 0.5),
                    z=f0[2] * dt)

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
    tables = {name: exp_linear(-dt / tau, ktab.size) for name, tau in taus.items()}
    tb = truth.table
    W = run.rate * (1.0 + tb.rate_error)             # true mean table rate
    nu = _ripple_nu(tb, run.rate) if tb.ripple else 0.0
    size = min(n, CHUNK) + 1
    ptab = PhaseTable(W * dt, size)
    rtab = PhaseTable(nu * dt, size) if tb.ripple else None
    kidx = np.arange(size, dtype=float)
    jit_last = float(normal_f32(rng, (1,), tb.jitter)[0]) if tb.jitter else 0.0
    buf = np.empty(3 * (size - 1))                    # signal rows, (3, m) views of it
    vbuf = np.empty((3 + len(extra)) * (size - 1))    # basis rows, (k, m) views of it
    for i0 in range(0, n, CHUNK):
        i1 = min(n, i0 + CHUNK)
        m = i1 - i0
        t_first = run.t_start + dt * i0
        t_on = t_first + ktab[:m + 1]                 # boundaries, time since power-on
        t_out[i0:i1] = t_on[1:]
        expo = {name: tab[:m + 1] * math.exp(-t_first / taus[name]) for name, tab in tables.items()}
        # table angle at the boundaries: alpha = phi0 + W dt k + d_alpha (ripple, jitter)
        phi0 = alpha0 + W * dt * i0
        d_alpha = None
        if tb.ripple:
            d_alpha = _ripple(tb, run.rate, rtab.sin(nu * dt * i0 + tb.ripple_phase, m + 1))
        if tb.jitter:
            jit = np.empty(m + 1)
            jit[0] = jit_last                         # the boundary shared with the last chunk
            jit[1:] = normal_f32(rng, (m,), tb.jitter)
            jit_last = jit[-1]
            d_alpha = jit if d_alpha is None else d_alpha + jit
        temp = None
        if need_temp:
            temp = thermal.ambient_c + thermal.rise_c * (1.0 - expo["temp"])
            if thermal.swing_c:
                temp += thermal.swing_c * np.sin(2 * np.pi * t_on / thermal.swing_period
                                                 + thermal.swing_phase)
        # The IMU's horizontal axes turn with beta = alpha + xi_w: the thermal rotation xi_w of
        # the IMU about z_b (C_b^s(t) = C_b^s rot_z(-xi_w)) adds to the table angle, and its
        # rate to the z increment. Over each interval beta is taken linear (xi_w changes by
        # < 1e-9 rad per sample), so int cos(beta) dt = (sin beta_k - sin beta_{k-1}) dt / d beta.
        d_beta = d_alpha
        if thermal_xi:
            xi = mount.warmup_xi_z * expo["xi"]
            if mount.xi_z_tempco:
                xi += mount.xi_z_tempco * (temp - thermal.reference_c)
            if np.abs(xi).max() > 1e-3:
                raise ValueError("mount: the thermal mount rotation exceeds 1e-3 rad (206 arcsec); "
                                 "allowed |warmup_xi_z + tempco * dT| <= 206 arcsec")
            d_beta = xi if d_beta is None else d_beta + xi
        ca, sa = ptab.cos_sin(phi0, m + 1)
        if d_beta is None:
            dbeta = W * dt                            # scalar: a constant-rate turn
        else:
            if np.abs(d_beta).max() <= MAX_DEVIATION:
                ca, sa = rotate_small(ca, sa, d_beta)
            else:
                beta = W * dt * kidx[:m + 1]
                beta += phi0
                beta += d_beta
                ca, sa = np.cos(beta), np.sin(beta)
            dbeta = np.diff(d_beta)
            dbeta += W * dt
        r = dt / dbeta
        V = vbuf[:(3 + len(extra)) * m].reshape(-1, m)   # basis rows of this chunk
        np.subtract(sa[1:], sa[:-1], out=V[0])
        V[0] *= r                                     # int cos(beta) dt over each interval
        np.subtract(ca[1:], ca[:-1], out=V[1])
        V[1] *= -r                                    # int sin(beta) dt
        np.add(dbeta, w0[2] * dt, out=V[2])           # z increment: turn + Earth rate
        row = 3
        if bw.any():
            np.subtract(expo["bias"][1:], expo["bias"][:-1], out=V[row])
            row += 1
        if tc.any():   # thermal terms vary over minutes: midpoint rule, error < 1e-12 relative
            np.add(temp[1:], temp[:-1], out=V[row])
            V[row] *= 0.5
            V[row] -= thermal.reference_c

        out = buf[:3 * m].reshape(3, m)
        gyro_s.rows(V, out)
        if scale:
            out *= 1.0 + sf + nl * (np.abs(out) / dt)
        if gcount is None:
            gyro_s.finish(out, rng, gyro[:, i0:i1])
        else:
            gyro_s.finish(out, rng, out)                  # noise, SI
            out *= gcount.k                               # to counts, then quantize
            gcount.finish(out, rng, gyro[:, i0:i1])

        acc_s.rows(V, out)
        acc_s.finish(out, rng, accel[:, i0:i1])

        am = encoder[i0:i1]
        if enc.sync_delay:      # (the jitter of the sample, white: it changes little in dt_sync)
            am[:] = table_angle(tb, run.rate, alpha0,
                                dt * np.arange(i0 + 1, i1 + 1, dtype=float) - enc.sync_delay)
            if tb.jitter:
                am += jit[1:]
        else:
            np.multiply(kidx[1:m + 1], W * dt, out=am)
            am += phi0
            if d_alpha is not None:
                am += d_alpha[1:]
        if enc.harmonics:
            err = np.zeros(m)
            for h in enc.harmonics:
                err += h.value(am)
            am += err
        if enc.resolution:
            am /= enc.resolution
            np.round(am, out=am)
            am *= enc.resolution

    meta = {"latitude_deg": math.degrees(truth.site.latitude),
            "rate_dps": math.degrees(run.rate), "azimuth_deg": math.degrees(run.azimuth),
            "t_start_s": float(run.t_start), "source": "hse_opt.sim",
            "temp_c": float(np.mean(temperature(thermal, run.t_start + np.linspace(0, n * dt, 201))))}
    return RawLog._trusted(t_out, gyro.T, accel.T, encoder, meta)
