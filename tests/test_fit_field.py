"""The fit on field campaigns: each unsurveyed position's unknown heading eliminated exactly.

Reference: ordinary weighted least squares (numpy) on the paper's closed form (Eq. 14) with
one explicit constant column per unsurveyed position (and the offset on the surveyed runs) --
the problem the elimination must reproduce -- and Eq. 16 for K_HSE per position. The data
are made from Eq. 14 with per-position constants the fit never sees.
"""
import numpy as np
import pytest

from hse_opt import units
from hse_opt.data import Runs
from hse_opt.field import position_lines
from hse_opt.fit import fit
from hse_opt.information import UnidentifiableError
from hse_opt.model import closed_form as cf

LAT = 28.07 * units.DEG
LAMBDA2 = 4.2 * units.ARCSEC


def _campaign(rng, surveyed_b=False, noise=3.0 * units.ARCSEC):
    """Positions A, B, C: true headings, tilts and rates; heading_deg = true + Eq. 14 + noise."""
    spec = {"A": (37.0, (150, -400), [20, 40, 60, -40]), "B": (150.0, (-300, 200), [20, -60, 40]),
            "C": (260.0, (500, 100), [40, -40, 60, 20, 60])}
    rows = []
    for label, (heading_deg, (pitch_as, roll_as), rates) in spec.items():
        for rate_dps in rates:
            rows.append((label, heading_deg, pitch_as, roll_as, rate_dps))
    n = len(rows)
    label = np.array([r[0] for r in rows])
    true = np.radians([r[1] for r in rows])
    pitch = np.array([r[2] for r in rows]) * units.ARCSEC
    roll = np.array([r[3] for r in rows]) * units.ARCSEC
    rate = np.array([r[4] for r in rows]) * units.DEG_PER_S
    err = cf.heading_error_eq14(rate, LAT, LAMBDA2, true, pitch, roll) + noise * rng.standard_normal(n)
    heading = true + err
    known = (label == "B") if surveyed_b else np.zeros(n, bool)
    cols = {"run": np.arange(1, n + 1), "rate_dps": rate / units.DEG_PER_S,
            "azimuth_deg": [np.degrees(t) if k else None for t, k in zip(true, known)],
            "heading_deg": np.degrees(heading), "latitude_deg": np.full(n, LAT / units.DEG),
            "duration_s": np.full(n, 600.0), "t_start_s": 3600.0 + 700.0 * np.arange(n),
            "pitch_arcsec": pitch / units.ARCSEC, "roll_arcsec": roll / units.ARCSEC,
            "heading_std_arcsec": np.full(n, noise / units.ARCSEC), "position": label}
    cols = {k: list(v) for k, v in cols.items()}
    return Runs.from_columns(cols, source="<field>")


def _reference(runs):
    """Weighted LS of heading_err on [constants..., Eq. 14 regressor]: lambda2, its sigma, chi2."""
    group, labels = runs.reference_groups()
    x = cf.heading_error_eq14(runs.rate, runs.latitude, 1.0, runs.azimuth, runs.pitch, runs.roll)
    cols = [(group == k).astype(float) for k in range(len(labels))]
    if (group < 0).any():
        cols.append((group < 0).astype(float))           # the offset of the surveyed runs
    A = np.column_stack([*cols, x]) / runs.heading_std[:, None]
    b = runs.heading_err / runs.heading_std
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    cov = np.linalg.inv(A.T @ A)
    r = b - A @ sol
    return sol[-1], np.sqrt(cov[-1, -1]), float(r @ r), len(runs) - A.shape[1]


@pytest.mark.parametrize("surveyed_b", [False, True])
def test_field_fit_equals_least_squares_with_explicit_position_constants(surveyed_b):
    runs = _campaign(np.random.default_rng(7), surveyed_b)
    f = fit(runs)
    lam, lam_std, chi2, dof = _reference(runs)
    i = f.names.index("lambda2")
    # the symbolic model against Eq. 14: 1e-4 relative (the paper's lambda1 approximation)
    assert f.values[i] * units.ARCSEC == pytest.approx(lam, rel=2e-3)
    assert f.std[i] * units.ARCSEC == pytest.approx(lam_std, rel=2e-3)
    assert f.chi2 == pytest.approx(chi2, rel=1e-2) and f.dof == dof
    assert not any("position" in name for name in f.names)              # never reported
    if surveyed_b:
        assert f.free[f.names.index("offset")]
    else:
        assert not f.free[f.names.index("offset")]
        assert any("offset held at 0" in note for note in f.notes)


def test_k_hse_per_position_is_eq16_with_the_positions_c23():
    runs = _campaign(np.random.default_rng(3))
    f = fit(runs)
    lam = f.values[f.names.index("lambda2")] * units.ARCSEC
    lines = position_lines(f, runs)
    assert [ln.label for ln in lines] == ["A", "B", "C"]
    for ln in lines:
        rows = runs.position == ln.label
        c23 = np.mean(cf.c23(runs.azimuth[rows], runs.pitch[rows], runs.roll[rows]))
        k = cf.k_hse(lam, c23, LAT)
        assert ln.k_hse_arcsec_per_radps == pytest.approx(k / units.ARCSEC, rel=2e-3)
        assert ln.k_hse_std_arcsec_per_radps == pytest.approx(
            abs(k / lam) * f.std[f.names.index("lambda2")], rel=2e-3)
        # normalised to 0 deg/s: the weighted line through the points passes through the origin
        w = 1 / ln.sigma ** 2
        assert np.sum(w * (ln.heading - ln.slope * ln.rate)) == pytest.approx(
            0.0, abs=1e-9 * np.sum(w * np.abs(ln.heading)))


def test_a_position_with_one_rate_is_named_when_lambda2_cannot_be_fitted():
    runs = _campaign(np.random.default_rng(1))
    a = runs.subset(np.flatnonzero(runs.position == "A"))
    a20 = a.replace(rate=np.full(len(a), 20 * units.DEG_PER_S))     # four runs, one rate
    with pytest.raises(UnidentifiableError, match=r"'A' \(20 deg/s\)") as err:
        fit(a20)
    assert "lambda2" in err.value.names and "one bias rate only" in str(err.value)
    # with B's three rates lambda2 is there again; A's runs then only cost their constant
    both = Runs.from_columns({**{k: np.concatenate([v, w]) for (k, v), w in zip(
        a20.to_columns().items(), runs.subset(np.flatnonzero(runs.position == "B")).to_columns().values())},
        "run": np.arange(7)}, source="<field>")
    f = fit(both)
    assert f.free[f.names.index("lambda2")] and f.dof == 7 - 1 - 2


def test_replicates_are_runs_of_one_position_at_one_rate():
    from hse_opt.fit.weights import replicate_groups
    runs = _campaign(np.random.default_rng(5))
    labels, _ = replicate_groups(runs)
    key = list(zip(runs.position.tolist(), np.round(runs.rate / units.DEG_PER_S).tolist()))
    for i in range(len(runs)):
        for j in range(len(runs)):
            assert (labels[i] == labels[j]) == (key[i] == key[j])


def test_robust_fit_refuses_unsurveyed_positions():
    with pytest.raises(ValueError, match="robust"):
        fit(_campaign(np.random.default_rng(2)), robust=True)


def test_compensated_field_heading_is_the_heading_less_eq14():
    from hse_opt.compensation import compensate
    runs = _campaign(np.random.default_rng(11))
    f = fit(runs)
    lam = f.values[f.names.index("lambda2")] * units.ARCSEC
    out = compensate(runs, f)
    eq14 = cf.heading_error_eq14(runs.rate, runs.latitude, lam, runs.azimuth, runs.pitch, runs.roll)
    expected = np.mod(runs.heading - eq14, 2 * np.pi) / units.DEG
    diff = (out.covariates["heading_comp_deg"] - expected) * 3600          # arcsec
    # the symbolic model against Eq. 14: one constant (Lambda's turn about the rotation axis, a
    # heading offset Eq. 14 drops: 0.38 arcsec here) and the terms the closed form drops in the
    # rate-dependent part (below 1 % of it)
    assert abs(np.mean(diff)) < 1.0
    assert np.ptp(diff) <= 0.01 * np.max(np.abs(eq14)) / units.ARCSEC, (diff, eq14 / units.ARCSEC)


def test_fit_report_draws_the_papers_fig2_per_position():
    from hse_opt.report import FIELD_LINE_CAPTION, fit_section, plot_field_line
    runs = _campaign(np.random.default_rng(4))
    f = fit(runs)
    fig = plot_field_line(f, runs)
    ax = fig.axes[0]
    lines = position_lines(f, runs)
    drawn = [ln for ln in ax.get_lines() if ln.get_linestyle() == "-" and len(ln.get_xdata()) > 2]
    assert len(drawn) == len(lines) == 3
    for d, ln in zip(drawn, lines):  # the drawn line: -K_HSE (Eq. 16) per deg/s, through the origin
        x, y = np.asarray(d.get_xdata()), np.asarray(d.get_ydata())
        slope = np.polyfit(x, y, 1)
        assert slope[0] == pytest.approx(-ln.k_hse_arcsec_per_radps * units.DEG_PER_S, rel=1e-9)
        assert abs(slope[1]) < 1e-9
    section = fit_section(f, runs)
    assert any(getattr(b, "caption", "") == FIELD_LINE_CAPTION for b in section.blocks)


@pytest.mark.parametrize("surveyed_b", [False, True])
def test_compensate_names_what_its_numbers_are_on_a_field_campaign(tmp_path, capsys, surveyed_b):
    """Without a reference the compensated numbers are each position's scatter about its own
    mean, never a 'heading error' (issue 24 item 6); in a mixed campaign the surveyed runs'
    heading error is summarised over those runs alone, as a hand computation from the file."""
    import json

    from hse_opt.cli import main
    from hse_opt.data import load_runs, save_runs
    runs = _campaign(np.random.default_rng(5), surveyed_b=surveyed_b)
    save_runs(runs, tmp_path / "RUNS.csv")
    assert main(["fit", str(tmp_path / "RUNS.csv"), "-o", str(tmp_path / "FIT.json")]) == 0
    capsys.readouterr()
    argv = ["compensate", str(tmp_path / "RUNS.csv"), "--fit", str(tmp_path / "FIT.json"), "-o"]
    assert main([*argv, str(tmp_path / "C.csv")]) == 0
    text = capsys.readouterr().out
    assert "scatter about each position's mean" in text
    assert ("heading error" in text.replace("heading errors are unknown", "")) == surveyed_b, text
    assert main([*argv, str(tmp_path / "C2.csv"), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert "unsurveyed" in got and ("surveyed" in got) == surveyed_b
    if surveyed_b:
        back = load_runs(tmp_path / "C.csv")
        b = back.surveyed
        err_as = back.heading_err[b] / units.ARCSEC
        assert got["surveyed"]["before"]["rms_arcsec"] == pytest.approx(np.sqrt(np.mean(err_as ** 2)), rel=1e-9)
        comp = np.asarray(back.covariates["heading_err_comp_arcsec"], float)[b]
        assert got["surveyed"]["after"]["rms_arcsec"] == pytest.approx(np.sqrt(np.mean(comp ** 2)), rel=1e-9)


def test_compensate_says_what_heading_err_comp_is_at_an_unsurveyed_row(tmp_path, capsys):
    """At a field position without azimuth_deg, heading_err_comp_arcsec was called the
    'compensated heading error'; it is the compensated heading less the position's stand-in
    reference (the mean of its uncompensated headings). Checked from the written file by hand:
    each position's circular mean of heading_deg, and the scatter the summary prints, from
    heading_comp_deg about each position's own mean; the text and --json say what the column is."""
    import csv
    import json

    from hse_opt.cli import main
    from hse_opt.data import save_runs
    save_runs(_campaign(np.random.default_rng(5), surveyed_b=True), tmp_path / "RUNS.csv")
    assert main(["fit", str(tmp_path / "RUNS.csv"), "-o", str(tmp_path / "FIT.json")]) == 0
    capsys.readouterr()
    argv = ["compensate", str(tmp_path / "RUNS.csv"), "--fit", str(tmp_path / "FIT.json"), "-o"]
    assert main([*argv, str(tmp_path / "C.csv")]) == 0
    text = capsys.readouterr().out
    with open(tmp_path / "C.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["azimuth_deg"] == ""]
    pos = np.array([r["position"] for r in rows])
    h, hc, col = (np.array([float(r[c]) for r in rows]) for c in ("heading_deg", "heading_comp_deg",
                                                                   "heading_err_comp_arcsec"))
    ref = {p: np.degrees(np.angle(np.mean(np.exp(1j * np.radians(h[pos == p]))))) for p in set(pos)}
    stand_in = np.array([ref[p] for p in pos])
    assert set(pos) == {"A", "C"}
    np.testing.assert_allclose(col, ((hc - stand_in + 180.0) % 360.0 - 180.0) * 3600.0, atol=1e-6)
    for p in ("A", "C"):  # its position mean: minus the mean correction, not an error
        assert np.mean(col[pos == p]) == pytest.approx(np.mean(hc[pos == p] - h[pos == p]) * 3600.0, abs=1e-6)
    assert "heading_err_comp_arcsec at their rows: the compensated heading (heading_comp_deg) less the " \
           "position's stand-in reference, the mean of its uncompensated headings (heading_deg)" in text
    assert "not an error against any reference" in text
    after = np.concatenate([(hc[pos == p] - np.mean(hc[pos == p])) * 3600.0 for p in ("A", "C")])
    line = next(ln for ln in text.splitlines() if "scatter about each position's mean" in ln)
    assert f"-> {np.sqrt(np.mean(after ** 2)):.4g} arcsec" in line, line
    assert main([*argv, str(tmp_path / "C2.csv"), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["unsurveyed"]["column"].startswith("heading_err_comp_arcsec: the compensated heading")
    assert got["unsurveyed"]["after"]["rms_arcsec"] == pytest.approx(np.sqrt(np.mean(after ** 2)), rel=1e-6)
