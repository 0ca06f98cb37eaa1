"""Which effect is missing: every catalogue effect not in the model (and ``covariate:<column>``
for every covariate column) tested by a score test at the fit, refitted (Delta-BIC, RMS after)
and ranked; candidates these runs cannot test are named with the reason; candidates that
explain the data equally well are grouped as ambiguous."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .. import units
from .plausibility import judge, moves
from ..factors import is_derived
from ..fit import FitResult, fit_profiled
from ..information import UnidentifiableError, check_identifiable, weighted_jacobian
from ..model import CATALOGUE, effect as make_effect
from ._format import num

#: a parameter that, at the edge of its bounds, moves no run's heading by this many sigma has
#: no heading signature in these runs
_BLIND = 1e-3
#: candidates whose Delta-BIC is within this of the best's are reported together (Kass &
#: Raftery 1995: a BIC difference below 6 is at most "positive", not "strong", evidence)
AMBIGUOUS_DELTA_BIC = 6.0
#: a candidate whose signature (each position's tilt at its mean) keeps less than this share
#: of its norm within the unsurveyed positions is a constant per position, not an effect (a
#: constant signature keeps ~2e-4 through second-order couplings with lambda2 and the rate)
_WITHIN = 1e-3


@dataclass(frozen=True, eq=False)
class Candidate:
    """A catalogue effect not in the model, tested against the residuals.

    Attributes
    ----------
    effect, description : str
    parameters : tuple of str
        Its parameters in the extended model (tilt-coupled ones as free C23 coefficients when
        the tilt is unknown).
    held : tuple of str
        Parameters without a heading signature in these runs, held at their nominal value
        (named, never silently).
    testable : bool
    reason : str
        Why it is not testable (confounded with which parameters), else "".
    statistic : float or None
        Score-test F statistic; ``dof`` its degrees of freedom; ``p_value``, ``log_p``.
    delta_bic : float or None
        BIC after refitting minus BIC before (negative: the effect pays for its parameters).
    rms_after : float or None
        Residual RMS after refitting, rad.
    chi2_red_after : float or None
    fit : FitResult or None
        The refit.
    significant : bool
        Its score test rejects at the family-wise level.
    ambiguous_with : tuple of str
        Candidates that explain the data equally well (see :class:`Diagnosis`).
    plausibility : tuple of str
        The refit's magnitudes beyond their physical range (:mod:`.plausibility`); empty when
        plausible.
    moves : tuple of str
        Base parameters the refit moves by more than 3 of their sigmas: the effect's alias,
        expected when it is real (:func:`.plausibility.moves`); no judgement.
    """

    effect: str
    description: str
    parameters: tuple
    held: tuple
    testable: bool
    reason: str
    statistic: float | None = None
    dof: tuple = ()
    p_value: float | None = None
    log_p: float | None = None
    delta_bic: float | None = None
    rms_after: float | None = None
    chi2_red_after: float | None = None
    fit: FitResult | None = None
    significant: bool = False
    ambiguous_with: tuple = ()
    plausibility: tuple = ()
    moves: tuple = ()

    @property
    def rms_after_arcsec(self):
        return None if self.rms_after is None else self.rms_after / units.ARCSEC

    def to_dict(self):
        return {"effect": self.effect, "p_value": num(self.p_value),
                "delta_bic": num(self.delta_bic), "rms_after_arcsec": num(self.rms_after_arcsec),
                "statistic": num(self.statistic), "dof": list(self.dof),
                "chi2_red_after": num(self.chi2_red_after), "significant": self.significant,
                "testable": self.testable, "reason": self.reason, "parameters": list(self.parameters),
                "held": list(self.held), "ambiguous_with": list(self.ambiguous_with),
                "plausibility": list(self.plausibility), "moves": list(self.moves),
                "description": self.description}



def covariate_columns(runs, covariates):
    """The covariate columns used as factors and candidates: by default every column but those
    derived from the heading error (:func:`hse_opt.factors.is_derived`: an outcome of the
    alignment, not a setting)."""
    if covariates is None:
        return [c for c in runs.covariates if not is_derived(c)]
    covariates = [c.strip() for c in covariates.split(",")] if isinstance(covariates, str) else list(covariates)
    missing = [c for c in covariates if c not in runs.covariates]
    for c in missing:
        if c in runs.metadata:  # a column of numbers with a text cell: name the row
            runs.covariate(c, "the diagnosis's covariates (--covariates)")
    if missing:
        raise ValueError(f"{runs.source}: covariate column(s) {missing} not in the runs; allowed: "
                         f"{', '.join(runs.covariates) or 'none (the file has no covariate columns)'}")
    return covariates


def candidate_names(f0, covariates, candidates):
    have = set(f0.model.effect_names)
    if candidates is None:
        names = [e for e in CATALOGUE if e not in have]
        names += [f"covariate:{c}" for c in covariates if f"covariate:{c}" not in have]
        return names
    names = [c.strip() for c in candidates.split(",")] if isinstance(candidates, str) else list(candidates)
    for name in names:
        make_effect(name)  # raises with the allowed names
        if name in have:
            raise ValueError(f"candidate {name!r} is already in the model ({', '.join(sorted(have))}); allowed: "
                             "effects not in the model")
    return names


def test_candidates(null, f0, runs, names, fix, refit):
    out, bases = [], {}
    for name in names:
        cand, U = _candidate(null, f0, runs, name, fix, refit)
        out.append(cand)
        if U is not None:
            bases[name] = U
    return out, bases


def _candidate(null, f0, runs, name, fix, refit):
    eff = make_effect(name)
    missing = [n for n in eff.needs if n not in f0.model.effect_names]
    if missing:  # a product with another effect's parameters (mount_xi with encoder_harmonic)
        return Candidate(name, eff.description, tuple(q.name for q in eff.params), (), False,
                         f"no heading signature without {', '.join(missing)} in the model (it acts "
                         "only in a product with it): test them together"), None
    model1 = f0.model + eff
    mm1 = model1.measurement(f0.tilt_known)
    X1 = mm1.inputs_from_runs(runs)
    known = {n: float(v) for n, v in zip(f0.names, f0.values)}
    p1 = mm1.vector({n: v for n, v in known.items() if n in mm1.names})
    new = [i for i, n in enumerate(mm1.names) if n not in known]
    params = tuple(mm1.names[i] for i in new)
    description = eff.description
    tested = [i for i in new if mm1.names[i] not in mm1.nonlinear and mm1.names[i] not in fix]
    J = mm1.jacobian(p1, X1)
    # blind parameters: at the edge of their bounds they move no heading by _BLIND sigma
    reach = np.array([np.max(np.abs(J[:, i])) * max(abs(mm1.params[i].lower), abs(mm1.params[i].upper))
                      * mm1.scale[i] / np.min(null.sigma) for i in tested])
    held = tuple(mm1.names[i] for i, r in zip(tested, reach) if r < _BLIND)
    tested = [i for i, r in zip(tested, reach) if r >= _BLIND]
    if not tested:
        return Candidate(name, description, params, held, False,
                         "no heading signature in these runs" + _signature_hint(params)), None
    # at positions without a heading reference only the differences within a position count:
    # a signature (nearly) constant at each such position is absorbed by its unknown heading
    if null.positions:
        Jl = mm1.jacobian(p1, mm1.inputs_from_runs(null.level_runs))
        share = null.within_share(weighted_jacobian(Jl[:, tested], null.sigma, mm1.scale[tested]))
        if np.all(share < _WITHIN):
            return Candidate(name, description, params, held, False,
                             "its heading signature is constant within each position without a heading "
                             "reference (that position's unknown heading absorbs it): these runs cannot "
                             "see it; runs at surveyed positions, or a change of tilt or time within a "
                             "position, would"), None
    # identifiable jointly with the model? (the same check the fit makes)
    free0 = [mm1.names.index(n) for n, fr in zip(f0.names, f0.free) if fr]
    cols = free0 + tested
    A1 = weighted_jacobian(J[:, cols], null.sigma, mm1.scale[cols])
    try:
        check_identifiable(A1.T @ A1, [mm1.names[i] for i in cols])
    except UnidentifiableError as err:
        other = [n for n in err.names if n not in params]
        mine = [n for n in err.names if n in params]
        if other:
            why = f"{', '.join(mine) or params[0]} cannot be told apart from {', '.join(other)} by these runs"
        else:
            why = f"{', '.join(err.names)} cannot be told apart from each other by these runs"
        return Candidate(name, description, params, held, False, why), None
    U = null.basis(A1[:, len(free0):])
    if U.shape[1] == 0:  # jointly identifiable, yet nothing left once the model (and positions) are fitted
        by = "the model's parameters" + (" and the unknown headings of the positions without a reference"
                                         if null.positions else "")
        return Candidate(name, description, params, held, False,
                         f"its heading signature is fitted already by {by}: these runs cannot tell it "
                         "apart; runs at other settings (surveyed azimuths, rates, tilts) would"), None
    F, dof, p, logp = null.score(U)
    cand = Candidate(name, description, params, held, True, "", F, dof, p, logp)
    if refit and p is not None:
        fix1 = dict(fix)
        fix1.update({n: mm1.params[mm1.parameter_index(n)].nominal for n in held})
        try:
            f1 = fit_profiled(null.scale.refit_runs(runs), model1, fix=fix1, tilt_known=f0.tilt_known,
                              start=known)
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as err:
            # the null fit validated the runs: this is the candidate not fitting these runs
            cand = dataclasses.replace(cand, reason=f"refit failed: {err}")
        else:
            # one likelihood scale: the base model's noise model (statistics.LikelihoodScale)
            delta_bic = null.scale.bic(f1.residuals, f1.dof) - null.scale.bic(f0.residuals, f0.dof)
            cand = dataclasses.replace(cand, delta_bic=float(delta_bic), rms_after=float(
                np.sqrt(np.mean(f1.residuals ** 2))), chi2_red_after=null.scale.chi2_red(f1.residuals, f1.dof),
                fit=f1, plausibility=judge(f1), moves=moves(f1, f0))
            nonlinear = [i for i in new if mm1.names[i] in mm1.nonlinear]
            if nonlinear:  # its signature at the fitted nonlinear values, for the comparisons
                p_nl = p1.copy()
                p_nl[nonlinear] = f1.p[nonlinear]
                J = mm1.jacobian(p_nl, X1)
                U = null.basis(weighted_jacobian(J[:, tested], null.sigma, mm1.scale[tested]))
    return cand, U


def _signature_hint(params):
    if any("*tilt_" in p for p in params):
        return " (it acts through the tilt, which these runs do not carry)"
    return ""


def rank(cands):
    """Testable candidates by Delta-BIC (score log p where there is no refit, and as tie-break),
    then the untestable ones."""
    def key(c):
        if not c.testable or c.p_value is None:
            return (2, 0.0, 0.0, c.effect)
        if c.delta_bic is None:
            return (1, c.log_p, 0.0, c.effect)
        return (0, c.delta_bic, c.log_p, c.effect)
    return sorted(cands, key=key)


def ambiguity(null, cands, bases, alpha, level=None):
    """The best significant candidate and every candidate these runs cannot tell apart from it:
    a significant one that makes it redundant (its score test given the other does not reject
    at ``alpha``: equally adequate fits), or one whose Delta-BIC is within
    :data:`AMBIGUOUS_DELTA_BIC` of the best's (on the one likelihood scale) -- unless the two
    are complementary: each still rejects given the other at the family-wise ``level`` (default
    ``alpha``), so the data need both (two missing effects, not two explanations of one)."""
    level = alpha if level is None else level
    sig = [c for c in cands if c.significant and c.effect in bases]
    if not sig:
        return [], cands
    best = sig[0]
    Ub = bases[best.effect]
    same = []
    if best.delta_bic is not None:
        same += [c.effect for c in cands if c is not best and c.testable and c.delta_bic is not None
                 and c.delta_bic < 0 and c.delta_bic <= best.delta_bic + AMBIGUOUS_DELTA_BIC
                 and not (c.effect in bases and _given(null, Ub, bases[c.effect]) < level
                          and _given(null, bases[c.effect], Ub) < level)]
    for c in sig[1:]:
        if c.effect in same:
            continue
        if _given(null, Ub, bases[c.effect]) >= alpha:
            same.append(c.effect)
    if not same:
        return [], cands
    group = [best.effect] + same
    cands = [dataclasses.replace(c, ambiguous_with=tuple(g for g in group if g != c.effect))
             if c.effect in group else c for c in cands]
    return group, cands


def _given(null, Ua, Ub):
    """p-value of the score test of signature ``Ua`` given ``Ub`` (both weighted, orthogonal to
    the model): the part of a orthogonal to b against the residual with b fitted (1.0 when
    nothing of a is left)."""
    U = null.basis(Ua, extra=Ub)
    r = null.r - Ub @ (Ub.T @ null.r)
    _, _, p, _ = null.score(U, r=r, rss=float(r @ r), k_extra=Ub.shape[1])
    return 1.0 if p is None else p
