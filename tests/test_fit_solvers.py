"""The fit's solver internals against independent references: the chi2 rounding the step
halving tolerates (measured on the model), and the profile start of a nonlinear parameter
(an exhaustive grid with the linear parameters solved by numpy's least squares)."""
import importlib

import numpy as np
import pytest

from hse_opt.fit import fit
from hse_opt.model import Model

from test_fit import design, twin

least_squares = importlib.import_module("hse_opt.fit.least_squares")
solvers = importlib.import_module("hse_opt.fit.solvers")
problem = importlib.import_module("hse_opt.fit.problem")

MODEL = Model(["hse", "axis_bias", "sync_delay", "warmup"])
TRUTH = dict(offset=3.0, lambda2=4.2, bias_z=0.2, delay=40.0, warmup_amp=60.0, warmup_tau=1800.0)


@pytest.mark.parametrize("sessions", [2, 20])
def test_chi2_noise_bounds_the_rounding_of_chi2(sessions):
    """chi2 at 1e-6 sigma from the optimum (a true change of ~1e-12) moves only by rounding;
    the step halving's tolerance must cover it at every size, or Gauss-Newton halves steps on
    noise (the fit of 10,000 runs took 38 model calls instead of 4)."""
    runs = twin(MODEL, design(n_sessions=sessions), TRUTH, np.random.default_rng(sessions))
    f = fit(runs, MODEL)
    mm = f.measurement
    X = mm.inputs_from_runs(runs)
    hJ = problem.residual_jacobian(mm)

    def chi2(p):
        u = (runs.heading_err - hJ(p, X, None)[:, 0]) / f.sigma
        return float(u @ u)

    rng = np.random.default_rng(0)
    c0 = chi2(f.p)
    moves = [chi2(f.p + np.where(f.free, rng.standard_normal(f.p.size) * f.std * mm.scale * 1e-6, 0.0)) - c0
             for _ in range(30)]
    assert c0 == pytest.approx(f.chi2, rel=1e-9)
    assert 0 < np.max(np.abs(moves)) < solvers.chi2_noise(c0)


def test_profile_start_takes_the_grid_optimum(monkeypatch):
    """The start of warmup_tau is the point of its 25-point grid (log-spaced over the declared
    range) where the linear parameters, solved by numpy's least squares, leave the smallest
    chi2 - found with 13 model calls (coarse to fine) instead of one per point."""
    runs = twin(MODEL, design(n_sessions=2, per=24), TRUTH, np.random.default_rng(3))
    seen = {}
    solve = least_squares.solve

    def spy(prob, w, z, notes):
        seen.setdefault("start", (prob, w, z.copy()))
        return solve(prob, w, z, notes)

    monkeypatch.setattr(least_squares, "solve", spy)
    fit(runs, MODEL)
    prob, w, z = seen["start"]
    j = prob.names.index("warmup_tau")
    mm = prob.mm
    X = mm.inputs_from_runs(runs)
    lin = ~prob.nonlinear
    q = mm.params[mm.parameter_index("warmup_tau")]
    grid = np.geomspace(q.lower, q.upper, 25)
    chi2 = []
    for tau in grid:
        p = prob.p(np.where(np.arange(z.size) == j, tau, z))
        A = (mm.jacobian(p, X) * mm.scale)[:, prob.free][:, lin] * w[:, None]
        r = (runs.heading_err - mm.predict(p, X)) * w
        _, rss, *_ = np.linalg.lstsq(A, r, rcond=None)
        chi2.append(float(rss[0]))
    assert z[j] == pytest.approx(grid[int(np.argmin(chi2))], rel=1e-12)
    assert np.argmin(chi2) % 3  # off the coarse grid (every third point): the fine stage found it


def test_a_large_campaign_is_profiled_on_a_spread_subset_with_the_same_fit(monkeypatch):
    """Above PROFILE_RUNS runs the profile start uses a subset spread in run order (a start
    value only): the fit equals the one whose profile saw every run, and the profile's model
    calls see PROFILE_RUNS runs."""
    runs = twin(MODEL, design(n_sessions=60, per=48), TRUTH, np.random.default_rng(5))
    sizes = []
    subset = problem.Problem.subset

    def spy(self, idx):
        sizes.append(len(idx))
        return subset(self, idx)

    monkeypatch.setattr(problem.Problem, "subset", spy)
    spread = fit(runs, MODEL)
    limit = least_squares.PROFILE_RUNS
    monkeypatch.setattr(least_squares, "PROFILE_RUNS", 10 ** 9)
    every = fit(runs, MODEL)
    assert len(runs.run) == 2880 and sizes == [limit]
    assert spread.status == every.status == "converged"
    np.testing.assert_allclose(spread.values, every.values, atol=1e-6 * every.std.max(), rtol=0)
    z = np.abs(spread.values - every.values) / np.where(every.std > 0, every.std, 1)
    assert z.max() < 1e-4
