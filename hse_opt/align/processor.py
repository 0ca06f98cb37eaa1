"""The alignment processor: raw log (simulated or real) -> heading, pitch, roll of b0.

Steps
-----
1. Calibration. Gyro increments are mapped to b with the lab-calibrated parameters,
   ``dtheta_b = C~_s^b K~_g dtheta_g``; accelerometer increments with ``C~_s^b A~_a``.
2. Projection into b0. Each interval ``(t_{k-1}, t_k]`` is turned into b0 with the encoder
   angle at its midpoint, ``alpha_mid = (alpha_{k-1} + alpha_k) / 2``, the table turn
   ``alpha_k - alpha_{k-1}`` is removed from the z increment, and the horizontal parts are
   divided by ``sinc(d alpha / 2)`` (the exact average of a rotating vector over the
   interval). On a static base b0 is fixed in n, so the projected record is that of a
   quasi-static IMU in which every b-frame constant error rotates at the table rate.
   The projection is linear, so it is done on block sums: per block, the sums of
   ``cos(alpha_mid) x``, ``sin(alpha_mid) x`` and ``x`` of the raw increments ``x`` (one
   batched matrix product), then the calibration and the turn.
3. Blocks. The projected increments are summed over blocks of ``L`` samples chosen so that a
   whole number ``m`` of blocks makes one revolution (``m`` = revolution time x
   ``filter_rate``, rounded, at least 3); the filter runs once per block.
4. Coarse alignment (TRIAD): the down axis from the mean specific force, east from
   ``down x`` mean rate. The means are fitted together with the table-fixed parts (a vector
   fixed in b turns with the table in b0: biases, the table rate leaking through a
   misaligned axis, up to several times the Earth rate), so they are free of them even
   though ``m L`` samples match a revolution only to within a few samples.
5. Fine alignment: a linear Kalman filter on the error of a navigation solution that is
   integrated open loop from the coarse attitude ``C0`` (horizontal attitude from the
   measured rates, velocity from the specific force, no Coriolis term in the navigation or
   in its error model, so both match). b0 is static, so the heading of the navigation
   solution is held (the vertical b0 rate carries no heading information on a static base;
   it reaches heading only through the tilt, which the filter sees in the east rate).
   Process noise: the gyros' angle random walk and the pulse quantization noise
   (:func:`quantization_arw`) on the horizontal attitude, the accelerometers' white noise
   on the velocity (a figure per sensor enters by its share of the horizontal plane:
   :func:`horizontal_rms`).
   States (9): attitude error phi = (N, E, D) of the navigation solution, horizontal
   velocity error, the horizontal gyro and accelerometer biases of the table top seen in b0
   (they rotate at the table rate: ``d/dt x = Omega [[0, -1], [1, 0]] x``). The model is
   time invariant, so the transition and process noise matrices are computed once (Van Loan).
   Measurement: zero velocity (the navigation velocity) after each block, noise variance
   ``accel_pulse^2 / 12 + velocity_floor^2`` per axis (the velocity pulse remainder). The
   covariance update is Joseph's form ``(I - K H) P (I - K H)^T + K R K^T``: the velocity
   variance falls by orders of magnitude in every update, and the short form
   ``P - K H P`` loses those digits to cancellation.
6. Whole-revolution smoothing: the reported angles are the mean of the block estimates over
   the last ``smoothing_revolutions`` revolutions, with the filter's 1-sigma averaged over
   the same blocks.

The static-base gyrocompass limit of this filter is Eq. 12: a constant east error ``dw_E``
of the revolution-averaged rate gives ``heading estimated - true = -dw_E / (w_ie cos L)``.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from hse_opt import units
from hse_opt.align.rotations import R_ZB_S_IDEAL, c_b_s, dcm_to_zyx, earth_rate_n
from hse_opt.align._angles import MAX_DEVIATION, SMALL_DEVIATION, rotate
from hse_opt.align._blas import one_thread
from hse_opt.align.rawlog import RawLog

__all__ = ["AlignConfig", "AlignResult", "AlignHistory", "align", "triad", "quantization_arw", "horizontal_rms",
           "latitude_of"]

_CHUNK_TARGET = 32768
#: a log's latitude_deg and the processor's may differ by this much, deg (0.1 m on the ground;
#: more is two different sites)
LATITUDE_TOL_DEG = 1e-6

#: the rows of ``[e_i x] C0`` (i = 0, 1, 2; 9 each) as entries of ``C0.ravel()`` with signs
_E_INDEX = np.array([0, 0, 0, 6, 7, 8, 3, 4, 5, 6, 7, 8, 0, 0, 0, 0, 1, 2, 3, 4, 5, 0, 1, 2, 0, 0, 0])
_E_SIGN = np.array([0, 0, 0, -1, -1, -1, 1, 1, 1, 1, 1, 1, 0, 0, 0, -1, -1, -1, -1, -1, -1, 1, 1, 1,
                    0, 0, 0], dtype=float)
_E_INDEX.flags.writeable = _E_SIGN.flags.writeable = False

#: ``np.dot`` without its ``__array_function__`` dispatch (a third of its cost on 9x9
#: matrices; the filter makes a few thousand such products per log)
_DOT = getattr(np.dot, "_implementation", np.dot)


def _mat(m):
    return tuple(tuple(float(x) for x in row) for row in np.asarray(m, dtype=float))


@dataclass(frozen=True)
class AlignConfig:
    """Processor settings: the lab calibration it applies and the filter's tuning (SI).

    Attributes
    ----------
    K_g_cal : 3x3 nested tuple
        Calibrated gyro matrix K~_g, gyro outputs (rad) -> s (default identity: orthogonal
        gyro axes along s).
    C_s_b_cal : 3x3 nested tuple
        Calibrated C~_s^b, s -> b (default: the paper's ideal mount, every gyro axis at
        54.74 deg from the rotation axis, ``c_b_s(R_ZB_S_IDEAL).T``).
    A_acc_cal : 3x3 nested tuple
        Calibrated accelerometer matrix, outputs (m/s) -> s (default identity: ideal axes).
        These three are a lab calibration, :class:`hse_opt.align.LabCalibration`
        (``CALIBRATION.toml``, :meth:`~hse_opt.align.LabCalibration.align_config`).
    latitude : float or None
        rad; for logs whose metadata gives no ``latitude_deg`` (the log's wins; the two
        differing is an error: :func:`latitude_of`).
    arw : float or tuple of 3 float
        Gyro angle random walk assumed by the filter, rad/sqrt(s): one for the three gyros,
        or one each (x_g, y_g, z_g; :func:`horizontal_rms` says how the filter combines them).
    vrw : float or tuple of 3 float
        Accelerometer white noise assumed by the filter, m/s/sqrt(s) (one, or one each).
    gyro_pulse, accel_pulse : float or tuple of 3 float
        Quanta, rad and m/s (one, or one each): the RLG pulse adds its quantization random
        walk to the process noise (:func:`quantization_arw`), the velocity pulse sets the
        measurement noise.
    encoder_counts_per_rev : float or None
        The table encoder's counts per revolution, when known: the quality checks' encoder
        quantum (:func:`hse_opt.align.quality.assess`); the filter does not use it.
    filter_rate : float
        Approximate filter rate, Hz (1 Hz default).
    smoothing_revolutions : int
        Whole revolutions averaged at the end.
    sigma0_tilt, sigma0_heading : float
        Prior 1-sigma of the coarse attitude, rad.
    sigma0_gyro_bias, sigma0_accel_bias : float
        Prior 1-sigma of the horizontal table-top biases, rad/s and m/s^2.
    velocity_floor : float
        Added to the velocity measurement 1-sigma, m/s.
    """

    K_g_cal: tuple = _mat(np.eye(3))
    C_s_b_cal: tuple = _mat(c_b_s(R_ZB_S_IDEAL).T)
    A_acc_cal: tuple = _mat(np.eye(3))
    latitude: float | None = None
    arw: float = 0.0120 * units.DEG_PER_H
    vrw: float = 1.0 * units.MICRO_G
    gyro_pulse: float = 0.1 * units.ARCSEC
    accel_pulse: float = 1e-4
    filter_rate: float = 1.0
    smoothing_revolutions: int = 1
    sigma0_tilt: float = 1e-3
    sigma0_heading: float = 1e-2
    sigma0_gyro_bias: float = 0.05 * units.DEG_PER_H
    sigma0_accel_bias: float = 1e-2
    velocity_floor: float = 1e-6
    encoder_counts_per_rev: float | None = None

    def __post_init__(self):
        for name in ("K_g_cal", "C_s_b_cal", "A_acc_cal"):
            m = np.asarray(getattr(self, name), dtype=float)
            if m.shape != (3, 3) or not np.isfinite(m).all():
                raise ValueError(f"AlignConfig.{name} must be a finite 3x3 matrix, got shape {m.shape}")
            object.__setattr__(self, name, _mat(m))
        for name in ("arw", "vrw", "gyro_pulse", "accel_pulse"):
            v = np.asarray(getattr(self, name), dtype=float)
            if v.shape not in ((), (3,)) or not np.all(np.isfinite(v) & (v >= 0)):
                raise ValueError(f"AlignConfig.{name} = {getattr(self, name)!r} is not allowed: one number >= 0 "
                                 "or three (x, y, z)")
            object.__setattr__(self, name, float(v) if v.ndim == 0 else tuple(float(x) for x in v))
        if not (math.isfinite(self.velocity_floor) and self.velocity_floor >= 0):
            raise ValueError(f"AlignConfig.velocity_floor = {self.velocity_floor!r} is not allowed: must be >= 0")
        c = self.encoder_counts_per_rev
        if c is not None and not (math.isfinite(c) and c >= 1):
            raise ValueError(f"AlignConfig.encoder_counts_per_rev = {c!r} is not allowed: a number >= 1")
        for name in ("filter_rate", "sigma0_tilt", "sigma0_heading", "sigma0_gyro_bias",
                     "sigma0_accel_bias"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"AlignConfig.{name} = {v!r} is not allowed: must be > 0")
        if int(self.smoothing_revolutions) != self.smoothing_revolutions or self.smoothing_revolutions < 1:
            raise ValueError(f"AlignConfig.smoothing_revolutions = {self.smoothing_revolutions!r}: "
                             "an integer >= 1 is required")
        if self.latitude is not None and not abs(self.latitude) < math.radians(89.0):
            raise ValueError(f"AlignConfig.latitude = {self.latitude!r} rad is not allowed: |latitude| < 89 deg")


@dataclass(frozen=True, eq=False)
class AlignHistory:
    """Per-block time history of the fine alignment (for plots); arrays of shape (nb,).

    ``t`` s (since the log's first timestamp, at block ends); angles and 1-sigmas rad."""

    t: np.ndarray
    heading: np.ndarray
    pitch: np.ndarray
    roll: np.ndarray
    heading_std: np.ndarray
    pitch_std: np.ndarray
    roll_std: np.ndarray


@dataclass(frozen=True, eq=False)
class AlignResult:
    """Result of one alignment (rad, s).

    Attributes
    ----------
    heading, pitch, roll : float
        Attitude of b0 (``C_b0^n = rot_z(heading) rot_y(pitch) rot_x(roll)``), after
        whole-revolution smoothing.
    heading_std, pitch_std, roll_std : float
        The filter's 1-sigma, averaged over the smoothing window.
    coarse_heading, coarse_pitch, coarse_roll : float
        The coarse alignment (step 4).
    rate : float
        Mean table rate from the encoder, rad/s.
    n_revolutions : int
        Whole revolutions of filter blocks in the record.
    block_samples, blocks_per_revolution : int
        Filter block length (samples) and blocks per revolution.
    history : AlignHistory
    """

    heading: float
    pitch: float
    roll: float
    heading_std: float
    pitch_std: float
    roll_std: float
    coarse_heading: float
    coarse_pitch: float
    coarse_roll: float
    rate: float
    n_revolutions: int
    block_samples: int
    blocks_per_revolution: int
    history: AlignHistory = field(repr=False)


def triad(f_b0, w_b0):
    """C_b0^n from a mean specific force and a mean rate in b0 (static base, NED).

    Down is ``-f / |f|``, east ``down x w`` normalised, north ``east x down``.

    Parameters
    ----------
    f_b0 : array_like, shape (3,)
        Specific force, m/s^2.
    w_b0 : array_like, shape (3,)
        Angular rate, rad/s.
    """
    f0, f1, f2 = np.asarray(f_b0, dtype=float).tolist()
    w0, w1, w2 = np.asarray(w_b0, dtype=float).tolist()
    k = -1.0 / math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
    d0, d1, d2 = f0 * k, f1 * k, f2 * k
    e0, e1, e2 = d1 * w2 - d2 * w1, d2 * w0 - d0 * w2, d0 * w1 - d1 * w0       # d x w
    k = 1.0 / math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    e0, e1, e2 = e0 * k, e1 * k, e2 * k
    return np.array([[e1 * d2 - e2 * d1, e2 * d0 - e0 * d2, e0 * d1 - e1 * d0],  # e x d
                     [e0, e1, e2], [d0, d1, d2]])


def _blocks(log, config):
    """Calibrate, project into b0 and block-sum.

    Returns a dict: ``dth``, ``dv`` (3, nb) block sums of the calibrated gyro and
    accelerometer increments projected into b0 (table turn removed from the gyro z);
    ``rot`` (nb,) complex block sums of ``exp(i alpha)`` times the sample period (the
    projection of a vector fixed in b: ``sum rot_z(alpha_k) v dt``); geometry ``L``,
    ``m``, ``nb``, ``dt``, ``rate``, ``block_time``.

    The projection is linear, so the calibration matrices are applied to block sums: for
    each block the processor forms ``sum cos(alpha_k) x_k``, ``sum sin(alpha_k) x_k`` and
    ``sum x_k`` of the raw increments ``x_k``, then the 3x3 calibration and the turn into b0.
    Within block ``b`` the midpoint angle is ``Phi_b + l dphi + d`` (``l < L``, ``dphi`` the
    mean turn per sample, ``d`` the small deviation of the measured angle): the sums are
    formed with ``cos``/``sin`` of ``l dphi + d`` (one table of ``L`` entries, ``d`` by its
    Taylor series) and turned by ``Phi_b`` afterwards.
    """
    n = len(log)
    enc = log.encoder
    # the geometry in Python floats (the same IEEE operations as on numpy scalars, cheaper)
    span = float(enc[-1]) - float(enc[0])
    duration = float(log.t[-1]) - float(log.t[0])
    rate = span / duration
    if not abs(span) >= 2 * math.pi:
        raise ValueError(f"raw log: the table turned {abs(span) / (2 * math.pi):.5f} revolutions; "
                         "the alignment needs at least one whole revolution; allowed: a log of one table "
                         "revolution or more")
    dt = duration / (n - 1)
    rev_samples = 2 * math.pi / (abs(rate) * dt)
    # at least 3 blocks per revolution: the table-fixed (once per revolution) states stay
    # observable
    m = max(3, int(round(rev_samples * dt * config.filter_rate)))
    nint = n - 1                               # intervals with an encoder angle at both ends
    # m blocks of L samples make one revolution; a log of barely one revolution gets blocks
    # one sample shorter, so that it still holds m of them
    L = max(1, min(int(round(rev_samples / m)), nint // m))
    nb = nint // L
    nu = nb * L                                # rows 1 .. nu of the log are used
    dphi = span / nint
    phi = enc[0] + dphi * (L * np.arange(nb, dtype=float) + 0.5)   # Phi_b, the blocks' start
    lin = dphi * np.arange(L, dtype=float)                         # l dphi
    cos_lin, sin_lin = np.cos(lin), np.sin(lin)
    two_lin = lin * 2.0
    calib = _calibration(config)
    # per block: sums of cos and sin of l dphi + d at each interval's midpoint, and sums of
    # those and of 1 times each raw increment (gyros then accelerometers: channels 0-5); a
    # group of blocks at a time (the working arrays stay in cache)
    wsum, Y = np.empty((2, nb)), np.empty((3, 6, nb))   # (cos/sin/1, channel, block)
    per = min(nb, max(1, _CHUNK_TARGET // L))
    work, W = np.empty((4, per, L)), np.empty((3, per, L))
    W[2] = 1.0
    ones = np.ones(L)
    srcs = [(x[:, 1:nu + 1].reshape(x.shape[0], nb, L), Y[:, k:k + x.shape[0]])
            for x, k in _channels(log)]                 # (channel, block, sample)
    for b0 in range(0, nb, per):
        b1 = min(nb, b0 + per)
        g = b1 - b0
        d2, q, w = work[0, :g], work[1, :g], W[:2, :g]
        np.add(enc[b0 * L:b1 * L].reshape(g, L), enc[b0 * L + 1:b1 * L + 1].reshape(g, L), out=d2)
        d2 -= 2.0 * phi[b0:b1, None]
        d2 -= two_lin                          # 2 (midpoint angle - (Phi_b + l dphi))
        np.multiply(d2, d2, out=q)
        q_max = float(q.max())
        if q_max <= 4 * MAX_DEVIATION ** 2:    # (the comparison is False for NaN)
            _rotate_half(cos_lin, sin_lin, d2, q, w, work[2:, :g], q_max > 4 * SMALL_DEVIATION ** 2)
        else:
            d2 += two_lin
            d2 *= 0.5
            np.cos(d2, out=w[0])
            np.sin(d2, out=w[1])
        np.matmul(w, ones, out=wsum[:, b0:b1])
        for x, y in srcs:
            _vecdot(W[:, None, :g], x[None, :, b0:b1], y[:, :, b0:b1])
    cph, sph = np.cos(phi), np.sin(phi)

    def turned(c, s):                          # the block sums turned by Phi_b
        return cph * c - sph * s, sph * c + cph * s

    rc, rs = turned(wsum[0], wsum[1])
    # exact average of a rotating vector over an interval: divide by sinc(d alpha / 2)
    y = math.pi * (span / nint / (2 * math.pi))
    corr = 1.0 / (np.sin(y) / y)
    out = {}
    for k, name in enumerate(("dth", "dv")):
        A = calib[k]
        yc, ys = turned(Y[0, 3 * k:3 * k + 3], Y[1, 3 * k:3 * k + 3])
        yc, ys = A @ yc, A @ ys                        # sum cos y, sum sin y, y = A x
        s = np.empty((3, nb))
        s[0] = yc[0] - ys[1]
        s[1] = ys[0] + yc[1]
        s[:2] *= corr
        s[2] = A[2] @ Y[2, 3 * k:3 * k + 3]
        out[name] = s
    out["dth"][2] -= np.diff(enc[0:nu + 1:L])           # the table turn of each block
    out.update(rot=(rc + 1j * rs) * (corr * dt), L=L, m=m, nb=nb, dt=dt, rate=rate,
               block_time=L * dt)
    return out


@functools.lru_cache(maxsize=8)
def _calibration(config):
    """The processor's gyro and accelerometer matrices, raw outputs -> b:
    ``C~_s^b K~_g`` and ``C~_s^b A~_a`` (read-only)."""
    C = np.asarray(config.C_s_b_cal)
    mats = (C @ np.asarray(config.K_g_cal), C @ np.asarray(config.A_acc_cal))
    for a in mats:
        a.flags.writeable = False
    return mats


def _rotate_half(c, s, d2, q, out, work, fourth):
    """cos and sin of ``phase + d2 / 2`` into ``out`` (2, ...) from ``c = cos(phase)``,
    ``s = sin(phase)``, a small ``d2`` (``|d2| / 2 <= MAX_DEVIATION``) and ``q = d2^2``, by
    the series ``cos d = 1 - d^2 / 2 (+ d^4 / 24 if fourth)``, ``sin d = d - d^3 / 6``
    (as :func:`hse_opt.sim._fastmath.rotate_small`, with the halving folded into the
    coefficients); ``q`` is overwritten, ``work`` (2, ...) is scratch."""
    cd, tmp = work[0], work[1]
    if fourth:                                 # 1 + q (q / 384 - 1 / 8)
        np.multiply(q, 1.0 / 384.0, out=cd)
        cd -= 0.125
        cd *= q
    else:
        np.multiply(q, -0.125, out=cd)
    cd += 1.0
    sd = q                                     # d2 (1 / 2 - q / 48)
    sd *= -1.0 / 48.0
    sd += 0.5
    sd *= d2
    rotate(c, s, cd, sd, out, tmp)


def _channels(log):
    """The raw increments as rows (channel, sample) with the index of their first channel:
    ``[(gyro and accelerometers (6, n), 0)]`` when the log holds them as the rows of one
    array (as :func:`hse_opt.sim.imu.generate` writes them), else ``[(gyro (3, n), 0),
    (accel (3, n), 3)]``."""
    g, a = log.gyro.T, log.accel.T
    if (g.strides == a.strides and g.shape == a.shape and g.dtype == a.dtype == np.float64
            and a.ctypes.data == g.ctypes.data + 3 * g.strides[0]):
        # the six rows are those of gyro and accel: a view of exactly their elements
        return [(np.lib.stride_tricks.as_strided(g, (6, g.shape[1]), g.strides, writeable=False), 0)]
    return [(g, 0), (a, 3)]


def _einsum_vecdot(a, b, out):
    """``sum(a * b, axis=-1)`` with broadcasting into ``out``, for numpy < 2."""
    return np.einsum("...i,...i->...", a, b, out=out)


#: ``_vecdot(a, b, out)``: ``sum(a * b, axis=-1)`` with broadcasting into ``out`` (None: a new
#: array); numpy >= 2's gufunc itself where it has one (no wrapper per call: the Allan analysis
#: calls it some 30 times a log)
_vecdot = getattr(np, "vecdot", _einsum_vecdot)


def _coarse(dth, dv, rot, T):
    """Mean rate and specific force in b0 with the table-fixed parts fitted out.

    A vector fixed in the turntable top b (a gyro or accelerometer bias, or the table rate
    leaking through a misaligned r_zb^s) turns with the table in b0; its block sums are
    ``rot_j v``. The horizontal block sums are fitted as ``T w + rot_j v`` (least squares,
    complex form), so the mean ``w`` is free of them even when the blocks do not span whole
    revolutions exactly; the vertical parts are plain means.
    """
    means = []
    # normal equations of the two complex unknowns (the columns T and rot are nearly
    # orthogonal: blocks span whole revolutions to within a few samples)
    n, sr, rr = rot.shape[0], rot.sum(), float(np.vdot(rot, rot).real)
    det = n * T * T * rr - T * T * abs(sr) ** 2
    for x in (dth, dv):
        z = x[0] + 1j * x[1]
        az, bz = T * z.sum(), np.vdot(rot, z)
        w = (rr * az - T * sr * bz) / det
        means.append(np.array([w.real, w.imag, x[2].sum() / n / T]))     # sum / n: np.mean
    return means


def _expm(A):
    """Matrix exponential by scaling and squaring of a 16-term Taylor series (after scaling
    the 1-norm is <= 1/2: truncation error < 1e-19 relative), the series evaluated by
    Paterson and Stockmeyer's scheme: ``X^0 .. X^3`` combined with the coefficients in one
    product, then Horner's rule in ``X^4``. Written with np.dot so that it stays
    single-threaded (scipy.linalg.expm wakes BLAS worker threads that then spin)."""
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    nrm = np.abs(A).sum(axis=0).max()
    sq = max(0, int(math.ceil(math.log2(nrm))) + 1) if nrm > 0 else 0
    pw = np.empty((4, n, n))                   # X^0 .. X^3
    pw[0] = np.eye(n)
    np.multiply(A, 0.5 ** sq, out=pw[1])
    _DOT(pw[1], pw[1], pw[2])
    _DOT(pw[2], pw[1], pw[3])
    X4 = _DOT(pw[2], pw[2])
    # B_j = sum_i X^i / (4 j + i)!, j = 0 .. 3; the sum is B_0 + X4 (B_1 + X4 (B_2 + X4 (B_3
    # + X4 / 16!)))
    B = _DOT(_PS_COEF, pw.reshape(4, n * n)).reshape(4, n, n)
    E, tmp = np.multiply(X4, 1.0 / math.factorial(16)), np.empty((n, n))
    E += B[3]
    for j in (2, 1, 0):
        _DOT(E, X4, tmp)
        np.add(tmp, B[j], out=E)
    for _ in range(sq):
        _DOT(E, E, tmp)
        E, tmp = tmp, E
    return E


#: the Taylor coefficients 1 / (4 j + i)! of :func:`_expm` (row j, column i)
_PS_COEF = np.array([[1.0 / math.factorial(4 * j + i) for i in range(4)] for j in range(4)])
_PS_COEF.flags.writeable = False


def quantization_arw(pulse, rate, dt):
    """Angle random walk (rad/sqrt(s)) that RLG pulse quantization adds to each horizontal
    axis in b0: ``q |Omega| sqrt(dt / 12)``.

    The pulse counter carries its remainder, so its error in the cumulative angle is bounded
    (uniform over one pulse ``q``, independent from sample to sample once the table's
    jitter dithers it). The processor turns each increment into b0 with the table angle;
    summed by parts, the bounded error meets the turn ``Omega dt`` of every sample, which
    leaves a white angle error of ``q / sqrt(12) Omega dt`` per sample in the horizontal
    axes: a random walk that grows with the table rate (0.0045 deg/h/sqrt(Hz) for 0.5 arcsec
    pulses at 40 deg/s). Undithered, the remainder can lock to the table angle at rates
    where a gyro's pulses per sample are close to a simple fraction, and the error becomes a
    bias of tens of arcseconds in heading (``tests/test_sim_imu.py``).
    """
    return pulse * abs(rate) * math.sqrt(dt / 12.0)


def horizontal_rms(value, M):
    """The noise of three sensors as the filter's horizontal axes in b0 see it.

    The filter's noise is one figure per horizontal axis of b0 (its model is time invariant);
    a sensor's noise reaches b along its axis (column ``i`` of ``M``: raw outputs -> b), and
    the table's turn spreads the horizontal part evenly over the horizontal axes of b0 (a
    2x2 covariance ``A`` turned through every angle averages to ``tr(A) / 2 I``). So each
    sensor counts with its share of the horizontal plane, ``h_i = M_0i^2 + M_1i^2`` (2/3 for
    each axis of the paper's triad):

        rms = sqrt(sum_i h_i v_i^2 / sum_i h_i)

    (normalised: for equal values it is that value whatever the calibration's scale factors;
    on an orthogonal triad it is ``sqrt(tr(A) / 2)`` exactly).

    Parameters
    ----------
    value : float or tuple of 3 float
        One figure for the three sensors, or one each (any unit; the result has it).
    M : numpy.ndarray, shape (3, 3)
        ``C~_s^b K~_g`` (gyros) or ``C~_s^b A~_a`` (accelerometers).

    Returns
    -------
    float
    """
    if not isinstance(value, tuple):
        return float(value)
    h = M[0] ** 2 + M[1] ** 2
    return math.sqrt(float(h @ np.square(value)) / float(h.sum()))


def _filter_matrices(C0, w_n, g, rate, T, dt, config):
    """Transition Phi, process noise Qd (Van Loan) for one block of length T (s); ``dt`` is
    the sample period (s), for the pulse quantization noise; per-axis noise as the
    horizontal axes see it (:func:`horizontal_rms`)."""
    F = np.zeros((9, 9))
    # attitude error (N, E; D held): phi_dot = -[w x] phi - C0[:, :2] x_g
    wN, wE, wD = w_n.tolist()
    F[0, 1], F[0, 2], F[1, 0], F[1, 2] = wD, -wE, -wD, wN          # -[w x], rows N, E
    F[0:2, 5:7] = -C0[0:2, 0:2]
    # velocity error: v_dot = f^n x phi + C0[:2, :2] x_a, f^n = (0, 0, -g)
    F[3, 1] = g
    F[4, 0] = -g
    F[3:5, 7:9] = C0[0:2, 0:2]
    F[5, 6] = F[7, 8] = -rate                   # rate [[0, -1], [1, 0]]
    F[6, 5] = F[8, 7] = rate
    Qc = np.zeros((9, 9))
    Mg, Ma = _calibration(config)
    Qc[0, 0] = Qc[1, 1] = (horizontal_rms(config.arw, Mg) ** 2
                           + quantization_arw(horizontal_rms(config.gyro_pulse, Mg), rate, dt) ** 2)
    Qc[3, 3] = Qc[4, 4] = horizontal_rms(config.vrw, Ma) ** 2
    M = np.zeros((18, 18))
    M[:9, :9] = -F
    M[:9, 9:] = Qc
    M[9:, 9:] = F.T
    E = _expm(M * T)
    Phi = E[9:, 9:].T
    Qd = Phi @ E[:9, 9:]
    Qd = 0.5 * (Qd + Qd.T)
    return Phi, Qd


def _kalman(Phi, Qd, Rv, P, vel):
    """The fine-alignment Kalman filter over the blocks: state 9 (x0 = 0, covariance ``P``),
    time update ``Phi``, ``Qd``, measurement of states 3, 4 (velocity) ``vel`` (2, nb) with
    noise variance ``Rv`` each. Returns the attitude states (nb, 3) and their covariance
    (nb, 3, 3) after each update.

    The covariance recursion does not depend on the data, so it runs first, written for the
    interpreter: the time update is one matrix-vector product on ``vec(P)`` (``Phi (x) Phi``
    with ``vec(Qd)`` appended); the measurement update is Joseph's form
    ``P+ = (I - K H) P (I - K H)^T + Rv K K^T = W blockdiag(P, Rv I) W^T`` with
    ``W = [I - K H, K]`` and the 2x2 innovation inverse in closed form. (The short form
    ``P - P H^T S^-1 H P`` subtracts nearly equal numbers: the velocity variance falls from
    its prior to about ``Rv`` in every update, and with a noise-free tuning the heading drifted
    by 0.3 arcsec over 10 minutes from a long-double evaluation of the same filter; Joseph's
    form stays within 1e-5 arcsec.) Every product works in fixed buffers, and one copy per
    block records the gain and the posterior's attitude rows. The state recursion
    ``x_j = (I - K_j H) Phi x_{j-1} + K_j z_j`` then is a chain of 10x10 products
    (:func:`_chain`)."""
    dot = _DOT
    nb = vel.shape[1]
    M = np.zeros((82, 82))
    np.multiply(Phi[:, None, :, None], Phi[None, :, None, :],
                out=M[:81, :81].reshape(9, 9, 9, 9))          # Phi (x) Phi
    M[:81, 81] = Qd.ravel()
    M[81, 81] = 1.0
    prior = np.empty(82)
    Pm = prior[:81].reshape(9, 9)
    HP = Pm[3:5]
    # one buffer: W^T = [(I - K H)^T; K^T] (11x9), then the posterior vec(P+) (82, ending in
    # 1); per block K^T and the posterior's rows 0-2 (contiguous) are recorded
    buf = np.empty(99 + 82)
    WT, post = buf[:99].reshape(11, 9), buf[99:]
    Pp = post[:81].reshape(9, 9)
    WT[:9] = np.eye(9)
    IKHT, Q, G, W = WT[:9], WT[3:5], WT[9:], WT.T     # (I - K H)^T, its rows 3, 4; K^T; W
    E2 = IKHT[3:5].copy()                              # H
    post[:81] = np.asarray(P, dtype=float).ravel()
    post[81] = 1.0
    rec = buf[81:126]
    hist = np.empty((nb, 45))
    Z = np.empty((11, 9))                              # blockdiag(P, Rv I) W^T
    ZP, ZR = Z[:9], Z[9:]
    Si = np.empty((2, 2))
    si, item, sub, mul = Si.ravel(), Pm.item, np.subtract, np.multiply    # looked up once
    rv = np.array(Rv)                                  # (a 0-d array multiplies faster)
    for h in hist:
        dot(M, post, prior)                      # Phi P Phi^T + Qd
        S00, S01, S11 = item(30) + Rv, item(31), item(40) + Rv
        det = S00 * S11 - S01 * S01
        si[1] = si[2] = -S01 / det
        si[0] = S11 / det
        si[3] = S00 / det
        dot(Si, HP, G)                           # K^T = S^-1 H P
        sub(E2, G, out=Q)
        dot(Pm, IKHT, ZP)
        mul(G, rv, out=ZR)
        dot(W, Z, Pp)
        h[...] = rec
    # x_j = A_j x_{j-1} + b_j with A_j = Phi - K_j H Phi and b_j = K_j z_j in 10x10 form: the
    # top 9 rows [A_j, b_j] of all blocks by one product, then copied whole rows at a time
    G = hist[:, :18].reshape(nb, 2, 9)                 # K_j^T
    R = np.zeros((2, 10))
    R[:, :9] = Phi[3:5]                                # H Phi
    top = (G.transpose(0, 2, 1).reshape(nb * 9, 2) @ R).reshape(nb, 9, 10)
    Phi_top = np.zeros((9, 10))
    Phi_top[:, :9] = Phi
    np.subtract(Phi_top, top, out=top)
    b = top[:, :, 9]
    np.multiply(G[:, 0], vel[0, :, None], out=b)
    b += G[:, 1] * vel[1, :, None]
    A = np.empty((nb, 10, 10))
    Af = A.reshape(nb, 100)
    Af[:, :90] = top.reshape(nb, 90)
    Af[:, 90:] = 0.0
    Af[:, 99] = 1.0
    x0 = np.zeros(10)
    x0[9] = 1.0
    return _chain(A, x0)[1:, :3], hist[:, 18:].reshape(nb, 3, 9)[:, :, :3]


def _chain(A, x0):
    """All ``x_{j+1} = A_j x_j`` (j < len(A)) from ``x0``: (len(A) + 1, n). Pairs of steps are
    multiplied out at once and the chain of pairs is solved the same way, so the loop runs
    over a few steps only; each level fills in its odd steps with one batched product."""
    nb = A.shape[0]
    x = np.empty((nb + 1, A.shape[1]))
    x[0] = x0
    if nb < 8:
        for j in range(nb):
            _DOT(A[j], x[j], x[j + 1])
        return x
    h = nb // 2
    even = _chain(np.matmul(A[1:2 * h:2], A[0:2 * h:2]), x0)     # x_0, x_2, ..., x_2h
    x[0:2 * h + 1:2] = even
    x[1:2 * h:2] = np.matmul(A[0:2 * h:2], even[:-1, :, None])[:, :, 0]
    if nb % 2:
        _DOT(A[nb - 1], x[nb - 1], x[nb])
    return x


def latitude_of(log, config):
    """The latitude a log is aligned at, rad: its metadata's ``latitude_deg`` when given, else
    ``config.latitude``.

    Raises
    ------
    ValueError
        Neither gives one; the metadata's is not a number within +-89 deg; or both give one and
        they differ by more than :data:`LATITUDE_TOL_DEG` (the message names both).
    """
    meta = log.meta.get("latitude_deg")
    if meta is None:
        if config.latitude is None:
            raise ValueError("no latitude: allowed: latitude_deg in the log's metadata, or a latitude given to "
                             "the processor (--latitude-deg, the calibration file's site.latitude_deg)")
        return config.latitude
    if isinstance(meta, bool) or not isinstance(meta, (int, float)) or not abs(meta) < 89.0:
        raise ValueError(f"metadata latitude_deg = {meta!r}; allowed: a number of degrees, |latitude| < 89")
    if config.latitude is not None and abs(config.latitude / units.DEG - meta) > LATITUDE_TOL_DEG:
        raise ValueError(f"the log's metadata latitude_deg = {meta!r} and the latitude given to the processor, "
                         f"{config.latitude / units.DEG:.10g} deg (--latitude-deg or the calibration file), "
                         f"differ; allowed: one latitude (within {LATITUDE_TOL_DEG:g} deg), or only one of them")
    return float(meta) * units.DEG


def align(log, config=None):
    """Align one raw log.

    Parameters
    ----------
    log : RawLog
    config : AlignConfig, optional
        Calibration and tuning (default: the orthogonal calibration, default tuning).

    Returns
    -------
    AlignResult

    Raises
    ------
    ValueError
        The table turned less than one revolution, or no latitude is known, or the log's and
        the config's differ (:func:`latitude_of`).
    """
    if not isinstance(log, RawLog):
        raise ValueError("align: a RawLog is required (see hse_opt.align.rawlog)")
    config = AlignConfig() if config is None else config
    with one_thread():      # (BLAS's second thread would gain 7 % of the time and spin for as long again)
        return _align(log, config)


def _align(log, config):
    """:func:`align` of a RawLog with its config."""
    lat = latitude_of(log, config)
    blk = _blocks(log, config)
    dth, dv, nb, m, T = blk["dth"], blk["dv"], blk["nb"], blk["m"], blk["block_time"]
    w_n = earth_rate_n(lat)

    # coarse alignment: TRIAD on the means, table-fixed parts fitted out
    n_rev = nb // m
    w_mean, f_mean = _coarse(dth, dv, blk["rot"], T)
    C0 = triad(f_mean, w_mean)
    g = math.sqrt(f_mean.dot(f_mean))

    # open-loop navigation solution from C0 (heading held), at block ends
    r = C0 @ dth - (w_n * T)[:, None]              # n-frame angle residual per block
    fn = C0 @ dv                                  # n-frame velocity increment per block
    wd = w_n[2]
    # psi_h: d/dt (psi_N + i psi_E) = -(r_N + i r_E)/T - i wd (psi_N + i psi_E)
    k = np.arange(1, nb + 1)
    rot = np.exp(1j * wd * T * k)
    zr = r[0] + 1j * r[1]
    z = -np.cumsum(zr * rot) / rot                # psi at the end of each block
    psi_n, psi_e = z.real, z.imag
    # the velocity increments with the mean tilt over each block (psi is 0 at the start)
    dvel = np.empty((2, nb))
    dvel[0, 0], dvel[1, 0] = psi_e[0], psi_n[0]
    np.add(psi_e[:-1], psi_e[1:], out=dvel[0, 1:])
    np.add(psi_n[:-1], psi_n[1:], out=dvel[1, 1:])
    gT = g * T * 0.5
    dvel[0] *= gT
    dvel[1] *= -gT
    dvel += fn[:2]
    vel = np.cumsum(dvel, axis=1)

    Phi, Qd = _filter_matrices(C0, w_n, g, blk["rate"], T, blk["dt"], config)
    Rv = horizontal_rms(config.accel_pulse, _calibration(config)[1]) ** 2 / 12.0 + config.velocity_floor ** 2
    P = np.diag([config.sigma0_tilt ** 2, config.sigma0_tilt ** 2, config.sigma0_heading ** 2,
                 config.velocity_floor ** 2, config.velocity_floor ** 2,
                 config.sigma0_gyro_bias ** 2, config.sigma0_gyro_bias ** 2,
                 config.sigma0_accel_bias ** 2, config.sigma0_accel_bias ** 2])
    delta, Ps = _kalman(Phi, Qd, Rv, P, vel)

    # corrected attitude: C = (I + [(phi - psi) x]) C0, psi = (psi_N, psi_E, 0)
    delta[:, 0] -= psi_n
    delta[:, 1] -= psi_e
    # (I + [delta x]) C0 = C0 + sum_i delta_i [e_i x] C0: one product with the rows of [e_i x] C0
    E = (C0.ravel()[_E_INDEX] * _E_SIGN).reshape(3, 9)
    C = (C0.ravel() + delta @ E).reshape(nb, 3, 3)
    # per block: heading, pitch, roll and their 1-sigmas, rows of one array (for the means)
    out = np.empty((6, nb))
    out[0], out[1], out[2] = dcm_to_zyx(C)
    heading = out[0]
    if not heading.max() - heading.min() < math.pi:     # else np.unwrap is the identity
        heading[...] = np.unwrap(heading)
    # 1-sigma: heading from phi_D; pitch and roll from the n-frame tilt turned into b0
    ch, sh = np.cos(heading), np.sin(heading)
    Pnn, Pee, Pne = Ps[:, 0, 0], Ps[:, 1, 1], Ps[:, 0, 1]
    var_roll = ch * ch * Pnn + 2 * ch * sh * Pne + sh * sh * Pee
    var_pitch = sh * sh * Pnn - 2 * ch * sh * Pne + ch * ch * Pee
    np.sqrt(Ps[:, 2, 2], out=out[3])
    np.sqrt(var_pitch, out=out[4])
    np.sqrt(var_roll, out=out[5])
    hist = AlignHistory(T * k, *out)
    w = min(nb, config.smoothing_revolutions * m)
    means = (np.add.reduce(out[:, nb - w:], axis=1) / w).tolist()   # each row's np.mean
    ch0, cp0, cr0 = dcm_to_zyx(C0)
    return AlignResult(
        *means, coarse_heading=float(ch0), coarse_pitch=float(cp0), coarse_roll=float(cr0),
        rate=float(blk["rate"]), n_revolutions=int(n_rev), block_samples=int(blk["L"]),
        blocks_per_revolution=int(m), history=hist)
