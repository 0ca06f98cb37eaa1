"""Sequential design: the next alignments of a campaign that is running.

While a campaign runs, the engineer decides the next alignment while the last one runs (the
paper's on-line procedure). :func:`next_runs` chooses it, and the ones after it for the time
left, one at a time, each the candidate that adds the most precision ``1/sigma^2`` of the
target parameter (``lambda2`` by default) per second of stand time, counting the runs so far
in the information:

* **Information.** Each run adds ``a a^T`` with ``a = (dh/dp) / sigma`` (display units) at
  the current estimate (or the nominal values), as in :func:`hse_opt.design.evaluate`. Each
  position without a heading reference adds one unknown constant, eliminated exactly (only
  differences within a position count), as the fit does
  (:func:`hse_opt.fit.problem.position_projector`): per position the information is
  ``S2 - S1 S1^T / S0`` with ``S0 = sum 1/sigma^2``, ``S1 = sum a / sigma``, ``S2 = sum a a^T``.
  The variance of the target is ``e^T F^+ e`` when the target is estimable (``e`` orthogonal
  to the null space of ``F``) and infinite otherwise; parameters held fixed in the fit
  (``offset`` of a campaign without any reference) are left out.
* **Candidates.** Every rate of ``rates_dps`` in both senses (``senses``), at the duration
  of the runs so far (their median), at:

  - an existing position without a reference (it keeps its heading and measured tilt);
  - a surveyed stand: its azimuths so far and every ``azimuth_step_deg`` (the tilt measured
    so far stays fixed in b0 as the stand turns: its C23 follows the azimuth); in a mixed
    campaign only the surveyed azimuths so far;
  - a new position ("move to a new heading"): two runs there (one position constant is
    eliminated, so one run alone tells nothing), the system's heading turned by 90, 180 or
    270 deg from the last position and its measured tilt in b0 kept (the system's own tilt on
    its vehicle; the convention of :func:`hse_opt.design.field.design_field`). On sloping ground
    the slope's own tilt does not turn with the vehicle: choose a place whose slope differs.

* **Time.** A candidate costs its alignment(s) plus the setup from the last run
  (:class:`hse_opt.design.Costs`: a change of azimuth/position ``azimuth_change``, of rate
  or sense ``rate_change``, ``run_overhead`` per run); the runs start after the last run so
  far ends. Time since power-on (``t_start_s``) advances with the plan, so a warm-up model
  sees each run at its own time; covariates keep the last run's value.
* **Stop.** When the time left cannot hold a candidate, when the target sigma is reached,
  or after ``max_runs``.

While no candidate can make the target estimable (a first run alone), the one that adds the
most independent directions to the information is taken.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import units
from ..data import Plan
from ..model.composition import as_model
from ..model.inputs import RunInputs
from .space import Costs

__all__ = ["NextRun", "Continuation", "next_runs", "DEFAULT_RATES_DPS", "NEW_POSITION"]

#: rates offered to the next runs, deg/s (both senses)
DEFAULT_RATES_DPS = (20.0, 40.0, 60.0)
#: position label prefix of planned new positions
NEW_POSITION = "new"
#: eigenvalues below this fraction of the largest are the information's null space
_NULL_TOL = 1e-10


@dataclass(frozen=True)
class NextRun:
    """One planned alignment.

    Attributes
    ----------
    position : str or None
        Its position label (an existing one, or ``new1``, ``new2``... for a new position);
        None on a surveyed stand (the azimuth says where).
    new_position : bool
        The first run at a new position: "move to a new heading".
    surveyed : bool
        At a surveyed azimuth (the stand reading is the reference).
    azimuth_deg : float
        The stand azimuth to set (surveyed), else the heading the position is expected at, deg.
    rate_dps : float
        Signed bias rate, deg/s.
    duration_s, t_start_s : float
        Alignment length and its planned start since power-on, s.
    sigma_after : float
        The target's sigma once this run is done (display unit; inf while not estimable).
    """

    position: str | None
    new_position: bool
    surveyed: bool
    azimuth_deg: float
    rate_dps: float
    duration_s: float
    t_start_s: float
    sigma_after: float

    def describe(self):
        """The run in words: where, rate and sense, duration."""
        sense = "positive" if self.rate_dps > 0 else "negative"
        what = f"{abs(self.rate_dps):g} deg/s {sense} sense, {self.duration_s:g} s"
        if self.new_position:
            return f"move to a new heading (about {self.azimuth_deg:.0f} deg), {what}"
        if self.surveyed:
            return f"stand azimuth {self.azimuth_deg:g} deg, {what}"
        return f"at position {self.position}, {what}"

    def to_dict(self):
        return {"position": self.position, "new_position": self.new_position, "surveyed": self.surveyed,
                "azimuth_deg": self.azimuth_deg, "rate_dps": self.rate_dps, "duration_s": self.duration_s,
                "t_start_s": self.t_start_s, "sigma_after": _finite(self.sigma_after),
                "text": self.describe()}


@dataclass(frozen=True)
class Continuation:
    """The rest of a campaign, planned sequentially.

    Attributes
    ----------
    runs : tuple of NextRun
        In order; ``runs[0]`` is the next alignment (empty when nothing fits the time left).
    target : str
        The parameter whose sigma is the criterion.
    unit : str
    sigma_now, sigma_end : float
        Its sigma from the runs so far, and after all of ``runs`` (inf while not estimable).
    time_left : float
        The time that was planned, s.
    plan : hse_opt.data.Plan or None
        ``runs`` as a PLAN table (None when empty).
    notes : tuple of str
    effects : tuple of str
        The model whose information was counted.
    """

    runs: tuple
    target: str
    unit: str
    sigma_now: float
    sigma_end: float
    time_left: float
    plan: Plan | None
    notes: tuple = ()
    effects: tuple = ()

    @property
    def next(self):
        """The next alignment (None when nothing fits)."""
        return self.runs[0] if self.runs else None

    def to_dict(self):
        return {"target": self.target, "unit": self.unit, "sigma_now": _finite(self.sigma_now),
                "sigma_end": _finite(self.sigma_end), "time_left_h": self.time_left / units.HOUR,
                "n_runs": len(self.runs), "next": None if self.next is None else self.next.to_dict(),
                "effects": list(self.effects), "notes": list(self.notes)}


def _finite(x):
    return float(x) if np.isfinite(x) else None


def _variances(F, e, ref=0.0):
    """``e^T F^+ e`` of each of a stack of matrices ``F`` (m, k, k), inf where ``e`` is not in
    the range of ``F`` (the target not estimable); and their ranks. Shapes (m,). Eigenvalues
    below :data:`_NULL_TOL` times the largest, or times ``ref`` (the information before the
    positions' constants were eliminated: what cancels in the elimination is rounding), are
    the null space."""
    lam, V = np.linalg.eigh(F)
    big = lam > _NULL_TOL * np.maximum(np.maximum(lam[:, -1:], ref), 1e-300)
    c = np.einsum("mkj,k->mj", V, e)
    rank = big.sum(axis=1)
    estimable = ~np.any((np.abs(c) > 1e-6 * np.linalg.norm(e)) & ~big, axis=1) & (rank > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.sum(np.where(big, c ** 2 / np.where(big, lam, 1.0), 0.0), axis=1)
    return np.where(estimable, v, np.inf), rank


def _variance(F, e, ref=0.0):
    """``e^T F^+ e``, or inf when ``e`` is not in the range of ``F`` (not estimable); and the
    rank of ``F`` (``ref``: :func:`_variances`)."""
    v, rank = _variances(F[None], e, ref)
    return float(v[0]), int(rank[0])


class _Information:
    """The campaign's information, surveyed rows and one accumulator per unsurveyed position."""

    def __init__(self, k, prior=None):
        self.Fs = np.zeros((k, k)) if prior is None else np.array(prior, dtype=float)
        self.groups = {}  # label -> [S0, S1, S2]
        self.scale = 0.0  # largest diagonal element of sum a a^T: the size of rounding in F

    def add(self, A, u, labels):
        """Rows ``A`` (m, k) weighted by 1/sigma; ``u`` (m,) = 1/sigma; labels None = surveyed."""
        self.scale = max(self.scale, float(np.max(np.sum(A * A, axis=0), initial=0.0)))
        for a, w, g in zip(A, u, labels):
            if g is None:
                self.Fs = self.Fs + np.outer(a, a)
            else:
                S0, S1, S2 = self.groups.get(g, (0.0, 0.0, 0.0))
                self.groups[g] = (S0 + w * w, S1 + w * a, S2 + np.outer(a, a))

    def delta(self, A, u, label):
        """What rows ``A`` (weighted), ``u`` (1/sigma) at position ``label`` (None: surveyed)
        add to the information matrix."""
        D = A.T @ A
        if label is None:
            return D
        S0, S1, _ = self.groups.get(label, (0.0, np.zeros(A.shape[1]), None))
        T0, T1 = S0 + float(u @ u), S1 + u @ A
        return D - np.outer(T1, T1) / T0 + (np.outer(S1, S1) / S0 if S0 > 0 else 0.0)

    def matrix(self):
        """The information matrix F."""
        Fs = self.Fs
        groups = self.groups
        F = Fs.copy()
        for S0, S1, S2 in groups.values():
            F += S2 - np.outer(S1, S1) / S0
        return F


def next_runs(runs, model, time_left, *, values=None, free=None, tilt_known=None, target="lambda2",
              sigma=None, costs=None, rates_dps=DEFAULT_RATES_DPS, senses=(1, -1), azimuth_step_deg=45.0,
              target_sigma=None, max_runs=200):
    """Plan the rest of a running campaign, one alignment at a time (module docstring).

    Parameters
    ----------
    runs : hse_opt.data.Runs
        The runs so far (surveyed, field or mixed; with ``t_start_s`` the plan continues from
        the last run's end, else from the sum of the durations).
    model : Model, str or sequence of str
        The model being calibrated (e.g. ``fit.model``).
    time_left : float
        Stand time left after the last run so far, s.
    values : mapping name -> value (display units), optional
        Where to linearise (the current estimate); default the nominal values.
    free : sequence of str, optional
        The parameters estimated (default: all, but ``offset`` when no run has a reference).
    tilt_known : bool, optional
        Default: when the runs carry pitch and roll.
    target : str
        The parameter whose sigma is the criterion.
    sigma : numpy.ndarray, shape (n,), optional
        Each run's heading sigma, rad (default ``runs.heading_std``; else
        :func:`hse_opt.information.heading_sigma`); a planned run gets their median.
    costs : Costs, optional
        Setup times (the warm-up is not used: the campaign is running).
    rates_dps : sequence of float
        Rate magnitudes offered, deg/s.
    senses : sequence of int
        Senses offered (+1, -1).
    azimuth_step_deg : float
        Grid of new stand azimuths on a surveyed stand, deg.
    target_sigma : float, optional
        Stop once the target's sigma is at most this (display unit).
    max_runs : int

    Returns
    -------
    Continuation
    """
    from ..information import heading_sigma

    model = as_model(model)
    costs = costs or Costs()
    if tilt_known is None:
        tilt_known = runs.pitch is not None
    mm = model.measurement(bool(tilt_known))
    if target not in mm.names:
        raise ValueError(f"target {target!r} is not a parameter of {'+'.join(model.effect_names)}; "
                         f"allowed: {', '.join(mm.names)}")
    if not np.isfinite(time_left) or time_left < 0:
        raise ValueError(f"time left {time_left!r} s; allowed: a finite time >= 0")
    p = mm.vector({k: v for k, v in (values or {}).items() if k in mm.names})
    X = mm.inputs_from_runs(runs)
    if sigma is None:
        sigma = runs.heading_std if runs.heading_std is not None else heading_sigma(runs.duration, runs.latitude)
    sigma = np.asarray(sigma, dtype=float)
    group, glabels = runs.reference_groups()
    surveyed_rows = group < 0
    if free is None:
        keep = np.array([n != "offset" or bool(surveyed_rows.any()) for n in mm.names])
    else:
        keep = np.isin(np.array(mm.names), list(free))
    if target not in np.array(mm.names)[keep]:
        raise ValueError(f"target {target!r} is not estimated (held fixed); allowed: a free parameter")
    scale = np.asarray(mm.scale)[keep]
    e = np.zeros(int(keep.sum()))
    e[list(np.array(mm.names)[keep]).index(target)] = 1.0
    unit = mm.params[mm.names.index(target)].unit

    def rows(Xc, s):
        return (mm.jacobian(p, Xc)[:, keep] * scale) / s[:, None], 1.0 / s

    # a planned run's row depends on its start time only through a thermal effect: without
    # one, the rows of the candidates are computed once and reused at every step
    timed = any(e.level == "thermal" for e in model.effects)
    memo = {}

    def cached_rows(Xc):
        K = Xc.copy()
        if not timed:
            K[RunInputs.INDEX["t_start"]] = 0.0
        keys = [k.tobytes() for k in K.T]
        todo = [j for j, k in enumerate(keys) if k not in memo]
        if todo:
            A_new, _ = rows(Xc[:, todo], np.full(len(todo), s_new))
            for j, a in zip(todo, A_new):
                memo[keys[j]] = a
        return np.array([memo[k] for k in keys]), np.full(len(keys), 1.0 / s_new)

    info = _Information(int(keep.sum()))
    A, u = rows(X, sigma)
    info.add(A, u, [None if g < 0 else glabels[g] for g in group])
    var_now, _ = _variance(info.matrix(), e, info.scale)

    # -- where the plan starts -------------------------------------------------------------
    ix = RunInputs.INDEX
    duration = round(float(np.median(runs.duration)), 1)   # the stand sets it to 0.1 s
    s_new = float(np.median(sigma))
    ends = X[ix["t_start"]] + X[ix["duration"]]
    last = int(np.argmax(ends))
    t_now = float(ends[last])
    state = {"azimuth": float(X[ix["azimuth"], last]), "rate": float(X[ix["rate"], last]),
             "label": None if group[last] < 0 else glabels[group[last]]}

    templates = []  # (label or None, surveyed, azimuth, template column index)
    if surveyed_rows.any():
        sv = np.flatnonzero(surveyed_rows)
        azimuths = np.unique(np.round(X[ix["azimuth"], sv], 9))
        if not (~surveyed_rows).any():  # a surveyed stand: new azimuths too
            grid = np.arange(0.0, 360.0, float(azimuth_step_deg)) * units.DEG
            azimuths = np.unique(np.round(np.concatenate([azimuths, grid]), 9))
        for az in azimuths:
            templates.append((None, True, float(az), int(sv[-1])))
    for k, label in enumerate(glabels):
        rows_k = np.flatnonzero(group == k)
        templates.append((label, False, float(np.mean(X[ix["azimuth"], rows_k])), int(rows_k[-1])))
    # tilt of each template: the mean measured over its rows (surveyed: all surveyed rows)
    tilt = {}
    if tilt_known:
        for label, sv_, az, col in templates:
            sel = surveyed_rows if sv_ else (group == glabels.index(label))
            tilt[label] = (float(np.mean(X[ix["pitch"], sel])), float(np.mean(X[ix["roll"], sel])))
    field = bool((~surveyed_rows).any())

    rates = sorted({abs(float(r)) for r in rates_dps})
    options = [s * r * units.DEG_PER_S for r in rates for s in senses]
    chosen, notes = [], []
    new_count = 0
    var = var_now
    t_used = 0.0
    while len(chosen) < max_runs:
        if target_sigma is not None and np.isfinite(var) and np.sqrt(var) <= target_sigma:
            break
        blocks = []  # (label, surveyed, new, azimuths, rates, template col)
        for label, sv_, az, col in templates:
            for r in options:
                blocks.append((label, sv_, False, (az,), (r,), col))
        if field or not surveyed_rows.any():
            new_label = next(f"{NEW_POSITION}{j}" for j in range(new_count + 1, new_count + len(glabels) + 2)
                             if f"{NEW_POSITION}{j}" not in glabels)   # a label no position has yet
            base = state["azimuth"]
            col = last
            for turn in (90.0, 180.0, 270.0):
                az = float(np.mod(base + turn * units.DEG, 2 * np.pi))
                for r in rates:
                    r = r * units.DEG_PER_S
                    for pair in ((r, -r), (r * senses[0], max(rates) * units.DEG_PER_S * senses[0])):
                        if pair[0] != pair[1]:
                            blocks.append((new_label, False, True, (az, az), pair, col))
        # each block's runs as columns, their setup and time
        cols, owner, times, starts = [], [], [], []
        for b, (label, sv_, new, azs, rs, col) in enumerate(blocks):
            t = t_now + t_used
            az_prev, r_prev, lab_prev = state["azimuth"], state["rate"], state["label"]
            for az, r in zip(azs, rs):
                moved = (label != lab_prev) if not sv_ else (lab_prev is not None or abs(az - az_prev) > 1e-9)
                t += (costs.azimuth_change if moved else 0.0) + (costs.rate_change if r != r_prev else 0.0)
                x = X[:, col].copy()
                x[ix["rate"]], x[ix["azimuth"]], x[ix["duration"]], x[ix["t_start"]] = r, az, duration, t
                if tilt_known:
                    x[ix["pitch"]], x[ix["roll"]] = tilt[label] if not new else tilt.get(state["label"], (
                        float(X[ix["pitch"], col]), float(X[ix["roll"], col])))
                cols.append(x)
                owner.append(b)
                starts.append(t)
                t += duration + costs.run_overhead
                az_prev, r_prev, lab_prev = az, r, label
            times.append(t - (t_now + t_used))
        if not blocks:
            break
        Xc = np.array(cols).T
        Ac, uc = cached_rows(Xc)
        owner = np.array(owner)
        F_now = info.matrix()
        _, rank_now = _variance(F_now, e, info.scale)
        fits = [b for b in range(len(blocks)) if t_used + times[b] <= time_left]
        if not fits:
            break
        F_all = np.array([F_now + info.delta(Ac[owner == b], uc[owner == b],
                                             None if blocks[b][1] else blocks[b][0]) for b in fits])
        v_all, rank_all = _variances(F_all, e, max(info.scale, float(np.max(np.sum(Ac * Ac, axis=0)))))
        with np.errstate(divide="ignore"):
            gain = np.where(np.isfinite(v_all), 1.0 / v_all - (1.0 / var if np.isfinite(var) else 0.0), 0.0)
        t_fit = np.array([times[b] for b in fits])
        order = np.lexsort(((rank_all - rank_now) / t_fit, gain / t_fit, np.isfinite(v_all)))
        j = int(order[-1])
        best = (None, fits[j], float(v_all[j]))
        if best is None:
            break
        _, b, v = best
        label, sv_, new, azs, rs, col = blocks[b]
        sel = np.flatnonzero(owner == b)
        info.add(Ac[sel], uc[sel], [None if sv_ else label] * sel.size)
        for j, (i, az, r) in enumerate(zip(sel, azs, rs)):
            last_of_block = j == sel.size - 1
            var_j = v if last_of_block else np.inf
            chosen.append(NextRun(None if sv_ else label, new and j == 0, sv_, round(float(np.degrees(az)) % 360.0, 6),
                                  float(r / units.DEG_PER_S), duration, float(starts[i]),
                                  float(np.sqrt(var_j)) if np.isfinite(var_j) else np.inf))
        if new:
            templates.append((label, False, azs[0], col))
            if tilt_known:
                tilt[label] = tilt.get(state["label"], (float(X[ix["pitch"], col]), float(X[ix["roll"], col])))
            new_count += 1
        state = {"azimuth": azs[-1], "rate": rs[-1], "label": None if sv_ else label}
        t_used += times[b]
        var = v
    if not chosen:
        notes.append(f"no alignment fits the {time_left / units.HOUR:.3g} h left")
    plan = None
    if chosen:
        first = int(np.max(runs.run)) + 1
        plan = Plan.from_columns({
            "run": np.arange(first, first + len(chosen)),
            "rate_dps": [c.rate_dps for c in chosen], "azimuth_deg": [c.azimuth_deg for c in chosen],
            "t_start_s": [round(c.t_start_s, 3) for c in chosen], "duration_s": [c.duration_s for c in chosen],
            **({"position": [c.position or "stand" for c in chosen]} if field else {})},
            source="<sequential plan>", min_rate_dps=0.0, allow_small_azimuths=True)
    return Continuation(tuple(chosen), target, unit, float(np.sqrt(var_now)), float(np.sqrt(var)),
                        float(time_left), plan, tuple(notes), tuple(model.effect_names))
