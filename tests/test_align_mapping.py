"""Mapping files (hse_opt.align.mapping): a stand's own CSV read without conversion scripts.

References: a simulated native log written here in each example stand's format by hand
(counters that roll over, rates, other axes' signs and order, other encoder sense and zero),
independently of the reader; the native log's own heading; hand-written bad mapping files.
"""
import json

import numpy as np
import pytest

from hse_opt import units
from hse_opt.align.mapping import EXAMPLES, example_mapping, load_mapping, mapping_from_dict, read_mapped
from hse_opt.app.cli import main
from hse_opt.data import load_runs
from hse_opt.sim import RunSpec, TruthConfig, generate, save_rawlog

TRUTH = TruthConfig.default()
META = {"latitude_deg": 28.07, "azimuth_deg": 33.0, "run": 5, "t_start_s": 4250.0}


@pytest.fixture(scope="module")
def native():
    # starts at 4250 s: the stand's 32-bit microsecond tick rolls over at 4294.97 s, mid-run
    spec = RunSpec(rate=-12 * units.DEG_PER_S, azimuth=np.radians(33.0), duration=120.0, t_start=4250.0)
    log = generate(TRUTH, spec, np.random.default_rng(11))
    object.__setattr__(log, "meta", dict(META))
    return log


def _counter_stand_csv(log, path, counts=7_200_000):
    """The native log as example 1's stand writes it (hse_opt/datasets/mappings/counter_stand.toml;
    ``counts``: its encoder's counts per revolution)."""
    tick = np.round(log.t * 1e6).astype(np.int64) % 2**32
    pulses = np.round(log.gyro / (0.1 * units.ARCSEC)).astype(np.int64)
    assert np.allclose(pulses * 0.1 * units.ARCSEC, log.gyro, rtol=1e-12, atol=0)    # whole pulses
    total = (np.cumsum(pulses * [1, -1, 1], axis=0) + 16_000_000) % 2**24          # GY counts about -y
    acc = np.round(log.accel / 1e-4).astype(np.int64)
    res = 2 * np.pi / counts
    enc = np.round(-log.encoder / res).astype(np.int64) % counts                    # counts up turning negatively
    lines = ["Stand 7 raw data", "operator;A. N. Other", "firmware;2,4", "tick_us;GY_total;GX_total;GZ_total;"
             "AX;AY;AZ;table_counts;supply_V"]
    for k in range(len(log)):
        lines.append(f"{tick[k]};{total[k, 1]};{total[k, 0]};{total[k, 2]};{acc[k, 0]};{acc[k, 1]};{acc[k, 2]};"
                     f"{enc[k]};27,9")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _rate_stand_csv(log, path):
    """The native log as example 2's stand writes it (rate_stand.toml): mean rates over each
    interval in deg/h and m/s^2, the stand's y and z the other way, columns z, x, y, the
    angle in degrees from 90 at the zero mark, temperature in kelvin, a text column."""
    t = log.t
    dt = np.diff(t)
    dt = np.concatenate((dt[:1], dt))
    flip = np.array([1.0, -1.0, -1.0])
    w = log.gyro * flip / dt[:, None] / units.DEG_PER_H
    f = log.accel * flip / dt[:, None]
    temp_k = 300.15 + 0.3 * (t - t[0]) / (t[-1] - t[0])
    deg = np.degrees(log.encoder) + 90.0
    rows = ["time_ms,status,wz_dph,wx_dph,wy_dph,fz_mps2,fx_mps2,fy_mps2,table_deg,imu_temp_K"]
    for k in range(len(log)):
        rows.append(f"{t[k] * 1e3:.17g},OK,{w[k, 2]:.17g},{w[k, 0]:.17g},{w[k, 1]:.17g},{f[k, 2]:.17g},"
                    f"{f[k, 0]:.17g},{f[k, 1]:.17g},{deg[k]:.17g},{temp_k[k]:.17g}")
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")


@pytest.mark.parametrize("name", EXAMPLES)
def test_the_example_mappings_load(name):
    m = load_mapping(example_mapping(name))
    assert len(m.columns) == (9 if name == "rate_stand" else 8)


@pytest.mark.parametrize("name, write", [("counter_stand", _counter_stand_csv), ("rate_stand", _rate_stand_csv)])
def test_a_stand_csv_gives_the_native_logs_heading(native, tmp_path, name, write, capsys):
    save_rawlog(native, tmp_path / "native.npz")
    stand = tmp_path / "stand"
    stand.mkdir()
    write(native, stand / "run5.csv")
    (stand / "run5.csv.json").write_text(json.dumps(META))
    mapped = read_mapped(stand / "run5.csv", example_mapping(name))
    log = mapped.log
    assert np.allclose(log.t, native.t, rtol=0, atol=1e-9)
    # each channel contiguous, as the quality checks' compiled passes read them
    assert all(np.asarray(a).T.strides[-1] == 8 for a in (log.gyro, log.accel, log.t, log.encoder))
    # counters give no increment for the first row (the processor does not use it)
    first = 1 if name == "counter_stand" else 0
    assert not first or not log.gyro[0].any()
    assert np.allclose(log.gyro[first:], native.gyro[first:], rtol=1e-9, atol=1e-15)
    assert np.allclose(log.accel, native.accel, rtol=1e-9, atol=1e-15)
    # the same angle up to whole turns (a single-turn reading unwrapped from its first sample)
    turns = (log.encoder - native.encoder) / (2 * np.pi)
    assert np.allclose(turns, np.round(turns[0]), rtol=0, atol=1e-9)
    assert log.meta["run"] == 5 and log.meta["azimuth_deg"] == 33.0
    if name == "rate_stand":
        assert mapped.temperature[0] == pytest.approx(27.0) and log.meta["temp_c"] == pytest.approx(27.15)
    else:
        assert log.meta["source"].startswith("counter stand")
    # the encoder's resolution, the quality checks' quantum, when the mapping gives it (counts)
    assert log.meta.get("encoder_counts_per_rev") == (7_200_000 if name == "counter_stand" else None)

    out_n, out_s = tmp_path / "RUNS_native.csv", tmp_path / "RUNS_stand.csv"
    assert main(["align", str(tmp_path / "native.npz"), "-o", str(out_n), "--no-progress"]) == 0
    assert main(["align", str(stand), "--mapping", example_mapping(name), "-o", str(out_s), "--no-progress"]) == 0
    a, b = load_runs(out_n), load_runs(out_s)
    assert abs(a.heading[0] - b.heading[0]) < 1e-6 * units.ARCSEC
    assert abs(a.heading_err[0] - b.heading_err[0]) < 1e-6 * units.ARCSEC
    quality = b.metadata["quality"][0]
    if name == "rate_stand":        # 0.3 K over the run: below the drift that is noted
        assert quality == "ok"


BASE = {"time": {"column": "t", "unit": "s"},
        "gyro": {"columns": ["gx", "gy", "gz"], "unit": "rad"},
        "accel": {"columns": ["ax", "ay", "az"], "unit": "m/s"},
        "encoder": {"column": "enc", "unit": "rad"}}


@pytest.mark.parametrize("change, message", [
    ({"gyro": {"unit": "rpm"}},
     "key 'gyro.unit' = 'rpm'; allowed: rad, mrad, deg, arcsec, pulses, rad/s, deg/s, deg/h"),
    ({"gyro": {"unit": "pulses"}}, "key 'gyro.pulse_arcsec' = None; allowed: one positive number or three"),
    ({"gyro": {"pulse_arcsec": 0.1}}, "key 'gyro.pulse_arcsec' = 0.1; allowed: only with unit = \"pulses\""),
    ({"gyro": {"columns": ["gx", "gy"]}}, "key 'gyro.columns' = ['gx', 'gy']; allowed: three column names"),
    ({"gyro": {"signs": [1, 0, 1]}}, "key 'gyro.signs' = [1, 0, 1]; allowed: three of +1 or -1"),
    ({"gyro": {"colums": ["a"]}}, "key 'gyro.colums' is not known; allowed: columns, cumulative"),
    ({"encoder": {"unit": "counts"}}, "key 'encoder.counts_per_rev' = None; allowed: a positive number"),
    ({"encoder": {"sign": 2}}, "key 'encoder.sign' = 2; allowed: +1 or -1"),
    ({"time": {"unit": "counts"}}, "key 'time.counts_per_s' = None; allowed: a positive number"),
    ({"file": {"decimal": ","}}, "key 'file.decimal' = ','; allowed: \".\" when the delimiter is \",\""),
    ({"file": {"header_line": 0}}, "key 'file.header_line' = 0; allowed: an integer >= 1"),
    ({"accel": {"columns": ["ax", "ay", "gx"]}},
     "key 'accel.columns' names column 'gx' again (also in 'gyro.columns')"),
    ({"gyros": {}}, "section 'gyros' is not known; allowed: file, time, gyro, accel"),
    ({"accel": {"unit": "m/s^2", "cumulative": True}}, "key 'accel.cumulative' = True; allowed: false for a rate unit"),
])
def test_a_bad_mapping_names_the_file_the_key_and_what_is_allowed(change, message):
    d = {k: dict(v) for k, v in BASE.items()}
    for sec, kv in change.items():
        d.setdefault(sec, {}).update(kv)
    with pytest.raises(ValueError) as err:
        mapping_from_dict(d, source="MAP.toml")
    assert str(err.value).startswith("MAP.toml: " + message), str(err.value)


def test_a_missing_key_is_named():
    d = {k: dict(v) for k, v in BASE.items()}
    del d["encoder"]["unit"]
    with pytest.raises(ValueError, match=r"^MAP.toml: key 'encoder.unit' is missing"):
        mapping_from_dict(d, source="MAP.toml")


def test_bad_mapping_on_the_command_line_is_one_line_and_exit_2(native, tmp_path, capsys):
    save_rawlog(native, tmp_path / "run.csv")
    bad = tmp_path / "MAP.toml"
    bad.write_text('[time]\ncolumn = "t_s"\nunit = "s"\n[gyro]\ncolumns = ["a", "b", "c"]\nunit = "furlongs"\n'
                   '[accel]\ncolumns = ["d", "e", "f"]\nunit = "m/s"\n[encoder]\ncolumn = "g"\nunit = "rad"\n')
    before = bad.read_bytes()
    assert main(["align", str(tmp_path / "run.csv"), "--mapping", str(bad), "-o", str(tmp_path / "R.csv"),
                 "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{bad}: key 'gyro.unit' = 'furlongs'; allowed: rad," in err[0]
    assert not (tmp_path / "R.csv").exists() and bad.read_bytes() == before


def test_a_csv_that_does_not_fit_the_mapping_names_line_and_column(tmp_path, capsys):
    m = mapping_from_dict(BASE, source="MAP.toml")
    p = tmp_path / "a.csv"
    p.write_text("t,gx,gy,gz,ax,ay,az,enc\n0.002,1,2,3,4,5,6,0\n0.004,1,2,x3,4,5,6,0\n")
    with pytest.raises(ValueError, match=r"a.csv: line 3, column gz: 'x3' is not a number"):
        read_mapped(p, m)
    p.write_text("t,gx,gy,gz,ax,ay,enc\n0.002,1,2,3,4,5,0\n")
    with pytest.raises(ValueError, match=r"a.csv: has no column 'az' \(mapping MAP.toml\)"):
        read_mapped(p, m)


def test_whitespace_columns_comments_and_a_preamble(native, tmp_path):
    """A stand writing whitespace-separated columns under a preamble, with comment lines among
    the data: the rows read are the native log's (increments in arcsec and mm/s, the angle in
    arcsec)."""
    m = mapping_from_dict({"file": {"delimiter": "whitespace", "header_line": 3, "comment": "%"},
                           "time": {"column": "t", "unit": "s"},
                           "gyro": {"columns": ["dx", "dy", "dz"], "unit": "arcsec"},
                           "accel": {"columns": ["vx", "vy", "vz"], "unit": "mm/s"},
                           "encoder": {"column": "angle", "unit": "arcsec"},
                           "meta": {"latitude_deg": 28.07}}, source="MAP.toml")
    n = 20_000
    g, a = native.gyro[:n] / units.ARCSEC, native.accel[:n] * 1e3
    e = native.encoder[:n] / units.ARCSEC
    lines = ["stand 3", "% preamble", "t dx dy dz vx vy vz angle"]
    for k in range(n):
        if k == 500:
            lines.append("% operator note: door opened")
        lines.append(f"{native.t[k]:.17g} {g[k, 0]:.17g} {g[k, 1]:.17g} {g[k, 2]:.17g}   {a[k, 0]:.17g} "
                     f"{a[k, 1]:.17g} {a[k, 2]:.17g}\t{e[k]:.17g}")
    p = tmp_path / "ws.txt"
    p.write_text("\n".join(lines) + "\n")
    log = read_mapped(p, m).log
    assert len(log) == n and log.meta["latitude_deg"] == 28.07
    assert np.allclose(log.gyro, native.gyro[:n], rtol=1e-12, atol=0)
    assert np.allclose(log.accel, native.accel[:n], rtol=1e-12, atol=0)
    assert np.allclose(log.encoder, native.encoder[:n], rtol=1e-12, atol=0)


def test_the_mappings_counts_per_rev_is_the_quality_checks_encoder_quantum(tmp_path):
    """The coarse encoder's 20-s log that studies/quality_false_alarms.py --full refused
    (seed 96: a one-count step taken for a jump) read through a counter stand's mapping of
    64,800 counts per revolution passes clean; the same mapping with a sidecar that says
    another resolution is an error naming both."""
    import sys
    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib
    from hse_opt.align.quality import assess
    coarse = TRUTH.updated({"encoder": {"resolution_arcsec": 20.0}, "table": {"jitter_arcsec": 0.0}})
    spec = RunSpec(rate=0.38780612891539773, azimuth=6.281353087327135, duration=20.0, t_start=4518.478663475609,
                   tilt=(0.0009445359525567823, 0.00034051607364603026))
    log = generate(coarse, spec, np.random.default_rng(96))
    assert assess(log).refused                        # the resolution unknown: the false alarm
    d = tomllib.loads(open(example_mapping("counter_stand"), encoding="utf-8").read())
    d["encoder"]["counts_per_rev"] = 64_800
    m = mapping_from_dict(d, source="coarse.toml")
    _counter_stand_csv(log, tmp_path / "r.csv", counts=64_800)
    mapped = read_mapped(tmp_path / "r.csv", m)
    assert mapped.log.meta["encoder_counts_per_rev"] == 64_800
    q = assess(mapped.log, temperature=mapped.temperature)
    assert q.summary() == "ok"
    (tmp_path / "r.csv.json").write_text(json.dumps({"encoder_counts_per_rev": 7_200_000}))
    with pytest.raises(ValueError, match=r"r.csv: metadata encoder_counts_per_rev = 7200000 and the mapping's "
                                         r"encoder.counts_per_rev = 64800 \(coarse.toml\) differ"):
        read_mapped(tmp_path / "r.csv", m)
