"""fold_linear: the same function as CasADi's own evaluation of the original graph, with fewer
operations where the graph holds constant linear chains."""
import casadi as ca
import numpy as np

from hse_opt.model.folding import fold_linear


def _chain(rng):
    """A revolution-average-like expression: constant 3x3 chains applied to a vector that
    depends nonlinearly on the inputs, at four table angles, then nonlinear outputs."""
    x = ca.SX.sym("x", 4)
    v = ca.vertcat(ca.cos(x[0]) * ca.sin(x[1]), ca.sin(x[0]) * x[2], ca.cos(x[1]))
    total = ca.SX.zeros(3)
    for k in range(4):
        a = 2 * np.pi * k / 4
        R = ca.DM([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        M1, M2 = (ca.DM(np.eye(3) + 1e-3 * rng.standard_normal((3, 3))) for _ in range(2))
        total = total + ca.mtimes([R, M1, M2, R.T, v]) + x[3] * ca.DM([0.0, 0.0, 1.0])
    mean = total / 4
    return x, [ca.atan2(mean[1], mean[0]) - 2.0 * mean[2], ca.vertcat(ca.sumsqr(mean), mean[2] / 3.0)]


def test_folded_graph_evaluates_like_the_original_with_fewer_operations(rng):
    x, outputs = _chain(rng)
    original = ca.Function("original", [x], outputs)
    folded = ca.Function("folded", [x], fold_linear([x], outputs))
    X = rng.uniform(-2, 2, (4, 500))
    for a, b in zip(original.map(500)(X), folded.map(500)(X)):
        a, b = np.array(a), np.array(b)
        assert np.allclose(a, b, rtol=1e-12, atol=1e-14)
    assert folded.n_instructions() < 0.6 * original.n_instructions()


def test_long_shared_sums_become_atoms(rng):
    """A sum longer than max_terms is written once and reused, not expanded in every place
    that uses it (the folding may still cost more than the original here: the export keeps
    whichever construction is smaller)."""
    x = ca.SX.sym("x", 40)
    s = ca.sum1(ca.sin(x))
    outputs = [ca.vertcat(*[ca.cos(s + k) for k in range(10)])]
    ref = ca.Function("r", [x], outputs)
    X = rng.standard_normal((40, 5))
    counts = {}
    for max_terms in (16, 1000):
        f = ca.Function("f", [x], fold_linear([x], outputs, max_terms=max_terms))
        assert np.allclose(np.array(f.map(5)(X)), np.array(ref.map(5)(X)), rtol=1e-12)
        counts[max_terms] = f.n_instructions()
    assert counts[16] < 0.6 * counts[1000]


def test_folding_keeps_sparsity_and_constant_outputs():
    x = ca.SX.sym("x", 2)
    out = ca.SX(ca.Sparsity.lower(2))
    out[0, 0] = 3 * (2 * x[0])
    out[1, 0] = ca.SX(5.0)
    out[1, 1] = x[0] - x[0] + ca.exp(x[1])
    (g,) = fold_linear([x], [out])
    assert g.sparsity() == out.sparsity()
    f = ca.Function("f", [x], [g])
    assert np.allclose(np.array(f([0.5, 0.25])), [[3.0, 0.0], [5.0, np.exp(0.25)]])


def test_small_angles_by_series_equal_libm_within_double_rounding(rng):
    """sin/cos of an input declared small become Taylor series: equal to libm (CasADi's
    evaluation of the original) to 1e-16 relative for |x| <= SMALL_ANGLE, and cheaper by the
    cost measure that counts a libm call as 40 operations."""
    from hse_opt.model.folding import SMALL_ANGLE, cost

    x = ca.SX.sym("x", 3)
    outputs = [ca.vertcat(ca.sin(x[1]) * ca.cos(x[0]), ca.cos(x[1]) + ca.sin(x[2]), ca.atan2(ca.sin(x[1]), 1.0))]
    original = ca.Function("o", [x], outputs)
    series = ca.Function("s", [x], fold_linear([x], outputs, small=[(0, 1)]))
    X = np.vstack([rng.uniform(-3, 3, 2000), rng.uniform(-SMALL_ANGLE, SMALL_ANGLE, 2000),
                   rng.uniform(-3, 3, 2000)])
    a, b = np.array(original.map(2000)(X)), np.array(series.map(2000)(X))
    assert np.max(np.abs(a - b)) < 4e-16
    assert cost(series) < cost(original)
    assert sum(series.instruction_id(k) in (ca.OP_SIN, ca.OP_COS) for k in range(series.n_instructions())) == 2
