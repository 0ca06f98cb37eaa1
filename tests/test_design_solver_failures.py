"""Solver trouble in ``hse-opt design`` is never an internal error (new-user trial): a conic
solver that ends inaccurate is backed by the even design and IPOPT from it, judged by the
equivalence theorem's certificate; a refinement IPOPT cannot finish keeps the grid plan; what
still fails is one line with the solver's status and what the user can change (exit 1), or
the input's fault (exit 2). References: the D-optimal design of quadratic regression on
[-1, 1] (a third of the runs at -1, 0 and 1: Kiefer-Wolfowitz), the candidate grid."""
import csv
import io
import re
from contextlib import redirect_stderr, redirect_stdout

import cvxpy as cp
import numpy as np
import pytest

from hse_opt import units
from hse_opt.cli import main
from hse_opt.design import DesignError, approximate_design
from hse_opt.design import approximate
from hse_opt.fit import SolverError

X = np.linspace(-1.0, 1.0, 21)
QUADRATIC = np.column_stack([np.ones_like(X), X, X * X])


def _cli(argv):
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def test_an_inaccurate_conic_solution_is_replaced_by_a_certified_one(monkeypatch):
    """Both conic solvers return a poor point ending 'optimal_inaccurate' (all runs on -1,
    -0.9 and 1): the even design and IPOPT from it give the D-optimal design, certified."""
    real = approximate._convex

    def poor(sub):
        w, mus, _, _, grads = real(sub)
        bad = np.zeros_like(w)
        bad[[0, 1, sub.n - 1]] = sub.budget / 3.0
        return bad, mus, cp.OPTIMAL_INACCURATE, sub.solver, grads
    monkeypatch.setattr(approximate, "_convex", poor)
    a = approximate_design(QUADRATIC, "D", budget=30.0)
    assert a.certified_efficiency >= 0.99 and "then IPOPT from the even design" in a.solver, a.solver
    expected = np.zeros(21)
    expected[[0, 10, 20]] = 10.0
    np.testing.assert_allclose(a.runs, expected, atol=1e-3)


def test_a_conic_program_no_solver_solves_is_one_line_with_the_status(monkeypatch, tmp_path):
    """Every conic solver fails: DesignError, a SolverError with its status; the command line
    prints one line naming it and what to change, exit 1 (was 'internal error')."""
    def fails(problem, name):
        raise cp.error.SolverError(f"{name} failed (test)")
    monkeypatch.setattr(approximate, "_run_solver", fails)
    with pytest.raises(DesignError) as err:
        approximate_design(QUADRATIC, "D", budget=30.0)
    assert isinstance(err.value, SolverError) and err.value.status == "not solved"
    code, out, text = _cli(["design", "--budget-h", "2", "--criterion", "D", "-o", str(tmp_path / "P.csv")])
    assert code == 1 and out == "" and text.count("\n") == 1, text
    assert text.startswith("hse-opt design: error: the approximate design's convex program was not solved")
    assert "CLARABEL: solver error" in text and "allowed:" in text and "internal error" not in text


def test_the_trials_design_is_the_inputs_fault_and_a_failed_refinement_keeps_the_grid(tmp_path):
    """The trial's command (one rate 33.3 deg/s, axis_bias: offset, lambda2 and bias_z barely
    separable) exits 2 naming what to change; a design whose refinement IPOPT ends
    Invalid_Number_Detected is the grid plan, said so (both were 'internal error', exit 1)."""
    code, _, err = _cli(["design", "--budget-h", "1.4", "--warmup-s", "600", "--rates", "33.3:73.3", "--n-rates",
                         "1", "--durations-s", "120", "--azimuth-step-deg", "45", "--effects", "axis_bias",
                         "-o", str(tmp_path / "A.csv")])
    assert code == 2 and "internal error" not in err and "allowed:" in err and err.count("\n") == 1, err
    assert not (tmp_path / "A.csv").exists()
    # the same at 10 deg/s with no warm-up: the conic solvers and the even design end uncertified
    # (0.34); the candidates' even information names the combination they barely see (exit 2)
    code, _, err = _cli(["design", "--budget-h", "1.4", "--warmup-s", "0", "--rates", "10:10", "--n-rates", "1",
                         "--durations-s", "120", "--azimuth-step-deg", "90", "--effects", "axis_bias",
                         "-o", str(tmp_path / "A.csv")])
    assert code == 2 and err.count("\n") == 1, err
    assert "parameters offset, lambda2, bias_z cannot be told apart" in err and "even with every candidate run" in err


def _heading_reach_arcsec(effects, nominal, rates_dps, azimuths_deg, duration_s=300.0):
    """max over the runs of |h(p + range e_j) - h(p)| per parameter (arcsec), by finite
    differences of the symbolic model's heading (not its Jacobian) over the whole declared range."""
    from hse_opt.model.composition import as_model
    mm = as_model(effects).measurement(True)
    rate, az = (np.deg2rad(g).ravel() for g in np.meshgrid(rates_dps, azimuths_deg))
    X = mm.inputs(rate, az, np.deg2rad(40.0), duration=duration_s, pitch=0.0, roll=0.0)
    p0 = mm.vector(nominal)
    h0 = np.ravel(mm.predict(p0, X))
    reach = np.zeros(len(mm.names))
    for j, q in enumerate(mm.params):  # one perturbed parameter vector per parameter
        p = p0.copy()
        p[j] += (q.upper - q.lower) * q.scale
        reach[j] = np.abs(np.ravel(mm.predict(p, X)) - h0).max() / units.ARCSEC
    return dict(zip(mm.names, reach))


def test_a_parameter_no_candidate_run_sees_is_named_not_planned_with_sigma_1e13(tmp_path):
    """design --effects encoder_harmonic quoted sigmas of 1e12-1e13 arcsec for enc_c1..enc_s2 after
    'optimal' conic programs with certificate 0 (the identifiability check normalised columns of
    rounding); --criterion A ended exit 1. The fit's floor (a parameter moving no run's heading by
    1e-6 arcsec across its whole range is invisible) now names them, exit 2, with what would help.
    Reference: finite differences of the model's heading over the parameters' whole ranges."""
    rates, azimuths = (20.0, 40.0, 60.0, -20.0, -60.0), (0.0, 90.0, 135.0, 270.0)
    reach = _heading_reach_arcsec(["hse", "encoder_harmonic"], {}, rates, azimuths)
    assert all(reach[n] < 1e-6 for n in ("enc_c1", "enc_s1", "enc_c2", "enc_s2")), reach
    assert reach["lambda2"] > 1.0, reach
    lit = _heading_reach_arcsec(["hse", "encoder_harmonic"], {"lambda2": 4.0}, rates, azimuths)
    assert lit["enc_c1"] > 1.0 and lit["enc_s1"] > 1.0 and max(lit["enc_c2"], lit["enc_s2"]) < 1e-6, lit
    for extra in ([], ["--criterion", "A"]):
        code, out, err = _cli(["design", "--budget-h", "1.4", "--warmup-s", "600", "--rates", "20:60", "--n-rates",
                               "3", "--durations-s", "300", "--azimuth-step-deg", "90", "--effects", "encoder_harmonic",
                               "--reverse", *extra, "-o", str(tmp_path / "B.csv")])
        assert code == 2 and out == "" and err.count("\n") == 1, (extra, code, err)
        assert "no information on enc_c1, enc_s1, enc_c2, enc_s2" in err, err
        assert "--nominal NAME=VALUE" in err and "fewer effects" in err and "e+1" not in err, err
        assert not (tmp_path / "B.csv").exists()
    # with lambda2 away from 0 the 1st harmonic is seen; the 2nd never is, and is still named
    code, out, err = _cli(["design", "--budget-h", "1.4", "--warmup-s", "600", "--rates", "20:60", "--n-rates", "3",
                           "--durations-s", "300", "--azimuth-step-deg", "90", "--effects", "encoder_harmonic",
                           "--nominal", "lambda2=4", "-o", str(tmp_path / "B.csv")])
    assert code == 2 and "no information on enc_c2, enc_s2:" in err and "enc_c1" not in err, err
    # --evaluate of a plan for the paper's model names them too (it printed sigma 1e13 arcsec)
    code, _, err = _cli(["design", "--budget-h", "1.4", "--warmup-s", "600", "--rates", "20:60", "--n-rates", "3",
                         "--durations-s", "300", "--azimuth-step-deg", "90", "--effects", "hse",
                         "-o", str(tmp_path / "P.csv")])
    assert code == 0, err
    code, out, err = _cli(["design", "--evaluate", str(tmp_path / "P.csv"), "--effects", "encoder_harmonic"])
    assert code == 2 and out == "" and "no information on enc_c1, enc_s1, enc_c2, enc_s2" in err, err


@pytest.mark.slow
def test_a_random_sweep_of_design_options_has_no_internal_error(tmp_path):
    """Twelve option sets drawn from a seeded generator around the trial's (budgets 0.8-3 h,
    warm-ups, one to three rate levels, durations, azimuth steps, an effect, both senses,
    criteria): each ends 0, or 2 (the input), or 1 with the solver's status in one line."""
    rng = np.random.default_rng(26)
    effects = ["axis_bias", "sync_delay", "scale_nonlinearity", "encoder_harmonic", ""]
    for k in range(12):
        lo = float(rng.choice([10.0, 20.0, 33.3, 40.0]))
        argv = ["design", "--budget-h", str(rng.choice([0.8, 1.4, 2.0, 3.0])), "--warmup-s",
                str(rng.choice([0, 600, 1200])), "--rates", f"{lo}:{lo + float(rng.choice([0, 20, 40]))}",
                "--n-rates", str(rng.choice([1, 2, 3])), "--durations-s", str(rng.choice(["120", "300", "120,600"])),
                "--azimuth-step-deg", str(rng.choice([30, 45, 90])), "-o", str(tmp_path / f"P{k}.csv")]
        effect = rng.choice(effects)
        argv += ["--effects", effect] if effect else []
        argv += ["--reverse"] if rng.random() < 0.3 else []
        code, _, err = _cli(argv)
        assert "internal error" not in err, (argv, err)
        assert code == 0 or (code in (1, 2) and err.count("\n") == 1 and "allowed" in err), (argv, code, err)
