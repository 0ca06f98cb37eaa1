"""Raw-log format: validation with sample indices, files (issue 3, items 2 and 6)."""
import numpy as np
import pytest

from hse_opt.align.rawlog import RawLog, load_rawlog, save_rawlog


def _arrays(n=2000, dt=0.002, rate=0.7):
    t = 100.0 + dt * np.arange(1, n + 1)
    rng = np.random.default_rng(3)
    gyro = rng.normal(0, 1e-3, (n, 3))
    accel = rng.normal(0, 1e-2, (n, 3))
    enc = rate * dt * np.arange(1, n + 1)
    return t, gyro, accel, enc


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("which, col", [("t", None), ("gyro", 1), ("accel", 2), ("encoder", None)])
def test_nan_is_rejected_with_sample_index(which, col, bad):
    t, g, a, e = _arrays()
    arr = {"t": t, "gyro": g, "accel": a, "encoder": e}[which]
    if col is None:
        arr[1234] = bad
    else:
        arr[1234, col] = bad
    with pytest.raises(ValueError, match="sample index 1234"):
        RawLog(t, g, a, e)


def test_non_monotonic_timestamps_are_rejected_with_index():
    t, g, a, e = _arrays()
    t[500] = t[498]
    with pytest.raises(ValueError, match="not strictly increasing at sample index 500"):
        RawLog(t, g, a, e)


def test_gap_is_rejected_with_index():
    t, g, a, e = _arrays()
    t[700:] += 0.01
    with pytest.raises(ValueError, match="gap before sample index 700"):
        RawLog(t, g, a, e)


def test_encoder_jump_is_rejected_with_index():
    t, g, a, e = _arrays()
    e[900:] += 2.0                                   # a 2 rad step: a lost encoder reading
    with pytest.raises(ValueError, match="encoder_rad jumps by 2.* at sample index 900.*allowed < pi/2"):
        RawLog(t, g, a, e)


def test_shape_mismatch_is_rejected():
    t, g, a, e = _arrays()
    with pytest.raises(ValueError, match="gyro_rad has shape"):
        RawLog(t, g[:-1], a, e)


def test_wrapped_encoder_is_unwrapped():
    t, g, a, e = _arrays(n=20000)
    wrapped = np.mod(e, 2 * np.pi)
    log = RawLog(t, g, a, wrapped)
    np.testing.assert_allclose(log.encoder - log.encoder[0], e - e[0], atol=1e-12)


@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_file_round_trip_is_exact(tmp_path, suffix):
    t, g, a, e = _arrays()
    log = RawLog(t, g, a, e, meta={"latitude_deg": 28.07, "rate_dps": 40.0})
    p = tmp_path / f"log{suffix}"
    save_rawlog(log, p)
    back = load_rawlog(p)
    for name in ("t", "gyro", "accel", "encoder"):
        np.testing.assert_array_equal(getattr(back, name), getattr(log, name))
    assert back.meta == log.meta
    assert load_rawlog(p, meta={"latitude_deg": 30.0}).meta["latitude_deg"] == 30.0


def test_bad_file_names_the_file(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("t_s,gyro_x_rad\n0,1\n")
    with pytest.raises(ValueError, match="bad.csv.*header"):
        load_rawlog(p)
    t, g, a, e = _arrays()
    g[42, 0] = np.inf
    p2 = tmp_path / "x.npz"
    np.savez(p2, t_s=t, gyro_rad=g, accel_mps=a, encoder_rad=e)
    with pytest.raises(ValueError, match="x.npz.*sample index 42"):
        load_rawlog(p2)
