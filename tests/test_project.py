"""The project file hse-opt.toml (issue 26 item 3): every command reads it, flags win, bad keys
are refused naming the file and key, ``hse-opt config`` says what is in force."""
import json
import subprocess
import sys

import pytest

from hse_opt.app.cli import _with_project, build_parser
from hse_opt.datasets import paper_table1_path


def cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "hse_opt.cli", *args], capture_output=True, text=True,
                          cwd=cwd, timeout=120)


def parsed(argv, cwd, monkeypatch):
    monkeypatch.chdir(cwd)
    parser = build_parser()
    return parser.parse_args(_with_project(parser, argv))


def test_the_file_sets_defaults_and_a_flag_wins(tmp_path, monkeypatch):
    (tmp_path / "hse-opt.toml").write_text('[site]\nlatitude_deg = 28.2\n[compute]\njobs = 2\n'
                                           '[model]\neffects = ["hse", "sync_delay"]\n')
    args = parsed(["design", "-o", "P.csv"], tmp_path, monkeypatch)
    assert args.latitude_deg == 28.2 and args.effects == "hse,sync_delay"
    args = parsed(["design", "-o", "P.csv", "--latitude-deg", "40", "--effects", "hse"], tmp_path, monkeypatch)
    assert args.latitude_deg == 40.0 and args.effects == "hse"
    assert parsed(["align", "L", "-o", "R.csv"], tmp_path, monkeypatch).jobs == 2
    assert parsed(["align", "L", "-o", "R.csv", "--jobs", "1"], tmp_path, monkeypatch).jobs == 1


def test_without_a_file_every_option_has_its_default(tmp_path, monkeypatch):
    with_file, without = tmp_path / "a", tmp_path / "b"
    with_file.mkdir(), without.mkdir()
    (with_file / "hse-opt.toml").write_text("[site]\nlatitude_deg = 12.5\n")
    assert parsed(["design", "-o", "P.csv"], without, monkeypatch).latitude_deg != 12.5
    assert parsed(["--config", str(with_file / "hse-opt.toml"), "design", "-o", "P.csv"], without,
                  monkeypatch).latitude_deg == 12.5


def test_a_fit_with_the_projects_effects_equals_the_fit_with_the_flag(tmp_path):
    from hse_opt.data import save_runs
    from hse_opt.datasets import example_campaign
    runs = str(tmp_path.parent / "RUNS.csv")
    save_runs(example_campaign(), runs)
    (tmp_path / "hse-opt.toml").write_text('[model]\neffects = "hse,sync_delay"\n')
    from_file = cli("fit", runs, "--json", cwd=tmp_path)
    from_flag = cli("fit", runs, "--json", "--effects", "hse,sync_delay", cwd=tmp_path.parent)
    plain = cli("fit", runs, "--json", cwd=tmp_path.parent)
    assert from_file.returncode == 0, from_file.stderr
    a, b, c = (json.loads(o.stdout) for o in (from_file, from_flag, plain))
    assert a["parameters"] == b["parameters"] and set(a["parameters"]) != set(c["parameters"])


def test_a_relative_calibration_path_is_taken_from_the_files_folder(tmp_path):
    from hse_opt.app import project
    (tmp_path / "site").mkdir()
    (tmp_path / "site" / "hse-opt.toml").write_text('[system]\ncalibration = "lab/CAL.toml"\n')
    p = project.load(tmp_path / "site" / "hse-opt.toml")
    assert p.settings[0].text == str((tmp_path / "site" / "lab" / "CAL.toml").resolve())


@pytest.mark.parametrize("text, words", [
    ("[site]\nlatitude = 28.2\n", ["[site] latitude", "allowed: latitude_deg"]),
    ("[sight]\nlatitude_deg = 28.2\n", ["[sight]", "allowed: site"]),
    ('[site]\nlatitude_deg = "north"\n', ["[site] latitude_deg", "allowed: a number"]),
    ("[compute]\njobs = 1.5\n", ["[compute] jobs", "allowed: an integer"]),
    ("[site\nlatitude_deg = 1\n", ["not a TOML file", "allowed: TOML"]),
    ("[model]\neffects = []\n", ["[model] effects", "allowed: a non-empty string"]),
])
def test_a_bad_project_file_is_refused_naming_the_file_and_key(tmp_path, text, words):
    (tmp_path / "hse-opt.toml").write_text(text)
    out = cli("fit", str(paper_table1_path()), cwd=tmp_path)
    assert out.returncode == 2 and out.stdout == ""
    line = out.stderr.strip()
    assert "\n" not in line and "hse-opt.toml" in line, line
    for w in words:
        assert w in line, line


def test_a_value_the_command_refuses_names_the_file_and_key(tmp_path):
    (tmp_path / "hse-opt.toml").write_text("[compute]\njobs = 0\n")
    out = cli("align", "nothing", "-o", "R.csv", cwd=tmp_path)
    assert out.returncode == 2 and "--jobs" in out.stderr and "[compute] jobs" in out.stderr, out.stderr


def test_config_prints_what_is_in_force_and_for_which_commands(tmp_path):
    (tmp_path / "hse-opt.toml").write_text('[site]\nlatitude_deg = 28.2\n[model]\neffects = "hse,sync_delay"\n')
    out = cli("config", "--json", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    rows = {r["key"]: r for r in got["settings"]}
    assert rows["latitude_deg"]["value"] == "28.2" and "align" in rows["latitude_deg"]["commands"]
    assert set(rows["effects"]["commands"]) >= {"fit", "diagnose", "design"}
    assert "fit" not in rows["latitude_deg"]["commands"]
    text = cli("config", cwd=tmp_path)
    assert "latitude_deg = 28.2" in text.stdout and "--latitude-deg" in text.stdout
    none = cli("config", cwd=tmp_path / "..")
    assert none.returncode == 0


def test_config_without_a_value_is_refused(tmp_path):
    out = cli("fit", str(paper_table1_path()), "--config", cwd=tmp_path)
    assert out.returncode == 2 and "--config" in out.stderr and "allowed" in out.stderr
