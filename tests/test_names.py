"""Names users give reach generated C, JSON keys, HTML and messages through one rule
(:mod:`hse_opt.names`), enforced where they enter: the CSV header reader, ``--effects
covariate:NAME`` and FIT.json's effects. The issue's hostile names (a quoted CSV header with
``*/``, newlines and ``#error``; ``t*/x``) are refused with exit 2 and "allowed: ...", the input
unchanged and nothing written; the names the tool itself uses all follow the rule."""
import json
import re

import numpy as np
import pytest

from hse_opt.cli import main as cli
from hse_opt.data import Plan, Runs, save_runs
from hse_opt.fit import fit, save_fit
from hse_opt.model import CATALOGUE, register_effect
from hse_opt.model.effects import Covariate, Effect
from hse_opt.names import check_name

#: the issue's names: a legal quoted CSV header that injects a preprocessor line, one that
#: closes a C comment, markup, a space, a non-ASCII letter, an over-long name
HOSTILE = ["c*/\n#error injected\n/*", "t*/x", "<script>alert(1)</script>", "temp c", "temp\u00b0c",
           "x" * 65, "a\\\n/"]


def _runs(rng, n=24):
    """A small campaign with a temperature column (rates both senses, 8 azimuths, tilts)."""
    from conftest import campaign
    from hse_opt.validation.synthetic import diagnostic_plan
    plan = diagnostic_plan(sessions=1, runs_per_session=n)
    return campaign({}, int(rng.integers(1 << 30)), plan=plan,
                    covariates={"temp_c": 25 + np.arange(n) % 5 * 0.5})


def _hostile_csv(tmp_path, rng, name):
    """RUNS.csv whose temperature column is called ``name`` (quoted as CSV allows)."""
    save_runs(_runs(rng), tmp_path / "CLEAN.csv")
    lines = (tmp_path / "CLEAN.csv").read_text().split("\n", 1)
    quoted = '"' + name.replace('"', '""') + '"'
    header = ",".join(quoted if h == "temp_c" else h for h in lines[0].split(","))
    path = tmp_path / "RUNS.csv"
    path.write_bytes((header + "\n" + lines[1]).encode())
    return path


def _run(capsys, argv):
    capsys.readouterr()
    code = cli(argv)
    err = capsys.readouterr().err
    return code, err


@pytest.mark.parametrize("name", HOSTILE)
def test_hostile_csv_header_is_refused(tmp_path, rng, capsys, name):
    """fit with --effects covariate:<the name> and compensate: exit 2, one line naming the
    file and the header field, "allowed:"; the input byte-identical, no output."""
    path = _hostile_csv(tmp_path, rng, name)
    before = path.read_bytes()
    code, err = _run(capsys, ["fit", str(path), "--effects", f"covariate:{name}", "-o", str(tmp_path / "FIT.json")])
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and "allowed:" in lines[0]
    if "\n" in name:   # a quoted cell over several lines is refused first, by the CSV reader
        assert "line 1: a quoted header field" in lines[0]
    else:
        assert "header field" in lines[0] and "allowed: letters A-Z a-z, digits 0-9 and _" in lines[0]
    assert path.read_bytes() == before and not (tmp_path / "FIT.json").exists()


@pytest.mark.parametrize("name", ["t*/x", "c*/\n#error injected\n/*", "k-1", ""])
def test_effects_option_refuses_hostile_covariate(tmp_path, rng, capsys, name):
    """--effects covariate:NAME is checked by the rule before any file is read: the message
    names --effects."""
    save_runs(_runs(rng), tmp_path / "RUNS.csv")
    code, err = _run(capsys, ["fit", str(tmp_path / "RUNS.csv"), "--effects", f"covariate:{name}"])
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "--effects: covariate column" in err and "allowed:" in err


def test_fit_json_with_hostile_covariate_is_refused(tmp_path, rng, capsys):
    """A FIT.json edited to carry a covariate effect with a hostile name (effects, names,
    parameters and run inputs all renamed consistently) is refused by export: exit 2 naming
    the file, no nav/ written."""
    runs = _runs(rng)
    save_fit(fit(runs, "hse,covariate:temp_c"), tmp_path / "FIT.json")
    bad = "c*/\n#error injected\n/*"
    text = (tmp_path / "FIT.json").read_text().replace("temp_c", json.dumps(bad)[1:-1])
    (tmp_path / "BAD.json").write_text(text)
    assert bad in json.loads(text)["effects"][-1]
    code, err = _run(capsys, ["export", str(tmp_path / "BAD.json"), "-o", str(tmp_path / "nav")])
    assert code == 2 and "BAD.json" in err and "allowed:" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "nav").exists()


def test_every_name_the_tool_uses_follows_the_rule():
    """The RUNS/PLAN columns and the catalogue's effect names (the rule written here as an
    independent regular expression) - so the rule refuses no file the tool writes."""
    rule = re.compile(r"[A-Za-z0-9_]{1,64}\Z")
    columns = [c.name for c in (*Runs._COLUMNS, *Plan._COLUMNS)]
    assert columns and all(rule.match(c) for c in columns), columns
    assert all(rule.match(e) for e in CATALOGUE)
    assert Covariate("temp_c").name == "covariate:temp_c"


@pytest.mark.parametrize("name", HOSTILE + ["", None, 7])
def test_check_name_refuses_with_one_line(name):
    with pytest.raises(ValueError, match=r"^covariate column .* is not allowed; allowed: letters") as err:
        check_name(name, "covariate column")
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match="allowed:"):
        Covariate(name)


def test_register_effect_refuses_a_hostile_name():
    class Bad(Effect):
        name = "bad*/name"
        params = ()

        def act(self, p, op, errors):  # pragma: no cover - never built
            pass
    with pytest.raises(ValueError, match="effect name 'bad\\*/name' is not allowed"):
        register_effect(Bad)
    assert "bad*/name" not in CATALOGUE
