"""Refinement: IPOPT (CasADi) moves the exact design's rates and azimuths off the candidate grid.

Runs sharing an azimuth or a rate keep sharing it, so setups do not grow; guards stay at or
above their bounds; IPOPT's point is checked independently before it is kept.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from ..interrupts import check as check_interrupt
from .criteria import CASADI
from .problem import mean_loss


def refine(prob, exact, stand, mm, space):
    """IPOPT over the distinct azimuths and signed rates of the exact design's settings
    (counts fixed; guards kept at or above their bounds). Updates ``exact`` in place when
    the loss falls; returns IPOPT's status."""
    crit, spec = prob.criterion, prob.spec
    st, counts = exact.settings, exact.counts
    az_u, ia = np.unique(np.round(st.azimuth, 12), return_inverse=True)
    r_u, ir = np.unique(np.round(st.rate, 12), return_inverse=True)
    ia, ir, n_az = ia.ravel(), ir.ravel(), az_u.size
    v = ca.MX.sym("v", n_az + r_u.size)
    lo, hi = space.rates
    half = space.azimuth_spacing
    lbx = np.concatenate([az_u - half, np.where(r_u > 0, lo, -hi)])
    ubx = np.concatenate([az_u + half, np.where(r_u > 0, hi, -lo)])
    sigma = stand.sigma(st.duration)
    X0 = st.inputs(mm, stand)
    xs = [ca.vertcat(v[n_az + ir[i]], v[ia[i]], X0[2:, i]) for i in range(counts.size)]

    def mean_over_samples(sp, fun):
        total = 0
        for p in sp.ps:
            F = ca.MX(sp.prior)
            for i, x in enumerate(xs):
                a = sp.fn(p, x) / sigma[i]
                F = F + counts[i] * ca.mtimes(a.T, a)
            total = total + fun(F)
        return total / len(sp.ps)

    loss0 = exact.loss
    f = mean_over_samples(spec, lambda F: crit.loss(F, CASADI, spec.names))
    g = [mean_over_samples(gd.spec, lambda F, gd=gd: -gd.criterion.loss(F, CASADI, gd.spec.names))
         for gd in exact.guards]
    floors = [min(gd.bound, gd.level(counts)) for gd in exact.guards]
    nlp = {"x": v, "f": f / abs(loss0)}  # order 1, so that IPOPT's barrier starts small against it
    if g:
        nlp["g"] = ca.vertcat(*g)
    solver = ca.nlpsol("refine", "ipopt", nlp, {
        "ipopt.print_level": 0, "print_time": 0, "show_eval_warnings": False, "ipopt.sb": "yes", "ipopt.max_iter": 200,
        "ipopt.bound_push": 1e-10, "ipopt.bound_frac": 1e-10, "ipopt.mu_init": 1e-6})
    args = {"x0": np.concatenate([az_u, r_u]), "lbx": lbx, "ubx": ubx}
    if g:
        args.update(lbg=np.array(floors) + 1e-7, ubg=np.full(len(g), np.inf))  # inside: IPOPT's tolerance
    sol = solver(**args)
    check_interrupt()  # a Ctrl-C inside IPOPT ends as its status NonIpopt_Exception_Thrown
    stats = solver.stats()
    # verify IPOPT's point independently: within the bounds, guards kept, loss lower
    vopt = np.clip(np.array(sol["x"]).ravel(), lbx, ubx)
    new = st.replace(azimuth=vopt[:n_az][ia], rate=vopt[n_az:][ir])
    X1 = new.inputs(mm, stand)
    rows = spec.numeric(X1, sigma)
    loss = mean_loss(crit, rows, spec, counts)
    guards = tuple(gd.at(gd.spec.numeric(X1, sigma)) for gd in exact.guards)
    # (guards to 1e-6 in log det, i.e. 1e-6/k in D-efficiency: IPOPT's tolerance and the clipping to the bounds)
    better = (loss < loss0 - 1e-9 * abs(loss0)
              and all(gd.level(counts) >= f - 1e-6 for gd, f in zip(guards, floors)))
    status = stats["return_status"]
    if not better:      # the grid plan stands on its own: a failed refinement only keeps it
        return f"{status} ({'IPOPT failed' if not stats['success'] else 'no improvement'}: the grid settings are kept)"
    exact.settings, exact.rows, exact.guards, exact.loss = new, rows, guards, loss
    return status if stats["success"] else f"{status} (its last point checked: feasible and better, kept)"

