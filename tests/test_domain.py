"""The calibration's validity domain (:mod:`hse_opt.fit.domain`): in the space the model
extrapolates in - |rate| and its senses, C23 (heading and tilt together) - and time only where
a parameter depends on it. The issue's campaign had three positions with alike C23 (-266,
-310, -286 arcsec) and rates 20/40/60/-40 deg/s; the exported C returned status 0 at the
same tilt with the heading 180 deg away (C23 +266..+310) and applied a correction the
calibration never saw. Here: the domain against a hand computation of the documented rule,
the C's status against the Python side bit for bit at points inside and outside, and
``hse-opt compensate`` flagging the rows (a column and one line on stderr)."""
import numpy as np
import pytest

from hse_opt import units
from hse_opt.cli import main as cli
from hse_opt.data import Runs, load_runs, save_runs
from hse_opt.fit import fit, save_fit
from hse_opt.fit.correction import validity_domain
from hse_opt.fit.domain import C23_BIT
from hse_opt.model import Model

from test_export import _build, _call, needs_cc

#: the issue's positions: C23 of each, arcsec, and the stand azimuths they were at
C23_ARCSEC = (-266.0, -310.0, -286.0)
AZIMUTH_DEG = (35.0, 160.0, 250.0)
RATES_DPS = (20.0, 40.0, 60.0, -40.0)


def _runs(rng, c23_arcsec=C23_ARCSEC, azimuth_deg=AZIMUTH_DEG, heading_shift_deg=0.0, repeats=2, truth=None,
          effects=("hse", "sync_delay", "scale_nonlinearity")):
    """Each position at each rate ``repeats`` times: heading errors from the measurement
    model with ``truth`` (default: lambda2 4.2 arcsec, a 300 us delay, 0.2 ppm/(deg/s)) plus
    2 arcsec noise. The tilt of each position is chosen so that C23 is the given value at
    the given azimuth; ``heading_shift_deg`` turns the system on the same tilted base."""
    mm = Model(list(effects)).measurement(True)
    truth = truth or {"offset": 3.0, "lambda2": 4.2, "delay": 300.0, "sf_nonlin": 0.2}
    az0 = np.radians(np.repeat(azimuth_deg, len(RATES_DPS) * repeats))
    c23 = np.repeat(c23_arcsec, len(RATES_DPS) * repeats) * units.ARCSEC
    pitch, roll = c23 * np.sin(az0), -c23 * np.cos(az0)        # -roll cos + pitch sin = c23
    az = az0 + np.radians(heading_shift_deg)
    n = az.size
    rate = np.tile(np.repeat(RATES_DPS, repeats), len(azimuth_deg)) * units.DEG_PER_S
    lat = np.full(n, 28.07 * units.DEG)
    t0 = 600.0 * np.arange(n)
    X = mm.inputs(rate, az, lat, 300.0, t0, pitch, roll, {})
    sigma = 2.0 * units.ARCSEC
    y = mm.predict(mm.vector({k: v for k, v in truth.items() if k in mm.names}), X) + sigma * rng.standard_normal(n)
    return Runs(run=np.arange(1, n + 1), rate=rate, azimuth=np.mod(az, 2 * np.pi), heading_err=y, latitude=lat,
                duration=np.full(n, 300.0), t_start=t0, pitch=pitch, roll=roll, heading_std=np.full(n, sigma))


def test_domain_by_hand(rng):
    """The rule on the issue's campaign, computed here: C23 in [-310 - 30, -266 + 30] arcsec
    (span 44, 10 % is 4.4 < the 30-arcsec floor), |rate| in [20 - 4, 60 + 4] deg/s (span 40,
    10 % is 4 > the 1 deg/s floor), both senses; no time or duration bound for the paper's
    model (no parameter depends on them)."""
    runs = _runs(rng)
    calibration = fit(runs)
    d = validity_domain(calibration)
    assert d.bounded == ("rate", "c23") and d.senses == (1, -1)
    assert d.lower / np.array([units.DEG_PER_S, units.ARCSEC]) == pytest.approx([16.0, -340.0], abs=1e-9)
    assert d.upper / np.array([units.DEG_PER_S, units.ARCSEC]) == pytest.approx([64.0, -236.0], abs=1e-9)
    X = calibration.measurement.inputs_from_runs(runs)
    assert np.all(d.status(X) == 0)
    # the same tilted base, the heading 180 deg away: C23 flips sign -> bit 30 on every run
    turned = calibration.measurement.inputs_from_runs(_runs(rng, heading_shift_deg=180.0))
    assert np.all(d.status(turned) == 1 << C23_BIT)
    assert "C23 +266 arcsec outside [-340, -236]" in d.reasons(turned)[0]
    # no bound on time: a run a day after power-on is inside
    late = X.copy()
    late[5] += 86400.0
    assert np.all(d.status(late) == 0)
    # a rate the runs never had, and a sense: bit 0
    fast = X.copy()
    fast[0] = 64.5 * units.DEG_PER_S
    assert np.all(d.status(fast) == 1)


def test_warmup_bounds_time_and_tilt_unknown_has_no_c23(rng):
    """With warmup in the model the correction depends on t_start and duration: both bounded
    (t_start: the runs' 0..14 400 s widened by max(1440, 600) s); a tilt-unknown fit's C23 is
    fitted as a function of the heading on its stand: no C23 bound."""
    runs = _runs(rng, effects=("hse", "warmup"), truth={"lambda2": 4.2, "warmup_amp": 20.0},
                 c23_arcsec=(-600.0, 200.0, 900.0), repeats=4)
    calibration = fit(runs, "hse,warmup")
    d = validity_domain(calibration)
    assert d.bounded == ("rate", "c23", "t_start", "duration")
    span = 600.0 * (len(runs) - 1)
    assert d.lower[2] == 0.0 and d.upper[2] == pytest.approx(span + max(0.1 * span, 600.0))
    assert d.lower[3] == pytest.approx(300.0 - 60.0) and d.upper[3] == pytest.approx(300.0 + 60.0)
    blind = validity_domain(fit(_runs(rng).replace(pitch=None, roll=None), fix={"lambda2*tilt_const": 0.0}))
    assert blind.bounded == ("rate",) and not blind.tilt_known


@needs_cc
def test_c_status_equals_python_inside_and_outside(tmp_path, rng, monkeypatch):
    """10,000 points spread beyond the domain (|rate| 5-80 deg/s both senses, headings all
    round, tilts to 600 arcsec, a few NaN and tilts beyond the 2-degree model limit): the
    exported C's return value equals Domain.status bit for bit, and both flag the issue's
    turned runs."""
    monkeypatch.chdir(tmp_path)
    runs = _runs(rng)
    calibration = fit(runs)
    save_fit(calibration, tmp_path / "FIT.json")
    assert cli(["export", str(tmp_path / "FIT.json"), "-o", str(tmp_path / "nav")]) == 0
    f = _build(tmp_path / "nav")
    n = 10_000
    X = calibration.measurement.inputs(
        rng.choice([-1, 1], n) * rng.uniform(5, 80, n) * units.DEG_PER_S, rng.uniform(0, 2 * np.pi, n),
        np.full(n, 28.07 * units.DEG), np.full(n, 300.0), rng.uniform(0, 1e5, n),
        rng.uniform(-600, 600, n) * units.ARCSEC, rng.uniform(-600, 600, n) * units.ARCSEC, {})
    X[2, :50] = 3 * units.DEG                     # beyond the model limit
    X[rng.integers(0, 7, 50), rng.integers(50, n, 50)] = np.nan
    status_c = _call(f, X)[0].astype(np.int64)
    status_py = validity_domain(calibration).status(X)
    assert np.array_equal(status_c, status_py)
    assert 0.05 < np.mean(status_py == 0) < 0.5 and np.any(status_py & (1 << C23_BIT))  # both kinds occur
    assert np.all(status_py[:50] & (1 << 2))
    turned = calibration.measurement.inputs_from_runs(_runs(rng, heading_shift_deg=180.0))
    assert np.all(_call(f, turned)[0] == 1 << C23_BIT)


def test_compensate_flags_the_rows(tmp_path, rng, capsys):
    """compensate writes comp_status (the C's status) and names the rows on stderr in one
    line; rows inside get 0."""
    runs = _runs(rng)
    save_fit(fit(runs), tmp_path / "FIT.json")
    turned = _runs(rng, heading_shift_deg=180.0)
    both = Runs(run=np.arange(1, 2 * len(runs) + 1), **{
        k: np.concatenate([getattr(runs, k), getattr(turned, k)])
        for k in ("rate", "azimuth", "heading_err", "latitude", "duration", "t_start", "pitch", "roll",
                  "heading_std")})
    save_runs(both, tmp_path / "RUNS.csv")
    capsys.readouterr()
    assert cli(["compensate", str(tmp_path / "RUNS.csv"), "--fit", str(tmp_path / "FIT.json"),
                "-o", str(tmp_path / "OUT.csv")]) == 0
    err = [ln for ln in capsys.readouterr().err.splitlines() if "validity domain" in ln]
    assert len(err) == 1 and f"{len(turned)} of {len(both)} runs outside" in err[0] and "C23" in err[0]
    status = load_runs(tmp_path / "OUT.csv").covariates["comp_status"]
    assert np.array_equal(status, np.r_[np.zeros(len(runs)), np.full(len(turned), 1 << C23_BIT)])



def test_simulated_field_campaign_of_the_issue(tmp_path, capsys):
    """The issue's case on the numeric simulator (the independent reference): the default
    system with a 300 us sync delay, 0.2 ppm/(deg/s) scale nonlinearity and its base tilted
    320 arcsec in pitch; a field campaign at three positions whose C23 are -265/-309/-285
    arcsec (azimuths 56/75/117 deg), rates 20/40/60/-40. The paper's model fits lambda2 far
    from the truth (the rate-dependent effects alias into it) and the correction is right
    only where the campaign was: at the same base turned 180 deg compensating makes every
    heading worse. compensate flags exactly those rows (bit 30) and none of the others."""
    import re as re_
    from importlib import resources

    text = resources.files("hse_opt.datasets").joinpath("truth_default.toml").read_text()
    text = text.replace("sync_delay_us = 0.0", "sync_delay_us = 300.0")
    text = re_.sub(r"sf_nonlinearity_ppm_per_dps = \[[^\]]*\]", "sf_nonlinearity_ppm_per_dps = [0.2, 0.2, 0.2]", text)
    text = re_.sub(r"mount_tilt_arcsec = \[[^\]]*\]", "mount_tilt_arcsec = [0.0, -320.0]", text)
    assert text.count("320.0") == 1 and "300.0" in text
    (tmp_path / "TRUTH.toml").write_text(text)
    plan = ["run,rate_dps,azimuth_deg,t_start_s,duration_s,position"]
    for pos, az, r in [(p_, a, r) for _ in range(2) for p_, a in (("P1", 56), ("P2", 75), ("P3", 117))
                       for r in (20, 40, 60, -40)]:
        plan.append(f"{len(plan)},{r},{az},{400 * (len(plan) - 1)},300,{pos}")
    (tmp_path / "PLAN.csv").write_text("\n".join(plan) + "\n")
    check = ["run,rate_dps,azimuth_deg,t_start_s,duration_s"]
    for az, r in [(a, r) for a in (56, 75, 117, 236, 255, 297) for r in (40, -40)]:
        check.append(f"{len(check)},{r},{az},{9600 + 400 * (len(check) - 1)},300")
    (tmp_path / "CHECK_PLAN.csv").write_text("\n".join(check) + "\n")
    d = str(tmp_path)
    for argv in (["simulate", f"{d}/PLAN.csv", "--truth", f"{d}/TRUTH.toml", "--field", "-o", f"{d}/RUNS.csv",
                  "--no-progress", "--seed", "1"],
                 ["simulate", f"{d}/CHECK_PLAN.csv", "--truth", f"{d}/TRUTH.toml", "-o", f"{d}/CHECK.csv",
                  "--no-progress", "--seed", "2"],
                 ["fit", f"{d}/RUNS.csv", "-o", f"{d}/FIT.json"],
                 ["compensate", f"{d}/CHECK.csv", "--fit", f"{d}/FIT.json", "-o", f"{d}/OUT.csv"]):
        assert cli(argv) == 0, argv
    out = load_runs(tmp_path / "OUT.csv")
    before = np.abs(out.heading_err) / units.ARCSEC
    after = np.abs(out.covariates["heading_err_comp_arcsec"])
    turned = np.degrees(out.azimuth) > 180
    assert np.array_equal(out.covariates["comp_status"], np.where(turned, 1 << C23_BIT, 0))
    assert np.all(after[turned] > before[turned] + 40)      # compensating there makes it worse
    assert np.all(after[~turned] < 20)                       # inside: the correction holds


def test_session_report_states_the_domain_the_c_enforces(tmp_path, rng):
    """The calibrate report's C interface says where the exported C returns status 0: on the
    issue's campaign |rate| 16-64 deg/s (of |rate|, both senses), pitch and roll within the
    2-degree model limit, latitude within 89 deg, and C23 in [-340, -236] arcsec with its bit
    30 (hand values as in test_domain_by_hand). It said 'any finite value' for pitch, roll and
    latitude, nothing of C23, and gave the rate's interval as if of the signed rate; with
    positive rates only it names the one sense."""
    import html
    import re

    from hse_opt.fit.export import export_calibration
    from hse_opt.report.session import interface_section

    def text(section):
        return html.unescape(re.sub(r"<[^>]+>", " ", " ".join(b for b in section.blocks if isinstance(b, str))))

    runs = _runs(rng)
    calibration = export_calibration(fit(runs), tmp_path / "nav")
    shown = re.sub(r"\s+", " ", text(interface_section(calibration)))
    rate = f"{np.radians(16.0):.6g} .. {np.radians(64.0):.6g} (of |rate|)"
    assert f"rate rad/s {rate}" in shown
    assert f"pitch rad |.| <= {np.radians(2.0):.6g} (model limit)" in shown
    assert f"roll rad |.| <= {np.radians(2.0):.6g} (model limit)" in shown
    assert f"latitude rad |.| <= {np.radians(89.0):.6g} (model limit)" in shown
    assert "bit 30 (HSE_COMP_OUT_C23)" in shown and "-340 .. -236 arcsec (the runs': -310 .. -266)" in shown
    assert "hse_compensation_systematic" in shown
    forward = export_calibration(fit(runs.subset(runs.rate > 0)), tmp_path / "nav_forward")
    shown = re.sub(r"\s+", " ", text(interface_section(forward)))
    assert f"{np.radians(16.0):.6g} .. {np.radians(64.0):.6g} (of |rate|, the positive sense only)" in shown
