"""``hse-opt export``: the generated C, compiled with the system's compiler and called through
ctypes, against ``hse-opt compensate`` (Python/CasADi) at 10,000 random operating points over
the validity range, for the paper's model and for one with every catalogue effect; the
validity range against the documented rule applied to the calibration runs' own columns;
the status code outside it; calibration.json against the paper's closed forms."""
import ctypes
import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from hse_opt import units
from hse_opt.cli import main as cli
from hse_opt.data import Runs, load_runs, save_runs
from hse_opt.export import MARGIN_FLOOR, MARGIN_FRACTION
from hse_opt.fit import fit, save_fit
from hse_opt.model import CATALOGUE, Model
from hse_opt.model import closed_form as cf

COMPILER = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
needs_cc = pytest.mark.skipif(COMPILER is None, reason="no C compiler (cc, gcc or clang) on PATH")
#: every catalogue effect, and one covariate (the catalogue's covariate:<column> form)
EVERY_EFFECT = [*CATALOGUE, "covariate:temp_c"]
N_POINTS = 10_000
#: input columns of RUNS.csv in the C entry point's order (file unit factors)
COLUMNS = (("rate_dps", units.DEG_PER_S), ("azimuth_deg", units.DEG), ("pitch_arcsec", units.ARCSEC),
           ("roll_arcsec", units.ARCSEC), ("latitude_deg", units.DEG), ("t_start_s", 1.0),
           ("duration_s", 1.0))


def _campaign(effects, n, rng):
    """``n`` runs from the measurement model plus 7.6-arcsec noise: rates 20-60 deg/s both
    senses, random azimuths, tilts up to 2 mrad, sessions after power-on, a temperature."""
    model = Model(effects)
    mm = model.measurement(True)
    rate = rng.choice([-1, 1], n) * rng.uniform(20, 60, n) * units.DEG_PER_S
    az = rng.uniform(0, 2 * np.pi, n)
    pitch, roll = rng.uniform(-2e-3, 2e-3, (2, n))
    lat = rng.uniform(0.48, 0.50, n)
    t0 = (np.arange(n) % 12) * 700.0 + 60.0
    temp = rng.normal(25, 2, n)
    cov = {c: temp for c in mm.covariates}
    X = mm.inputs(rate, az, lat, 600.0, t0, pitch, roll, cov)
    truth = {q.name: (q.nominal if q.name in mm.nonlinear else
                      0.01 * (q.upper - q.lower) * rng.choice([-1, 1])) for q in mm.params}
    sigma = 7.6 * units.ARCSEC
    y = mm.predict(mm.vector(truth), X) + sigma * rng.standard_normal(n)
    runs = Runs(run=np.arange(1, n + 1), rate=rate, azimuth=az, heading_err=y, latitude=lat,
                duration=np.full(n, 600.0), t_start=t0, pitch=pitch, roll=roll,
                heading_std=np.full(n, sigma), covariates={"temp_c": temp} if cov else {})
    # parameters without a heading signature in these runs (the encoder's 2nd harmonic)
    J = mm.jacobian(mm.vector(truth), X)
    per_unit = np.abs(J).max(axis=0) * mm.scale             # rad of heading per display unit
    held = {nm: 0.0 for nm, g in zip(mm.names, per_unit) if g < 1e-6 * units.ARCSEC}
    # the mount's horizontal misalignment reaches heading only in a product with the encoder's
    # 1st harmonic: held at its true value, the encoder's is fitted
    held.update({nm: truth[nm] for nm in ("xi_x", "xi_y") if nm in mm.names})
    return runs, fit(runs, model, fix=held)


def _expected_range(runs, bounded):
    """The documented rule (hse_opt/fit/domain.py) on the runs' own columns: [min, max] of
    |rate|, C23 = -roll cos(azimuth) + pitch sin(azimuth) and the other bounded inputs,
    widened by max(MARGIN_FRACTION * span, floor); |rate| and times not below 0."""
    c23 = -runs.roll * np.cos(runs.azimuth) + runs.pitch * np.sin(runs.azimuth)
    cols = {"rate": np.abs(runs.rate), "c23": c23, "t_start": runs.t_start, "duration": runs.duration,
            **runs.covariates}
    out = {}
    for name in bounded:
        v = cols[name]
        m = max(MARGIN_FRACTION * np.ptp(v), MARGIN_FLOOR.get(name, 0.0))
        lo = v.min() - m
        out[name] = (max(lo, 0.0) if name in ("rate", "t_start", "duration") else lo, v.max() + m)
    return out


def _build(directory):
    lib = directory / "libhse.so"
    subprocess.run([COMPILER, "-std=c99", "-pedantic", "-O2", "-shared", "-fPIC", "-o", str(lib),
                    str(directory / "hse_compensation.c"), "-lm"], check=True, capture_output=True)
    f = ctypes.CDLL(str(lib)).hse_compensation
    f.restype = ctypes.c_int
    f.argtypes = [ctypes.POINTER(ctypes.c_double)] * 3
    return f


def _call(f, X):
    """The C entry point at each column of X: (status, correction_rad, sigma_rad)."""
    n = X.shape[1]
    XT = np.ascontiguousarray(X.T)
    out = np.empty((3, n))
    c, s = ctypes.c_double(), ctypes.c_double()
    ptr = ctypes.POINTER(ctypes.c_double)
    for i in range(n):
        out[0, i] = f(XT[i].ctypes.data_as(ptr), ctypes.byref(c), ctypes.byref(s))
        out[1, i], out[2, i] = c.value, s.value
    return out


def _random_points(cal_json, n, rng):
    """``n`` operating points drawn uniformly over the validity domain (SI, C order): inputs
    with an interval within it, the others over the calibration runs' range (headings all
    round, tilts up to 1 mrad), then kept where C23 lies in its interval."""
    rows = cal_json["inputs"]
    c23 = {q["name"]: q for q in cal_json["domain"]["quantities"]}.get("c23")
    X = np.empty((len(rows), 0))
    while X.shape[1] < n:
        Y = np.empty((len(rows), 4 * n))
        for r in rows:
            rng_ = r["range"] or r["data_range"]
            if r["name"] == "azimuth":
                Y[r["index"]] = rng.uniform(0, 2 * np.pi, 4 * n)
            elif r["name"] in ("pitch", "roll"):
                Y[r["index"]] = rng.uniform(-1e-3, 1e-3, 4 * n)
            else:
                Y[r["index"]] = rng.uniform(rng_["lower"], rng_["upper"], 4 * n)
        Y[0] *= rng.choice(rows[0]["senses"], 4 * n)
        if c23 is not None:
            v = -Y[3] * np.cos(Y[1]) + Y[2] * np.sin(Y[1])
            Y = Y[:, (v > c23["lower"]) & (v < c23["upper"])]
        X = np.concatenate([X, Y], axis=1)
    return X[:, :n]


def _compensate_cli(tmp_path, fit_json, X, covariates):
    """``hse-opt compensate`` at the points X: (correction to add, sigma), rad."""
    cols = {name: X[i] / f for i, (name, f) in enumerate(COLUMNS)}
    cols.update({c: X[len(COLUMNS) + j] for j, c in enumerate(covariates)})
    n = X.shape[1]
    runs = Runs(run=np.arange(1, n + 1), rate=X[0], azimuth=X[1], heading_err=np.zeros(n),
                latitude=X[4], duration=X[6], t_start=X[5], pitch=X[2], roll=X[3],
                covariates={c: X[len(COLUMNS) + j] for j, c in enumerate(covariates)})
    save_runs(runs, tmp_path / "POINTS.csv")
    assert cli(["compensate", str(tmp_path / "POINTS.csv"), "--fit", str(fit_json),
                "-o", str(tmp_path / "OUT.csv"), "--allow-small-azimuths"]) == 0
    out = load_runs(tmp_path / "OUT.csv", allow_small_azimuths=True)
    # heading_err 0: the compensated error is minus the modelled error, the correction to add
    return (out.covariates["heading_err_comp_arcsec"] * units.ARCSEC,
            out.covariates["heading_comp_std_arcsec"] * units.ARCSEC, out.covariates["comp_status"])


def _export(tmp_path, calibration):
    save_fit(calibration, tmp_path / "FIT.json")
    assert cli(["export", str(tmp_path / "FIT.json"), "-o", str(tmp_path / "nav")]) == 0
    return json.loads((tmp_path / "nav" / "calibration.json").read_text())


def _check_against_compensate(tmp_path, cal_json, rng, covariates=()):
    f = _build(tmp_path / "nav")
    X = _random_points(cal_json, N_POINTS, rng)
    status, corr_c, sigma_c = _call(f, X)
    corr_py, sigma_py, status_py = _compensate_cli(tmp_path, tmp_path / "FIT.json", X, covariates)
    assert np.all(status == 0) and np.all(status_py == 0)
    assert np.abs(corr_c - corr_py).max() / units.ARCSEC < 1e-6
    assert np.abs(sigma_c - sigma_py).max() / units.ARCSEC < 1e-6
    assert np.ptp(corr_py) > 1.0 * units.ARCSEC and sigma_py.min() > 0  # a comparison that can fail
    return f, X


def _check_status(f, cal_json, expected):
    """Each bounded input just outside its interval sets exactly its own bit, just inside 0;
    every input NaN sets its bit; C23 just outside sets bit 30; the other sense its bit."""
    rows = cal_json["inputs"]
    quantities = {q["name"]: q for q in cal_json["domain"]["quantities"]}
    assert set(quantities) == set(expected)
    base = np.array([[0.5 * (r["range"]["lower"] + r["range"]["upper"]) if r["range"] else
                      0.0 if r["name"] in ("pitch", "roll") else
                      0.5 * (r["data_range"]["lower"] + r["data_range"]["upper"])] for r in rows])
    assert _call(f, base)[0, 0] == 0
    for r in rows:
        k = r["index"]
        X = base.copy()
        X[k] = np.nan   # heading, pitch or roll NaN: C23 too
        c23_too = "c23" in quantities and r["name"] in ("azimuth", "pitch", "roll")
        assert _call(f, X)[0, 0] == (1 << k) | (c23_too << 30), r["name"]
        if r["range"] is None:
            continue
        lo, hi = expected[r["name"]]
        assert r["range"]["lower"] == pytest.approx(lo, rel=1e-12, abs=1e-15)
        assert r["range"]["upper"] == pytest.approx(hi, rel=1e-12)
        for value, bit in ((hi * (1 + 1e-9) + 1e-12, 1 << k), (hi * (1 - 1e-9), 0)):
            X = base.copy()
            X[k] = value
            assert _call(f, X)[0, 0] == bit, (r["name"], value)
    if "c23" in quantities:   # roll alone at heading 0: C23 = -roll
        lo, hi = expected["c23"]
        assert quantities["c23"]["lower"] == pytest.approx(lo, rel=1e-12)
        assert quantities["c23"]["upper"] == pytest.approx(hi, rel=1e-12)
        for value, bit in ((hi * (1 + 1e-9) + 1e-12, 1 << 30), (hi * (1 - 1e-9), 0),
                           (lo * (1 + 1e-9) - 1e-12, 1 << 30), (lo * (1 - 1e-9), 0)):
            X = base.copy()
            X[1], X[3] = 0.0, -value
            assert _call(f, X)[0, 0] == bit, ("c23", value)
    X = base.copy()
    X[0] = -X[0]  # the other rotation sense
    assert _call(f, X)[0, 0] == (0 if len(rows[0]["senses"]) == 2 else 1)


@needs_cc
def test_paper_model_c_equals_compensate(tmp_path, monkeypatch, rng):
    monkeypatch.chdir(tmp_path)  # CasADi's jit of the 10,000 points writes objects into the cwd
    runs, calibration = _campaign(["hse"], 60, rng)
    cal_json = _export(tmp_path, calibration)
    f, _ = _check_against_compensate(tmp_path, cal_json, rng)
    _check_status(f, cal_json, _expected_range(runs, ("rate", "c23")))
    # Eq. 14 coefficients: K_HSE at each position from the closed form with the fitted lambda2
    lam, lam_std = calibration.value("lambda2")
    assert cal_json["eq14"]["lambda2_arcsec"] == {"value": lam, "std": lam_std}
    for pos in cal_json["eq14"]["positions"][:5]:
        k = cf.k_hse(lam, cf.c23(np.radians(pos["azimuth_deg"]), pos["pitch_arcsec"] * units.ARCSEC,
                                 pos["roll_arcsec"] * units.ARCSEC), np.radians(pos["latitude_deg"]))
        assert pos["k_hse_arcsec_per_radps"] == pytest.approx(k, rel=1e-9)


@needs_cc
@pytest.mark.slow
def test_every_catalogue_effect_c_equals_compensate(tmp_path, monkeypatch, rng):
    monkeypatch.chdir(tmp_path)  # CasADi's jit of the 10,000 points writes objects into the cwd
    runs, calibration = _campaign(EVERY_EFFECT, 240, rng)
    cal_json = _export(tmp_path, calibration)
    assert cal_json["effects"] == EVERY_EFFECT and cal_json["eq14"] is None
    assert [r["name"] for r in cal_json["inputs"]][-1] == "temp_c"
    f, _ = _check_against_compensate(tmp_path, cal_json, rng, covariates=("temp_c",))
    # warmup: the correction depends on the time since power-on and the duration; the
    # covariate is the stand's (not compensated): not bounded
    _check_status(f, cal_json, _expected_range(runs, ("rate", "c23", "t_start", "duration")))


@needs_cc
def test_paper_table1_export(tmp_path, monkeypatch):
    """Table 1 (tilt unknown, one rate, no times): K_HSE at the four stand azimuths from the
    fitted C23 sinusoid; pitch/roll are not inputs of such a calibration; one rotation sense."""
    monkeypatch.chdir(tmp_path)  # CasADi's jit of the 10,000 points writes objects into the cwd
    from hse_opt.datasets import paper_table1

    runs = paper_table1()
    calibration = fit(runs, fix={"lambda2*tilt_const": 0.0})
    cal_json = _export(tmp_path, calibration)
    f, X = _check_against_compensate(tmp_path, cal_json, np.random.default_rng(1))
    assert [r["range"] is None for r in cal_json["inputs"]] == [False] + [True] * 6   # |rate| alone
    assert [q["name"] for q in cal_json["domain"]["quantities"]] == ["rate"]          # C23 fitted per heading
    assert cal_json["inputs"][0]["senses"] == [1]
    eq = cal_json["eq14"]
    assert eq["lambda2_arcsec"] is None and len(eq["positions"]) == 4
    tc, ts = calibration.value("lambda2*tilt_cos")[0], calibration.value("lambda2*tilt_sin")[0]
    for pos, az in zip(eq["positions"], np.radians([0.0, 91.8795, 181.2953, 272.8711])):
        lam_c23 = (tc * np.cos(az) + ts * np.sin(az)) * units.ARCSEC * units.MRAD
        k = cf.k_hse(lam_c23, 1.0, np.radians(28.07)) / units.ARCSEC
        assert pos["k_hse_arcsec_per_radps"] == pytest.approx(k, rel=1e-9)
    assert "pitch_arcsec" not in eq["positions"][0]           # no tilts in Table 1
    assert "SIGN: *correction_rad is the correction to ADD" in (tmp_path / "nav" / "hse_compensation.h").read_text()


def test_generated_source_is_reentrant_c99_with_libm_only(tmp_path, rng):
    """No file-scope mutable state (only const tables and functions), no allocation, only
    <math.h> and its own header included."""
    _, calibration = _campaign(["hse", "sync_delay"], 30, rng)
    _export(tmp_path, calibration)
    src = (tmp_path / "nav" / "hse_compensation.c").read_text()
    assert set(re.findall(r"#include\s*[<\"]([^>\"]+)", src)) == {"math.h", "hse_compensation.h"}
    assert not re.search(r"\b(malloc|calloc|realloc|free|printf)\s*\(", src)
    body, previous = src, None
    while body != previous:  # remove every brace-enclosed body, innermost first
        previous, body = body, re.sub(r"\{[^{}]*\}", ";", body)
    file_scope = [ln for ln in body.splitlines() if re.match(r"^(static\s+)?[A-Za-z_][\w\s\*]*\w\s*(\[|=|;)", ln)]
    assert all(ln.startswith("static const") for ln in file_scope), file_scope


def test_export_needs_the_fit_runs(tmp_path):
    """A FIT.json without the calibration runs' inputs cannot say where it holds: exit 2."""
    runs, calibration = _campaign(["hse"], 30, np.random.default_rng(3))
    save_fit(calibration, tmp_path / "FIT.json")
    d = json.loads((tmp_path / "FIT.json").read_text())
    del d["runs"]["inputs"]
    (tmp_path / "OLD.json").write_text(json.dumps(d))
    assert cli(["export", str(tmp_path / "OLD.json"), "-o", str(tmp_path / "nav")]) == 2
    assert not (tmp_path / "nav").exists()


#: the strictest flags the issue names, and a caller that includes the header (C99 and C++)
STRICT = ["-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror"]
CALLER = """#include "hse_compensation.h"
int main(void) {
  double in[HSE_COMP_N_INPUTS] = {0}, c = 0.0, s = 0.0;
  return hse_compensation(in, &c, &s) == HSE_COMP_OK ? 0 : 1;
}
"""


def _compile_strict(nav):
    """nav/hse_compensation.c and a caller compiled and linked with :data:`STRICT`; the
    compiler's output on failure."""
    (nav / "caller.c").write_text(CALLER)
    done = subprocess.run([COMPILER, *STRICT, "-o", str(nav / "caller"), str(nav / "caller.c"),
                           str(nav / "hse_compensation.c"), "-lm"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert not done.stderr  # not even a note


@needs_cc
@pytest.mark.parametrize("effects", [["hse"], ["hse", "warmup", "covariate:temp_c"]])
def test_generated_code_compiles_clean_under_wextra(tmp_path, rng, effects):
    """-std=c99 -pedantic -Wall -Wextra -Werror: no warning (CasADi's functions take iw, w
    and mem whether they use them or not: the generator marks the unused ones)."""
    _, calibration = _campaign(effects, 40, rng)
    _export(tmp_path, calibration)
    src = (tmp_path / "nav" / "hse_compensation.c").read_text()
    assert "(void)mem;" in src          # the case that warned: the model's release(int mem)
    _compile_strict(tmp_path / "nav")


@needs_cc
def test_hostile_source_name_stays_in_its_comment(tmp_path, rng):
    """The source's name (FIT.json's file name from the command line, any string from
    Python) is the one free text that reaches the C files' comments: one that closes the
    comment by a backslash-newline splice (``*\\`` newline ``/``) and then holds an ``#error``
    line compiles clean, and no line of the header or source starts with ``#error``; from the
    command line too, with a file name holding newlines and ``#error``."""
    from hse_opt.export import export_calibration

    _, calibration = _campaign(["hse"], 30, rng)
    export_calibration(calibration, tmp_path / "api", source="x*\\\n/\n#error injected\n/*")
    name = "x*\\\n#error injected\n.json"
    save_fit(calibration, tmp_path / name)
    assert cli(["export", str(tmp_path / name), "-o", str(tmp_path / "nav")]) == 0
    for nav in ("api", "nav"):
        for f in ("hse_compensation.h", "hse_compensation.c"):
            text = (tmp_path / nav / f).read_text()
            assert not re.search(r"^\s*#\s*error", text, re.M) and "\\\n" not in text
        _compile_strict(tmp_path / nav)
