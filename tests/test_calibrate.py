"""``hse-opt calibrate``: the field session end to end on simulated raw logs (the simulator's
truth is the reference), for a surveyed, a field and a mixed campaign with a hidden effect
(a 400-us encoder sync delay the paper's model lacks); the exported C run on its test
vectors; the report in the real browser; ``--watch`` fed one log at a time."""
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from browser import render
from hse_opt import cli, units
from hse_opt.data import Plan, load_plan
from hse_opt.fit import load_fit
from hse_opt.align import save_calibration
from hse_opt.sim import TruthConfig, run_campaign
from hse_opt.sim.campaign import lab_calibration

COMPILER = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
DELAY_US = 400.0
TRUTH = TruthConfig.default().updated({"encoder": {"sync_delay_us": DELAY_US}})
LAMBDA2 = sum(TRUTH.gyro.eps) / units.ARCSEC          # the simulated system's true lambda2, arcsec
RATES = (20.0, 40.0, 60.0, -40.0)
HEADINGS = (0.0, 120.0, 240.0)
DURATION_S = 120.0
CALIBRATION = None          # the lab calibration file (set by a fixture)


def _plan():
    rows = [(r, h, f"P{k + 1}") for k, h in enumerate(HEADINGS) for r in RATES]
    n = len(rows)
    rate, az, pos = zip(*rows)
    return Plan.from_columns({"run": np.arange(1, n + 1), "rate_dps": rate, "azimuth_deg": az,
                              "t_start_s": 3600.0 + 200.0 * np.arange(n), "duration_s": np.full(n, DURATION_S),
                              "position": list(pos)}, source="test plan")


@pytest.fixture(scope="module")
def campaigns(tmp_path_factory):
    """Raw logs of the three campaigns: {kind: folder}; and the system's lab calibration
    file (what ``hse-opt simulate --write-calibration`` writes) under ``"calibration"``."""
    out = {}
    for kind, field, surveyed in (("surveyed", False, ()), ("field", True, ()), ("mixed", True, ("P1",))):
        folder = tmp_path_factory.mktemp(kind)
        run_campaign(_plan(), TRUTH, 5, field=field, surveyed=surveyed, raw_logs=folder)
        out[kind] = folder
    out["calibration"] = tmp_path_factory.mktemp("lab") / "CALIBRATION.toml"
    save_calibration(lab_calibration(TRUTH), out["calibration"])
    return out


@pytest.fixture(autouse=True)
def _lab_calibration(campaigns):
    global CALIBRATION
    CALIBRATION = str(campaigns["calibration"])


def _calibrate(args, capsys, calibration=True):
    extra = ["--calibration", CALIBRATION] if calibration else []
    status = cli.main(["calibrate", *map(str, args), "--no-progress", *extra])
    out = capsys.readouterr()
    return status, out.out, out.err


def _listing(folder):
    return sorted(os.listdir(folder))


@pytest.mark.parametrize("kind", ["surveyed", "field", "mixed"])
def test_each_campaign_end_to_end_finds_the_hidden_effect(kind, campaigns, tmp_path, capsys):
    logs = campaigns[kind]
    before = {f: (logs / f).read_bytes() for f in _listing(logs)}
    out = tmp_path / "session"
    status, stdout, err = _calibrate([logs, "--out", out, "--json", "--time-left-h", "1"], capsys)
    assert status == 0, err
    data = json.loads(stdout)
    assert data == json.loads((out / "summary.json").read_text())    # --json prints summary.json
    assert data["campaign"] == kind
    assert data["n_logs"] == data["n_runs"] == 12 and data["bad_logs"] == []
    assert "sync_delay" in data["effects"] and data["diagnosis"]["added"] == ["sync_delay"]
    p = data["parameters"]
    for name, truth in (("delay", DELAY_US), ("lambda2", LAMBDA2)):
        assert abs(p[name]["value"] - truth) < 3.5 * p[name]["std"], (name, p[name])
        assert set(p[name]) >= {"value", "std", "systematic", "unit"}
    assert p["offset"]["free"] is (kind != "field")      # no reference anywhere: offset not estimable
    assert data["verdict"] in ("usable", "not yet") and (data["verdict"] == "usable") == (not data["reasons"])
    # the files: all of them, consistent with the summary
    assert _listing(out) == ["FIT.json", "NEXT_PLAN.csv", "RUNS.csv", "nav", "report.html", "summary.json"]
    fit = load_fit(out / "FIT.json")
    assert fit.value("lambda2")[0] == pytest.approx(p["lambda2"]["value"], rel=1e-12)
    plan = load_plan(out / "NEXT_PLAN.csv", min_rate_dps=0.0, allow_small_azimuths=True)
    assert len(plan) == data["next"]["n_runs"] > 0
    assert plan.rate[0] / units.DEG_PER_S == pytest.approx(data["next"]["next"]["rate_dps"])
    assert plan.t_start[-1] + plan.duration[-1] <= 3600.0 + 200.0 * 11 + DURATION_S + units.HOUR + 1e-6
    assert {"hse_compensation.c", "hse_compensation.h", "calibration.json", "test_vectors.csv",
            "test_hse_compensation.c"} <= set(os.listdir(out / "nav"))
    assert {f: (logs / f).read_bytes() for f in _listing(logs)} == before      # inputs untouched


def test_the_runs_are_what_hse_opt_align_writes_with_the_same_processor(campaigns, tmp_path, capsys):
    """Without a calibration file both take the orthogonal system and tune the filter from the
    logs' pooled noise: the session's RUNS.csv is align's, byte for byte."""
    logs = campaigns["field"]
    status, _, err = _calibrate([logs, "--out", tmp_path / "s"], capsys, calibration=False)
    assert status == 0
    assert cli.main(["align", str(logs), "-o", str(tmp_path / "R.csv"), "--no-progress"]) == 0
    err_align = capsys.readouterr().err
    assert (tmp_path / "s" / "RUNS.csv").read_bytes() == (tmp_path / "R.csv").read_bytes()
    page = (tmp_path / "s" / "report.html").read_text()
    assert "gyro ARW" in page and "quality" in page        # the noise and the quality of the logs
    # what was assumed without the file: once on stderr for each command, in the report and summary.json
    for text, command in ((err, "calibrate"), (err_align, "align")):
        notes = [line for line in text.splitlines() if "no --calibration: assumed an orthogonal" in line]
        assert len(notes) == 1 and notes[0].startswith(f"hse-opt {command}: note:"), text
        assert "--calibration CALIBRATION.toml" in notes[0]
    data = json.loads((tmp_path / "s" / "summary.json").read_text())
    assert [n for n in data["notes"] if n.startswith("no --calibration: assumed an orthogonal")]
    assert "no --calibration: assumed an orthogonal" in page
    assert "the filter's noise: gyro ARW: data; accel VRW: data; gyro quantum: data; accel quantum: data" in \
        "\n".join(data["notes"])


def test_text_output_starts_with_the_verdict(campaigns, tmp_path, capsys):
    status, stdout, err = _calibrate([campaigns["surveyed"], "--out", tmp_path / "s", "--target-sigma", "0.01"],
                                     capsys)
    assert status == 0, err
    assert "no --calibration" not in err                    # the file given: nothing assumed
    first = stdout.splitlines()[0]
    assert first.startswith("hse-opt calibrate: Verdict: NOT YET")
    assert "above the target 0.01 arcsec" in first          # an unreachable target is the reason
    data = json.loads((tmp_path / "s" / "summary.json").read_text())
    assert data["verdict"] == "not yet" and data["target"]["target_sigma"] == 0.01


@pytest.mark.skipif(COMPILER is None, reason="no C compiler (cc, gcc or clang) on PATH")
def test_exported_c_agrees_with_its_test_vectors_and_the_driver_can_fail(campaigns, tmp_path, capsys):
    out = tmp_path / "s"
    assert _calibrate([campaigns["mixed"], "--out", out], capsys)[0] == 0
    nav = out / "nav"
    exe = tmp_path / "t"
    subprocess.run([COMPILER, "-std=c99", "-O2", "-Wall", "-o", str(exe), str(nav / "test_hse_compensation.c"),
                    str(nav / "hse_compensation.c"), "-lm"], check=True, capture_output=True)
    ran = subprocess.run([str(exe), str(nav / "test_vectors.csv")], capture_output=True, text=True, timeout=60)
    lines = (nav / "test_vectors.csv").read_text().splitlines()
    n = len(lines) - 1
    assert ran.returncode == 0 and ran.stdout.strip() == f"{n} of {n} test vectors agree"
    head = lines[0].split(",")
    rows = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])
    status = rows[:, head.index("status")].astype(int)
    assert (status == 0).sum() >= 8                                    # inside the validity domain
    assert (status[8:] != 0).all() and status[8:].size >= 4            # |rate|, C23, limits outside
    assert status[8] == 1                                               # |rate|: bit 0 alone
    # the expected correction is minus the model's heading error at the runs' inputs:
    # at the first run (the first vector) it equals compensate's column for that run
    from hse_opt.fit.correction import compensation
    from hse_opt.data import load_runs
    runs = load_runs(out / "RUNS.csv")
    corr, std = compensation(runs, load_fit(out / "FIT.json"))
    order = np.argsort(runs.t_start)
    assert rows[0, head.index("correction_rad")] == pytest.approx(-corr[order[0]], rel=1e-12)
    assert rows[0, head.index("sigma_rad")] == pytest.approx(std[order[0]], rel=1e-12)
    # a vector the target gets wrong is reported and fails the driver
    bad = lines[:2] + [",".join(lines[2].split(",")[:-4] + ["0.001", "0", "0", "0"])] + lines[3:]
    (tmp_path / "bad.csv").write_text("\n".join(bad) + "\n")
    ran = subprocess.run([str(exe), str(tmp_path / "bad.csv")], capture_output=True, text=True, timeout=60)
    assert ran.returncode == 1 and ran.stdout.splitlines()[-1] == f"{n - 1} of {n} test vectors agree"


def test_a_bad_log_is_left_out_and_named(campaigns, tmp_path, capsys):
    logs = tmp_path / "logs"
    shutil.copytree(campaigns["surveyed"], logs)
    data = (logs / "run_3.npz").read_bytes()
    (logs / "run_3.npz").write_bytes(data[: len(data) // 3])          # truncated
    status, stdout, err = _calibrate([logs, "--out", tmp_path / "s", "--json"], capsys)
    assert status == 0
    summary = json.loads(stdout)
    assert summary["n_runs"] == 11 and len(summary["bad_logs"]) == 1
    assert "run_3.npz" in summary["bad_logs"][0] and "run_3.npz" in err


def test_no_good_log_is_bad_input_and_writes_nothing(tmp_path, capsys):
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "x.npz").write_bytes(b"not a log")
    status, stdout, err = _calibrate([logs, "--out", tmp_path / "s"], capsys)
    assert status == 2 and "x.npz" in err and err.count("\n") == 1
    assert not (tmp_path / "s").exists()
    status, _, err = _calibrate([tmp_path / "empty_nothing", "--out", tmp_path / "s"], capsys)
    assert status == 2 and "empty_nothing" in err and "allowed" in err
    status, _, err = _calibrate([logs, "--out", tmp_path / "s", "--time-left-h", "-1"], capsys)
    assert status == 2 and "--time-left-h" in err and "allowed" in err


def test_the_report_renders_in_chromium_with_the_verdict_first(campaigns, tmp_path, capsys):
    out = tmp_path / "s"
    assert _calibrate([campaigns["field"], "--out", out], capsys)[0] == 0
    page = (out / "report.html").read_text()
    summary = page.index('class="summary"')
    assert page.index("Verdict: ", summary) < page.index("<section")
    for title in ("The calibration", "The evidence", "Raw logs", "The C interface", "The next plan"):
        assert f">{title}" in page
    probe, pixels = render(out / "report.html", tmp_path)
    assert probe["images"] >= 5 and probe["decoded"] == probe["images"]
    assert probe["sections"] >= 6


def test_the_next_plans_sigma_says_its_model_and_the_report_fits_the_page(tmp_path, capsys):
    """The README's session (three positions, only A surveyed, 2 h left): the plan's sigma of
    lambda2 is in the fit's model with the fit's weights, so it starts from the fit's own
    statistical sigma (summary.json's), and the line says what the plan protects against; the
    raw-log table lists run_1 ... run_12 in natural order; nothing in the report is wider than
    the browser's page."""
    import re

    from browser import WIDTH

    truth = TruthConfig.default()
    rows = [(r, h, p) for p, h in (("A", 0.0), ("B", 131.0), ("C", 250.0)) for r in (20.0, 60.0, -40.0, -60.0)]
    rate, az, pos = zip(*rows)
    plan = Plan.from_columns({"run": np.arange(1, 13), "rate_dps": rate, "azimuth_deg": az,
                              "t_start_s": 3600.0 + 200.0 * np.arange(12), "duration_s": np.full(12, 120.0),
                              "position": list(pos)}, source="README plan")
    logs = tmp_path / "logs"
    logs.mkdir()
    run_campaign(plan, truth, 2, field=True, surveyed=("A",), raw_logs=logs)
    save_calibration(lab_calibration(truth), tmp_path / "CAL.toml")
    out = tmp_path / "s"
    status = cli.main(["calibrate", str(logs), "--out", str(out), "--calibration", str(tmp_path / "CAL.toml"),
                       "--time-left-h", "2", "--no-progress"])
    stdout = capsys.readouterr().out
    assert status == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["next"]["effects"] == summary["effects"]     # one model: the fit's
    std = summary["parameters"]["lambda2"]["std"]
    assert summary["next"]["sigma_now"] == pytest.approx(std, rel=1e-3)
    line = next(ln for ln in stdout.splitlines() if "takes sigma(lambda2)" in ln)
    assert f"from {summary['next']['sigma_now']:.3g} to" in line, line
    # the plan is the protected continuation (design --field --runs): what it protects, said
    guarded = [p["effect"] for p in summary["next"]["protection"] if p["protected"]]
    assert summary["next"]["criterion"] == "protect:lambda2" and guarded
    assert f"(statistical; the diagnosis would see {', '.join(guarded)} with power >= 0.8)" in line, line
    assert f"+- {std:.3g} arcsec (statistical, 1-sigma)" in stdout
    # one precision in the box: the verdict's sentence and the line below give lambda2's sigma alike
    assert f"lambda2 = {summary['parameters']['lambda2']['value']:.4g} +- {std:.3g} arcsec statistical" in stdout
    page = (out / "report.html").read_text()
    logs_section = page[page.index("<h2>Raw logs"):]
    keys = re.findall(r'data-key="(run_\d+)\.npz"', logs_section[:logs_section.index("</table>")])
    assert keys == [f"run_{i}" for i in range(1, 13)]
    probe, _ = render(out / "report.html", tmp_path)
    assert probe["width"] <= WIDTH, probe["width"]


# -- the live session -------------------------------------------------------------------------
def _readline(proc, timeout):
    """One line of ``proc``'s stdout within ``timeout`` s (None at the end)."""
    import selectors
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    if not sel.select(timeout):
        raise AssertionError(f"no line within {timeout} s")
    line = proc.stdout.readline()
    return line or None


def test_watch_reads_each_new_log_once_whole_and_stops_on_ctrl_c(campaigns, tmp_path):
    src = campaigns["mixed"]
    names = sorted(os.listdir(src), key=lambda f: int(f.split("_")[1].split(".")[0]))
    logs, out = tmp_path / "logs", tmp_path / "session"
    logs.mkdir()
    for f in names[:3]:
        shutil.copy(src / f, logs / f)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen([sys.executable, "-m", "hse_opt.cli", "calibrate", str(logs), "--out", str(out),
                             "--watch", "--poll-s", "0.2", "--time-left-h", "2", "--calibration", CALIBRATION],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        lines = [_readline(proc, 120)]
        assert lines[0].startswith("[3 runs]"), lines
        for k, f in enumerate(names[3:7], start=4):
            # written slowly in pieces, each well within a poll interval: never read half
            data = (src / f).read_bytes()
            with open(logs / f, "wb") as fh:
                for i in range(4):
                    fh.write(data[i * len(data) // 4:(i + 1) * len(data) // 4])
                    fh.flush()
                    time.sleep(0.05)
            lines.append(_readline(proc, 60))
            assert lines[-1].startswith(f"[{k} runs]"), lines
            assert "; next: " in lines[-1]
        proc.send_signal(signal.SIGINT)       # at once: the report of the 7th log is finished first
        rest, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, err
    assert rest == ""
    assert "interrupted" in err and "complete for the 7 logs" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_runs"] == 7 and summary["bad_logs"] == [] and summary["campaign"] == "mixed"
    assert summary["next"]["next"]["text"] in lines[-1]
    assert sorted(f for f in os.listdir(tmp_path) if f.startswith(".")) == []   # no temporary left


def test_watch_stops_at_the_target(campaigns, tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    done = subprocess.run([sys.executable, "-m", "hse_opt.cli", "calibrate", str(campaigns["field"]), "--out",
                           str(tmp_path / "s"), "--watch", "--poll-s", "0.1", "--target-sigma", "1000",
                           "--calibration", CALIBRATION],
                          capture_output=True, text=True, env=env, timeout=180)
    assert done.returncode == 0, done.stderr
    assert len(done.stdout.splitlines()) == 1 and "usable" in done.stdout
    assert "the target is reached" in done.stderr


def test_calibrate_on_a_dask_scheduler_writes_what_one_local_process_writes(campaigns, tmp_path, capsys):
    """``--dask ADDRESS`` (issue 26 item 4): a scheduler with worker processes, reached by its
    address; RUNS.csv, FIT.json and summary.json are byte-identical to ``--jobs 1``'s."""
    distributed = pytest.importorskip("distributed")
    logs = campaigns["mixed"]
    status, _, err = _calibrate([logs, "--out", tmp_path / "serial", "--jobs", "1", "--time-left-h", "1"], capsys)
    assert status == 0, err
    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                                  dashboard_address=None) as cluster:
        status, _, err = _calibrate([logs, "--out", tmp_path / "remote", "--dask", cluster.scheduler_address,
                                     "--time-left-h", "1"], capsys)
    assert status == 0, err
    for name in ("RUNS.csv", "FIT.json", "NEXT_PLAN.csv"):
        assert (tmp_path / "remote" / name).read_bytes() == (tmp_path / "serial" / name).read_bytes(), name
    # the summary too, but for where it was written and how long each stage took
    a, b = (json.loads((tmp_path / d / "summary.json").read_text()) for d in ("serial", "remote"))
    for d in (a, b):
        for key in ("report", "out", "seconds"):
            d.pop(key)
    assert a == b
