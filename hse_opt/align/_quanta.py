"""A raw log's quanta and its encoder's step statistics (private), worked out once by
:func:`hse_opt.align.quality.assess` for the checks that all take them: check 1 (the table's
step, its robust 1-sigma and the encoder's count), check 3 (each channel's pulse and the
encoder's count) and check 3b (the table's jitter, the gyros' pulses, the encoder's count).

The quantum of a channel is the smallest nonzero change between its consecutive values over
its first :data:`QUANTUM_SAMPLES` samples (module docstring of :mod:`hse_opt.align.quality`,
*Noise model and false alarms*): one pulse (or one encoder count) of a quantized channel, ~0
for an unquantized one.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from hse_opt.align import _compiled
from hse_opt.align._stats import every_29th_step, step_stats

__all__ = ["Quanta", "EncoderSteps", "quantum", "encoder_quantum", "QUANTUM_SAMPLES", "QUANTUM_CHANGES"]

#: the quanta are seen in this many first samples (of a channel, or of the encoder's steps)
QUANTUM_SAMPLES = 4000
#: a channel that changes in this many of them or fewer has no quantum (0)
QUANTUM_CHANGES = 20


def _row_quanta(x):
    """:func:`quantum` of each row of ``x`` (k, N), N <= :data:`QUANTUM_SAMPLES`: shape (k,)."""
    dd = np.subtract(x[:, 1:], x[:, :-1])
    np.abs(dd, out=dd)
    # not rounding of whole multiples: above 1e-9 of the row's mean |value|
    same = dd <= 1e-9 * (np.add.reduce(np.abs(x), axis=-1) / x.shape[-1])[:, None]
    # a channel that changes in only a few samples (a glitch in an exact ramp) has no quantum
    many = np.array([dd.shape[-1] - np.count_nonzero(row) > QUANTUM_CHANGES for row in same], dtype=bool)
    if not dd.shape[-1]:
        return np.zeros(x.shape[0])
    np.putmask(dd, same, np.inf)
    return np.where(many, dd.min(axis=-1), 0.0)


def _quanta_of_rows(rows):
    """:func:`_row_quanta` of rows of one length given as a list (the channels' own memory,
    not copied), shape (k,): by the compiled kernel (:mod:`hse_opt.align._compiled`) where it is
    built and each row is contiguous float64, else numpy's route on the rows stacked."""
    if _compiled.takes(*rows):
        return np.array(_compiled.kernels.quanta(rows, QUANTUM_CHANGES))
    return _row_quanta(np.stack(rows))


def quantum(x):
    """The smallest nonzero change between consecutive values of ``x`` over its first
    :data:`QUANTUM_SAMPLES` samples, per column, above 1e-9 of its values (float rounding of
    whole multiples): one pulse (or one encoder count) of a quantized channel, ~0 for an
    unquantized one, 0 when it changes in :data:`QUANTUM_CHANGES` samples or fewer. Window sums
    of counters that carry their remainders are off by less than one pulse each, so a threshold
    of three quanta is never reached by quantization alone, however its residuals bunch (a
    median absolute deviation can be 0).

    Parameters
    ----------
    x : numpy.ndarray, shape (n,) or (n, k)
        Samples (a channel's increments, rad or m/s; the encoder's steps, rad).

    Returns
    -------
    float or numpy.ndarray, shape (k,)
        In the unit of ``x``.
    """
    x = np.asarray(x)[:QUANTUM_SAMPLES]
    q = _row_quanta(x.T if x.ndim == 2 else x[None])
    return q if x.ndim == 2 else q[0]


def encoder_quantum(enc, resolution):
    """One encoder count, rad: the smallest change of its first steps (:func:`quantum` of
    steps 1 .. :data:`QUANTUM_SAMPLES` of ``enc`` (n,), rad), or ``resolution`` (rad: the
    counts per revolution given), whichever is larger."""
    return max(float(quantum(np.diff(enc[:QUANTUM_SAMPLES + 2])[1:])), resolution)


@dataclass(frozen=True, eq=False)
class EncoderSteps:
    """What the checks read of the encoder's steps ``alpha_k - alpha_{k-1}`` over the whole
    log, from one pass over them (:meth:`of`; :func:`hse_opt.align.blocks.block_sums` makes it
    with the pass it takes for check 3b's sums): their extremes, the table's step and its
    robust 1-sigma, and the first steps the encoder's count is seen in. The steps themselves
    (a record's size) are not kept: :attr:`steps` takes them again when a check needs them
    (an encoder sample to repair or refuse).

    Attributes
    ----------
    encoder : numpy.ndarray, shape (n,)
        The angles they are of, rad.
    largest, smallest : float
        The largest and the smallest step, rad.
    step, step_sigma : float
        :func:`hse_opt.align._stats.step_stats` of the steps, rad.
    first : numpy.ndarray, shape (min(QUANTUM_SAMPLES, n - 2),)
        Steps 1 .. :data:`QUANTUM_SAMPLES`, rad (a copy).
    """

    encoder: np.ndarray
    largest: float
    smallest: float
    step: float
    step_sigma: float
    first: np.ndarray

    @classmethod
    def of(cls, enc, steps=None, extremes=None):
        """Of the encoder ``enc`` (n,), rad; ``steps``: its steps ``enc[1:] - enc[:-1]`` when
        already taken (else taken here, and let go); ``extremes``: their largest and smallest
        when already known (the compiled pass, :func:`hse_opt.align.blocks.block_sums`: the
        steps are then not taken; the statistics read the same steps from ``enc``)."""
        N = min(QUANTUM_SAMPLES, enc.shape[0] - 2)
        if extremes is not None:
            step, sigma = step_stats(every_29th_step(enc), taken=True)
            return cls(enc, float(extremes[0]), float(extremes[1]), step, sigma, enc[2:N + 2] - enc[1:N + 1])
        steps = enc[1:] - enc[:-1] if steps is None else steps
        step, sigma = step_stats(steps)
        return cls(enc, float(steps.max()), float(steps.min()), step, sigma, steps[1:N + 1].copy())

    @functools.cached_property
    def steps(self):
        """The steps, shape (n - 1,), rad (taken on first use)."""
        return self.encoder[1:] - self.encoder[:-1]


@dataclass(frozen=True, eq=False)
class Quanta:
    """A raw log's quanta and its encoder's step statistics, for the checks that take them
    (module docstring); :meth:`of` works them out once for a log's arrays.

    Attributes
    ----------
    encoder, gyro, accel : numpy.ndarray, shapes (n,), (n, 3), (n, 3)
        The arrays they are of (the log's, or a repaired copy's): rad, rad, m/s.
    resolution : float
        The encoder's count when known (its counts per revolution), else 0, rad.
    seen : EncoderSteps
        The encoder's steps' extremes and statistics (:attr:`steps`, :attr:`step`,
        :attr:`step_sigma` are its).
    count : float
        One encoder count: :func:`encoder_quantum`, rad.
    pulses : numpy.ndarray, shape (6,)
        One pulse of each channel: :func:`quantum` of samples 1 .. :data:`QUANTUM_SAMPLES` of
        gyro x, y, z (rad) and accelerometer x, y, z (m/s); ~0 for an unquantized channel.
    """

    encoder: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    resolution: float
    seen: EncoderSteps
    count: float
    pulses: np.ndarray

    @property
    def steps(self):
        """The encoder's steps ``alpha_k - alpha_{k-1}``, shape (n - 1,), rad (taken on first
        use: :attr:`EncoderSteps.steps`)."""
        return self.seen.steps

    @property
    def step(self):
        """The table's step: the median of the encoder's every 29th step
        (:func:`hse_opt.align._stats.step_stats`), rad."""
        return self.seen.step

    @property
    def step_sigma(self):
        """The robust 1-sigma of those steps (the table's jitter and the encoder's resolution
        seen in the steps), rad."""
        return self.seen.step_sigma

    @property
    def jitter(self):
        """The table's jitter per sample, rad: ``step_sigma / sqrt(2)`` (a step is the
        difference of two samples' jitter)."""
        return self.step_sigma / math.sqrt(2.0)

    @classmethod
    def of(cls, enc, gyro, accel, resolution=0.0, like=None, seen=None):
        """The quanta of the arrays ``enc`` (n,), ``gyro`` (n, 3), ``accel`` (n, 3) (rad, rad,
        m/s); ``resolution``: the encoder's count when known, rad (0: as seen in the data).

        ``like``: quanta worked out before (of the log before a repair), returned when they are
        of these very arrays (the same objects) and resolution; their encoder's or channels'
        part is kept when only those arrays are the same. ``seen``: the encoder's
        :class:`EncoderSteps` when already taken (with the block sums), used when of ``enc``.

        Returns
        -------
        Quanta
        """
        same_enc = same_channels = False
        if like is not None and like.resolution == resolution:
            same_enc = like.encoder is enc
            same_channels = like.gyro is gyro and like.accel is accel
            if same_enc and same_channels:
                return like
        if same_enc:
            seen, count = like.seen, like.count
        elif seen is None or seen.encoder is not enc:
            seen = EncoderSteps.of(enc)
        first = seen.first
        if same_channels:
            pulses = like.pulses
        elif first.shape[0] == QUANTUM_SAMPLES and not same_enc:
            # the encoder's steps 1 .. N and the channels' samples 1 .. N, one row each
            q = _quanta_of_rows([first, *gyro.T[:, 1:QUANTUM_SAMPLES + 1], *accel.T[:, 1:QUANTUM_SAMPLES + 1]])
            return cls(enc, gyro, accel, resolution, seen, max(float(q[0]), resolution), q[1:])
        else:
            pulses = _quanta_of_rows([*gyro.T[:, 1:QUANTUM_SAMPLES + 1], *accel.T[:, 1:QUANTUM_SAMPLES + 1]])
        if not same_enc:
            count = max(float(_quanta_of_rows([first])[0]), resolution)
        return cls(enc, gyro, accel, resolution, seen, count, pulses)
