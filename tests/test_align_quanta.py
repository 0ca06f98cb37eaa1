"""The quanta and encoder step statistics the raw-log checks share (hse_opt.align._quanta.Quanta):
against logs built here from whole counts and pulses of known size, numpy's own median, and
check 3b's figures as its definition states them (hse_opt.align.quality._check_gyro_steps)."""
import math

import numpy as np
import pytest

from hse_opt.align._quanta import QUANTUM_SAMPLES, Quanta, quantum
from hse_opt.align.quality import assess
from hse_opt.sim import RunSpec, TruthConfig, generate
from hse_opt.units import ARCSEC, DEG_PER_S

COUNT = 2.0 * math.pi / 2 ** 20                       # one count of a 20-bit encoder, rad (1.24 arcsec)
GYRO_PULSE = np.array([1.0, 2.0, 0.5]) * ARCSEC       # rad
ACCEL_PULSE = np.array([1e-4, 1e-4, 2e-4])            # m/s


def _counts_log(n, rng):
    """Encoder, gyro and accelerometer arrays made of whole counts and pulses: the encoder steps
    37 counts plus a jitter of -2..2 counts (each its own step, not a sample's: every step
    differs from 37 by the jitter drawn for it), each channel a whole number of its pulses
    -1..1 pulse off its mean (consecutive samples differ by 0..2 pulses); accel_z unquantized."""
    jit = rng.integers(-2, 3, n - 1)
    enc = COUNT * np.concatenate(([0.0], np.cumsum(37 + jit)))
    g = GYRO_PULSE * (500 + rng.integers(-1, 2, (n, 3)))
    a = ACCEL_PULSE * (rng.integers(-1, 2, (n, 3)) + np.array([0, 0, 981]))
    a[:, 2] = 9.81 * 0.002 + 1e-4 * rng.standard_normal(n)
    return enc, np.asfortranarray(g), np.asfortranarray(a), jit * COUNT


@pytest.mark.parametrize("n", [QUANTUM_SAMPLES + 2, 3001, 20_000])
def test_the_quanta_are_the_counts_and_pulses_the_log_is_made_of(n):
    """One count of the encoder, one pulse of each quantized channel (within the float rounding
    of a difference of whole multiples), a small fraction of the unquantized channel's spread;
    the table's step and its robust 1-sigma from numpy's median of every 29th step (from all
    steps below 2,900), the jitter that 1-sigma over sqrt(2)."""
    enc, gyro, accel, jit = _counts_log(n, np.random.default_rng(n))
    q = Quanta.of(enc, gyro, accel)
    assert q.count == pytest.approx(COUNT, rel=1e-9)
    assert q.pulses[:3] == pytest.approx(GYRO_PULSE, rel=1e-9)
    assert q.pulses[3:5] == pytest.approx(ACCEL_PULSE[:2], rel=1e-9)
    assert 0.0 < q.pulses[5] < 1e-2 * 1e-4
    sub = np.diff(enc)[::29] if n - 1 >= 2900 else np.diff(enc)
    assert q.step == np.median(sub) == pytest.approx(37 * COUNT, rel=1e-12)
    assert q.step_sigma == pytest.approx(1.4826 * np.median(np.abs(sub - np.median(sub))), rel=1e-12)
    assert q.jitter == pytest.approx(q.step_sigma / math.sqrt(2.0), rel=1e-15)
    assert np.array_equal(q.steps, np.diff(enc))
    # a coarser encoder resolution given is the count; a finer one is not
    assert Quanta.of(enc, gyro, accel, resolution=3 * COUNT).count == 3 * COUNT
    assert Quanta.of(enc, gyro, accel, resolution=0.5 * COUNT).count == q.count


def test_a_channel_that_changes_in_20_samples_or_fewer_has_no_quantum():
    """An exact ramp with a few glitches: 0 (no quantum), as a channel that never changes; 21
    changes: the smallest."""
    x = np.zeros((QUANTUM_SAMPLES + 1, 3))
    x[100:120, 0] = 1e-6                     # changes at 100 and 120: 2
    x[:, 1] = np.where(np.arange(QUANTUM_SAMPLES + 1) % 200 < 100, 0.0, 3e-6)      # 40 changes of 3e-6
    x[5:25:2, 2] = 2e-6                       # 10 one-sample glitches: 20 changes
    got = quantum(x)
    assert got[0] == 0.0 and got[1] == pytest.approx(3e-6, rel=1e-12) and got[2] == 0.0
    x[500, 2] = 2e-6                          # one more glitch: 22 changes
    assert quantum(x)[2] == pytest.approx(2e-6, rel=1e-12)


def test_quanta_of_the_same_arrays_are_worked_out_once_and_a_repaired_copys_anew():
    enc, gyro, accel, _ = _counts_log(6000, np.random.default_rng(1))
    q = Quanta.of(enc, gyro, accel)
    assert Quanta.of(enc, gyro, accel, like=q) is q
    enc2 = enc.copy()
    enc2[1:10] += 5 * COUNT                   # a repaired copy whose first steps differ
    q2 = Quanta.of(enc2, gyro, accel, like=q)
    assert q2.pulses is q.pulses and q2.encoder is enc2
    assert np.array_equal(q2.steps, np.diff(enc2))
    assert Quanta.of(enc2, gyro, accel).count == q2.count
    g2 = gyro.copy()
    g2[1:QUANTUM_SAMPLES + 1, 0] *= 2.0       # gyro_x: 2 arcsec pulses in the samples the quantum sees
    q3 = Quanta.of(enc, g2, accel, like=q)
    assert q3.steps is q.steps and q3.pulses[0] == pytest.approx(2 * GYRO_PULSE[0], rel=1e-9)
    assert Quanta.of(enc, gyro, accel, resolution=COUNT, like=q) is not q


def test_the_quanta_are_check_3bs_figures_on_a_simulated_log(monkeypatch):
    """The record holds, for a clean simulated log, the jitter (from every 29th encoder step, over
    sqrt(2)), the gyros' quanta and the encoder's count as written out here from their
    definitions, and check 3b (hse_opt.align.steps.check_steps) is handed those."""
    import hse_opt.align.quality as quality
    log = generate(TruthConfig.default(), RunSpec(rate=25 * DEG_PER_S, azimuth=0.3, duration=30.0, t_start=3600.0),
                   np.random.default_rng(5))
    seen = {}

    def spy(t, enc, gyro, *args, **kw):
        seen.update(kw)
        return gyro, []
    monkeypatch.setattr(quality, "check_steps", spy)
    assert assess(log).findings == ()
    q = Quanta.of(log.encoder, log.gyro, log.accel)
    sub = log.encoder[1::29] - log.encoder[:-1:29]
    jitter = 1.4826 * np.median(np.abs(sub - np.median(sub))) / math.sqrt(2.0)
    assert q.jitter == pytest.approx(jitter, rel=1e-12) and seen["jitter"] == q.jitter
    first = log.gyro[1:QUANTUM_SAMPLES + 1]
    dd = np.abs(np.diff(first, axis=0))
    ref = np.array([dd[dd[:, j] > 1e-9 * np.abs(first[:, j]).mean(), j].min() for j in range(3)])
    assert np.allclose(q.pulses[:3], ref, rtol=1e-12) and np.array_equal(seen["q"], q.pulses[:3])
    steps = np.diff(log.encoder[:QUANTUM_SAMPLES + 2])[1:]
    ds = np.abs(np.diff(steps))
    ref_e = ds[ds > 1e-9 * np.abs(steps).mean()].min()
    assert q.count == pytest.approx(ref_e, rel=1e-12) and seen["qe"] == q.count


def test_a_log_of_three_samples_has_no_quantum_and_is_assessed():
    """Three samples (the least the loader takes) hold one change of each channel and none of
    the encoder's steps: no quantum (0), the encoder's count the resolution given; the checks
    run (they raised numpy's 'zero-size array to reduction operation' before)."""
    from hse_opt.align import RawLog
    t = np.arange(3) * 0.002
    enc = np.arange(3) * 1e-3
    gyro = np.array([[1.0, 2.0, 3.0], [1.5, 2.0, 3.0], [1.0, 2.5, 3.0]]) * 1e-4
    accel = np.tile([0.0, 0.0, 9.8 * 0.002], (3, 1))
    q = Quanta.of(enc, gyro, accel, resolution=COUNT)
    assert np.array_equal(q.pulses, np.zeros(6)) and q.count == COUNT
    assert assess(RawLog(t, gyro, accel, enc, {})).findings == ()
