"""The shortest plan that would resolve the systematic risks: runs added one at a time.

A risk (:mod:`hse_opt.aliasing`) stands when an effect the diagnosis's test would miss at its
plausible size could move a fitted parameter by more than that parameter's sigma. More runs
end it in two ways at once: the test gains power against the effect (the largest size it
misses shrinks), and the effect's columns separate from the model's (its alias shrinks). Not
any runs: runs that inform the fitted parameters but not the effect shrink the sigma the
shift is compared with and can make a risk worse.

:func:`resolving_plan` adds, one at a time, the candidate run that most lowers the worst
ratio *undetectable shift / sigma* over every fitted parameter and every effect at risk, until
no ratio exceeds 1, or :data:`MAX_RUNS` runs are added, or the last :data:`STALL_RUNS` runs
lowered it by less than :data:`STALL` (it tends to a limit above 1: more of the same runs
shrink the shift and the sigma alike) -- a greedy sequential design. The
quantities are those of :func:`hse_opt.aliasing.alias_budget` -- the fit's weighted Jacobian
at its estimate, extended by the effects' columns, with every unsurveyed position's heading
eliminated -- computed from the normal matrix ``N = [A_M A_E]' [A_M A_E]`` so that a run is a
rank-one update:

* covariance of the fitted parameters ``C = (N_MM)^-1`` (their sigma: ``sqrt(diag C)``);
* alias ``B = C N_ME``; the effect's part the model cannot absorb ``S = N_EE - N_EM C N_ME``;
* noncentrality at a vertex ``v`` of the plausible box ``lambda = v' S v``; the test misses the
  effect up to ``sqrt(lambda_80 / lambda)`` of it (``lambda_80``: the noncentrality of
  :data:`~hse_opt.aliasing.POWER_LIMIT` power, :func:`~hse_opt.aliasing.noncentrality_for_power`);
* undetectable shift ``max_v |B v| min(1, sqrt(lambda_80 / lambda))``.

The added runs carry the campaign's median sigma; the test's degrees of freedom grow by one
per run. Candidates: both senses at the smallest and largest |rate|, start times of the
campaign (0 s, its median, its last); on a stand campaign azimuths every 45 deg at the stand's
observed tilts; on a field campaign the positions already occupied, each at its own heading
and tilt (a run at a new position says nothing alone: ``hse-opt design --field --runs`` plans
new positions).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from .. import units
from ..aliasing import _vertices, noncentrality_for_power
from ..information import weighted_jacobian
from ..model.composition import Model
from ..model.effects import effect as make_effect
from ..model.plausible import RANGES

#: the most runs the plan adds before it says the risks cannot be resolved this way
MAX_RUNS = 48
#: the search stops when the last STALL_RUNS runs lowered the worst ratio by less than STALL
STALL_RUNS, STALL = 8, 0.02


@dataclasses.dataclass(frozen=True)
class ResolvingPlan:
    """Runs that would resolve the systematic risks of a fit.

    Attributes
    ----------
    effects : tuple of str
        The effects at risk the plan was made for.
    runs : tuple of dict
        One dict per distinct run: ``rate_dps``, ``azimuth_deg``, ``t_start_s`` (and
        ``pitch_arcsec``, ``roll_arcsec`` when the tilt is known; ``position`` on a field
        campaign), ``count`` (how many times), ``text``.
    n_runs : int
        Runs added.
    resolved : bool
        Whether the worst ratio fell to 1 or below; False: :data:`MAX_RUNS` runs did not, or
        it stalled above 1.
    ratio_before, ratio_after : float
        The worst undetectable shift in sigmas before and after.
    hours : float
        The alignments' time (``n_runs`` runs of the campaign's median duration), h.
    stalled : bool
        The search stopped because the last runs barely lowered the ratio.
    fitted : tuple of (name, unit, sigma now, sigma fitted, systematic now)
        The other way to end the risks, without runs: fit the effects with the model on these
        runs. Per parameter at risk, its statistical sigma now and with the effects fitted
        (display units; ``inf`` when these runs cannot fit them together), and its systematic
        now. The text proposes the fit when every sigma fitted is below statistical +
        systematic now.
    """

    effects: tuple
    runs: tuple
    n_runs: int
    resolved: bool
    ratio_before: float
    ratio_after: float
    hours: float
    fitted: tuple = ()
    stalled: bool = False

    def text(self, field=False):
        """One sentence: how many runs, which, how long; or why none would do (``field``: a
        campaign whose runs are at positions of unknown heading)."""
        what = "; ".join(r["text"] + (f" x{r['count']}" if r["count"] > 1 else "") for r in self.runs)
        it = "it" if len(self.effects) == 1 else "them"
        if self.resolved:
            return f"{self.n_runs} runs would resolve {it} (about {self.hours:.2g} h of alignments): {what}"
        left = (f"{self.n_runs} more would leave it at {self.ratio_after:.2g} sigma, from {self.ratio_before:.2g}"
                + (", and further runs barely lower it" if self.stalled else "")
                if self.n_runs else f"no run lowers its {self.ratio_before:.2g} sigma")
        if field:
            text = (f"runs at the positions so far cannot resolve {it} ({left}); positions at other headings may: "
                    "hse-opt design --field --runs RUNS.csv plans them")
        else:
            text = f"runs varying rate, sense, azimuth or start time cannot resolve {it} ({left})"
        if self.fitted and all(w < s + sys_ for _, _, s, w, sys_ in self.fitted):
            sig = ", ".join(f"{n} +- {w:.3g} {u} (now {s:.3g} statistical, {sys_:.3g} systematic)"
                            for n, u, s, w, sys_ in self.fitted)
            return (f"{text}; fitted with the model, these runs would give {sig}: hse-opt fit --effects "
                    f"{','.join(self.effects)}")
        if field:
            return text
        return (f"{text}; fit {it} with the model on a campaign designed for both (hse-opt design --effects "
                f"{','.join(self.effects)})")


class _Normal:
    """The normal matrix of one campaign with a risk: model columns (free parameters, then the
    positions' constants) and each effect's columns; :meth:`ratios` evaluates a stack of them."""

    def __init__(self, k, n_pos, blocks, vertices, level):
        self.k, self.n_pos, self.blocks, self.vertices, self.level = k, n_pos, blocks, vertices, level
        self.lam80 = None

    def at_dof(self, dof):
        """Set the fit's residual degrees of freedom (each effect's test has ``dof - q``)."""
        self.lam80 = [noncentrality_for_power(b.stop - b.start, max(dof - (b.stop - b.start), 1), self.level)
                      for b in self.blocks]
        return self

    def ratios(self, N):
        """Worst shift / sigma over parameters and effects, per matrix in ``N`` (c, d, d)."""
        m = self.k + self.n_pos
        C = np.linalg.inv(N[:, :m, :m])
        std = np.sqrt(np.clip(np.diagonal(C, axis1=1, axis2=2)[:, :self.k], 0.0, None))
        worst = np.zeros(N.shape[0])
        for sl, V, lam80 in zip(self.blocks, self.vertices, self.lam80):
            N_ME = N[:, :m, sl]
            B = C @ N_ME
            S = N[:, sl, sl] - np.swapaxes(N_ME, 1, 2) @ B
            lam = np.einsum("qv,cqr,rv->cv", V, S, V)
            reach = np.where(lam > 0, np.sqrt(lam80 / np.where(lam > 0, lam, 1.0)), np.inf)
            shift = np.abs(B[:, :self.k, :] @ V) * np.minimum(1.0, reach)[:, None, :]
            r = shift.max(axis=2) / np.where(std > 0, std, np.inf)
            worst = np.maximum(worst, r.max(axis=1))
        return worst


def resolving_plan(fit_result, runs, effects, *, level, max_runs=MAX_RUNS, start=()):
    """The shortest greedy plan that resolves ``effects``' risks to ``fit_result`` (module docstring).

    Parameters
    ----------
    fit_result : FitResult
        The fit at risk, of ``runs``.
    runs : hse_opt.data.Runs
    effects : sequence of str
        Catalogue effects at risk (each with a plausible range, not in the model).
    level : float
        The diagnosis's test level.
    max_runs : int
        The most runs to add.
    start : sequence of ResolvingPlan
        Plans whose runs are added first (counted in ``max_runs``): e.g. each effect's own
        plan, before the greedy steps for all of them together.

    Returns
    -------
    ResolvingPlan
        With no run when none lowers the worst ratio.
    """
    f = fit_result
    effs = [make_effect(e) for e in effects]
    mm = Model(f.model.effects + tuple(effs), f.model.geometry).measurement(f.tilt_known)
    p = mm.nominal.copy()
    for n, v in zip(f.names, f.p):
        if n in mm.names:
            p[mm.parameter_index(n)] = v
    free = np.asarray(f.free, bool)
    cols = [mm.parameter_index(n) for n in np.array(f.names)[free]]
    group, positions = runs.reference_groups()
    k, n_pos = len(cols), len(positions)
    # columns: the free parameters, the positions' constants, each effect's block
    blocks, vertices, ecols = [], [], []
    for eff in effs:
        params = [q for q in eff.params if q.name not in eff.nonlinear]
        idx = [mm.parameter_index(q.name) for q in params]
        first = k + n_pos + len(ecols)
        blocks.append(slice(first, first + len(idx)))
        vertices.append(_vertices([max(abs(RANGES[q.name][0]), abs(RANGES[q.name][1])) for q in params]))
        ecols += idx
    sigma = np.asarray(f.sigma, float)
    sig_new = float(np.median(sigma))

    def rows(X, s, g):
        A = weighted_jacobian(mm.jacobian(p, X), s, mm.scale)
        G = (g[:, None] == np.arange(n_pos)[None, :]) / np.broadcast_to(s, (X.shape[1],))[:, None]
        return np.column_stack([A[:, cols], G, A[:, ecols]])

    A0 = rows(mm.inputs_from_runs(runs), sigma, group)
    cand, cand_group, info = _candidates(runs, group, positions)
    Ac = rows(mm.inputs_from_runs(cand), sig_new, cand_group)
    # a factor nothing depends on is left out: candidates with the same columns are one
    _, keep = np.unique(np.round(Ac / max(np.abs(Ac).max(), 1e-300), 12), axis=0, return_index=True)
    keep = np.sort(keep)
    vary_t = len({info[i]["t_start_s"] for i in keep}) > 1
    Ac = Ac[keep]
    info = [dict(info[i], text=info[i]["text"] if vary_t else info[i]["text"].split(",")[0]) for i in keep]
    dof0 = int(f.dof)
    N = A0.T @ A0
    fitted = _fitted(f, N, k, np.array(f.names)[free], [e.name for e in effs])
    outer = Ac[:, :, None] * Ac[:, None, :]
    normal = _Normal(k, n_pos, blocks, vertices, level)
    before = float(normal.at_dof(dof0).ratios(N[None])[0])
    counts = np.zeros(len(Ac), int)
    key = {_key(d): i for i, d in enumerate(info)}
    for plan in start:
        for d in plan.runs:
            i = key.get(_key(d))
            if i is not None:
                counts[i] += d["count"]
    N = N + np.einsum("c,cij->ij", counts, outer)
    ratio = float(normal.at_dof(dof0 + int(counts.sum())).ratios(N[None])[0])
    trail, stalled = [ratio], False
    while ratio > 1.0 and counts.sum() < max_runs:
        stalled = len(trail) > STALL_RUNS and trail[-1] > (1.0 - STALL) * trail[-1 - STALL_RUNS]
        if stalled:
            break           # more of the same runs shrink the shift and the sigma alike
        # the test's denominator dof grows by one with each run
        r = normal.at_dof(dof0 + int(counts.sum()) + 1).ratios(N[None] + outer)
        best = int(np.argmin(r))
        if not r[best] < ratio - 1e-12:
            break           # no run lowers it: none is added
        N = N + outer[best]
        counts[best] += 1
        ratio = float(r[best])
        trail.append(ratio)
    n = int(counts.sum())
    picked = tuple(dict(info[i], count=int(counts[i])) for i in np.flatnonzero(counts))
    picked = tuple(sorted(picked, key=lambda r: -r["count"]))
    hours = n * float(np.median(runs.duration)) / units.HOUR
    return ResolvingPlan(tuple(e.name for e in effs), picked, n, ratio <= 1.0, before, ratio, hours, fitted, stalled)


def _fitted(f, N, k, names, effects):
    """Per parameter at risk: (name, unit, sigma now, sigma with the effects fitted, systematic),
    from the normal matrix ``N`` of these runs (the model's ``k`` free parameters first, every
    effect's columns in it); ``inf`` when the extended model is singular here."""
    at_risk = [n for n, by in zip(f.names, f.systematic_by or ()) if set(by) & set(effects)]
    d = np.sqrt(np.clip(np.diag(N), 1e-300, None))
    s = np.linalg.svd(N / np.outer(d, d), compute_uv=False)
    with_std = (np.sqrt(np.clip(np.diag(np.linalg.inv(N))[:k], 0.0, None)) if s[-1] > 1e-12 * s[0]
                else np.full(k, np.inf))
    out = []
    for j, name in enumerate(names):
        if name in at_risk:
            i = list(f.names).index(name)
            out.append((str(name), f.units[i], float(f.std[i]), float(with_std[j]), float(f.systematic[i])))
    return tuple(out)


def _key(d):
    return (round(d["rate_dps"], 9), round(d["azimuth_deg"], 9), round(d["t_start_s"], 6), d.get("position"))


def _candidates(runs, group, positions):
    """Candidate runs (a Runs table), their position group (-1: surveyed) and description dicts."""
    from ..data import Runs

    r = np.abs(np.asarray(runs.rate, float))
    rates = np.unique(np.concatenate([[r.min(), r.max()], [-r.min(), -r.max()]]))
    t_obs = (np.asarray(runs.t_start, float) if runs.t_start is not None
             else np.concatenate([[0.0], np.cumsum(np.asarray(runs.duration)[:-1])]))
    times = np.unique([0.0, float(np.median(t_obs)), float(np.max(t_obs))])
    has_tilt = runs.pitch is not None
    places = []        # (azimuth, pitch, roll, group, label)
    if positions:
        for j, name in enumerate(positions):
            at = group == j
            places.append((float(np.mean(runs.azimuth[at])), *(_tilt(runs, at) if has_tilt else (0.0, 0.0)), j,
                           str(name)))
    if runs.surveyed is None or np.any(runs.surveyed):
        surveyed = group < 0 if positions else np.ones(len(runs), bool)
        q = (np.round(np.column_stack([runs.pitch, runs.roll])[surveyed] / (60 * units.ARCSEC)) if has_tilt
             else np.zeros((1, 2)))
        _, first = np.unique(q, axis=0, return_index=True)
        idx = np.flatnonzero(surveyed)
        tilts = ([(float(runs.pitch[idx[i]]), float(runs.roll[idx[i]])) for i in sorted(first)[:4]] if has_tilt
                 else [(0.0, 0.0)])
        for a in np.deg2rad(np.arange(0.0, 360.0, 45.0)):
            for tp, tr in tilts:
                places.append((a, tp, tr, -1, None))
    rows = [(rate, pl, t) for pl in places for rate in rates for t in times]
    m = len(rows)
    table = Runs(run=np.arange(m), rate=np.array([x[0] for x in rows]),
                 azimuth=np.array([x[1][0] for x in rows]), heading_err=np.zeros(m),
                 latitude=np.full(m, float(np.mean(runs.latitude))),
                 duration=np.full(m, float(np.median(runs.duration))), t_start=np.array([x[2] for x in rows]),
                 pitch=np.array([x[1][1] for x in rows]) if has_tilt else None,
                 roll=np.array([x[1][2] for x in rows]) if has_tilt else None,
                 covariates={c: np.full(m, float(np.mean(v))) for c, v in runs.covariates.items()},
                 source="candidate runs")
    vary_t = times.size > 1
    info = []
    for rate, pl, t in rows:
        d = {"rate_dps": float(rate / units.DEG_PER_S), "azimuth_deg": float(np.mod(np.degrees(pl[0]), 360.0)),
             "t_start_s": float(t)}
        if has_tilt:
            d.update(pitch_arcsec=float(pl[1] / units.ARCSEC), roll_arcsec=float(pl[2] / units.ARCSEC))
        where = f"at {pl[4]}" if pl[4] is not None else f"at azimuth {d['azimuth_deg']:.4g} deg"
        if pl[4] is not None:
            d["position"] = pl[4]
        when = (f", {t / 60:.0f} min after power-on" if t > 0 else ", at power-on") if vary_t else ""
        d["text"] = f"{d['rate_dps']:+.4g} deg/s {where}{when}"
        info.append(d)
    return table, np.array([x[1][3] for x in rows], int), info


def _tilt(runs, at):
    return float(np.mean(runs.pitch[at])), float(np.mean(runs.roll[at]))
