"""``hse-opt demo``: the hidden effect against the simulator, the printed/JSON/report numbers
against each other, and the report in a real browser."""
import json
import re
from pathlib import Path

import numpy as np
import pytest

from browser import render
from hse_opt import demo, units
from hse_opt.cli import main
from hse_opt.information import heading_sigma
from hse_opt.model import Model
from hse_opt.sim import TruthConfig, simulate_heading_error

SEED = 0


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    """One demo run through the command line's steps: (JSON, output directory, printed lines)."""
    from hse_opt.commands.demo import summary_lines
    out = tmp_path_factory.mktemp("demo") / "out"
    result = demo.run_demo(SEED)
    data = json.loads(json.dumps(demo.write_outputs(result, out)))
    return data, out, summary_lines(result, "hse_opt_demo")


#: the designed plans' sigma and gain reproduce to this relative tolerance on any machine: the
#: c-optimum is flat and its symmetric candidates tie exactly, but ties are broken canonically
#: (hse_opt/design/ties.py: 1e-12 noise in every row gives the same plan, test_design.py), so
#: the plan is the same and its sigma differs by IPOPT's tolerance; 1% leaves room for the
#: printed digit (before the canonical ties: 0.502 or 0.491 arcsec, and 3%)
DESIGN_RTOL = 0.01


@pytest.mark.slow
def test_the_readme_shows_what_the_demo_prints(demo_run):
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
    shown = re.search(r"```text\n(hse-opt demo, seed 0:.*?)```", readme, re.S).group(1).splitlines()
    printed = demo_run[2]
    assert len(shown) == len(printed)
    number = r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?"
    for a, b in zip(shown, printed):
        if "optimised" not in a:
            assert a == b
            continue
        assert re.sub(number, "#", a) == re.sub(number, "#", b)  # the same words
        for x, y in zip(re.findall(number, a), re.findall(number, b)):
            assert float(x) == pytest.approx(float(y), rel=DESIGN_RTOL), (a, b)


def test_json_is_the_summary_file_and_the_reports_numbers(demo_run):
    data, out, _ = demo_run
    assert sorted(p.name for p in out.iterdir()) == sorted(demo.OUTPUT_FILES)
    assert json.loads((out / "summary.json").read_text()) == data
    html = (out / "report.html").read_text(encoding="utf-8")
    # the statistics tables show the JSON's numbers (4 significant digits)
    rms = [float(v) for v in re.findall(r'<tr data-key="rms_arcsec"><td>[^<]*</td><td>([^<]*)</td>', html)]
    assert rms[0] == pytest.approx(data["before"]["rms_arcsec"], rel=5e-4)
    embedded = json.loads(re.search(r'id="hse-opt-data">(.*?)</script>', html, re.S).group(1))
    fit = embedded["The paper's model"]["fit"]
    assert fit["rms_arcsec"] == pytest.approx(data["before"]["rms_arcsec"], rel=1e-12)
    assert fit["n_runs"] == data["n_runs"] == len(demo.demo_plan())


def test_the_campaign_shows_the_hidden_effect(demo_run):
    data, _, _ = demo_run
    hidden = demo.hidden_effect(SEED)
    assert data["hidden_effect"] == hidden.name
    # the noise is the simulator's 10-minute heading scatter, and the paper's model misfits
    assert data["noise_arcsec"] == pytest.approx(heading_sigma(600.0, 28.07 * units.DEG) / units.ARCSEC,
                                                 rel=0.05)
    # 2 sigma RMS hidden on top of the noise: sqrt(1 + 2^2) noise sigmas, within the scatter
    expect = np.sqrt(1 + demo.HIDDEN_SIGMAS ** 2) * data["noise_arcsec"]
    assert 0.75 * expect < data["before"]["rms_arcsec"] < 1.25 * expect
    assert data["before"]["chi2_red"] > 2.5


def test_the_diagnosis_names_the_hidden_effect_and_the_error_falls(demo_run):
    data, _, _ = demo_run
    assert data["diagnosis"]["verdict"] == "missing-effect"
    assert data["named_effect"] == data["hidden_effect"] and data["found"]
    after = data["after"]
    assert after["effects"] == ["hse", data["hidden_effect"]]
    # down to the noise: within 20 % of the simulator's scatter, and no test rejecting
    assert after["rms_arcsec"] < 1.2 * data["noise_arcsec"]
    # no test rejects; a residual systematic risk (another effect this campaign would miss) makes
    # the verdict inconclusive, never the hidden effect itself (it is in the model now)
    risky = {e for p in after["parameters"].values() for e in p["systematic_by"]}
    assert data["verdict_after"] == ("inconclusive" if risky else "adequate")
    assert data["hidden_effect"] not in risky
    # the hidden parameters are recovered within 3 of their standard errors
    for name, value in data["hidden_values"].items():
        p = after["parameters"][name]
        assert abs(p["value"] - value) < 3 * p["std"], name


def test_demo_reproduces_the_papers_numbers(demo_run):
    paper = demo_run[0]["paper"]
    assert abs(paper["k_hse_model_arcsec_per_radps"] - 17.4) < 0.01
    assert 25 < paper["example_amplitude_model"] < 35


def test_demo_report_renders_in_chromium(demo_run, tmp_path):
    _, out, _ = demo_run
    probe, pixels = render(out / "report.html", tmp_path)
    assert probe["images"] == (out / "report.html").read_text().count('<img class="plot"') >= 9
    assert probe["decoded"] == probe["images"]
    assert pixels.std() > 10


def test_hidden_effects_put_into_the_simulator_match_the_model():
    """The truth changes of every drawable effect make the simulator's heading errors what
    the symbolic model predicts with the hidden parameter values (noise-free, 7 plan runs,
    differences between runs since the offsets differ)."""
    plan = demo.demo_plan()
    idx = np.array([0, 1, 4, 8, 19, 25, 33])
    sub = plan.subset(idx)
    base = TruthConfig.ideal().updated({"thermal": {"swing_c": 1.5, "swing_period_s": 14400.0}})
    seen = {}
    for seed in range(200):
        h = demo.hidden_effect(seed)
        seen.setdefault(h.name, h)
        if len(seen) == len(demo.showable()):
            break
    assert set(seen) == set(demo.showable())
    for name, h in seen.items():
        truth = base.updated(h.truth_changes)
        sim = np.array([simulate_heading_error(truth, sub.rate[i], sub.azimuth[i], duration=600.0,
                                               t_start=sub.t_start[i], tilt=(sub.tilt_x[i], sub.tilt_y[i]))
                        for i in range(len(sub))])
        mm = Model(["hse", name]).measurement(tilt_known=True)
        pred = mm.predict(mm.vector(h.values), demo._plan_inputs(mm, sub, truth))
        d_sim, d_mod = (sim - sim.mean()) / units.ARCSEC, (pred - pred.mean()) / units.ARCSEC
        assert np.ptp(d_sim) > 10, name                     # the effect is there, a few sigmas
        assert np.max(np.abs(d_sim - d_mod)) < 0.03 * np.ptp(d_sim) + 0.1, name


def test_every_drawable_effect_is_drawn_and_the_rest_have_no_signature():
    names = [demo.hidden_effect(s).name for s in range(60)]
    assert set(names) == set(demo.showable())
    not_drawn = set(demo.hideable()) - set(demo.showable())
    assert not_drawn == {"encoder_harmonic"}
    # the sizing model (hse + encoder_harmonic, no mount_xi) at lambda2 = 0: no heading signature
    mm = Model(["hse", "encoder_harmonic"]).measurement(tilt_known=True)
    plan = demo.demo_plan()
    J = mm.jacobian(mm.nominal, demo._plan_inputs(mm, plan, demo.demo_truth()))
    enc = J[:, 2:] * mm.scale[2:]
    assert np.max(np.abs(enc)) < 1e-6 * units.ARCSEC      # per arcsec of encoder error


@pytest.mark.parametrize("args, match", [
    (["--seed", "-1"], "--seed -1 is not allowed"),
    (["--out", __file__], "is a file"),
])
def test_bad_arguments_exit_2_with_one_line(args, match, capsys):
    assert main(["demo", *args, "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and re.search(match, err)


def test_the_demo_designs_a_better_next_plan(demo_run):
    nxt = demo_run[0]["next_plan"]
    assert not nxt["failed"]
    assert nxt["effects"] == ["hse", demo_run[0]["named_effect"]]
    assert nxt["criterion"] == "protect:lambda2"
    # within the paper plan's test time, and better than it for the paper's goal: a little
    # under the paper's own limits, by far with the tilt fixture (issue 5's targets)
    from hse_opt.design import paper_plan
    paper = paper_plan()
    for key, least in (("paper_limits", 1.0), ("tilt_fixture", 5.0)):
        d = nxt[key]
        assert d["total_time_h"] <= (paper.t_start[-1] + paper.duration[-1]) / 3600 + 1e-9
        assert d["gain"] == pytest.approx(nxt["paper_sigma_lambda2_arcsec"] / d["sigma_lambda2_arcsec"])
        assert d["gain"] > least, key


@pytest.mark.parametrize("name", demo.showable())
def test_the_next_plan_is_designed_for_every_drawable_effect(name):
    """The design step of the chain for the model each seed can end with, linearised at the
    hidden values (what the refit recovers)."""
    h = next(demo.hidden_effect(s) for s in range(200) if demo.hidden_effect(s).name == name)
    nxt = demo.design_next(Model(["hse", name]), h.values)
    assert nxt.design is not None and nxt.level is not None, nxt.notes
    assert nxt.design.std_of("lambda2") < 0.2


@pytest.mark.slow
def test_a_short_warm_up_gets_a_next_plan_too():
    """The shortest warm-up the demo draws (10 min): the plan starts at power-on, in four time
    slots, and beats the paper's plan with and without the fixture."""
    nxt = demo.design_next(Model(["hse", "warmup"]), {"warmup_amp": -90.0, "warmup_tau": 600.0})
    assert nxt.design is not None and nxt.level is not None, nxt.notes
    assert nxt.design.plan.t_start[0] < 600.0                # during the transient
    assert nxt.gain("level") > 1.0 and nxt.gain("design") > 5.0


def test_the_report_compares_the_fixture_plan_as_such(demo_run):
    """The next plan's sigmas against the paper's plan: the figure says the plan has the tilt
    fixture the paper's plan has not (before: "the optimised plan ... 64.7x smaller")."""
    _, out, _ = demo_run
    html = (out / "report.html").read_text(encoding="utf-8")
    assert "the optimised plan with the 0.5-deg tilt fixture against the paper&#x27;s plan" in html \
        or "the optimised plan with the 0.5-deg tilt fixture against the paper's plan" in html
    assert 'data-key="power:sync_delay"' in html   # the plan's protection is in the report


def test_the_live_session_steers_the_campaign_and_its_sigma_falls(demo_run):
    """The demo's live session: one line per log, the runs counted, the next alignment each
    time; the alignments the session asked for bring lambda2's sigma down."""
    lines = demo_run[0]["session"]
    assert len(lines) == demo.SESSION_LOGS
    for k, line in enumerate(lines, start=1):
        assert line.startswith(f"[{k} run{'s' if k > 1 else ''}]") and "; next: " in line
    sigmas = [float(m.group(1)) for m in (re.search(r"\+- ([0-9.e+]+) arcsec", ln) for ln in lines) if m]
    assert len(sigmas) >= 2 and sigmas[-1] < 0.5 * sigmas[0]
