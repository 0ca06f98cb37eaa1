"""``hse-opt fit`` and ``hse-opt compensate`` (issue 4, item 8)."""
import json
import subprocess
import sys

import numpy as np
import pytest

from hse_opt.cli import main
from hse_opt.data import load_runs
from hse_opt.datasets import paper_table1_path
from hse_opt.fit import load_fit

TABLE1 = str(paper_table1_path())
FIX = "lambda2*tilt_const=0"


def test_fit_json_and_compensate(tmp_path, capsys):
    fit_path = tmp_path / "FIT.json"
    assert main(["fit", TABLE1, "--fix", FIX, "--json", "-o", str(fit_path)]) == 0
    out, err = capsys.readouterr()
    d = json.loads(out)  # one object, nothing else on stdout
    assert {"effects", "n_runs", "parameters", "chi2", "dof", "chi2_red", "aic", "bic",
            "rms_arcsec"} <= set(d)
    assert d["effects"] == ["hse"] and d["n_runs"] == 12 and d["dof"] == 9
    assert d["parameters"]["lambda2*tilt_const"] == {"value": 0.0, "std": 0.0, "unit": "arcsec*mrad",
                                                     "free": False, "lower": 0.0, "upper": 0.0,
                                                     "systematic": 0.0, "systematic_by": {}}
    # the fitted sinusoid against numpy's least squares on [1, cos, sin] of the azimuth:
    # at 40 deg/s one arcsec*mrad of lambda2*C23 is -lambda1 / (3 w_ie cos L) of heading
    runs = load_runs(TABLE1)
    A = np.column_stack([np.ones(12), np.cos(runs.azimuth), np.sin(runs.azimuth)])
    coef = np.linalg.lstsq(A, runs.heading_err, rcond=None)[0] * 206264.806
    k = -(40 * np.pi / 180 - 7.292115e-5 * np.sin(0.49)) * 4.8481368e-9 / (3 * 7.292115e-5 * np.cos(0.49))
    k_arcsec = k * 206264.806
    p = d["parameters"]
    assert p["lambda2*tilt_cos"]["value"] * k_arcsec == pytest.approx(coef[1], rel=1e-3)
    assert p["lambda2*tilt_sin"]["value"] * k_arcsec == pytest.approx(coef[2], rel=1e-3)
    # the README's amplitude of the heading-sensitive sinusoid (3.3 +- 1.1 arcsec*mrad of lambda2 * C23):
    # hypot of numpy's two coefficients, its sigma from numpy's covariance by the delta method
    amp = np.hypot(coef[1], coef[2]) / abs(k_arcsec)
    cov = np.linalg.inv(A.T @ A)[1:, 1:] / k_arcsec ** 2
    g = coef[1:] / np.hypot(coef[1], coef[2])
    a = d["tilt_amplitudes"]["lambda2"]
    assert a["value"] == pytest.approx(amp, rel=1e-3) and round(a["value"], 1) == 3.3
    assert a["unit"] == "arcsec*mrad" and round(a["std"], 1) == 1.1
    s2 = d["parameters"]["lambda2*tilt_cos"]["std"] ** 2 / (cov[0, 0])       # the fit's sigma^2
    assert a["std"] == pytest.approx(np.sqrt(s2 * g @ cov @ g), rel=1e-3)
    assert main(["fit", TABLE1, "--fix", FIX]) == 0           # and in words, as the README quotes it
    assert (f"heading-sensitive sinusoid lambda2 * C23 (tilt unknown): amplitude {a['value']:.3g} +- 1.1 "
            "arcsec*mrad") in capsys.readouterr().out
    assert "wrote" in err
    out_csv = tmp_path / "OUT.csv"
    assert main(["compensate", TABLE1, "--fit", str(fit_path), "-o", str(out_csv), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    comp = load_runs(out_csv)
    assert comp.covariates["heading_err_comp_arcsec"].shape == (12,)
    np.testing.assert_array_equal(comp.heading_err, runs.heading_err)  # the input column is kept
    # the residual of the fit is what compensation leaves, up to the offset it keeps
    fitted = load_fit(fit_path)
    np.testing.assert_allclose(comp.covariates["heading_err_comp_arcsec"] - fitted.value("offset")[0],
                               fitted.residuals * 206264.806, atol=1e-6)
    assert s["after"]["rms_arcsec"] < s["before"]["rms_arcsec"]


def test_readable_report_and_bounds(capsys):
    assert main(["fit", TABLE1, "--fix", FIX, "--bound", "lambda2*tilt_cos=:1.5"]) == 0
    out = capsys.readouterr().out
    assert "lambda2*tilt_cos" in out and "(at its bound)" in out and "arcsec*mrad" in out
    assert "bounds that bind: lambda2*tilt_cos" in out and "chi2" in out and "AIC" in out



def test_fit_summary_is_the_commands_report(capsys):
    """The command prints its title and ``FitResult.summary()``; every parameter line shows the
    value and 1-sigma the JSON output carries (a separate serialisation of the same fit)."""
    from hse_opt.aliasing import alias_budget
    from hse_opt.fit import fit

    argv = ["fit", TABLE1, "--fix", FIX, "--robust"]
    assert main(argv) == 0
    out = capsys.readouterr().out.splitlines()
    assert main(argv + ["--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    runs = load_runs(TABLE1)
    result = fit(runs, fix={"lambda2*tilt_const": 0.0}, robust=True)
    result = result.with_budget(alias_budget(result, runs))
    lines = result.summary()
    assert out == [f"hse-opt fit: {TABLE1}: {lines[0]}", *lines[1:]]
    rows = {line.split()[0]: line.split()[1:] for line in lines[4:8]}
    assert set(rows) == set(d["parameters"])
    for name, p in d["parameters"].items():
        assert float(rows[name][0]) == pytest.approx(p["value"], rel=1e-4, abs=1e-9)
        if p["free"]:
            assert float(rows[name][1]) == pytest.approx(p["std"], rel=1e-3)
    assert f"chi2 {d['chi2']:.4g} / dof {d['dof']}" in "\n".join(lines)
    assert "Huber loss" in "\n".join(lines)

@pytest.mark.parametrize("args, text", [
    (["--bound", "lambda2=1"], "allowed form NAME=LO:HI"),
    (["--fix", "lambda2*tilt_const=abc"], "is not a number"),
    (["--fix", "lambda3=0"], "unknown parameter"),
    (["--effects", "warmpu"], "unknown effect 'warmpu'"),
])
def test_bad_input_exit_2(args, text, capsys):
    assert main(["fit", TABLE1, "--fix", FIX] + args) == 2
    assert text in capsys.readouterr().err


def test_unidentifiable_exit_2_names_parameters(capsys):
    assert main(["fit", TABLE1, "--effects", "hse,sync_delay", "--fix", FIX, "--json"]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert "offset, delay cannot be told apart" in err and "--fix" in err


def test_default_fit_of_table1_works_with_a_note(capsys):
    assert main(["fit", TABLE1, "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["parameters"]["lambda2*tilt_const"]["free"] is False
    assert any("absorbed into the offset" in n for n in d["notes"])


def test_help_has_examples():
    for cmd in ("fit", "compensate"):
        out = subprocess.run([sys.executable, "-m", "hse_opt.cli", cmd, "--help"], capture_output=True,
                             text=True)
        assert out.returncode == 0 and f"hse-opt {cmd}" in out.stdout.split("example")[-1]


@pytest.mark.parametrize("command", [["fit"], ["diagnose", "--covariates", "none"]])
def test_input_checks_are_options(tmp_path, capsys, command):
    # a fine azimuth sweep in degrees (0-4.5 deg) looks like radians, and 4 deg/s is inside
    # the default lock-in limit: each an error (exit 2) until the user says otherwise
    src = load_runs(TABLE1)
    rows = ["run,rate_dps,azimuth_deg,heading_err_arcsec,latitude_deg,duration_s"]
    rows += [f"{i + 1},{4.0 if i == 0 else 40.0},{1.5 * (i % 4)},{h:.2f},28.07,600"
             for i, h in enumerate(src.heading_err / 4.8481368110953599e-6)]
    path = tmp_path / "SWEEP.csv"
    path.write_text("\n".join(rows) + "\n")
    base = [command[0], str(path), "--fix", FIX, *command[1:], "--json"]
    assert main(base) == 2
    assert "--min-rate-dps" in capsys.readouterr().err
    assert main(base + ["--min-rate-dps", "3"]) == 2
    assert "--allow-small-azimuths" in capsys.readouterr().err
    assert main(base + ["--min-rate-dps", "3", "--allow-small-azimuths"]) == 0
    assert json.loads(capsys.readouterr().out)["n_runs"] == 12


def test_report_p_value_matches_scipy():
    """The fit report's chi2 p-value (numpy/math, kept free of scipy for start-up time)
    against scipy.stats over even and odd dof, both tails."""
    from scipy.stats import chi2

    from hse_opt.fit.result import chi2_sf
    for dof in (1, 2, 3, 10, 11, 96, 97, 9996, 9997):
        for x in np.concatenate([[0.0, 1e-8], dof * np.array([0.05, 0.5, 0.9, 1.0, 1.1, 1.5, 3.0])]):
            assert chi2_sf(x, dof) == pytest.approx(chi2.sf(x, dof), rel=1e-8, abs=1e-300)
    with pytest.raises(ValueError, match="dof 2.5"):
        chi2_sf(1.0, 2.5)


@pytest.mark.parametrize("budget", ["present", "zero", "absent"])
def test_compensate_states_the_systematic_bound_in_words(tmp_path, capsys, budget):
    """The systematic bound is its size when there is one (the output column's maximum), 'none'
    when FIT.json's budget is zero everywhere, and 'not computed' when the file has no budget
    (written before budgets); never 'up to 0 arcsec' (new-user trial)."""
    fit_path = tmp_path / "FIT.json"
    assert main(["fit", TABLE1, "--fix", FIX, "-o", str(fit_path)]) == 0
    d = json.loads(fit_path.read_text())
    for p in d["parameters"].values():
        if budget == "zero":
            p["systematic"], p["systematic_by"] = 0.0, {}
        elif budget == "absent":
            del p["systematic"], p["systematic_by"]
    fit_path.write_text(json.dumps(d))
    capsys.readouterr()
    out_csv = tmp_path / "OUT.csv"
    assert main(["compensate", TABLE1, "--fit", str(fit_path), "-o", str(out_csv)]) == 0
    text = capsys.readouterr().out
    assert "up to 0 arcsec" not in text
    column = np.asarray(load_runs(out_csv).covariates["heading_comp_sys_arcsec"], float)
    if budget == "present":
        assert column.max() > 1.0
        assert f"up to {column.max():.3g} arcsec" in text
    elif budget == "zero":
        assert not column.any() and "systematic bound: none" in text
    else:
        assert not column.any() and "systematic bound: not computed" in text
