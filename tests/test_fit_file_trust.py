"""A tampered FIT.json is refused, naming the field (issue: ``p_si`` 1e308 exported C that
returned status 0 and -624885 arcsec with sigma 0; ``parameters.lambda2.value`` 1000 changed
calibration.json but not the C; a covariance of 1e308 gave sigma 2.8e153 arcsec). Each edit
below is made to a file hse-opt fit -o wrote; export, compensate and design --prior exit 2
with one line naming the file, the field and "allowed:", write nothing, and leave the file
byte-identical. The untampered file passes (no false refusal) and its numbers agree as the
check requires, by a hand computation here."""
import copy
import json

import numpy as np
import pytest

from hse_opt import units
from hse_opt.cli import main as cli
from hse_opt.data import save_runs
from hse_opt.fit import fit, load_fit, save_fit


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """A FIT.json of the paper's model from a small tilted campaign, and its RUNS.csv."""
    from conftest import campaign
    from hse_opt.validation.synthetic import diagnostic_plan
    d = tmp_path_factory.mktemp("fit")
    runs = campaign({}, 11, plan=diagnostic_plan(sessions=1, runs_per_session=24))
    save_runs(runs, d / "RUNS.csv")
    save_fit(fit(runs), d / "FIT.json")
    return d


def _set(path, value):
    """An edit of the JSON object at ``path`` (keys and indices)."""
    def edit(obj):
        for k in path[:-1]:
            obj = obj[k]
        obj[path[-1]] = value(obj[path[-1]]) if callable(value) else value
    return edit


def _both_lambda2(value):
    def edit(d):
        d["parameters"]["lambda2"]["value"] = value
        d["p_si"][d["names"].index("lambda2")] = value * units.ARCSEC
    return edit


def _not_psd(d):
    c, r = d["covariance"], d["correlation"]
    s = np.sqrt(np.diag(c))
    c[0][1] = c[1][0] = 1.5 * s[0] * s[1]   # |correlation| 1.5: no covariance matrix
    r[0][1] = r[1][0] = 1.5


def _std_and_cov(d):
    d["covariance"][1][1] = 1e308
    d["parameters"]["lambda2"]["std"] = 1e154


#: edit -> the field the message must name
TAMPERED = {
    "p_si 1e308": (_set(["p_si", 1], 1e308), '"p_si[1]"'),
    "lambda2 value 1000": (_set(["parameters", "lambda2", "value"], 1000.0), "parameters.lambda2.value 1000"),
    "covariance 1e308": (_set(["covariance", 1, 1], 1e308), '"parameters.lambda2.std"'),
    "covariance and std 1e308": (_std_and_cov, '"parameters.lambda2.std" = 1e+154'),
    "lambda2 1000 with p_si": (_both_lambda2(1000.0), '"parameters.lambda2.value" = 1000'),
    "asymmetric": (_set(["covariance", 0, 1], lambda v: v + 1.0), '"covariance[0][1]"'),
    "not PSD": (_not_psd, '"covariance" is not positive semidefinite'),
    "correlation": (_set(["correlation", 0, 1], 0.99), '"correlation[0][1]"'),
    "tilt_known text": (_set(["tilt_known"], "no"), '"tilt_known"'),
    "free text": (_set(["parameters", "lambda2", "free"], "yes"), '"parameters.lambda2.free"'),
    "rate in rad/s as deg/s": (_set(["runs", "inputs", "rate", 0], 40.0), '"runs.inputs.rate[0]"'),
    "latitude 90 deg": (_set(["runs", "inputs", "latitude", 2], np.pi / 2), '"runs.inputs.latitude[2]"'),
    "unknown effect": (_set(["effects"], ["hse", "gremlin"]), "unknown effect 'gremlin'"),
}


def _write(written, tmp_path, edit):
    d = json.loads((written / "FIT.json").read_text())
    edit(d)
    path = tmp_path / "TAMPERED.json"
    path.write_text(json.dumps(d))
    return path


@pytest.mark.parametrize("case", TAMPERED)
def test_tampered_fit_json_is_refused(written, tmp_path, capsys, case):
    edit, field = TAMPERED[case]
    path = _write(written, tmp_path, edit)
    before = path.read_bytes()
    for argv in (["export", str(path), "-o", str(tmp_path / "nav")],
                 ["compensate", str(written / "RUNS.csv"), "--fit", str(path), "-o", str(tmp_path / "OUT.csv")]):
        capsys.readouterr()
        assert cli(argv) == 2, (case, argv[0])
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "TAMPERED.json" in err and field in err and "allowed:" in err, err
    assert path.read_bytes() == before
    assert not (tmp_path / "nav").exists() and not (tmp_path / "OUT.csv").exists()


def test_prior_from_a_tampered_fit_is_refused(written, tmp_path, capsys):
    path = _write(written, tmp_path, TAMPERED["p_si 1e308"][0])
    assert cli(["fit", str(written / "RUNS.csv"), "--prior", str(path)]) == 2
    assert '"p_si[1]"' in capsys.readouterr().err


def test_the_written_file_agrees_with_itself(written, tmp_path):
    """No false refusal: the file hse-opt fit -o wrote loads and exports; its numbers satisfy
    the rule by a hand computation (p_si = value x arcsec; std = sqrt(diag))."""
    d = json.loads((written / "FIT.json").read_text())
    lam = d["parameters"]["lambda2"]
    assert d["p_si"][1] == pytest.approx(lam["value"] * np.pi / 180 / 3600, rel=1e-12)
    assert lam["std"] == pytest.approx(np.sqrt(d["covariance"][1][1]), rel=1e-12)
    assert load_fit(written / "FIT.json").value("lambda2") == (lam["value"], lam["std"])
    assert cli(["export", str(written / "FIT.json"), "-o", str(tmp_path / "nav")]) == 0


def test_std_at_the_edge_of_its_declared_range(written, tmp_path, capsys):
    """The std bound is the declared range's width (lambda2: [-200, 200] arcsec, 400): a
    consistent file with std 399 loads, one with 401 is refused naming the bound."""
    def with_std(s):
        def edit(d):
            d2 = copy.deepcopy(d)
            c = np.array(d2["covariance"])
            scale = np.ones(len(c))
            scale[1] = s / np.sqrt(c[1, 1])
            c = c * np.outer(scale, scale)
            d["covariance"] = c.tolist()
            d["parameters"]["lambda2"]["std"] = float(np.sqrt(c[1, 1]))
        return edit
    assert load_fit(_write(written, tmp_path, with_std(399.0))).value("lambda2")[1] == pytest.approx(399.0)
    with pytest.raises(ValueError, match=r'"parameters.lambda2.std" = 401 .*allowed: 0 <= std <= 400 arcsec'):
        load_fit(_write(written, tmp_path, with_std(401.0)))
