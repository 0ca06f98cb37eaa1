"""The approximate design: the optimal (fractional) number of runs of every candidate.

A convex program (cvxpy) over the runs ``w_i >= 0`` of the candidates, the alignment time linear
(``sum w_i cost_i <= budget``, each time slot its share), solved by column generation over a
growing active set. The general equivalence theorem certifies the solution over every
candidate: the Frank-Wolfe gap of the Lagrangian bounds the loss of optimality
(:attr:`ApproximateDesign.certified_efficiency`). Each conic solution is re-solved on its
support with IPOPT (:func:`polish_weights`; conic solvers leave ~1e-4 in the weights), except
with power floors, where the conic solution is certified as it is.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace

import casadi as ca
import cvxpy as cp
import numpy as np

from ..fit.result import SolverError
from ..information import UnidentifiableError
from ..interrupts import check as check_interrupt
from .criteria import CASADI, CvxOps, NotSmooth, Scaled, as_criterion
from . import ties
from .problem import Problem, Rows
from .reduction import SUPPORT_TOL
from .space import Candidates, positive
from .ties import VALUE_RTOL

SOLVERS = ("CLARABEL", "SCS")
#: a certified efficiency that ends the column generation when another round does not raise it
ENOUGH = 0.9999


#: what a user can change when the convex program fails (an ill-conditioned design space)
CHANGE = ("allowed: a design space that separates the parameters better (more rate levels --n-rates, both senses "
          "--reverse, a tilt fixture --max-tilt-arcsec, fewer --effects) or another --criterion (D, A)")


class DesignError(SolverError):
    """A solver failed; ``status`` is its status (the message carries it too). A
    :class:`~hse_opt.fit.SolverError`: the command line names it in one line, exit 1."""

    def __init__(self, message, status=None):
        RuntimeError.__init__(self, message)
        self.status = status


@dataclass(frozen=True)
class ApproximateDesign:
    """The optimal approximate design over the candidates.

    Attributes
    ----------
    candidates : Candidates
    runs : numpy.ndarray, shape (n_candidates,)
        Optimal (fractional) number of runs of each candidate.
    loss : float
        Criterion loss (mean over the prior sample).
    status, solver : str
        cvxpy's ``problem.status`` and the solver that reached it.
    certified_efficiency : float
        Lower bound on this design's efficiency against the true optimum over all
        candidates, from the equivalence theorem (duality gap of the Lagrangian).
    solve_time : float
        s, including building the problems.
    iterations : int
        Column-generation rounds (each a convex program over the active candidates).
    n_active : int
        Candidates in the last convex program.
    """

    candidates: Candidates
    runs: np.ndarray
    loss: float
    status: str
    solver: str
    certified_efficiency: float
    solve_time: float
    iterations: int = 1
    n_active: int = 0

    @property
    def support(self):
        """Indices of the candidates that carry runs."""
        return np.flatnonzero(self.runs > SUPPORT_TOL * self.runs.max())


def solve_approximate(prob, batch=128, polish=True, target=1 - 1e-7, enough=ENOUGH, start=None):
    """The approximate design of ``prob`` by column generation: convex programs over a
    growing active set until the equivalence theorem certifies the solution over every
    candidate to ``target``, or to ``enough`` when a round raises the certificate by less than
    1e-5 (the conic solver's accuracy, not the active set, then limits it); ``polish``: each
    solution re-solved on its support by :func:`polish_weights`, except with power floors
    (:mod:`.protection`): IPOPT then carries a matrix per floor and sample over supports of
    hundreds of candidates (1.5-2 s a re-solve at 10,368 candidates, and it failed on every
    one of the design benchmark's such problems), and the conic solution is certified as it
    is; ``start``: candidates the first active set also holds (e.g. the support of a
    neighbouring problem's design)."""
    t0 = time.perf_counter()
    n, slot = prob.n, prob.slot
    polish = polish and not any(g.is_power for g in prob.guards)
    active = _initial_active(prob)
    if start is not None:
        active = np.union1d(active, start)
    last = -np.inf
    for it in range(1, 100):
        best, failures = None, []
        sub = prob.take(active)
        for solver in (prob.solver,) if prob.solver else SOLVERS:
            try:
                w_a, mus, status, used, sup_grads = _convex(replace(sub, solver=solver))
            except DesignError as err:  # the next solver
                failures.append(str(err).partition("not solved: ")[2] or str(err))
                continue
            w = np.zeros(n)
            w[active] = w_a
            loss, h, cert = certify(prob, w, mus, sup_grads)
            polished = polish_weights(prob, w, loss) if polish else None
            if polished is not None:
                trial = certify(prob, *polished)
                if trial[2] > cert:
                    (w, mus), (loss, h, cert) = polished, trial
            if best is None or cert > best[2]:
                best = (w, mus, cert, loss, h, status, used)
            # an inaccurate end is judged by the certificate over the candidates it was given
            # (over all of them it is low in early rounds, whatever the solver); else the next solver
            if status == cp.OPTIMAL or cert >= 0.99 or certify(sub, w[active], mus, sup_grads)[2] >= 0.99:
                break
        if best is None:
            raise DesignError("the approximate design's convex program was not solved: " + "; ".join(failures)
                              + f"; {CHANGE}", "not solved")
        w, mus, cert, loss, h, status, used = best
        if active.size == n or cert >= target or (cert >= enough and cert - last < 1e-5):
            break
        last = max(last, cert)
        # a candidate enters when spending its slot's share of the budget on it beats the slot's runs
        value = h * np.minimum(prob.slot_budget[slot] / prob.cost,
                               np.inf if prob.max_runs is None else prob.max_runs)
        now = np.bincount(slot, h * w, minlength=prob.n_slots)[slot]
        order = ties.order(-(value - now), prob.rank, VALUE_RTOL)
        new = order[(value[order] > now[order] + 1e-9 * abs(now[order])) & ~np.isin(order, active)][:batch]
        if new.size == 0:
            break
        active = np.union1d(active, new)
    if status != cp.OPTIMAL and not cert >= 0.99:  # an inaccurate solve is judged by its certificate
        fallback = _fallback(prob, active, loss if np.isfinite(loss) else None)
        if fallback is not None and fallback[2] > cert:
            w, mus, cert, loss, used = fallback[0], fallback[1], fallback[2], fallback[3], f"{used}, then {fallback[4]}"
    if status != cp.OPTIMAL and not cert >= 0.99:
        what = (f"the approximate design's convex program ended {status} ({used}) with a certified efficiency "
                f"of only {cert:.4g}")
        _raise_if_ill_conditioned(prob, what)
        raise DesignError(f"{what}; {CHANGE}", status)
    return ApproximateDesign(prob.candidates, w, loss, status, used, cert, time.perf_counter() - t0, it,
                             int(active.size))


def certify(prob, w, mus, sup_grads=None):
    """Loss, Lagrangian gradient and certified efficiency of the weights ``w``.

    ``sup_grads`` (E-optimality): a supergradient ``G_s`` of lambda_min per sample (PSD, trace
    1; the conic program's dual). lambda_min(F) <= <G, F> for every F, so the linear model
    ``-mean <G_s, F_s>`` bounds the loss from below everywhere: its Frank-Wolfe gap certifies
    ``w`` also where the smallest eigenvalue is multiple (where -v v^T of one eigenvector
    would not)."""
    loss = prob.loss(w)
    if sup_grads is None:
        h = prob.lagrangian_gradient(w, mus)
        return loss, h, certificate(prob, loss, h, w, mus)
    F = prob.spec.information(prob.rows, w)
    h = prob.lagrangian_gradient(w, mus, np.mean([np.einsum("ni,ij,nj->n", r, G, r)
                                                  for r, G in zip(prob.rows, sup_grads)], axis=0))
    tangent = -float(np.mean([np.sum(G * Fs) for G, Fs in zip(sup_grads, F)]))
    return loss, h, certificate(prob, loss, h, w, mus, tangent)


def polish_weights(prob, w, loss0):
    """The convex program re-solved by IPOPT (CasADi) on the conic solution's support.

    Interior-point conic solvers stop at about 1e-8 in the objective; the loss is flat at the
    optimum, so that leaves about 1e-4 in the weights and small weights spread over
    near-optimal candidates, which then differ from one solver build to the next. The smooth
    problem on the support (the same loss, time budget per slot, run limit and guards) is
    solved to 1e-12 (``loss0``: the loss at ``w``, the objective's scale). Returns
    ``(weights, guard multipliers)``, or None when the criterion has no smooth form or IPOPT
    fails (the caller keeps whichever the certificate prefers)."""
    crit, spec, cost, slot, max_runs = prob.criterion, prob.spec, prob.cost, prob.slot, prob.max_runs
    sup = np.flatnonzero(w > 1e-6 * w.max())
    m, n_slots = sup.size, prob.n_slots
    u = ca.SX.sym("u", m)  # runs of each support candidate
    # each information matrix is a variable tied to the runs by linear equalities: the Hessian
    # of the Lagrangian is then k^2 x k^2 per matrix, not a dense m x m one
    infos, links, values = [], [], []

    def mean_loss_of(r, sp, fun):
        total = 0
        for s in range(r.shape[0]):
            a = r[s][sup]
            Q = np.einsum("ni,nj->ijn", a, a).reshape(sp.k * sp.k, m)
            F = ca.SX.sym(f"F{len(infos)}", sp.k * sp.k)
            infos.append(F)
            links.append((F - ca.mtimes(ca.DM(Q), u), sp.prior.ravel()))
            values.append(sp.prior.ravel() + Q @ w[sup])
            total = total + fun(ca.reshape(F, sp.k, sp.k))
        return total / r.shape[0]

    try:
        f = mean_loss_of(prob.rows, spec, lambda F: crit.loss(F, CASADI, spec.names))
    except NotSmooth:
        return None
    scale = max(1.0, abs(loss0)) if crit.degree == 0 else abs(loss0)
    if not (np.isfinite(loss0) and scale > 0):
        return None
    S = np.zeros((n_slots, m))
    S[slot[sup], np.arange(m)] = cost[sup]
    lin = [S] + ([np.ones((1, m))] if max_runs is not None else [])
    ub = [prob.slot_budget] + ([[max_runs]] if max_runs is not None else [])
    g = ([ca.mtimes(ca.DM(np.vstack(lin)), u)]
         + [mean_loss_of(gd.rows, gd.spec, _concave(gd)) for gd in prob.guards])
    g += [e for e, _ in links]
    x = ca.vertcat(u, *infos)
    solver = ca.nlpsol("weights", "ipopt", {"x": x, "f": (f - loss0) / scale, "g": ca.vertcat(*g)}, {
        "ipopt.print_level": 0, "print_time": 0, "show_eval_warnings": False, "ipopt.sb": "yes", "ipopt.max_iter": 200,
        "ipopt.tol": 1e-12, "ipopt.bound_push": 1e-12, "ipopt.bound_frac": 1e-12, "ipopt.mu_init": 1e-8})
    n_lin, n_g = n_slots + len(lin) - 1, len(prob.guards)
    eq = np.concatenate([v for _, v in links])
    n_f = eq.size
    sol = solver(x0=np.concatenate([w[sup], *values]),
                 lbx=np.concatenate([np.zeros(m), np.full(n_f, -np.inf)]), ubx=np.inf,
                 lbg=np.concatenate([np.full(n_lin, -np.inf), [gd.bound for gd in prob.guards], eq]),
                 ubg=np.concatenate([np.concatenate(ub), np.full(n_g, np.inf), eq]))
    check_interrupt()  # a Ctrl-C inside IPOPT ends as its status NonIpopt_Exception_Thrown
    if not solver.stats()["success"]:
        return None
    out = np.zeros_like(w)
    out[sup] = np.clip(np.array(sol["x"]).ravel()[:m], 0.0, None)
    lam = np.array(sol["lam_g"]).ravel()[n_lin:n_lin + n_g]
    return out, [max(0.0, -float(v) * scale) for v in lam]


class IllConditioned(DesignError, UnidentifiableError):
    """A convex program that failed on candidates that barely separate some parameters: a
    :class:`DesignError` to the design's own fallbacks (a power floor dropped, a candidate set
    passed over), the design space's fault (:class:`~hse_opt.information.UnidentifiableError`,
    exit 2) to the command line."""

    def __init__(self, message, names, direction=None, condition=np.inf):
        DesignError.__init__(self, message, "ill-conditioned")
        self.names, self.direction, self.condition = tuple(names), direction, condition


#: the candidates' information (all of them, evenly) worse conditioned than this (in the
#: parameters' own scales) is the design space's fault when the convex program fails: some
#: combination of the parameters is determined 10^4 times worse than another by any plan
ILL_CONDITION = 1e4


def _raise_if_ill_conditioned(prob, what):
    """UnidentifiableError naming the parameters the candidate runs barely separate (the even
    design over every candidate, condition number above :data:`ILL_CONDITION`), with ``what``
    the solver said; nothing when they are well separated (the solver's own failure)."""
    from ..information import check_identifiable
    F = np.mean(prob.spec.information(prob.rows, prob.budget / prob.cost / prob.n), axis=0)
    try:
        check_identifiable(F, prob.spec.names, max_condition=ILL_CONDITION)
    except UnidentifiableError as err:
        raise IllConditioned(f"{str(err).rstrip('.')}, even with every candidate run: {what}", err.names,
                             err.direction, err.condition) from None


def _fallback(prob, active, loss0):
    """When the conic solvers end inaccurate (an ill-conditioned program): the even design over
    the active candidates (each time slot's budget spent evenly) and IPOPT's solution from it
    on them (:func:`polish_weights`), the one with the better certificate. Returns
    ``(w, mus, cert, loss, what)`` or None (no even design meets the run limit or the guards)."""
    w = np.zeros(prob.n)
    for s in range(prob.n_slots):
        idx = active[prob.slot[active] == s]
        if idx.size:
            w[idx] = prob.slot_budget[s] / prob.cost[idx].sum()
    if prob.max_runs is not None and w.sum() > prob.max_runs:
        w *= prob.max_runs / w.sum()
    mus = [0.0] * len(prob.guards)
    try:
        loss, _, cert = certify(prob, w, mus, None)
    except (np.linalg.LinAlgError, ValueError):
        return None
    if prob.guards and not all(g.level(w) >= g.bound for g in prob.guards):
        return None
    best = (w, mus, cert, loss, "the even design")
    polished = polish_weights(prob, w, loss if loss0 is None else loss0)
    if polished is not None:
        trial = certify(prob, *polished)
        if trial[2] > cert:
            best = (*polished, trial[2], trial[0], "IPOPT from the even design")
    return best


def _concave(guard):
    """The guarded function of one information matrix as a CasADi expression."""
    return lambda F: -guard.criterion.loss(F, CASADI, guard.spec.names)


def _initial_active(prob, size=256):
    """A strided subset of the candidates plus the extremes of every feature column."""
    n = prob.n
    if n <= 2 * size:
        return np.arange(n)
    picks = [np.linspace(0, n - 1, size).astype(int)]
    for r in [prob.rows, *[g.rows for g in prob.guards]]:
        z = r / np.sqrt(prob.cost)[None, :, None]
        picks += [np.argmax(z, axis=1).ravel(), np.argmin(z, axis=1).ravel()]
    return np.unique(np.concatenate(picks))


def _convex(prob):
    """One convex program (cvxpy): returns run numbers, guard duals, status, solver."""
    n, slot, n_slots = prob.n, prob.slot, prob.n_slots
    scale = prob.budget / prob.cost  # runs per unit budget fraction
    u = cp.Variable(n, nonneg=True)  # fraction of the alignment-time budget per candidate
    if n_slots == 1:
        cons = [cp.sum(u) <= 1]
    else:  # each time slot its share of the budget
        S = np.zeros((n_slots, n))
        S[slot, np.arange(n)] = 1.0
        cons = [S @ u <= prob.slot_budget / prob.budget]
    if prob.max_runs is not None:
        cons.append(scale @ u <= prob.max_runs)

    def info(r, sp):
        out = []
        for s in range(r.shape[0]):
            # column scales: the information of spending the whole budget evenly
            d = np.sqrt(np.mean(r[s] ** 2 * scale[:, None], axis=0) + np.diag(sp.prior) / n)
            blind = [nm for nm, v in zip(sp.names, d) if not v > 0]
            if blind:
                raise UnidentifiableError(f"no candidate run carries information on {', '.join(blind)}", blind)
            rs = r[s] / d[None, :]
            Q = np.einsum("ni,nj->ijn", rs, rs).reshape(sp.k * sp.k, n) * scale[None, :]
            # symmetric as it is (Q's rows (i, j) and (j, i) are the same products; the prior
            # made so) and only ever used in PSD constraints, which take the symmetric part: an
            # explicit (F + F.T) / 2 gives cvxpy the same conic data with a third more to
            # canonicalise
            P = sp.prior / np.outer(d, d)
            F = cp.reshape(Q @ u, (sp.k, sp.k), order="C") + (P + P.T) / 2
            out.append(Scaled(F, d))
        return out

    ops, spec = CvxOps(), prob.spec
    objective = sum(prob.criterion.loss(F, ops, spec.names) for F in info(prob.rows, spec)) / prob.rows.shape[0]
    guard_cons = [-sum(g.criterion.loss(F, ops, g.spec.names) for F in info(g.rows, g.spec)) / g.rows.shape[0] >= g.bound
                  for g in prob.guards]
    problem = cp.Problem(cp.Minimize(objective), cons + ops.constraints + guard_cons)
    status, used = _solve(problem, prob.solver)
    mus = [max(0.0, float(c.dual_value)) if c.dual_value is not None else 0.0 for c in guard_cons]
    return np.clip(u.value, 0.0, None) * scale, mus, status, used, _supergradients(ops.eigen_bounds)


def _supergradients(eigen_bounds):
    """Supergradients of lambda_min in display units from the duals ``Z`` of the constraints
    ``F' - t D^-2 >= 0`` (``F' = D^-1 F D^-1``): ``G = D^-1 Z D^-1``, made PSD with trace 1;
    None when the criterion has no such constraint or a dual is missing."""
    out = []
    for con, d in eigen_bounds:
        Z = con.dual_value
        if Z is None:
            return None
        G = np.asarray(Z, float) / np.outer(d, d)
        lam, vec = np.linalg.eigh((G + G.T) / 2)
        G = (vec * np.clip(lam, 0.0, None)) @ vec.T
        if not np.trace(G) > 0:
            return None
        out.append(G / np.trace(G))
    return out or None


def _solve(problem, solver):
    """Solve with ``solver`` (or the first of :data:`SOLVERS` that ends ``optimal`` or
    ``optimal_inaccurate``; the certificate judges the latter, in :func:`solve_approximate`);
    else raise with every status."""
    tried = []
    for name in ((solver,) if solver else SOLVERS):
        try:
            with warnings.catch_warnings():  # an inaccurate solution is judged by its certificate
                warnings.simplefilter("ignore", UserWarning)
                _run_solver(problem, name)
        except (cp.error.SolverError, np.linalg.LinAlgError) as err:  # LinAlgError: a singular
            # information matrix met in cvxpy's own evaluation of the objective
            tried.append(f"{name}: solver error ({type(err).__name__}: {str(err).splitlines()[0]})")
            continue
        if problem.status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
            return problem.status, name
        tried.append(f"{name}: status {problem.status}")
    raise DesignError("the approximate design's convex program was not solved: " + "; ".join(tried))


def _run_solver(problem, name):
    try:
        if name == "SCS":
            problem.solve(solver=name, eps_abs=1e-8, eps_rel=1e-8, max_iters=20000)  # a fallback: seconds, not minutes
        elif name == "CLARABEL":  # the chordal split of the small dense cones costs accuracy; A-optimal
            # programs with time slots take 200-400 iterations (the default 200 ended them user_limit,
            # and SCS then took 1 s a program)
            problem.solve(solver=name, chordal_decomposition_enable=False, max_iter=1000)
        else:
            problem.solve(solver=name)
    finally:
        check_interrupt()  # a solver in C that caught the Ctrl-C returns a status, or fails


def certificate(prob, loss, h, w, mus, tangent=None):
    """Efficiency lower bound of ``w`` from weak duality: the optimum is at most the
    Lagrangian's maximum over the feasible set, itself at most its value at ``w`` plus the
    Frank-Wolfe gap (a concave function lies below its tangent). ``tangent``: the value at
    ``w`` of the linear lower bound of the loss whose gradient ``h`` is (default: the loss)."""
    cost, slot, n_slots, max_runs = prob.cost, prob.slot, prob.n_slots, prob.max_runs
    if max_runs is None:
        per_slot = np.full(n_slots, -np.inf)
        np.maximum.at(per_slot, slot, h / cost)
        best = float(np.maximum(per_slot, 0.0) @ prob.slot_budget)
    else:
        from scipy.optimize import linprog
        S = np.zeros((n_slots, cost.size))
        S[slot, np.arange(cost.size)] = cost
        res = linprog(-h, A_ub=np.vstack([S, np.ones_like(cost)]),
                      b_ub=[*prob.slot_budget, max_runs], bounds=(0, None), method="highs")
        if res.status != 0:
            raise DesignError(f"equivalence-theorem bound: linprog status {res.status} ({res.message})")
        best = float(-res.fun)
    gap = max(0.0, best - float(h @ w))
    gap += sum(mu * max(0.0, g.level(w) - g.bound) for g, mu in zip(prob.guards, mus))
    crit, k = prob.criterion, prob.spec.k
    if crit.degree == 0:
        return float(np.exp(-gap / k))
    if crit.degree < 0:
        return float(max(0.0, 1.0 - gap / loss))
    tangent = loss if tangent is None else tangent
    return float(abs(loss) / (abs(tangent) + gap)) if loss < 0 and tangent < 0 else 0.0


def approximate_design(features, criterion="D", *, cost=None, budget=1.0, max_runs=None, names=None,
                       prior=None, solver=None):
    """The optimal approximate design for any linear(ised) model: the convex program of
    :func:`design` on given information rows.

    Parameters
    ----------
    features : array_like, shape (n, k) or (S, n, k)
        Row ``a_i`` of each candidate (``a_i a_i^T`` is one run's information), or one set
        per prior draw (the criterion is averaged over them).
    criterion : Criterion or str
    cost : array_like, shape (n,), optional
        Cost of one run of each candidate (default 1).
    budget : float
        ``sum_i w_i cost_i <= budget``.
    max_runs : float, optional
        ``sum_i w_i <= max_runs``.
    names : sequence of str, optional
        Column names (default ``p0, p1, ...``), for ``c:NAME``.
    prior : numpy.ndarray, shape (k, k), optional
        Information added to every design.
    solver : str, optional

    Returns
    -------
    ApproximateDesign
        ``runs`` is the optimal number of runs of each candidate (``candidates`` is None).
    """
    rows = np.asarray(features, dtype=float)
    if rows.ndim == 2:
        rows = rows[None]
    if rows.ndim != 3 or rows.shape[1] < 1 or rows.shape[2] < 1 or not np.all(np.isfinite(rows)):
        raise ValueError(f"features has shape {np.shape(features)}; allowed: (n, k) or (S, n, k) finite "
                         "numbers")
    n, k = rows.shape[1:]
    cost = np.ones(n) if cost is None else np.asarray(cost, dtype=float)
    if cost.shape != (n,) or np.any(~np.isfinite(cost)) or np.any(cost <= 0):
        raise ValueError(f"cost: allowed ({n},) positive numbers")
    names = tuple(names) if names is not None else tuple(f"p{i}" for i in range(k))
    if len(names) != k:
        raise ValueError(f"names: {len(names)} given for {k} feature columns")
    prob = Problem(as_criterion(criterion), Rows(names, None, [], prior), rows, cost=cost,
                   budget=positive("budget", budget), max_runs=max_runs, solver=solver)
    return solve_approximate(prob)

