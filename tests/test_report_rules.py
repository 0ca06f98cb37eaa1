"""Reports that never overstate (issue 18, item 2), one test per rule: factors are plotted
only where they vary beyond their resolution; columns derived from the heading error are
never factors; Fig. 2's caption says what the slope holds and the hse part alone is drawn
against the paper's closed form; every table column has a label; the title names the input;
a figure that cannot be drawn is explained."""
import re

import numpy as np
import pytest

from hse_opt import report, units
from hse_opt.cli import main as cli
from hse_opt.data import Runs, save_runs
from hse_opt.datasets import paper_table1
from hse_opt.factors import RESOLUTION
from hse_opt.fit import fit
from hse_opt.model import Model
from hse_opt.model import closed_form as cf

LAT = 28.07 * units.DEG
THETA, GAMMA = -120 * units.ARCSEC, -55 * units.ARCSEC


def _runs(model="hse", truth=None, pitch_spread=0.15, seed=0, **cols):
    """3 rates x 4 azimuths x 2 repeats from the measurement model plus 1-arcsec noise; the
    leveled pitch wanders by ``pitch_spread`` arcsec around THETA."""
    rng = np.random.default_rng(seed)
    rate, az = np.meshgrid(np.array([20.0, 40.0, 60.0]) * units.DEG_PER_S,
                           np.array([0.0, 90.0, 180.0, 270.0]) * units.DEG)
    rate, az = np.repeat(rate.ravel(), 2), np.repeat(az.ravel(), 2)
    n = rate.size
    pitch = THETA + np.linspace(0, pitch_spread, n) * units.ARCSEC
    roll = np.full(n, GAMMA)
    mm = Model(model.split(",")).measurement(True)
    t0 = 3600.0 + 700.0 * np.arange(n)
    X = mm.inputs(rate, az, LAT, 600.0, t0, pitch, roll)
    y = mm.predict(mm.vector(truth or {"lambda2": 30.0, "offset": -7.0}), X)
    y = y + rng.normal(0, units.ARCSEC, n)
    return Runs(run=np.arange(1, n + 1), rate=rate, azimuth=az, heading_err=y, latitude=np.full(n, LAT),
                duration=np.full(n, 600.0), t_start=t0, pitch=pitch, roll=roll,
                heading_std=np.full(n, units.ARCSEC), covariates=cols)


def _panel_labels(fig):
    return [ax.get_xlabel() for ax in fig.axes if ax.get_visible()]


def test_factor_within_its_resolution_is_listed_not_plotted():
    runs = _runs(pitch_spread=0.15)
    f = fit(runs)
    assert "pitch of b0 [arcsec]" not in _panel_labels(report.plot_residuals(f, runs))
    html = report.fit_section(f, runs).html("s1")
    lo, hi = np.min(runs.pitch) / units.ARCSEC, np.max(runs.pitch) / units.ARCSEC
    m = re.search(r"pitch of b0 \[arcsec\]: (\S+) to (\S+) \(spread (\S+), not beyond its resolution (\S+)\)", html)
    assert m and float(m.group(1)) == pytest.approx(lo) and float(m.group(2)) == pytest.approx(hi)
    assert float(m.group(3)) == pytest.approx(0.15, rel=1e-3) and float(m.group(4)) == RESOLUTION["pitch"]
    assert "roll of b0 [arcsec]: -55 in every run" in html
    # a tilt that really varies is plotted
    runs = _runs(pitch_spread=100.0)
    assert "pitch of b0 [arcsec]" in _panel_labels(report.plot_residuals(fit(runs), runs))


def test_derived_columns_are_never_factors(tmp_path):
    # Table 1's compensated heading error is recognised by its name
    runs = paper_table1()
    f = fit(runs, fix={"lambda2*tilt_const": 0.0})
    labels = _panel_labels(report.plot_residuals(f, runs))
    assert "heading_err_compensated_arcsec" not in labels and "stand azimuth [deg]" in labels
    section = report.fit_section(f, runs)
    assert section.data["factors"]["derived"] == ["heading_err_compensated_arcsec"]
    # a derived column the user names, through the API and the command line
    y = _runs()
    runs = y.replace(comp_err=(y.heading_err / units.ARCSEC) - 3.0, temp_c=25 + 0.1 * np.arange(len(y)))
    f = fit(runs)
    assert "comp_err" in _panel_labels(report.plot_residuals(f, runs))
    assert "comp_err" not in _panel_labels(report.plot_residuals(f, runs, derived=["comp_err"]))
    assert "temp_c" in _panel_labels(report.plot_residuals(f, runs, derived=["comp_err"]))
    save_runs(runs, tmp_path / "RUNS.csv")
    assert cli(["fit", str(tmp_path / "RUNS.csv"), "--derived", "comp_err", "--report", str(tmp_path / "r")]) == 0
    text = (tmp_path / "r" / "report.html").read_text()
    assert "Derived from the heading error, never a factor: comp_err" in text


def test_calibration_line_caption_says_what_the_slope_holds():
    lam = 30.0
    runs = _runs("hse,sync_delay", {"lambda2": lam, "offset": -7.0, "delay": 400.0}, pitch_spread=0.0)
    f = fit(runs, "hse,sync_delay")
    parts = report.slope_parts(f, runs)
    caption = report.slope_caption(parts)
    assert "not K_HSE alone" in caption and "sync_delay" in caption
    # the hse part is -K_HSE of the closed form (Eq. 16) with the fitted lambda2, per azimuth
    lam_fit = f.value("lambda2")[0] * units.ARCSEC
    psi = parts["azimuth_deg"] * units.DEG
    c23 = np.sin(psi) * np.sin(THETA) * np.cos(GAMMA) - np.cos(psi) * np.sin(GAMMA)
    k = -cf.k_hse(lam_fit, c23, LAT) / units.ARCSEC * units.DEG_PER_S   # arcsec per deg/s, our sign
    assert parts["parts"]["hse"] == pytest.approx(k, rel=3e-3, abs=1e-5)
    # the drawn hse part alone: line slopes equal the same closed form
    ax = report.plot_calibration_line(f, runs, hse_only=True).axes[0]
    lines = [ln for ln in ax.get_lines() if len(ln.get_xdata()) == 61]
    slopes = [np.polyfit(ln.get_xdata(), ln.get_ydata(), 1)[0] for ln in lines]
    assert slopes == pytest.approx(k, rel=3e-3, abs=1e-5)
    # the full figure draws the hse part dashed beside each full line
    ax = report.plot_calibration_line(f, runs).axes[0]
    styles = [ln.get_linestyle() for ln in ax.get_lines() if len(ln.get_xdata()) == 61]
    assert styles.count("--") == styles.count("-") == 4
    # the paper's model alone: the caption calls the slope K_HSE
    runs = _runs(pitch_spread=0.0)
    assert "not K_HSE alone" not in report.slope_caption(report.slope_parts(fit(runs), runs))


def _headers(text):
    return [re.findall(r"<th>(.*?)</th>", t) for t in re.findall(r"<thead>(.*?)</thead>", text)]


def test_every_table_column_is_labelled_and_the_title_names_the_input(tmp_path):
    runs = paper_table1()
    save_runs(runs, tmp_path / "table1.csv")
    assert cli(["fit", str(tmp_path / "table1.csv"), "--fix", "lambda2*tilt_const=0",
                "--report", str(tmp_path / "fit")]) == 0
    assert cli(["diagnose", str(tmp_path / "table1.csv"), "--fix", "lambda2*tilt_const=0", "--covariates",
                "none", "--report", str(tmp_path / "diag")]) == 0
    for sub in ("fit", "diag"):
        text = (tmp_path / sub / "report.html").read_text()
        assert "table1.csv" in re.search(r"<title>(.*?)</title>", text).group(1)
        heads = _headers(text)
        assert heads and all(h and all(cell.strip() for cell in h) for h in heads), heads
    # the Table 1 parameter table: a labelled state column, no sigma cell repeating "fixed"
    text = (tmp_path / "fit" / "report.html").read_text()
    # (the fit command assesses the systematic: a column beside the 1-sigma)
    assert _headers(text)[0] == ["parameter", "value", "1-sigma", "systematic", "unit", "state", "meaning"]
    row = re.findall(r"<td>(.*?)</td>", re.search(r'data-key="param:lambda2\*tilt_const">(.*?)</tr>', text).group(1))
    assert row[2] != "fixed" and row[5] == "fixed"
    # a comparison of two fits: labelled too
    y = _runs()
    text = report.comparison_section(fit(y), fit(y, "hse,sync_delay"), y).html("s1")
    assert all(all(c.strip() for c in h) for h in _headers(text))


def test_a_figure_that_cannot_be_drawn_is_explained():
    runs = paper_table1()
    f = fit(runs, fix={"lambda2*tilt_const": 0.0})
    text = report.fit_section(f, runs).html("s1")
    assert "No calibration line (the paper&#x27;s Fig. 2): every run is at 40 deg/s" in text


def test_sensor_noise_columns_are_not_called_derived_from_the_heading_error():
    """hse-opt align writes each log's noise figures (gyro_arw_dph_rthz, accel_vrw_ug_rthz, ...):
    computed from the raw gyro and accelerometer samples, not from the heading error. They stay
    out of the factors, but the report's note said 'Derived from the heading error' of them."""
    from hse_opt.factors import campaign_factors
    y = _runs()
    n = len(y)
    runs = y.replace(gyro_arw_dph_rthz=np.full(n, 0.012), accel_vrw_ug_rthz=np.full(n, 1.0),
                     heading_err_comp_arcsec=y.heading_err / units.ARCSEC, temp_c=25 + 0.1 * np.arange(n))
    facs = campaign_factors(runs)
    assert set(facs.derived) == {"gyro_arw_dph_rthz", "accel_vrw_ug_rthz", "heading_err_comp_arcsec"}
    notes = facs.notes()
    heading = [s for s in notes if s.startswith("Derived from the heading error")]
    sensors = [s for s in notes if "own sensors" in s]
    assert len(heading) == 1 and "heading_err_comp_arcsec" in heading[0] and "gyro_" not in heading[0]
    assert len(sensors) == 1 and "gyro_arw_dph_rthz" in sensors[0] and "accel_vrw_ug_rthz" in sensors[0]
    assert "temp_c" not in " ".join(notes)


def test_fit_report_states_the_tilt_unknown_sinusoid_amplitude():
    """Table 1 (no tilts): the heading-sensitive sinusoid's amplitude, which the README quotes
    from hse-opt fit ('amplitude 3.28 +- 1.1 arcsec*mrad', tests/test_readme.py), is in the
    fit report too (it was on the command line only); a fit with known tilt has no such line."""
    from pathlib import Path
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
    quote = re.search(r'it prints "(amplitude [^"]+)"', readme).group(1)
    runs = paper_table1()
    section = report.fit_section(fit(runs, fix={"lambda2*tilt_const": 0.0}), runs)
    assert f"lambda2 * C23 (tilt unknown): {quote}" in " ".join(b for b in section.blocks if isinstance(b, str))
    y = _runs()
    known = report.fit_section(fit(y), y)
    assert "tilt unknown" not in " ".join(b for b in known.blocks if isinstance(b, str))
