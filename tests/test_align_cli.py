"""``hse-opt align``: raw logs (npz, CSV increments, CSV pulse counts) -> RUNS.csv, and bad logs.

References: the simulator's true attitude and commanded rate (not the processor's output),
the generated log's own arrays for the pulse-count form, and hand-made defects at known
sample indices.
"""
import json
import shutil

import numpy as np
import pytest

from hse_opt import units
from hse_opt.app.cli import main
from hse_opt.data import load_runs
from hse_opt.align import save_calibration
from hse_opt.align.rawlog import check_rawlog
from hse_opt.sim import RunSpec, TruthConfig, generate, lab_calibration, load_rawlog, save_rawlog, true_attitude

TRUTH = TruthConfig.default()
RUNS_SPEC = [  # (rate deg/s, stand azimuth deg, position, surveyed)
    (20.0, 30.0, "A", False), (40.0, 30.0, "A", False), (-40.0, 30.0, "A", False), (40.0, 120.0, "B", True)]


@pytest.fixture(scope="module")
def logdir(tmp_path_factory):
    d = tmp_path_factory.mktemp("logs")
    truths = []
    for i, (rate, az, pos, surveyed) in enumerate(RUNS_SPEC):
        spec = RunSpec(rate=rate * units.DEG_PER_S, azimuth=np.radians(az), duration=30.0, t_start=900.0 + 60 * i)
        log = generate(TRUTH, spec, np.random.default_rng(i))
        meta = {**log.meta, "position": pos, "run": 10 + i}
        if not surveyed:
            del meta["azimuth_deg"]
        object.__setattr__(log, "meta", meta)
        kw = {"pulse_weights": (TRUTH.gyro.pulse, TRUTH.accel.pulse)} if i == 1 else {}
        save_rawlog(log, d / (f"r{i}.csv" if i == 1 else f"r{i}.npz"), **kw)
        truths.append((log, true_attitude(TRUTH, spec)))
    return d, truths


def test_pulse_count_csv_reads_back_the_generated_increments(logdir):
    d, truths = logdir
    log = truths[1][0]
    back = load_rawlog(d / "r1.csv")
    assert np.array_equal(back.t, log.t)
    # the generated increments are whole pulses; counts x weight give them back to rounding
    assert np.allclose(back.gyro, log.gyro, rtol=1e-12, atol=0)
    assert np.allclose(back.accel, log.accel, rtol=1e-12, atol=0)
    assert back.meta["gyro_pulse_arcsec"] == pytest.approx([TRUTH.gyro.pulse / units.ARCSEC] * 3)


def test_align_writes_one_row_per_log_with_metadata(logdir, tmp_path, capsys):
    d, truths = logdir
    out = tmp_path / "RUNS.csv"
    save_calibration(lab_calibration(TRUTH), tmp_path / "CAL.toml")
    assert main(["align", str(d), "-o", str(out), "--jobs", "2", "--calibration", str(tmp_path / "CAL.toml"),
                 "--no-progress"]) == 0
    runs = load_runs(out)
    assert runs.run.tolist() == [10, 11, 12, 13]
    assert runs.position.tolist() == ["A", "A", "A", "B"]
    assert runs.surveyed.tolist() == [False, False, False, True]
    for i, (rate, az, _, _) in enumerate(RUNS_SPEC):
        log, att = truths[i]
        assert runs.rate[i] / units.DEG_PER_S == pytest.approx(rate, rel=1e-3)      # from the encoder
        assert runs.duration[i] == pytest.approx(log.t[-1] - log.t[0], abs=1e-6)    # the span of its samples
        assert runs.duration[i] == pytest.approx(30.0 - 0.002, abs=1e-6)            # n - 1 intervals of 2 ms
        assert runs.t_start[i] == pytest.approx(900.0 + 60 * i)
        # the alignment against the simulator's true attitude of b0, within 5 of its own sigmas
        dh = (runs.heading[i] - att["heading"] + np.pi) % (2 * np.pi) - np.pi
        assert abs(dh) < 5 * runs.heading_std[i] + 30 * units.ARCSEC
        assert abs(runs.pitch[i] - att["pitch"]) < 20 * units.ARCSEC
        assert abs(runs.roll[i] - att["roll"]) < 20 * units.ARCSEC
    # the surveyed log: heading minus the stand reading
    assert runs.heading_err[3] == pytest.approx(runs.heading[3] - np.radians(120.0), abs=1e-9)
    assert "4 of 4 logs aligned" in capsys.readouterr().err


def _bad(d, tmp_path, name, edit):
    """Copy the good logs and break one of them with ``edit(path)``."""
    work = tmp_path / "logs"
    shutil.copytree(d, work)
    edit(work / name)
    return work


def _rewrite(path, **change):
    z = dict(np.load(path))
    for k, fun in change.items():
        z[k] = fun(np.array(z[k]))
    np.savez(path, **z)


def _set(index, value, column=None):
    def fun(a):
        if column is None:
            a[index] = value
        else:
            a[index, column] = value
        return a
    return fun


@pytest.mark.parametrize("name, edit, expected", [
    ("r2.npz", lambda p: p.write_bytes(p.read_bytes()[:200000]), "r2.npz: is truncated"),
    ("r1.csv", lambda p: p.write_text(p.read_text()[:-30]), "r1.csv: .*sample index 14999 .*truncated"),
    ("r0.npz", lambda p: _rewrite(p, gyro_rad=_set(4321, np.nan, 1)), "r0.npz: .*not finite.*sample index 4321"),
    ("r0.npz", lambda p: _rewrite(p, t_s=lambda t: np.where(np.arange(t.size) >= 777, t + 0.05, t)),
     "r0.npz: .*gap before sample index 777"),
    ("r3.npz", lambda p: _rewrite(p, accel_mps=_set(slice(None), 0.0, 2)), "r3.npz: .*accel_z is zero in every sample"),
    ("r3.npz", lambda p: _rewrite(p, gyro_rad=lambda g: g / units.DEG), "r3.npz: .*gyro_rad and encoder_rad disagree.*ratio 57"),
    ("r0.npz", lambda p: _rewrite(p, accel_mps=lambda a: a / 9.80665), "r0.npz: .*specific force is 0.99.*about 1 is g s"),
])
def test_a_bad_log_is_named_and_the_others_still_written(logdir, tmp_path, capsys, name, edit, expected):
    d, _ = logdir
    work = _bad(d, tmp_path, name, edit)
    out = tmp_path / "RUNS.csv"
    assert main(["align", str(work), "-o", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if "error:" in ln]
    assert len(lines) == 1
    import re
    assert re.search(expected, lines[0]), lines[0]
    assert "3 of 4 logs aligned" in err and "1 bad log" in err
    assert len(load_runs(out)) == 3


def test_pulse_counts_need_their_weights_and_whole_numbers(logdir, tmp_path):
    d, _ = logdir
    work = _bad(d, tmp_path, "r1.csv", lambda p: None)
    meta = json.loads((work / "r1.csv.json").read_text())
    del meta["gyro_pulse_arcsec"]
    (work / "r1.csv.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="r1.csv: pulse counts need the pulse weight 'gyro_pulse_arcsec'"):
        load_rawlog(work / "r1.csv")
    lines = (d / "r1.csv").read_text().splitlines()
    fields = lines[6].split(",")
    fields[2] = fields[2] + ".5"
    lines[6] = ",".join(fields)
    (work / "r1.csv").write_text("\n".join(lines) + "\n")
    (work / "r1.csv.json").write_text((d / "r1.csv.json").read_text())
    with pytest.raises(ValueError, match="sample index 5, column gyro_y_pulses: .* not a whole number"):
        load_rawlog(work / "r1.csv")


def test_simulated_logs_pass_the_real_log_checks(logdir):
    _, truths = logdir
    for log, _ in truths:
        check_rawlog(log)          # no exception: generated logs have the units and channels


def test_no_log_aligned_writes_nothing(tmp_path, capsys):
    (tmp_path / "x.npz").write_bytes(b"not a zip")
    out = tmp_path / "RUNS.csv"
    assert main(["align", str(tmp_path / "x.npz"), "-o", str(out), "--no-progress"]) == 2
    assert not out.exists() and "nothing written" in capsys.readouterr().err
    assert main(["align", str(tmp_path / "missing.npz"), "-o", str(out)]) == 2


def test_aligned_repeats_of_one_setting_are_replicates(tmp_path):
    """Runs aligned from raw logs carry the rate measured by the encoder, which differs from
    repeat to repeat (the table's ripple, the encoder's steps); repeats of one commanded
    setting are still one replicate group, and the two settings two."""
    from hse_opt.fit import replicate_groups
    d = tmp_path / "logs"
    d.mkdir()
    for i, rate in enumerate((40.0, 40.0, 40.0, -40.0, -40.0)):
        spec = RunSpec(rate=rate * units.DEG_PER_S, azimuth=np.radians(30.0), duration=20.0, t_start=900.0 + 30 * i)
        log = generate(TRUTH, spec, np.random.default_rng(100 + i))
        object.__setattr__(log, "meta", {**log.meta, "run": i})
        save_rawlog(log, d / f"r{i}.npz")
    out = tmp_path / "RUNS.csv"
    assert main(["align", str(d), "-o", str(out), "--no-progress"]) == 0
    runs = load_runs(out)
    assert len(set(runs.rate.tolist())) == 5                    # five different measured rates
    labels, groups = replicate_groups(runs)
    assert groups == 2 and len(set(labels[:3])) == 1 and len(set(labels[3:])) == 1


def test_align_on_a_dask_scheduler_gives_the_rows_of_one_local_process(logdir, tmp_path, capsys):
    """``--dask ADDRESS`` (issue 26 item 4): a scheduler with worker processes, reached by its
    address; the RUNS.csv is byte-identical to ``--jobs 1``'s."""
    distributed = pytest.importorskip("distributed")
    d, _ = logdir
    serial, remote = tmp_path / "serial.csv", tmp_path / "remote.csv"
    assert main(["align", str(d), "-o", str(serial), "--jobs", "1", "--no-progress"]) == 0
    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                                  dashboard_address=None) as cluster:
        assert main(["align", str(d), "-o", str(remote), "--no-progress",
                     "--dask", cluster.scheduler_address]) == 0
    assert remote.read_bytes() == serial.read_bytes()


@pytest.mark.parametrize("command", ["align", "simulate"])
def test_a_dask_address_that_does_not_connect_names_the_option(logdir, tmp_path, capsys, command):
    d, _ = logdir
    first = str(d) if command == "align" else str(tmp_path / "PLAN.csv")
    if command == "simulate":
        (tmp_path / "PLAN.csv").write_text("run,rate_dps,azimuth_deg,t_start_s,duration_s\n1,40,0,0,60\n")
    status = main([command, first, "-o", str(tmp_path / "out.csv"), "--no-progress", "--dask", "not an address"])
    err = capsys.readouterr().err
    assert status == 2 and "--dask not an address" in err and "allowed:" in err, err
    assert not (tmp_path / "out.csv").exists()


def test_the_quality_column_align_writes_is_no_news_to_the_fit(logdir, tmp_path, capsys):
    """RUNS.csv from ``hse-opt align`` carries its own ``quality`` text column: kept as
    metadata without the 'column is text' note (which a user's own text column still gets)."""
    d, _ = logdir
    out = tmp_path / "RUNS.csv"
    assert main(["align", str(d), "-o", str(out), "--no-progress"]) == 0
    runs = load_runs(out)
    assert "quality" in runs.metadata
    assert not [n for n in runs.notes if "'quality'" in n]
    text = out.read_text().splitlines()
    other = tmp_path / "OTHER.csv"
    other.write_text("\n".join([text[0] + ",operator"] + [line + ",ann" for line in text[1:]]) + "\n")
    assert [n for n in load_runs(other).notes if "'operator' is text" in n]


def test_align_without_a_calibration_says_once_what_it_assumed(logdir, tmp_path, capsys):
    """No --calibration: one note line on stderr (the orthogonal, perfectly mounted IMU and how
    to give the file) and the report says it too; with --calibration no such note, and the
    filter's noise source line names the file's figures."""
    d, _ = logdir
    assert main(["align", str(d), "-o", str(tmp_path / "A.csv"), "--no-progress", "--report",
                 str(tmp_path / "rep")]) == 0
    err = capsys.readouterr().err.splitlines()
    notes = [line for line in err if "assumed an orthogonal, perfectly mounted IMU" in line]
    assert len(notes) == 1 and notes[0].startswith("hse-opt align: note: no --calibration:"), err
    assert "--calibration CALIBRATION.toml" in notes[0]
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "assumed an orthogonal, perfectly mounted IMU" in page
    assert "gyro ARW: data; accel VRW: data" in page
    save_calibration(lab_calibration(TRUTH), tmp_path / "CAL.toml")
    assert main(["align", str(d), "-o", str(tmp_path / "B.csv"), "--no-progress", "--calibration",
                 str(tmp_path / "CAL.toml")]) == 0
    err = capsys.readouterr().err
    assert "assumed an orthogonal" not in err
    assert "the filter's noise: gyro ARW: file; accel VRW: file; gyro quantum: file; accel quantum: file" in err
    assert set(load_runs(tmp_path / "B.csv").metadata["noise_source"]) == {
        "gyro ARW: file; accel VRW: file; gyro quantum: file; accel quantum: file"}
