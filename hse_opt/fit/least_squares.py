"""The fit itself: :func:`fit` (solvers and weights as :mod:`hse_opt.fit` describes)."""
import dataclasses

import numpy as np

from .. import units
from ..information import (UnidentifiableError, analyse, blind_out, confounded, invisible, null_space,
                           separation_advice)
from ..model.composition import as_model
from .problem import Problem, position_projector, setup
from .result import FitResult, SolverError
from .solvers import gauss_newton, gauss_newton_step, solve, subspace
from .weights import (HUBER_C, huber_weights, lack_of_fit_test, mad_scale, multiplicity, replicate_groups,
                      run_sigma)


#: the profile start runs on at most this many runs (evenly spread in run order)
PROFILE_RUNS = 1000


def _profile_start(prob, w, z, A_eq, b_eq, lin, given=(), points=25, coarse=3):
    """Start values of the nonlinear parameters from their profiles: each in turn on a grid of
    ``points`` over its range (log-spaced for a positive one, e.g. a time constant), the linear
    parameters solved exactly at each point (they enter linearly: one step, one batch call of
    the model), the point of the smallest objective kept. The grid is searched coarse to fine:
    every ``coarse``-th point, then the points between the best one's neighbours. A start far
    from the optimum of a time constant otherwise leaves the solvers on a plateau (IPOPT's
    Maximum_Iterations_Exceeded on a warm-up campaign). ``given``: names whose start the
    caller chose (kept). A campaign of more than ``PROFILE_RUNS`` runs is profiled on that many,
    spread evenly in run order, their weights scaled to the whole campaign's (a start value
    only: the solver then fits every run)."""
    n = prob.X.shape[1]
    if n > PROFILE_RUNS and prob.project is None:
        runs = np.unique(np.linspace(0, n - 1, PROFILE_RUNS).round().astype(int))
        prob, w = prob.subset(runs), np.asarray(w)[runs] * np.sqrt(n / len(runs))
    for j in np.flatnonzero(prob.nonlinear):
        if prob.names[j] in given:
            continue
        lo, hi = prob.lb[j], prob.ub[j]
        if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
            continue
        grid = np.geomspace(lo, hi, points) if lo > 0 else np.linspace(lo, hi, points)
        f_start, tried = prob.objective(z, w), {}

        def profile(i):
            """(objective, z) with parameter j at grid[i], the linear parameters solved."""
            if i not in tried:
                trial = z.copy()
                trial[j] = grid[i]
                Z, trial = subspace(prob, trial, A_eq, b_eq, lin)
                out = gauss_newton_step(prob, w, trial, Z) if Z.shape[1] else (0.0, None, None)
                if out is None or not np.all(np.isfinite(out[0])):
                    tried[i] = (np.inf, trial)
                else:
                    # the QR's predicted objective is the objective after the step (the linear
                    # parameters enter linearly); evaluated when a bound clips the step
                    step, _, f = out
                    stepped = trial + step
                    trial = np.clip(stepped, prob.lb, prob.ub)
                    if f is None or not np.array_equal(trial, stepped):
                        f = prob.objective(trial, w)
                    tried[i] = (f, trial)
            return tried[i]

        best = min(range(0, points, coarse), key=lambda i: profile(i)[0])
        best = min(range(max(best - coarse + 1, 0), min(best + coarse, points)), key=lambda i: profile(i)[0])
        f, trial = profile(best)
        if f < f_start:
            z = trial
    return z


def fit(runs, model=None, *, fix=None, tilt_known=None, bounds=None, constraints=(), prior=None,
        robust=False, huber_c=HUBER_C, max_iter=100, jit=None, start=None):
    """Calibrate ``model`` on ``runs`` by weighted least squares.

    Parameters
    ----------
    runs : hse_opt.data.Runs
    model : Model, str or sequence of str, optional
        Default: the paper's model (``hse``). See :func:`as_model`.
    fix : mapping name -> value (display unit), optional
        Parameters held at a value.
    tilt_known : bool, optional
        Use the runs' pitch/roll (default: when the runs have them).
    bounds : mapping name -> (lower, upper), optional
        Display units; ``None`` for an open side. Nonlinear parameters default to their
        declared range.
    constraints : sequence of Constraint, optional
        Linear equalities and inequalities between parameters.
    prior : Prior or FitResult, optional
        Gaussian prior information, e.g. the previous calibration (on-line update).
    robust : bool
        Huber loss instead of squares; ``huber_c`` is its threshold in sigmas.
    max_iter : int
        Iterations of the robust reweighting.
    jit : bool, optional
        Evaluate the model's batches with compiled C (compiled once per machine and kept in
        :mod:`hse_opt.compile_cache`; about half a second the first time, then ten times
        faster than the virtual machine): default from 1,000 runs; worth it for repeated fits
        of the same model, such as on-line updates.
    start : mapping name -> value (display unit), optional
        Where the iteration starts for free parameters (default: their nominal values); needed
        when a parameter's signature vanishes at the nominal values of the others.

    Returns
    -------
    FitResult

    Raises
    ------
    UnidentifiableError
        The runs cannot separate some free parameters (named, with runs that would).
    SolverError
        The solver failed (its status in the message and ``.status``).
    ValueError
        Bad arguments, infeasible constraints, too few runs.

    Notes
    -----
    Without tilt columns the tilt-coupled terms are free C23 coefficients the tool creates
    (``lambda2*tilt_const``, ...); when the runs cannot separate such a constant nuisance from
    the offset (one bias rate: the paper's Table 1), it is held at 0 -- absorbed into the
    offset -- and a note says so. Parameters of the user's model are never held silently.
    """
    kw = dict(fix=fix, tilt_known=tilt_known, bounds=bounds, constraints=constraints, prior=prior,
              robust=robust, huber_c=huber_c, max_iter=max_iter, jit=jit, start=start)
    try:
        return _fit(runs, model, **kw)
    except UnidentifiableError as err:
        fix = dict(fix or {})
        nuisance = [n for n in err.names if n.endswith("*tilt_const") and n not in fix]
        if not nuisance or "offset" not in err.names or "offset" in fix \
                or not set(err.names) <= set(nuisance) | {"offset"}:
            raise
        f = _fit(runs, model, **{**kw, "fix": {**fix, **{n: 0.0 for n in nuisance}}})
    return dataclasses.replace(f, notes=f.notes + (
        f"{', '.join(nuisance)} held at 0, absorbed into the offset: these runs cannot separate the "
        "constant tilt term the tool adds without tilt columns from the offset (one bias rate)",))


def _fit(runs, model, *, fix, tilt_known, bounds, constraints, prior, robust, huber_c, max_iter, jit, start):
    model = as_model(model)
    if tilt_known is None:
        tilt_known = runs.pitch is not None
    if tilt_known and runs.pitch is None:
        raise ValueError(f"{runs.source}: tilt_known=True needs pitch_arcsec/roll_arcsec columns; allowed: "
                         "runs with both columns, or tilt_known=False")
    if not huber_c > 0:
        raise ValueError(f"huber_c must be > 0 sigma, got {huber_c}")
    mm = model.measurement(tilt_known)
    X = mm.inputs_from_runs(runs)
    y = np.asarray(runs.heading_err, dtype=float)
    n = y.size
    notes = list(runs.notes)
    group, positions = runs.reference_groups()
    if positions:  # field campaign: one unknown constant per unsurveyed position
        if robust:
            raise ValueError(f"{runs.source}: robust=True (--robust) with positions without a heading "
                             "reference is not supported; allowed: the least-squares fit")
        notes.append(f"{len(positions)} position{'s' if len(positions) > 1 else ''} without a heading "
                     f"reference ({', '.join(positions)}): each one's unknown heading eliminated exactly "
                     "(only differences within a position count; never reported)")
        if not (group < 0).any() and "offset" in mm.names and "offset" not in (fix or {}):
            fix = {**(fix or {}), "offset": 0.0}
            notes.append("offset held at 0: no surveyed position (each position's constant absorbs it; "
                         "not a calibration result)")
    if tilt_known is False and runs.pitch is not None:
        notes.append("pitch/roll given but not used: tilt-coupled terms fitted as free C23 coefficients")
    (p_base, free, lower, upper, A_eq, b_eq, A_in, l_in, u_in, L, Lmu,
     kept) = setup(mm, runs, fix, bounds, constraints, prior, notes, start)
    k = int(free.sum())
    sigma, weighting, more = run_sigma(runs, robust, mm)
    notes += more
    # copies of one measurement (Runs.copies) share its weight: they count once in the degrees
    # of freedom and in the likelihood, and a sigma estimated from the residuals is shared too
    count, _ = multiplicity(runs)
    n_meas = int(round(float(np.sum(1.0 / count))))
    project, n_pos = position_projector(runs, sigma)
    prob = Problem(mm, X, y, p_base, free, lower[free], upper[free], A_eq, b_eq, A_in, l_in, u_in,
                   L, Lmu, jit, project=project)
    r_prior = L.shape[0]
    k_eq = np.linalg.matrix_rank(A_eq) if A_eq.size else 0
    if n_meas - n_pos + r_prior <= k - k_eq:
        field = f" ({n_pos} go to the positions' unknown headings)" if n_pos else ""
        field += f" (the {n} rows hold {n_meas} distinct measurements: the others are copies)" if n_meas < n else ""
        why = (_single_rate_positions(runs, group, positions) if positions else
               "allowed: more runs than free parameters, or hold some with --fix NAME=VALUE")
        raise ValueError(f"{runs.source}: {n_meas} runs{field} cannot fit {k - k_eq} free parameters "
                         f"({', '.join(prob.names)}); {why}")
    units_free = [q.unit for q, f in zip(mm.params, free) if f]

    def advice_for(mask):
        full = free.copy()
        full[free] = mask

        def advice(direction):
            return separation_advice(mm, prob.p(z), X, full, direction)
        return advice

    def field_analyse(*a, **kw):
        """:func:`analyse`; for a field campaign the error says which positions saw one rate only."""
        try:
            return analyse(*a, **kw)
        except UnidentifiableError as err:
            if not positions:
                raise
            raise UnidentifiableError(f"{err}; {_single_rate_positions(runs, group, positions)}", err.names,
                                      err.direction, err.condition) from None

    # identifiability of the linear part before solving (nonlinear parameters held)
    z = np.clip(p_base[free] / prob.scale, prob.lb, prob.ub)
    lin = ~prob.nonlinear
    eq_lin = A_eq[:, lin][~np.any(A_eq[:, ~lin] != 0, axis=1)] if A_eq.size else np.zeros((0, int(lin.sum())))

    def check_start(z):
        J0 = prob.jacobian(z)
        A0 = J0[:, lin] / sigma[:, None]
        field_analyse(blind_out(A0.T @ A0, invisible(J0, prob.ranges)[lin]) + L[:, lin].T @ L[:, lin],
                np.array(prob.names)[lin], np.array(units_free)[lin],
                advice=advice_for(lin), Z=null_space(eq_lin, int(lin.sum())))

    # a bilinear effect (the encoder harmonics act through lambda2) has no heading signature
    # where the parameters it multiplies start at 0: solve the others first
    blind = lin & invisible(prob.jacobian(z), prob.ranges)
    if blind.any() and (lin & ~blind).any() and not A_eq.size:
        z, _ = gauss_newton(prob, 1 / sigma, z, np.zeros((0, k)), np.zeros(0), mask=lin & ~blind)
    check_start(z)
    if prob.nonlinear.any():  # start: the linear parameters solved with the nonlinear ones held
        eq_rows = ~np.any(A_eq[:, ~lin] != 0, axis=1) if A_eq.size else np.zeros(0, bool)
        z, _ = gauss_newton(prob, 1 / sigma, z, A_eq[eq_rows], b_eq[eq_rows], max_iter=1, mask=lin)
        z = _profile_start(prob, 1 / sigma, np.clip(z, prob.lb, prob.ub), A_eq[eq_rows], b_eq[eq_rows], lin,
                           given=set(start or ()))

    # solve; with robust weights or a sigma estimated from the residuals, re-solve until the
    # weights settle (the sigma matters to the solution only against a prior, and to IPOPT's
    # tolerances)
    hw = np.ones(n)
    if robust:
        notes.append(f"Huber loss, threshold {huber_c:g} sigma (iteratively reweighted)")
    z_start = z.copy()

    def unidentifiable(err):
        """A solver failure on runs that barely separate some parameters is that, not a
        numerical accident: the error names the confounded group (exit 2, not 1)."""
        # the linear parameters at the start (a nonlinear one's column vanishes where its
        # amplitude starts at 0: no confounding of the data's making)
        J0 = prob.jacobian(z_start)[:, lin]
        A0 = J0 / sigma[:, None]
        F0 = blind_out(A0.T @ A0, invisible(J0, prob.ranges[lin])) + L[:, lin].T @ L[:, lin]
        try:
            C0 = np.linalg.inv(F0)
        except np.linalg.LinAlgError:
            return err
        groups0 = confounded(F0, C0, np.array(prob.names)[lin], advice=advice_for(lin))
        if not groups0:
            return err
        g = groups0[0]
        advice = f". {g.advice[:1].upper()}{g.advice[1:]}" if g.advice else ""
        return UnidentifiableError(f"parameters {', '.join(g.names)} cannot be told apart by these runs (|r| up to "
                                   f"{g.correlation:.4f}, sigma inflated up to {max(g.inflation):.3g}-fold; the "
                                   f"solver failed along their combination: {err}){advice}", g.names,
                                   g.direction, np.inf)

    for _ in range(max_iter):
        try:
            z, C, binding, act, method, status = solve(prob, np.sqrt(hw) / sigma, z, notes)
        except SolverError as err:
            raise unidentifiable(err) from None
        res = prob.residual(z)
        k_eff = null_space(C, k).shape[1]
        dof = n_meas + r_prior - k_eff - n_pos
        if dof <= 0:
            raise ValueError(f"{runs.source}: no degrees of freedom left ({n_meas} runs, {k_eff} free "
                             "directions); allowed: more runs than free parameters, or some held with --fix")
        new_sigma = sigma
        if weighting in ("residual", "robust-scale"):
            s = np.sqrt(np.sum(res ** 2 / count) / dof) if weighting == "residual" else mad_scale(res)
            if s <= 0:
                raise ValueError(f"{runs.source}: the model fits the runs exactly; sigma cannot be "
                                 "estimated from the residuals; allowed: runs with heading_std_arcsec, or more "
                                 "runs than parameters")
            new_sigma = s * np.sqrt(count)
        new_hw = huber_weights(res / new_sigma, huber_c) if robust else hw
        settled = (np.max(np.abs(new_hw - hw)) < 1e-7  # ~1e-7/n sigma on the estimates
                   and np.max(np.abs(new_sigma / sigma - 1)) < 1e-6)
        sigma, hw = new_sigma, new_hw
        if settled or not (robust or (weighting == "residual" and (r_prior > 0 or method == "ipopt"))):
            break
    else:
        raise SolverError(f"the weights did not settle in {max_iter} re-solves", "max_iter")
    if robust:
        method += "+huber"
    if weighting == "residual":
        notes.append(f"sigma {sigma[0] / np.sqrt(count[0]) / units.ARCSEC:.3g} arcsec estimated from the residuals")
    elif weighting == "robust-scale":
        notes.append(f"sigma {sigma[0] / units.ARCSEC:.3g} arcsec from the residuals' median absolute "
                     "deviation")
    Z = null_space(C, k)

    A = prob.jacobian(z) / sigma[:, None]
    F_data = A.T @ A
    u = res / sigma
    if robust:
        psi, dpsi = np.clip(u, -huber_c, huber_c), (np.abs(u) <= huber_c).astype(float)
        m_ = dpsi.mean()
        if m_ == 0:
            raise ValueError(f"{runs.source}: every run is beyond the Huber threshold; allowed: a larger "
                             "huber_c")
        K = 1 + k_eff / n * dpsi.var() / m_ ** 2
        F_data = F_data / (K ** 2 * np.sum(psi ** 2) / max(n - k_eff, 1) / m_ ** 2)
    info = field_analyse(blind_out(F_data, invisible(A * sigma[:, None], prob.ranges)) + L.T @ L,
                   prob.names, units_free, advice=advice_for(np.ones(k, bool)), Z=Z)
    groups = confounded(info.fisher, info.covariance, prob.names, advice=advice_for(np.ones(k, bool)))
    for g in groups:
        notes.append(f"{g.text()} (confounded: |r| > 0.99 or sigma inflated more than 10-fold)")

    n_p = len(mm.names)
    cov = np.zeros((n_p, n_p))
    cov[np.ix_(free, free)] = info.covariance
    corr = np.zeros((n_p, n_p))
    corr[np.ix_(free, free)] = info.correlation
    std = np.sqrt(np.diag(cov))
    e = L @ z - Lmu
    chi2_prior = float(e @ e)
    chi2 = float(u @ u) + chi2_prior
    rss = np.sum(res ** 2 / count)
    ll_term = n_meas * np.log(rss / n_meas) + chi2_prior if weighting == "residual" else chi2
    binding_names = tuple(str(prob.names[j]) for j in binding)
    for nm in binding_names:
        notes.append(f"{nm} is held at its bound (std 0: the bound, not the data, sets it)")
    inequalities = [c for c in kept if not c.is_equality]
    active = tuple(str(inequalities[j]) for j in act)
    order = np.argsort(hw, kind="stable")
    down = tuple(int(runs.run[i]) for i in order if hw[i] < 1 - 1e-12)
    p = prob.p(z)
    # the replicates' test of the model (one rule with hse-opt diagnose); a prior's pull on the
    # parameters is no part of the replicate groups' means: no test then
    lof = None
    if not r_prior:
        labels, g = replicate_groups(runs, mm)
        lof = lack_of_fit_test(res, sigma, labels, g, n_meas, k_eff + n_pos)
    return FitResult(
        model=model, tilt_known=tilt_known, names=mm.names, units=tuple(q.unit for q in mm.params),
        values=p / mm.scale, std=std, covariance=cov, correlation=corr, free=free, p=p,
        run=np.asarray(runs.run), residuals=res, sigma=sigma, standardized=u,
        chi2=chi2, dof=int(dof), chi2_red=chi2 / dof, aic=ll_term + 2 * (k_eff + n_pos),
        bic=ll_term + (k_eff + n_pos) * np.log(n_meas), condition=info.condition, weighting=weighting,
        method=method, status=status, binding=binding_names, downweighted=down, notes=tuple(notes),
        lower=lower, upper=upper, constraints=kept, active=active, weights=hw, chi2_prior=chi2_prior,
        inputs=X, confounded=groups, lack_of_fit=lof)


def _single_rate_positions(runs, group, positions):
    """What a field campaign's identifiability error adds: which unsurveyed positions saw one
    bias rate only (their constant absorbs everything one rate shows)."""
    single = []
    for k, label in enumerate(positions):
        rates = np.unique(np.round(runs.rate[group == k] / units.DEG_PER_S, 1))   # encoder rates: 0.1 deg/s
        if rates.size == 1:
            single.append(f"{label!r} ({rates[0]:g} deg/s)")
    if single:
        return (f"position{'s' if len(single) > 1 else ''} {', '.join(single)} without a heading reference "
                f"{'have' if len(single) > 1 else 'has'} one bias rate only: a position's unknown heading "
                "absorbs everything a single rate shows, so it tells nothing about lambda2; allowed: two or "
                "more rates (or both senses) at a position, or its azimuth_deg")
    return ("only differences within each position without a heading reference count (its unknown heading "
            "absorbs the rest): a parameter that is constant at every such position cannot be fitted; "
            "allowed: more rates, senses or times per position, or surveyed positions")
