"""The solvers of a fit (:mod:`hse_opt.fit`): Gauss-Newton with QR on the active set, and
IPOPT with a Gauss-Newton Hessian for bounds that bind and inequality constraints."""
from functools import lru_cache

import casadi as ca
import numpy as np

from ..information import null_space
from ..interrupts import check as check_interrupt
from .result import SolverError

#: chi2 changes below ``_CHI2_NOISE * sqrt(1 + chi2 / 10)`` are rounding, not fit
#: (:func:`chi2_noise`): the gyrocompass heading carries ~1e-12 relative rounding (Earth rate
#: read out of a rate 1e4 times larger)
_CHI2_NOISE = 1e-6
#: rounding of a computed heading error, rad (measured: ~2e-13 rad between two evaluations of
#: the same model): a fit cannot place a parameter more finely than this moves the heading,
#: which matters only for sigmas near it (noise-free data with tiny heading_std)
_HEADING_ROUNDING = 1e-12


def chi2_noise(chi2):
    """The rounding of a chi2 of this size: each run's rounding enters ``2 sum(u_i e_i)``, so it
    grows as the square root of the run count (measured at 1e-6 sigma from the optimum of the
    whole catalogue's fit: spread 2e-7, 5e-7, 1.4e-6 at 100, 1,000, 10,000 runs; this is ~7x
    that)."""
    return _CHI2_NOISE * float(np.sqrt(1.0 + max(chi2, 0.0) / 10.0))


# -- Gauss-Newton with QR on the active set ------------------------------------------------------
def subspace(prob, z, C, d, mask=None):
    """``(Z, z)``: the null space (k, m) of ``C`` and of the rows holding the parameters outside
    ``mask`` (k,) bool, and ``z`` moved onto ``C z = d``."""
    k = prob.k
    mask = np.ones(k, bool) if mask is None else mask
    held = np.eye(k)[~mask]
    C = np.vstack([C.reshape(-1, k), held])
    d = np.concatenate([np.asarray(d, dtype=float).ravel(), z[~mask]])
    z = z + np.linalg.pinv(C) @ (d - C @ z) if C.shape[0] else z.copy()
    return null_space(C, k), z


def gauss_newton_step(prob, w, z, Z, r=None):
    """One Gauss-Newton step from ``z`` in the span of ``Z`` by one QR, from one batch call of
    the model (``r``: the residuals at ``z`` when known).

    Returns ``(step, std, predicted)`` - the step (k,), each parameter's sigma along ``Z`` (k,)
    and the objective after the step were the model linear (the part of the weighted
    residuals outside the Jacobian's span: the QR's last diagonal entry) - or None when the
    Jacobian is singular along ``Z``."""
    m = Z.shape[1]
    r = prob.residual(z) if r is None else r
    M = np.vstack([w[:, None] * prob.jacobian(z), prob.L]) @ Z
    rhs = np.concatenate([w * r, prob.Lmu - prob.L @ z])
    R_aug = np.linalg.qr(np.column_stack([M, rhs]), mode="r")  # Q' rhs in the last column
    R = R_aug[:m, :m]
    predicted = float(R_aug[m, m] ** 2) if R_aug.shape[0] > m else 0.0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        try:  # R is triangular: LU does back substitution (numpy's: no scipy import at start)
            X = np.linalg.solve(R, np.column_stack([R_aug[:m, m], np.eye(m)]))
        except np.linalg.LinAlgError:
            return None
        return Z @ X[:, 0], np.linalg.norm(Z @ X[:, 1:], axis=1), predicted


def gauss_newton(prob, w, z, C, d, max_iter=50, mask=None, tol=1e-6, box=False):
    """Minimise ``|w r(z)|^2 + |L z - Lmu|^2`` subject to ``C z = d`` by Gauss-Newton, each step
    by QR in the null space of ``C``. ``mask`` (k,) bool: only those parameters move.
    Converged when a step is below ``tol`` of every parameter's sigma (or below what the
    rounding of the heading, :data:`_HEADING_ROUNDING`, lets it resolve). ``box``: give up (not
    converged) as soon as a step leaves the open box of the bounds, where the solution of
    the bounded problem is another one (IPOPT's).

    Returns ``(z, converged)``.
    """
    Z, z = subspace(prob, z, C, d, mask)
    if Z.shape[1] == 0:
        return z, True
    r = prob.residual(z)
    f_old = prob.objective(z, w, r)
    tol = max(tol, _HEADING_ROUNDING * float(np.max(w, initial=0.0)))  # in sigmas
    for _ in range(max_iter):
        out = gauss_newton_step(prob, w, z, Z, r)
        if out is None:
            return z, False
        step, std, _ = out
        if not np.all(np.isfinite(step)) or (box and not prob.inside(z + step)):
            return z, False
        # converged when the step is a negligible fraction of each parameter's sigma
        if np.all(np.abs(step) <= tol * std + 1e-14 * np.abs(z)):
            return z + step, True
        t = 1.0
        while True:  # step halving keeps the objective from rising on a nonlinear model
            z_new = z + t * step
            r_new = prob.residual(z_new)
            f_new = prob.objective(z_new, w, r_new)
            if f_new <= f_old + chi2_noise(f_old) or t < 1e-3:
                break
            t *= 0.5
        z, r, f_old = z_new, r_new, f_new
    return z, False


# -- IPOPT with a Gauss-Newton Hessian -----------------------------------------------------------
#: IPOPT finds the active set and a point within ~1e-4 sigma of the optimum (variables are
#: scaled to sigma units); the Gauss-Newton polish converges from there. Tighter IPOPT
#: tolerances only make its line search fight the rounding of chi2 (see :func:`chi2_noise`).
_IPOPT_OPTIONS = {"ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": False,
                  "ipopt.tol": 1e-6, "ipopt.acceptable_tol": 1e-4, "ipopt.acceptable_iter": 1,
                  "ipopt.compl_inf_tol": 1e-8, "ipopt.acceptable_compl_inf_tol": 1e-7,
                  "ipopt.bound_relax_factor": 0.0,
                  "ipopt.honor_original_bounds": "yes", "ipopt.max_iter": 200,
                  "ipopt.mu_strategy": "adaptive"}


@lru_cache(maxsize=32)
def _nlp_solver(mm, n, free_key, m, r, linear, jit):
    """The IPOPT solver for ``mm`` over ``n`` runs, free set ``free_key``, ``m`` linear
    constraint rows and an ``r``-row prior; data enter as NLP parameters (built once)."""
    free = np.array(free_key, dtype=bool)
    k, n_p, n_x = int(free.sum()), len(free), mm.n_x
    sizes = [("X", n_x * n), ("y", n), ("w", n), ("p0", n_p), ("L", r * k), ("Lmu", r), ("A", m * k),
             ("D", k)]
    P = ca.MX.sym("P", sum(s for _, s in sizes))
    parts, i = {}, 0
    for name, s in sizes:
        parts[name] = P[i:i + s]
        i += s
    X = ca.reshape(parts["X"], n_x, n)
    y, w, p0 = parts["y"], parts["w"], parts["p0"]
    L, Lmu, A = ca.reshape(parts["L"], r, k), parts["Lmu"], ca.reshape(parts["A"], m, k)
    v = ca.MX.sym("v", k)  # the variables: z (display units) = D v, D ~ each parameter's sigma
    z = parts["D"] * v
    S = ca.DM(np.eye(n_p)[:, free] * mm.scale[free][None, :])  # z (display) -> p (SI)
    p = p0 + ca.mtimes(S, z)
    res = w * (y - mm.predict_graph(p, X, jit).T)
    e = ca.mtimes(L, z) - Lmu
    f = 0.5 * (ca.sumsqr(res) + ca.sumsqr(e))
    Jv = -ca.mtimes(ca.transpose(S * ca.repmat(ca.transpose(parts["D"]), n_p, 1)),
                    mm.jacobian_graph(p, X, jit)) * ca.repmat(ca.transpose(w), k, 1)  # dres/dv'
    LD = L * ca.repmat(ca.transpose(parts["D"]), r, 1)
    grad = ca.mtimes(Jv, res) + ca.mtimes(ca.transpose(LD), e)
    H = ca.mtimes(Jv, ca.transpose(Jv)) + ca.mtimes(ca.transpose(LD), LD)
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", m)
    opts = dict(_IPOPT_OPTIONS)
    opts["grad_f"] = ca.Function("nlp_grad_f", [v, P], [f, grad], ["x", "p"], ["f", "grad_f_x"])
    opts["hess_lag"] = ca.Function("nlp_hess_l", [v, P, lam_f, lam_g], [ca.triu(lam_f * H)],
                                   ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])
    if linear:
        opts["ipopt.hessian_constant"] = "yes"
    if m:
        opts["ipopt.jac_c_constant"] = opts["ipopt.jac_d_constant"] = "yes"
    nlp = {"x": v, "p": P, "f": f}
    if m:
        nlp["g"] = ca.mtimes(A, z)
    return ca.nlpsol(f"fit_{n}", "ipopt", nlp, opts)


def _hint(prob):
    """What to try when the solver fails: the free nonlinear parameters and a bound on them."""
    names = [q for q, free in zip(prob.mm.params, prob.free) if free and q.name in prob.mm.nonlinear]
    if not names:
        return "; hold a parameter (--fix NAME=VALUE) or add runs that separate the parameters"
    q = names[0]
    return (f"; nonlinear parameters {', '.join(f'{p.name} ({p.unit})' for p in names)} did not settle: "
            f"bound them nearer the data, e.g. --bound {q.name}=LO:HI within [{q.lower:g}, {q.upper:g}] "
            f"{q.unit}, or --fix {q.name}=VALUE")


def _ipopt(prob, w, z0):
    """Solve with IPOPT; return ``(z, lam_x, lam_g)``. Raises :class:`SolverError`."""
    mm, n = prob.mm, prob.y.size
    A = np.vstack([prob.A_eq, prob.A_in])
    m, r = A.shape[0], prob.L.shape[0]
    solver = _nlp_solver(mm, n, tuple(bool(b) for b in prob.free), m, r, not prob.nonlinear.any(),
                         prob.jit)
    p0 = np.where(prob.free, 0.0, prob.p_base)  # the NLP adds the free part
    z0 = np.clip(z0, prob.lb, prob.ub)
    # variables in units of each parameter's sigma at the start: IPOPT's tolerances then mean
    # the same for every parameter
    a = np.sqrt(np.sum((w[:, None] * prob.jacobian(z0)) ** 2, axis=0) + np.sum(prob.L ** 2, axis=0))
    D = np.where(a > 0, 1 / np.where(a > 0, a, 1), np.where(np.isfinite(prob.ub - prob.lb),
                                                             prob.ub - prob.lb, 1.0))
    P = np.concatenate([prob.X.ravel(order="F"), prob.y, w, p0, prob.L.ravel(order="F"),
                        prob.Lmu, A.ravel(order="F"), D])
    args = {"x0": z0 / D, "p": P, "lbx": prob.lb / D, "ubx": prob.ub / D}
    if m:
        args["lbg"] = np.concatenate([prob.b_eq, prob.l_in])
        args["ubg"] = np.concatenate([prob.b_eq, prob.u_in])
    sol = solver(**args)
    check_interrupt()  # a Ctrl-C inside IPOPT ends as its status NonIpopt_Exception_Thrown
    stats = solver.stats()
    if not stats["success"]:
        status = stats["return_status"]
        if status in ("Infeasible_Problem_Detected", "Restoration_Failed") and m:
            raise ValueError(f"the bounds and constraints cannot all hold (IPOPT: {status}); allowed: bounds "
                             "and constraints that hold together")
        raise SolverError("IPOPT did not solve the fit" + _hint(prob), status)
    return (np.array(sol["x"]).ravel() * D, np.array(sol["lam_x"]).ravel() / D,
            np.array(sol["lam_g"]).ravel()[prob.A_eq.shape[0]:], stats["return_status"], D)


def _active_set(prob, z, lam_x, lam_g, D):
    """Rows ``(C, d)`` of the equalities, binding bounds and active inequalities, with the
    binding parameter indices and active inequality indices. A bound is active when the
    solution is within 1e-5 sigma of it (``D``: sigma per parameter) and its multiplier
    pushes against it."""
    tol = 1e-5
    lam_tol = 1e-8 * max(1.0, np.abs(lam_x * D).max(initial=0.0), np.abs(lam_g).max(initial=0.0))
    at_lo = np.isfinite(prob.lb) & ((z - prob.lb) / D <= tol) & (lam_x * D < -lam_tol)
    at_hi = np.isfinite(prob.ub) & ((prob.ub - z) / D <= tol) & (lam_x * D > lam_tol)
    g = prob.A_in @ z
    g_sigma = np.sqrt(np.sum((prob.A_in * D[None, :]) ** 2, axis=1))  # sigma of each combination
    g_lo = np.isfinite(prob.l_in) & ((g - prob.l_in) / g_sigma <= tol) & (lam_g < -lam_tol)
    g_hi = np.isfinite(prob.u_in) & ((prob.u_in - g) / g_sigma <= tol) & (lam_g > lam_tol)
    binding = np.flatnonzero(at_lo | at_hi)
    bound_val = np.where(at_lo, prob.lb, prob.ub)[binding]
    act = np.flatnonzero(g_lo | g_hi)
    act_val = np.where(g_lo, prob.l_in, prob.u_in)[act]
    C = np.vstack([prob.A_eq, np.eye(prob.k)[binding], prob.A_in[act]])
    d = np.concatenate([prob.b_eq, bound_val, act_val])
    return C, d, binding, bound_val, act


def _feasible(prob, z, eps=1e-9):
    g = prob.A_in @ z
    tol = lambda b: eps * (1 + np.abs(np.where(np.isfinite(b), b, 0)))  # noqa: E731
    return bool(np.all(z >= prob.lb - tol(prob.lb)) and np.all(z <= prob.ub + tol(prob.ub))
                and np.all(g >= prob.l_in - tol(prob.l_in)) and np.all(g <= prob.u_in + tol(prob.u_in)))


def solve(prob, w, z, notes):
    """One weighted solve. Returns ``(z, C_active, binding, active, method, status)``.

    Without inequality constraints, Gauss-Newton first: when it converges strictly inside the
    bounds (nonlinear parameters always have some), no bound binds and that is the bounded
    problem's solution too. Otherwise (and with inequalities) IPOPT finds the active set.
    """
    bounded = bool(np.isfinite(prob.lb).any() or np.isfinite(prob.ub).any())
    if not prob.A_in.shape[0]:
        z_gn, ok = gauss_newton(prob, w, z, prob.A_eq, prob.b_eq, box=bounded)
        if ok:
            method = "gauss-newton" if prob.nonlinear.any() else "qr"
            return z_gn, prob.A_eq, np.zeros(0, int), np.zeros(0, int), method, "converged"
        if not bounded and not prob.nonlinear.any():
            raise SolverError("Gauss-Newton did not converge in 50 steps", "max_iter")
    z_ip, lam_x, lam_g, status, D = _ipopt(prob, w, z)
    C, d, binding, bound_val, act = _active_set(prob, z_ip, lam_x, lam_g, D)
    z_pol, ok = gauss_newton(prob, w, z_ip, C, d)
    z_pol[binding] = bound_val
    f_ip = prob.objective(z_ip, w)
    if ok and _feasible(prob, z_pol) and prob.objective(z_pol, w) <= f_ip + chi2_noise(f_ip):
        return z_pol, C, binding, act, "ipopt", status
    notes.append("the Gauss-Newton polish on IPOPT's active set was not accepted; IPOPT's solution kept")
    return z_ip, C, binding, act, "ipopt", status
