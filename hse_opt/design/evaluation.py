"""Evaluation: what a plan predicts for a model -- each parameter's sigma, their correlations,
the criterion's loss and the bias a slow linear heading drift (1 arcsec/h) puts on each."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import units
from ..data import Plan
from ..model.composition import as_model
from ..information import analyse, blind_out, invisible, separation_advice, weighted_jacobian
from .criteria import as_criterion
from .problem import criterion_rows, mean_loss, own, prior_information
from .space import Stand

#: a heading drift of this size (rad/s) is the unit of the reported drift bias: 1 arcsec/h
DRIFT_UNIT = units.ARCSEC / units.HOUR


@dataclass(frozen=True)
class Evaluation:
    """What a plan predicts for a model.

    Attributes
    ----------
    criterion : str
    criterion_value : float
        The criterion's loss for this plan (nan when no criterion was given).
    effects : tuple of str
    tilt_known : bool
    names, units : tuple of str
    std : numpy.ndarray, shape (n_p,)
        Predicted standard deviations, display units.
    covariance, correlation : numpy.ndarray, shape (n_p, n_p)
    condition : float
    n_runs : int
    total_time : float
        End of the last alignment since power-on, s.
    drift_bias : numpy.ndarray, shape (n_p,)
        Bias of each estimate from a linear heading drift of 1 arcsec/h, display units.
    """

    criterion: str
    criterion_value: float
    effects: tuple
    tilt_known: bool
    names: tuple
    units: tuple
    std: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    condition: float
    n_runs: int
    total_time: float
    drift_bias: np.ndarray

    def std_of(self, name):
        """Predicted standard deviation of one parameter, display units."""
        if name not in self.names:
            raise ValueError(f"unknown parameter {name!r}; this model has: {', '.join(self.names)}")
        return float(self.std[self.names.index(name)])

    def to_dict(self):
        """The JSON form (the contract keys of ``docs/formats.md``, and more)."""
        return {
            "criterion": self.criterion,
            "criterion_value": float(self.criterion_value) if np.isfinite(self.criterion_value) else None,
            "effects": list(self.effects),
            "tilt_known": self.tilt_known,
            "n_runs": self.n_runs,
            "total_time_h": self.total_time / units.HOUR,
            "predicted_std": {n: {"value": float(s), "unit": u}
                              for n, s, u in zip(self.names, self.std, self.units)},
            "drift_bias_per_arcsec_per_h": {n: {"value": float(b), "unit": u}
                                            for n, b, u in zip(self.names, self.drift_bias, self.units)},
            "condition": float(self.condition),
            "correlation": self.correlation.tolist(),
        }

    def summary(self):
        """Report lines."""
        lines = [f"model {'+'.join(self.effects)} (tilt {'known' if self.tilt_known else 'unknown'}): "
                 f"{self.n_runs} runs, {self.total_time / units.HOUR:.3f} h from power-on to the last run's "
                 "end",
                 f"  {'parameter':<20}{'predicted sigma':>22}{'bias per arcsec/h drift':>28}"]
        for n, s, b, u in zip(self.names, self.std, self.drift_bias, self.units):
            b = 0.0 if abs(b) < 1e-9 * s else b  # rounding of a trend-free order
            lines.append(f"  {n:<20}{s:>14.4g} {u:<7}{b:>+20.3g} {u}")
        return lines



def evaluate(plan, model=None, *, stand=None, tilt_known=True, criterion=None, nominal=None, prior=None,
             field=False, sigma=None):
    """Predicted sigmas of a plan for a model.

    Parameters
    ----------
    plan : hse_opt.data.Plan
    model : Model, str or sequence of str, optional
        Default: the paper's model.
    stand : Stand, optional
    tilt_known : bool
    criterion : Criterion or str, optional
        Also report this criterion's loss.
    nominal : mapping name -> value, optional
        Values (display units) at which the model is linearised.
    prior : FitResult, Prior or numpy.ndarray, optional
        Prior information (see :func:`design`).
    field : bool
        A field campaign: no position has a heading reference. Positions are the plan's
        ``position`` labels (else one per stand azimuth); each adds one unknown constant,
        eliminated as the fit does (:func:`hse_opt.fit.problem.position_projector`), so only
        the differences within positions count; ``offset`` is then not estimable and left out.
        The plan's ``tilt_x_arcsec``/``tilt_y_arcsec`` give each placement's own tilt.
    sigma : array_like, shape (n,), optional
        Each run's heading 1-sigma, rad (e.g. measured runs' own); default the stand's noise
        model for the run's duration (:meth:`Stand.sigma`).

    Returns
    -------
    Evaluation

    Raises
    ------
    UnidentifiableError
        The plan cannot identify the model; the parameters are named, with runs that would
        separate them.
    """
    model = as_model(model)
    stand = stand or Stand()
    if not isinstance(plan, Plan):
        raise TypeError(f"expected a hse_opt.data.Plan, got {type(plan).__name__}")
    tx, ty = (plan.tilt_x, plan.tilt_y) if plan.tilt_x is not None else (0.0, 0.0)
    if not tilt_known and np.any(np.asarray(tx) != 0) | np.any(np.asarray(ty) != 0):
        raise ValueError(f"{plan.source}: columns tilt_x_arcsec/tilt_y_arcsec vary the tilt, but with the tilt "
                         "unknown the model assumes one tilt fixed in b0; allowed: tilt_known=True")
    mm = model.measurement(tilt_known)
    unknown = sorted(set(nominal or {}) - set(mm.names))
    if unknown:
        raise ValueError(f"nominal: {', '.join(unknown)} {'is not a parameter' if len(unknown) == 1 else 'are not parameters'} "
                         f"of {'+'.join(model.effect_names)}; allowed: {', '.join(mm.names)}")
    X = stand.inputs(mm, plan.rate, plan.azimuth, tx, ty, plan.duration, plan.t_start)
    sigma = stand.sigma(plan.duration) if sigma is None else np.broadcast_to(np.asarray(sigma, float),
                                                                             plan.duration.shape)
    p = mm.vector(own(nominal or {}, mm))
    Aw = weighted_jacobian(mm.jacobian(p, X), sigma, mm.scale)
    F0 = prior_information(prior, mm.names)
    drift = (plan.t_start + plan.duration / 2) * DRIFT_UNIT / sigma
    names, units_, keep = mm.names, [q.unit for q in mm.params], np.ones(len(mm.names), bool)
    if field:
        labels = plan.position if plan.position is not None else np.round(plan.azimuth, 9).astype(str)
        G = (labels[:, None] == np.unique(labels)[None, :]) / np.broadcast_to(sigma, labels.shape)[:, None]
        Q, _ = np.linalg.qr(G)
        before = np.linalg.norm(Aw, axis=0)
        Aw, drift = Aw - Q @ (Q.T @ Aw), drift - Q @ (Q.T @ drift)
        # a column constant within every position keeps only rounding: no information
        Aw[:, np.linalg.norm(Aw, axis=0) <= 1e-9 * before] = 0.0
        keep = np.array([nm != "offset" for nm in mm.names])
        names, units_, Aw = tuple(np.array(names)[keep]), list(np.array(units_)[keep]), Aw[:, keep]
        F0 = None if F0 is None else F0[np.ix_(keep, keep)]

    # a parameter that moves no run's heading by the fit's floor across its whole range has no
    # information (what it leaves is rounding, which analyse's column scaling would blow up into
    # a sigma of 1e13 arcsec): named as the fit names it, unless a prior informs it
    ranges = np.array([q.upper - q.lower for q in mm.params])[keep]
    blind = invisible(Aw * np.broadcast_to(sigma, plan.duration.shape)[:, None], ranges)
    if F0 is not None:
        blind &= np.diag(F0) == 0
    info = analyse(blind_out(Aw.T @ Aw, blind) + (0 if F0 is None else F0), names, units_,
                   advice=lambda d: separation_advice(mm, p, X, keep, d))
    mid = plan.t_start + plan.duration / 2
    bias = info.covariance @ (Aw.T @ (drift if field else (mid - mid.mean()) * DRIFT_UNIT / sigma))
    label, value = "", float("nan")
    if criterion is not None:
        crit = as_criterion(criterion)
        if field:  # the information within the positions, as evaluated above
            if crit.features(model, tilt_known) is not None:
                raise ValueError(f"criterion {crit.label} builds its own rows: not with a field plan; allowed: "
                                 "protect:NAME, D, A, E, c:NAME")
            label, value = crit.label, crit.value(info.fisher, names)
        else:
            spec = criterion_rows(crit, model, tilt_known, [dict(nominal or {})], F0)
            label, value = crit.label, mean_loss(crit, spec.numeric(X, sigma), spec, np.ones(plan.run.size))
    return Evaluation(label, value, model.effect_names, bool(tilt_known), tuple(str(n) for n in names), info.units, info.std,
                      info.covariance, info.correlation, info.condition, int(plan.run.size),
                      float(np.max(plan.t_start + plan.duration)), bias)



#: a parameter is given up when its sigma exceeds this multiple of the reference plans' best
SACRIFICE_RATIO = 3.0


def sacrificed(evaluation, *references):
    """Parameters a plan gives up: ``(name, sigma, best reference sigma, unit)`` for each whose
    predicted sigma exceeds :data:`SACRIFICE_RATIO` times the smallest of the reference
    evaluations' (e.g. the paper's plan, the current plan; None entries are skipped)."""
    out = []
    for i, name in enumerate(evaluation.names):
        refs = [r.std_of(name) for r in references if r is not None and name in r.names]
        if refs and evaluation.std[i] > SACRIFICE_RATIO * min(refs):
            out.append((name, float(evaluation.std[i]), float(min(refs)), evaluation.units[i]))
    return out
