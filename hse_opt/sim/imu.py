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

import functools
import math
import types

import numpy as np

from hse_opt import units
from hse_opt.align.rotations import dcm_to_zyx, earth_rate_n, rot_x, rot_y, rot_z, rotvec_to_dcm
from hse_opt.sim._fastmath import (MAX_DEVIATION, PhaseTable, box_muller_f32, exp_linear,
                                   rotate_small, splits_words, uniform_bits)
from hse_opt.align.rawlog import RawLog
from hse_opt.sim.truth import RunSpec, gyro_matrices, per_configuration, temperature, validate_run

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
    C = rot_z(az) @ rot_y(the) @ rot_x(gam)
    if any(truth.stand.tilt):
        C = rotvec_to_dcm(np.array([truth.stand.tilt[0], truth.stand.tilt[1], 0.0])) @ C
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
#: stream is drawn chunk by chunk (table jitter, gyro noise, then accelerometer noise), so a
#: seeded run is reproducible for this chunk size.
CHUNK = 16384

#: the Box-Muller noise of :func:`~hse_opt.sim._fastmath.box_muller_f32` is bounded: its float32 uniforms keep
#: ``1 - u >= 2**-24``, so ``|n| <= sqrt(48 ln 2) sigma = 5.77 sigma``
_NOISE_BOUND = 5.8


class _Counter:
    """The pulse counters of stacked sensor triads (3 rows each, quantum ``q`` per triad, SI):
    the running sum of the increments is floored to whole pulses and differenced, so the
    remainder is carried from sample to sample and from chunk to chunk (initial remainder
    ``phase``, pulses).

    The running sum is kept in int64 fixed point, ``2**bits`` units per pulse: the increments
    arrive scaled by the triad's :attr:`units` entry (SI -> units; scaling by a power of two
    is exact in float) and offset by :data:`MAGIC` (which rounds them to whole units, less
    than ``2**-bits`` pulse per sample, and makes their bit patterns ``MAGIC`` bits + the
    integer), are summed exactly (numpy's integer cumulative sum is six times faster than the
    floating one) and floored by a shift. ``bits`` keeps a chunk's running sum below ``2**60``
    for increments up to ``xmax`` (SI, signal and noise): ``2**-bits`` is about ``2**-60`` of
    the chunk's largest count, finer than a float64 running sum resolves (``2**-52`` of the
    count).

    Parameters
    ----------
    triads : list of (name, q, phase, xmax, unit)
        Per triad: the TOML key for messages, the quantum (SI), the initial remainders (3,),
        the largest increment per sample (SI) and the unit of ``name`` (for messages).
    """

    #: 1.5 * 2**52: ``x + MAGIC`` holds ``round(x)`` in its low bits for ``|x| < 2**51``
    MAGIC = 1.5 * 2.0 ** 52

    def __init__(self, triads):
        bits = []
        for name, q, _, xmax, unit in triads:
            pulses = 1.0 + CHUNK * xmax / q              # largest running count of a chunk
            bits.append(60 - math.ceil(math.log2(pulses)))
            if bits[-1] < 16:
                raise ValueError(f"{name} = {q / unit:g} is too small for this run: more than 2**44 "
                                 f"pulses in {CHUNK} samples; allowed {name} >= "
                                 f"{CHUNK * xmax / 2.0 ** 43 / unit:.3g}")
        #: per triad: SI -> units of the running sum
        self.units = [2.0 ** b / t[1] for b, t in zip(bits, triads)]
        self.bits = np.repeat(np.array(bits, dtype=np.int64), 3)
        self.q = np.repeat([t[1] for t in triads], 3)[:, None]
        self.rem = np.concatenate([np.floor(np.asarray(t[2], dtype=float) * 2.0 ** b)
                                   for b, t in zip(bits, triads)]).astype(np.int64)

    def count(self, x, dest, scratch):
        """SI pulse increments into ``dest`` (k, m) from ``x`` (k, m): the increments in units
        plus :data:`MAGIC` (``x`` is overwritten); ``scratch``: int64, at least k * m."""
        k, m = x.shape
        s = scratch[:k * m].reshape(k, m)
        b = x.view(np.int64)                            # MAGIC's bits + the rounded increment
        b[:, 0] += self.rem
        np.cumsum(b, axis=1, out=s)
        s -= _MAGIC_SUMS[:m]
        last = s[:, -1].copy()
        np.right_shift(s, self.bits[:, None], out=s)  # floor to whole pulses
        self.rem = last - (s[:, -1] << self.bits)
        np.subtract(s[:, 1:], s[:, :-1], out=dest[:, 1:])
        dest[:, 0] = s[:, 0]
        dest *= self.q


#: ``(k + 1) * MAGIC``'s bits for k < CHUNK, modulo 2**64 like the integer sums that carry them
_MAGIC_SUMS = (np.arange(1, CHUNK + 1, dtype=np.uint64)
               * np.float64(_Counter.MAGIC).view(np.uint64)).view(np.int64)


class _Workspace:
    """One float64 block for all of a call's working arrays, handed out in slices (64-byte
    aligned). The block is at least 4 MB: numpy asks the kernel for transparent huge pages for
    such blocks, and glibc then keeps freed memory for the next call instead of returning it.
    A fresh 4-kB page costs 2-3 us at its first touch on this class of machine: with separate
    arrays, generate of 1-minute runs one after the other took 5.6-6.1 ms, with the block
    3.2-3.3 ms (``benchmarks/simulator.py``, its first line)."""

    #: numpy's threshold for huge pages, bytes
    HUGE = 1 << 22

    def __init__(self, n):
        self.block = np.empty(max(n + 8 * 16, self.HUGE // 8 + 1))
        self.used = 0

    def take(self, *shape, dtype=float):
        """A fresh (uninitialised) array of ``shape`` (float64 or another 8-byte dtype)."""
        k = math.prod(shape)
        a = self.block[self.used:self.used + k]
        self.used += -(-k // 8) * 8
        return a.view(dtype).reshape(shape)


def _readonly(*arrays):
    for a in arrays:
        a.setflags(write=False)
    return arrays


@functools.lru_cache(maxsize=8)
def _grid(dt, dphi, size):
    """The tables of a chunk of ``size`` sample boundaries, depending only on the sample
    period and the turn per sample (so shared by the runs of a campaign): cos and sin of
    ``k dphi`` (:class:`PhaseTable`), the times ``k dt`` and the linear turn ``k dphi``
    (read-only)."""
    tab = PhaseTable(dphi, size)
    tab.cs = np.stack([tab.c, tab.s])           # (2, size): cos and sin rows for one product
    tab.c, tab.s = _readonly(tab.cs[0], tab.cs[1])
    tab.cs.setflags(write=False)
    k = np.arange(size, dtype=float)
    return (tab,) + _readonly(dt * k, dphi * k)


@functools.lru_cache(maxsize=8)
def _exp_table(rate, size):
    """``exp(rate k)`` for ``k < size`` (:func:`exp_linear`), read-only and shared."""
    return _readonly(exp_linear(rate, size))[0]


@per_configuration(maxsize=8)
def _configuration(truth):
    """What :func:`generate` needs of the configuration alone (:class:`types.SimpleNamespace`,
    read-only arrays), computed once per frozen configuration: ``mats``
    (:func:`~hse_opt.sim.truth.gyro_matrices`), ``G = K_g^-1 C_b^s`` (b -> gyro outputs),
    ``A`` (b -> accelerometer outputs), the scale-factor columns ``sf``, ``nl`` and whether
    they act (``scale``), the gyro biases ``bias`` and tempcos ``tc``, the warm-up and
    temperature transients ``extra`` ((name, coefficient per sample at t_on = 0, tau)), the
    tempco's constant part per sample ``const_tc`` (or None), ``swing_row`` and the number of
    gyro basis rows ``kg``."""
    mats = gyro_matrices(truth)
    g, thermal, dt = truth.gyro, truth.thermal, truth.timing.sample_period
    tau_b, tau_t = g.bias_warmup_tau, thermal.tau
    sf = np.asarray(g.sf_error)[:, None]
    nl = np.asarray(g.sf_nonlinearity)[:, None]
    bw = np.asarray(g.bias_warmup)
    tc = np.asarray(g.bias_tempco)
    extra, const_tc = [], None                           # (name, coefficient at t_on = 0, tau)
    if bw.any():   # int b_w exp(-t / tau) over an interval: b_w tau (1 - exp(-dt / tau)) exp(-t_k / tau)
        extra.append(("bias", bw * tau_b * -math.expm1(-dt / tau_b), tau_b))
    if tc.any():   # tempco dt (temperature at the interval's midpoint - reference)
        const_tc = tc * dt * (thermal.ambient_c + thermal.rise_c - thermal.reference_c)
        extra.append(("temp", tc * dt * -thermal.rise_c * 0.5 * (1.0 + math.exp(-dt / tau_t)), tau_t))
    swing_row = bool(tc.any() and thermal.swing_c)
    cfg = types.SimpleNamespace(
        mats=mats, G=mats["K_g_inv"] @ mats["C_b_s"], A=mats["A_acc"] @ mats["C_b_s"], sf=sf, nl=nl,
        scale=bool(np.any(sf) or np.any(nl)), bias=np.asarray(g.bias, dtype=float), tc=tc, extra=extra,
        const_tc=const_tc, swing_row=swing_row, kg=4 + len(extra) + swing_row)
    _readonly(cfg.G, cfg.A, sf, nl, cfg.bias, tc, *(c for _, c, _ in extra),
              *(() if const_tc is None else (const_tc,)))
    return cfg


@per_configuration(maxsize=64)
def _base_vectors(truth, azimuth, tilt):
    """The Earth rate and the specific force in b0 (rad/s, m/s^2; read-only) for a stand
    azimuth reading and a deliberate tilt (rad), cached: a campaign repeats its few stand
    settings."""
    C_n_b0 = true_attitude(truth, RunSpec(rate=1.0, azimuth=azimuth, tilt=tilt))["C_b0_n"].T
    return _readonly(C_n_b0 @ earth_rate_n(truth.site.latitude),
                     C_n_b0 @ np.array([0.0, 0.0, -truth.site.gravity]))


def _horizontal_columns(M, v0):
    """Columns of the outputs ``M @ v_b`` on ``(int cos beta dt, int sin beta dt)`` for the
    b0 vector ``v0``: ``v_b = rot_z(-beta) v0``, so ``x = cos v0x + sin v0y``,
    ``y = cos v0y - sin v0x``."""
    return np.column_stack([M[:, 0] * v0[0] + M[:, 1] * v0[1], M[:, 0] * v0[1] - M[:, 1] * v0[0]])


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
    (table jitter, gyro noise, then accelerometer noise).

    Each sensor row is a matrix product ``C @ V`` of a few coefficients and the basis rows
    ``V`` of a chunk: ``int cos beta' dt``, ``-int sin beta' dt`` (``beta'`` the IMU's turn
    since the chunk's start phase ``Phi``: the rotation by ``Phi`` is folded into ``C``), a row
    of ones (constant biases, the Earth rate's vertical part, the temperature's constant
    part), the turn increment ``d beta`` and the exponentials of the warm-up transients on the
    sample grid (``exp(-t / tau)`` is a fixed table times a per-chunk factor in ``C``). Only
    the first, second and fourth rows are computed per chunk. The table angle's deviation
    from the line ``Phi + k W dt`` (ripple, jitter, thermal mount rotation, < 1e-3 rad) enters
    ``cos``/``sin`` by its Taylor series (``hse_opt.sim._fastmath``).

    Precision: the white noise is drawn in float32 (:func:`~hse_opt.sim._fastmath.box_muller_f32`:
    its rounding, 6e-8 of a sample's noise, is white and far below the quantum it dithers),
    the signal rows and coefficients are float64 (a gyro increment carries the Earth rate's
    1e-7 rad beside the table's 1e-3 rad turn per sample), and the counters' running sums are
    exact int64 fixed point (:class:`_Counter`).
    """
    cfg = _configuration(truth)
    validate_run(truth, run, cfg.mats)
    need_rng = (not truth.is_noise_free) or run.alpha0 is None
    if rng is None and need_rng:
        raise ValueError("rng: a numpy.random.Generator is required for a system with noise or "
                         "quantization, or when run.alpha0 is None")
    dt = truth.timing.sample_period
    n = int(round(run.duration / dt))
    alpha0 = float(run.alpha0) if run.alpha0 is not None else float(rng.uniform(0.0, 2 * np.pi))
    w0, f0 = _base_vectors(truth, float(run.azimuth), tuple(float(v) for v in run.tilt))
    g, a, enc = truth.gyro, truth.accel, truth.encoder
    mount, thermal, tb = truth.mount, truth.thermal, truth.table
    G, A, sf, nl, scale, tc = cfg.G, cfg.A, cfg.sf, cfg.nl, cfg.scale, cfg.tc
    extra, swing_row, kg = cfg.extra, cfg.swing_row, cfg.kg
    thermal_xi = bool(mount.warmup_xi_z or mount.xi_z_tempco)
    W = run.rate * (1.0 + tb.rate_error)                # true mean table rate
    wdt = W * dt
    # the counters' random initial phases (pulses), then the table's first jitter sample
    gphase = (rng.uniform(0.0, 1.0, 3) if rng is not None else np.full(3, 0.5)) if g.pulse else None
    aphase = (rng.uniform(0.0, 1.0, 3) if rng is not None else np.full(3, 0.5)) if a.pulse else None
    split = rng is not None and splits_words(rng)       # uniforms from whole 64-bit words
    jit_last = 0.0                                      # (drawn with the first chunk's jitter)

    # the table angle at the sample boundaries: Phi + k W dt + d_k with the deviation d_k of the
    # ripple (its constant part folded into Phi), the jitter and the thermal mount rotation
    # xi_w of the IMU about z_b (C_b^s(t) = C_b^s rot_z(-xi_w)), which adds to the angle the
    # IMU turns by and its rate to the z increment. Over each interval the angle is taken
    # linear (the ripple bends it by alpha_ddot dt^2 / 8 ~ 1e-10 rad, xi_w changes by < 1e-9
    # rad per sample), so int cos(beta) dt = (sin beta_k - sin beta_{k-1}) dt / d beta.
    nu = _ripple_nu(tb, run.rate) if tb.ripple else 0.0
    amp = W * tb.ripple / nu if tb.ripple else 0.0      # ripple amplitude, rad
    tau_xi, tau_t = mount.warmup_tau, thermal.tau
    dtemp = abs(thermal.ambient_c - thermal.reference_c) + abs(thermal.rise_c) + thermal.swing_c
    xi_bound = (abs(mount.warmup_xi_z) * math.exp(-run.t_start / tau_xi) + abs(mount.xi_z_tempco) * dtemp
                if thermal_xi else 0.0)
    d_bound = abs(amp) + _NOISE_BOUND * tb.jitter + min(xi_bound, 1e-3)

    # coefficients (SI per sample) of the basis rows: int cos, -int sin, ones, d beta, the
    # warm-up and temperature exponentials, the temperature swing
    hg = _horizontal_columns(G, w0)
    const_g = (cfg.bias + g.axis_bias * G[:, 2] + G[:, 2] * w0[2]) * dt
    if cfg.const_tc is not None:
        const_g = const_g + cfg.const_tc
    # the coefficients of the six outputs: rows 0-2 the gyros (every basis row), rows 3-5 the
    # accelerometers (int cos, -int sin, ones)
    C = np.zeros((6, kg))
    C[:3, 2] = const_g
    C[:3, 3] = G[:, 2]
    if swing_row:
        C[:3, -1] = tc * dt * thermal.swing_c
    ha = _horizontal_columns(A, f0)
    C[3:, 2] = (np.asarray(a.bias) + A[:, 2] * f0[2]) * dt

    # bounds of the increments per sample (SI) for the counters' fixed point
    xmax_g = ((np.abs(hg).sum(axis=1) * dt + np.abs(G[:, 2]) * (abs(wdt) + 2.0 * d_bound)
               + np.abs(const_g) + sum(np.abs(c) * math.exp(-run.t_start / t) for _, c, t in extra)
               + np.abs(tc) * dt * dtemp).max())
    if scale:
        xmax_g *= 1.0 + float(np.abs(sf).max()) + float(np.abs(nl).max()) * xmax_g / dt
    xmax_g += _NOISE_BOUND * g.arw * math.sqrt(dt)
    xmax_a = ((np.abs(ha).sum(axis=1) * dt + np.abs(C[3:, 2])).max()
              + _NOISE_BOUND * a.vrw * math.sqrt(dt))
    # one counter for the triads with a quantum: rows `counted` of the six outputs
    triads = ([("gyro.pulse_arcsec", g.pulse, gphase, xmax_g, units.ARCSEC)] if g.pulse else []) + \
             ([("accel.pulse_mps", a.pulse, aphase, xmax_a, 1.0)] if a.pulse else [])
    counter = _Counter(triads) if triads else None
    counted = slice(0 if g.pulse else 3, 6 if a.pulse else 3)
    gunit = counter.units[0] if (g.pulse and not scale) else 1.0
    aunit = counter.units[-1] if a.pulse else 1.0
    C[:3, 2:] *= gunit
    C[3:, 2] *= aunit
    if g.pulse and not scale:
        C[:3, 2] += _Counter.MAGIC                      # the ones row: round for the counter
    if a.pulse:
        C[3:, 2] += _Counter.MAGIC
    H = np.vstack([hg * gunit, ha * aunit])            # per chunk: turned by Phi
    extra_u = np.column_stack([c * gunit for _, c, _ in extra]) if extra else None
    # the white noises drawn per chunk after the table's jitter: gyros then accelerometers
    sigmas = [(rows3, sig) for rows3, sig in ((slice(0, 3), g.arw * math.sqrt(dt) * gunit),
                                              (slice(3, 6), a.vrw * math.sqrt(dt) * aunit)) if sig]
    noise_rows = slice(sigmas[0][0].start, sigmas[-1][0].stop) if sigmas else None

    imu = np.empty((6, n))                              # gyros then accelerometers
    encoder = np.empty(n)
    t_out = np.empty(n)
    size = min(n, CHUNK) + 1
    ptab, ktab, lin = _grid(dt, wdt, size)
    rtab, rsign = None, 1.0
    if tb.ripple:                 # once per revolution the ripple's phase steps with the table's
        rtab, rsign = (ptab, math.copysign(1.0, W)) if tb.ripple_order == 1 else (_grid(dt, nu * dt, size)[0], 1.0)
    # basis rows: int cos, -int sin, ones, d beta, exponentials, swing; (k, m) views of vbuf
    ws = _Workspace((kg + 6 + 6) * size + 7 * size)
    vbuf = ws.take(kg, size - 1)
    vbuf[2] = 1.0
    for j, (_, _, tau) in enumerate(extra):
        vbuf[4 + j] = _exp_table(-dt / tau, size)[:size - 1]
    xtab = _exp_table(-dt / tau_xi, size) if thermal_xi else None
    ttab = _exp_table(-dt / tau_t, size) if mount.xi_z_tempco else None
    dbuf, xbuf, cs, work = ws.take(size), ws.take(size), ws.take(2, size), ws.take(3, size)
    obuf = ws.take(6 * (size - 1))
    ibuf = ws.take(counter.bits.size * (size - 1), dtype=np.int64) if counter is not None else None
    ripple_const = -amp * math.sin(tb.ripple_phase) if tb.ripple else 0.0
    for i0 in range(0, n, CHUNK):
        i1 = min(n, i0 + CHUNK)
        m = i1 - i0
        t_first = run.t_start + dt * i0
        np.add(ktab[1:m + 1], t_first, out=t_out[i0:i1])
        phi = alpha0 + wdt * i0 + ripple_const          # Phi: the chunk's start on the line
        # the chunk's random numbers in the stream's order: the table's jitter, then the gyros'
        # and the accelerometers' white noise (one draw of uniforms, see box_muller_f32); the
        # first chunk's draw starts with the pair of the jitter at the run's start
        jit = noise = None
        if tb.jitter or sigmas:
            hj, h3 = ((m + 1) // 2 if tb.jitter else 0), (3 * m + 1) // 2
            lead = 2 if (tb.jitter and i0 == 0) else 0
            u = uniform_bits(rng, lead + 2 * hj + 2 * h3 * len(sigmas), split)
            if lead:            # that pair and the chunk's own, transformed together
                z = box_muller_f32(np.concatenate((u[:1], u[2:2 + hj], u[1:2], u[2 + hj:2 + 2 * hj]))[None],
                                   (tb.jitter,))[0]
                jit_last, jit = float(z[0]), np.concatenate((z[1:hj + 1], z[hj + 2:]))[:m]
            elif tb.jitter:
                jit = box_muller_f32(u[None, :2 * hj], (tb.jitter,))[0, :m]
            if sigmas:
                noise = box_muller_f32(u[lead + 2 * hj:].reshape(len(sigmas), 2 * h3), [sig for _, sig in sigmas])
                noise = noise[:, :3 * m].reshape(3 * len(sigmas), m)
        d = None
        if tb.ripple:
            p0 = nu * dt * i0 + tb.ripple_phase
            d = np.dot((amp * math.sin(p0), amp * rsign * math.cos(p0)), rtab.cs[:, :m + 1], out=dbuf[:m + 1])
        if tb.jitter:
            if d is None:
                d = dbuf[:m + 1]
                d[0] = jit_last
                d[1:] = jit
            else:
                d[0] += jit_last
                d[1:] += jit
            jit_last = float(jit[-1])

        # encoder: alpha_meas(t_k) = alpha(t_k - dt_sync) + sum a_h sin(h alpha + phi_h), rounded
        am = encoder[i0:i1]
        if enc.sync_delay:      # (the jitter of the sample, white: it changes little in dt_sync)
            am[:] = table_angle(tb, run.rate, alpha0,
                                dt * np.arange(i0 + 1, i1 + 1, dtype=float) - enc.sync_delay)
            if jit is not None:
                am += jit
        else:
            np.add(lin[1:m + 1], phi, out=am)
            if d is not None:
                am += d[1:]
        if enc.harmonics:
            err = np.zeros(m)
            for h in enc.harmonics:
                err += h.value(am)
            am += err
        if enc.resolution:
            am *= 1.0 / enc.resolution
            np.rint(am, out=am)
            am *= enc.resolution

        d_max = d_bound
        if thermal_xi:
            xi = np.multiply(xtab[:m + 1], mount.warmup_xi_z * math.exp(-t_first / tau_xi), out=xbuf[:m + 1])
            if mount.xi_z_tempco:
                temp = thermal.ambient_c + thermal.rise_c * (1.0 - math.exp(-t_first / tau_t) * ttab[:m + 1])
                if thermal.swing_c:
                    temp += thermal.swing_c * np.sin(2 * np.pi * (t_first + ktab[:m + 1]) / thermal.swing_period
                                                     + thermal.swing_phase)
                xi += mount.xi_z_tempco * (temp - thermal.reference_c)
            if xi_bound > 1e-3 and np.abs(xi).max() > 1e-3:
                raise ValueError("mount: the thermal mount rotation exceeds 1e-3 rad (206 arcsec); "
                                 "allowed |warmup_xi_z + tempco * dT| <= 206 arcsec")
            d = xi if d is None else np.add(d, xi, out=d)
        V = vbuf[:, :m]
        if d is None:                                   # a constant-rate turn
            c, s = ptab.c[:m + 1], ptab.s[:m + 1]
            V[3] = wdt
            r = dt / wdt
        else:
            if d_max > MAX_DEVIATION:
                d_max = max(float(d.max()), -float(d.min()))
            if d_max <= MAX_DEVIATION:
                c, s = rotate_small(ptab.c[:m + 1], ptab.s[:m + 1], d, cs[:, :m + 1], work[:, :m + 1], d_max)
            else:
                c, s = np.add(lin[:m + 1], d, out=cs[1, :m + 1]), cs[:, :m + 1]
                c, s = np.cos(c, out=cs[0, :m + 1]), np.sin(c, out=cs[1, :m + 1])
            np.subtract(d[1:], d[:-1], out=V[3])
            V[3] += wdt                                 # the turn over each interval
            r = np.divide(dt, V[3], out=work[0, :m])
        np.subtract(s[1:], s[:-1], out=V[0])
        V[0] *= r                                       # int cos(beta') dt over each interval
        np.subtract(c[1:], c[:-1], out=V[1])
        V[1] *= r                                       # -int sin(beta') dt
        if swing_row:           # thermal terms vary over minutes: midpoint rule, error < 1e-12 relative
            sw = np.sin(2 * np.pi * (t_first + ktab[:m + 1]) / thermal.swing_period + thermal.swing_phase)
            np.add(sw[1:], sw[:-1], out=V[-1])
            V[-1] *= 0.5

        # the turn by Phi in the horizontal coefficients; the transients' factors at t_first
        cph, sph = math.cos(phi), math.sin(phi)
        turn = np.array([[cph, sph], [sph, -cph]])
        C[:, :2] = H @ turn
        if extra:
            C[:3, 4:4 + len(extra)] = extra_u * [math.exp(-t_first / tau) for _, _, tau in extra]

        out = obuf[:6 * m].reshape(6, m)
        np.matmul(C, V, out=out)
        if scale:
            out[:3] *= 1.0 + sf + nl * (np.abs(out[:3]) / dt)
        if noise is not None:
            out[noise_rows] += noise
        if scale and g.pulse:
            out[:3] *= counter.units[0]
            out[:3] += _Counter.MAGIC
        if counter is not None:
            counter.count(out[counted], imu[counted, i0:i1], ibuf)
        if counted != slice(0, 6):
            keep = slice(3, 6) if g.pulse else slice(0, 3) if a.pulse else slice(0, 6)
            imu[keep, i0:i1] = out[keep]

    meta = {"latitude_deg": math.degrees(truth.site.latitude),
            "rate_dps": math.degrees(run.rate), "azimuth_deg": math.degrees(run.azimuth),
            "t_start_s": float(run.t_start), "source": "hse_opt.sim",
            "temp_c": float(np.mean(temperature(thermal, run.t_start + np.linspace(0, n * dt, 201))))}
    return RawLog._trusted(t_out, imu[:3].T, imu[3:].T, encoder, meta)
