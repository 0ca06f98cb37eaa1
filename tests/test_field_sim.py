"""``hse-opt simulate --field``: field campaigns with hidden true headings, and raw logs for
``hse-opt align`` (the chain raw logs -> align -> RUNS.csv).

References: the same campaign simulated as a surveyed one (same seed, same runs: the stand
azimuth the field file hides), and the plan's own columns.
"""
import numpy as np
import pytest

from hse_opt import units
from hse_opt.cli import main
from hse_opt.data import load_plan, load_runs
from hse_opt.sim import TruthConfig, run_campaign

PLAN = """run,rate_dps,azimuth_deg,t_start_s,duration_s,tilt_x_arcsec,tilt_y_arcsec,position
1,20,37,1000,30,100,-50,A
2,-40,37,1100,30,100,-50,A
3,60,37,1200,30,100,-50,A
4,40,150,1400,30,-80,60,B
5,-40,150,1500,30,-80,60,B
"""


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    d = tmp_path_factory.mktemp("field")
    (d / "PLAN.csv").write_text(PLAN)
    (d / "logs").mkdir()
    assert main(["simulate", str(d / "PLAN.csv"), "-o", str(d / "RUNS.csv"), "--field", "--surveyed", "B",
                 "--raw-logs", str(d / "logs"), "--seed", "4", "--no-progress",
                 "--write-calibration", str(d / "CAL.toml")]) == 0
    return d


def test_field_runs_hide_the_unsurveyed_headings(campaign):
    text = (campaign / "RUNS.csv").read_text()
    assert ",37," not in text and ",37\n" not in text          # position A's stand azimuth is nowhere
    runs = load_runs(campaign / "RUNS.csv")
    assert runs.position.tolist() == ["A", "A", "A", "B", "B"]
    assert runs.surveyed.tolist() == [False, False, False, True, True]
    # reference: the same runs simulated with their stand azimuths known
    surveyed = run_campaign(load_plan(campaign / "PLAN.csv"), TruthConfig.default(), seed=4)
    head = runs.heading
    assert np.allclose((head - surveyed.azimuth - surveyed.heading_err + np.pi) % (2 * np.pi) - np.pi, 0,
                       atol=1e-9)
    assert runs.heading_err[3:] == pytest.approx(surveyed.heading_err[3:], abs=1e-12)
    # position A: the heading errors up to one constant -- differences equal the surveyed ones
    assert np.diff(runs.heading_err[:3]) / units.ARCSEC == pytest.approx(
        np.diff(surveyed.heading_err[:3]) / units.ARCSEC, abs=1e-6)


def test_raw_logs_align_back_to_the_same_runs(campaign, tmp_path):
    out = tmp_path / "ALIGNED.csv"
    # the simulated system's lab calibration, as simulate wrote it (without it the processor
    # assumes an orthogonal, perfectly mounted IMU: a different system)
    assert main(["align", str(campaign / "logs"), "-o", str(out), "--no-progress",
                 "--calibration", str(campaign / "CAL.toml")]) == 0
    aligned, simulated = load_runs(out), load_runs(campaign / "RUNS.csv")
    assert aligned.run.tolist() == simulated.run.tolist()
    assert aligned.position.tolist() == simulated.position.tolist()
    assert aligned.surveyed.tolist() == simulated.surveyed.tolist()
    for name in ("heading", "pitch", "roll", "heading_std", "t_start"):
        assert np.allclose(getattr(aligned, name), getattr(simulated, name), rtol=0, atol=1e-9), name
    # the record's length is t_{n-1} - t_0: the first row's increments (no encoder angle at
    # their start) are not used, one 2-ms sample period less than the plan's 30 s
    assert np.allclose(aligned.duration, simulated.duration - 0.002, rtol=0, atol=1e-9)
    # the rate from the encoder: the commanded rate plus the table's own rate error
    assert aligned.rate / simulated.rate == pytest.approx(1.0, abs=1e-4)


def test_field_options_are_checked(campaign, tmp_path, capsys):
    out = str(tmp_path / "R.csv")
    assert main(["simulate", str(campaign / "PLAN.csv"), "-o", out, "--surveyed", "A"]) == 2
    assert "--surveyed" in capsys.readouterr().err
    assert main(["simulate", str(campaign / "PLAN.csv"), "-o", out, "--field", "--surveyed", "Z"]) == 2
    assert "'Z'" in capsys.readouterr().err
    assert main(["simulate", str(campaign / "PLAN.csv"), "-o", out, "--raw-logs", str(tmp_path / "no")]) == 2
    assert "--raw-logs" in capsys.readouterr().err
