"""The HTML report: plots checked against the paper's closed forms (Eqs. 14, 16), the page
checked for self-containment, atomic writing, and rendering in a real browser (chromium)."""
import json
import re

import numpy as np
import pytest

from browser import colour, ink, render
from hse_opt import report, units
from hse_opt.data import Runs
from hse_opt.fit import fit
from hse_opt.model import closed_form as cf

LAT = 28.07 * units.DEG
THETA, GAMMA = -120 * units.ARCSEC, -55 * units.ARCSEC      # tilt of b0, fixed in b0
LAMBDA2 = 30 * units.ARCSEC
OFFSET = -7.0 * units.ARCSEC


def eq14_runs(noise_arcsec=0.0, seed=0, lambda2=LAMBDA2):
    """Runs whose heading error is Eq. 14 (our sign) plus a constant offset: 3 rates x 4
    azimuths x 2 repeats, pitch/roll given, 1-arcsec sigmas."""
    rate, az = np.meshgrid(np.array([20.0, 40.0, 60.0]) * units.DEG_PER_S,
                           np.array([0.0, 90.0, 180.0, 270.0]) * units.DEG)
    rate, az = np.repeat(rate.ravel(), 2), np.repeat(az.ravel(), 2)
    n = rate.size
    y = cf.heading_error_eq14(rate, LAT, lambda2, az, THETA, GAMMA) + OFFSET
    y = y + np.random.default_rng(seed).normal(0, noise_arcsec * units.ARCSEC, n)
    return Runs(run=np.arange(1, n + 1), rate=rate, azimuth=az, heading_err=y,
                latitude=np.full(n, LAT), duration=np.full(n, 600.0),
                t_start=3600.0 + 700.0 * np.arange(n), pitch=np.full(n, THETA),
                roll=np.full(n, GAMMA), heading_std=np.full(n, units.ARCSEC),
                covariates={"temp_c": 25 + 0.1 * np.arange(n)})


def _curves(ax, npts):
    return [ln for ln in ax.get_lines() if len(ln.get_xdata()) == npts]


def test_azimuth_plot_compensates_eq14():
    runs = eq14_runs()
    f = fit(runs)
    fig = report.plot_azimuth(f, runs)
    before, after = fig.axes[:2]
    # model curves (one per rate, 181 azimuths) equal Eq. 14 + offset
    curves = _curves(before, 181)
    assert len(curves) == 3
    for ln, rate_dps in zip(curves, (20, 40, 60)):
        psi = np.asarray(ln.get_xdata()) * units.DEG
        ref = (cf.heading_error_eq14(rate_dps * units.DEG_PER_S, LAT, LAMBDA2, psi, THETA, GAMMA)
               + OFFSET) / units.ARCSEC
        assert np.max(np.abs(np.asarray(ln.get_ydata()) - ref)) < 0.05
    # after compensation every run sits on the offset; before, they swing as Eq. 14 does
    pts_after = np.concatenate([c.lines[0].get_ydata() for c in after.containers])
    pts_before = np.concatenate([c.lines[0].get_ydata() for c in before.containers])
    assert np.ptp(pts_after) < 0.05
    for ln in _curves(after, 181):                          # the compensated model: flat, on the runs
        assert np.ptp(ln.get_ydata()) < 1e-9
        assert abs(ln.get_ydata()[0] - np.mean(pts_after)) < 0.05
    assert np.ptp(pts_before) == pytest.approx(np.ptp(runs.heading_err) / units.ARCSEC)
    assert np.ptp(pts_before) > 20


def test_calibration_line_slope_is_k_hse():
    runs = eq14_runs()
    f = fit(runs)
    ax = report.plot_calibration_line(f, runs).axes[0]
    lines = _curves(ax, 61)
    assert len(lines) == 4                                  # one per stand azimuth
    for ln, psi_deg in zip(lines, (0, 90, 180, 270)):
        x = np.asarray(ln.get_xdata()) * units.DEG_PER_S
        slope = np.polyfit(x, np.asarray(ln.get_ydata()) * units.ARCSEC, 1)[0]
        psi = psi_deg * units.DEG
        c23 = np.sin(psi) * np.sin(THETA) * np.cos(GAMMA) - np.cos(psi) * np.sin(GAMMA)
        k_hse = -cf.k_hse(LAMBDA2, c23, LAT)                # Eq. 16, our sign
        assert slope == pytest.approx(k_hse, rel=2e-3, abs=1e-4 * units.ARCSEC)


def test_no_calibration_line_from_one_bias_rate():
    # Table 1: every run at 40 deg/s; a line over a 0.1 deg/s axis would be meaningless
    from hse_opt.datasets import paper_table1
    runs = paper_table1()
    f = fit(runs, fix={"lambda2*tilt_const": 0.0})
    assert report.plot_calibration_line(f, runs) is None
    alts = [fg.alt for fg in report.fit_section(f, runs).figures]
    assert "heading error against bias rate" not in alts and len(alts) == 2


def test_residual_panels_cover_every_varying_factor():
    runs = eq14_runs(noise_arcsec=1.0)
    keys = [k for k, _, _ in report.factors(runs)]
    # duration and latitude are constant here: left out; the covariate is in
    assert keys == ["rate", "azimuth", "t_start", "covariate:temp_c"]
    fig = report.plot_residuals(fit(runs), runs)
    labels = [ax.get_xlabel() for ax in fig.axes if ax.get_visible()]
    assert labels == ["bias rate [deg/s]", "stand azimuth [deg]", "time since power-on [h]", "temp_c"]


def _sections(runs):
    before = fit(runs, "hse")
    after = fit(runs, "hse,sync_delay")
    return before, after, [report.fit_section(before, runs), report.comparison_section(before, after, runs)]


def test_page_is_self_contained_and_carries_the_numbers(tmp_path):
    runs = eq14_runs(noise_arcsec=1.0)
    before, after, sections = _sections(runs)
    path = report.write_report(tmp_path / "out", sections, "test report", ["a summary line"])
    assert path == tmp_path / "out" / "report.html"
    text = path.read_text(encoding="utf-8")
    # nothing fetched from anywhere: no external URLs, no external scripts/styles/fonts
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//)""", text)
    assert "@import" not in text and "url(" not in text
    scripts = re.findall(r"<script[^>]*>", text)
    assert scripts == ['<script type="application/json" id="hse-opt-data">']
    srcs = re.findall(r'<img class="plot" src="([^"]+)"', text)
    assert len(srcs) == 4 and all(s.startswith("data:image/svg+xml;base64,") for s in srcs)
    # the visible tables show the fit's numbers
    row = re.search(r'<tr data-key="param:lambda2">(.*?)</tr>', text).group(1)
    cells = re.findall(r"<td>(.*?)</td>", row)
    assert float(cells[1]) == pytest.approx(before.value("lambda2")[0], rel=1e-4)
    assert float(cells[2]) == pytest.approx(before.value("lambda2")[1], rel=1e-2)
    assert abs(float(cells[1]) - LAMBDA2 / units.ARCSEC) < 4 * float(cells[2])
    data = json.loads(re.search(r'id="hse-opt-data">(.*?)</script>', text, re.S).group(1))
    assert data[sections[1].title]["after"]["effects"] == ["hse", "sync_delay"]


def test_write_is_whole_or_nothing(tmp_path, monkeypatch):
    runs = eq14_runs(noise_arcsec=1.0)
    sec = [report.comparison_section(fit(runs), fit(runs, "hse,sync_delay"), runs)]
    path = report.write_report(tmp_path, sec)
    first = path.read_bytes()

    def broken(*a, **k):
        raise RuntimeError("disk full")
    monkeypatch.setattr("os.fsync", broken)
    with pytest.raises(RuntimeError, match="disk full"):
        report.write_report(tmp_path, sec, title="another title")
    assert path.read_bytes() == first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.html"]
    with pytest.raises(ValueError, match="is a file"):
        report.write_report(path, sec)


def test_report_renders_in_chromium(tmp_path):
    runs = eq14_runs(noise_arcsec=1.0)
    _, _, sections = _sections(runs)
    path = report.write_report(tmp_path / "out", sections, "browser check")
    probe, pixels = render(path, tmp_path)
    n_fig = sum(len(s.figures) for s in sections)
    assert probe["sections"] == 2
    assert probe["images"] == n_fig == 4
    assert probe["decoded"] == n_fig                       # every plot decoded by the browser
    assert pixels.shape[0] >= probe["height"] - 1
    for left, top, width, height in probe["rects"]:
        assert width > 300 and height > 150                # laid out at a readable size
        crop = pixels[int(top):int(top + height), int(left):int(left + width)]
        assert ink(crop) > 0.02                            # axes, text and data drawn
        assert colour(crop) > 200                          # coloured markers and lines
    blank = pixels[:, -30:]                                # the right margin stays empty
    assert ink(blank) < 0.01


def test_fit_command_writes_the_report_with_its_json_numbers(tmp_path, capsys):
    from hse_opt.cli import main
    from hse_opt.data import save_runs
    save_runs(eq14_runs(noise_arcsec=1.0), tmp_path / "RUNS.csv")
    assert main(["fit", str(tmp_path / "RUNS.csv"), "--json", "--report", str(tmp_path / "rep")]) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)                        # stdout: the JSON object only
    assert "report:" in captured.err
    text = (tmp_path / "rep" / "report.html").read_text(encoding="utf-8")
    for name, p in data["parameters"].items():
        cells = re.findall(r"<td>(.*?)</td>",
                           re.search(rf'<tr data-key="param:{re.escape(name)}">(.*?)</tr>', text).group(1))
        assert float(cells[1]) == pytest.approx(p["value"], rel=1e-4, abs=1e-9)
        assert float(cells[2]) == pytest.approx(p["std"], rel=1e-2)
