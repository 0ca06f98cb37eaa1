"""Compensation: the heading error a calibration (:class:`hse_opt.fit.FitResult`) removes from
alignments, with its 1-sigma from the fit's covariance."""
import numpy as np

from .. import units
from ..information import propagated_std
from ..model.inputs import RUN_FIELDS
from .domain import Domain

#: columns :func:`compensate` adds (arcsec): compensated heading error and its 1-sigma
COMPENSATED_COLUMN = "heading_err_comp_arcsec"
COMPENSATION_STD_COLUMN = "heading_comp_std_arcsec"
#: column :func:`compensate` adds for runs with their own heading (``heading_deg``): the
#: compensated heading, deg -- what a field alignment reports after compensation
COMPENSATED_HEADING_COLUMN = "heading_comp_deg"
#: column :func:`compensate` adds (arcsec): the correction's systematic bound (:func:`systematic_at`)
COMPENSATION_SYS_COLUMN = "heading_comp_sys_arcsec"
#: column :func:`compensate` adds: the validity domain's status of each run, the exported C's
#: return value (0 inside; else the bitmask of :mod:`hse_opt.fit.domain`; -1 when the fit
#: carries no run inputs to set the domain from)
DOMAIN_STATUS_COLUMN = "comp_status"


def compensated_parameters(fit_result):
    """The parameters whose error a compensation removes: every parameter of the system
    (sensor, encoder, processing, thermal effects) except the stand's own errors - the
    ``offset`` of the b0 zero mark against the stand and the ``reference``-level effects
    (stand azimuth reading errors, covariate offsets)."""
    mm = fit_result.measurement
    stand = {"offset"}
    for e in fit_result.model.effects:
        if e.level == "reference":
            stand.update(q.name for q in e.params)
    return tuple(nm for nm in mm.names
                 if nm not in stand and nm.split("*", 1)[0] not in stand)


def compensation_point(fit_result, parameters=None):
    """``(use, p)``: the mask of the compensated parameters (default
    :func:`compensated_parameters`; unknown names raise) and the SI parameter vector the
    compensation evaluates -- compensated and nonlinear parameters at the estimate, the others
    at their nominal values."""
    mm = fit_result.measurement
    names = compensated_parameters(fit_result) if parameters is None else tuple(parameters)
    for nm in names:
        mm.parameter_index(nm)
    use = np.array([nm in names for nm in mm.names])
    keep = use | np.array([nm in mm.nonlinear for nm in mm.names])
    return use, np.where(keep, fit_result.p, mm.nominal)


def compensation(runs, fit_result, parameters=None):
    """The modelled heading error of each run that compensation removes, and its 1-sigma.

    Parameters
    ----------
    runs : hse_opt.data.Runs
        Alignments to compensate (any position, rate or latitude). A tilt-known fit needs
        their pitch/roll (Eq. 14 uses each alignment's own leveling); a tilt-unknown fit's
        C23 coefficients hold for the stand it was calibrated on.
    fit_result : FitResult
    parameters : sequence of str, optional
        Parameters whose error is removed (default :func:`compensated_parameters`); the
        others are set to their nominal (no-error) value, nonlinear ones kept as fitted.

    Returns
    -------
    correction, std : numpy.ndarray, shape (n,)
        Heading error (estimated - true) predicted from those parameters, rad, and its
        1-sigma from the fit's covariance, rad (the calibration's uncertainty, not the
        run's own noise; :func:`~hse_opt.information.propagated_std`).

    Raises
    ------
    ValueError
        The runs lack what the fit needs, or the fit's covariance is not positive
        semidefinite (a damaged FIT.json): the message names the parameters.
    """
    mm = fit_result.measurement
    if fit_result.tilt_known and runs.pitch is None:
        raise ValueError(f"{runs.source}: the calibration was fitted with known tilt; compensating "
                         "needs each run's pitch_arcsec/roll_arcsec (Eq. 14 uses C23 from leveling); allowed: "
                         "runs with both columns")
    return compensation_at(mm.inputs_from_runs(runs), fit_result, parameters)


def compensation_at(X, fit_result, parameters=None):
    """:func:`compensation` at run inputs ``X`` (measurement-model order, SI; shape (n_x, n)):
    the modelled heading error (rad) and its 1-sigma (rad), each shape (n,)."""
    correction, Jd, use = _at(X, fit_result, parameters)
    C = np.asarray(fit_result.covariance)[np.ix_(use, use)]
    return correction, propagated_std(Jd, C, np.array(fit_result.measurement.names)[use])


def _at(X, fit_result, parameters):
    """The modelled heading error at ``X`` (rad, (n,)), its Jacobian in the compensated
    parameters (rad per display unit, (n, k)) and their mask."""
    mm = fit_result.measurement
    use, p = compensation_point(fit_result, parameters)
    return mm.predict(p, X), mm.jacobian(p, X)[:, use] * mm.scale[use][None, :], use


def systematic_shifts(fit_result, use):
    """What the campaign could not rule out, per compensated parameter: ``(S, effects)`` with
    ``S[j, e]`` the shift (display unit, >= 0) effect ``effects[e]`` could cause in the ``j``-th
    parameter of mask ``use`` (``FitResult.systematic_by``; shape (k, 0) without any)."""
    by = getattr(fit_result, "systematic_by", None) or ()
    rows = [by[i] if i < len(by) and by[i] else {} for i in np.flatnonzero(use)]
    effects = tuple(sorted({e for r in rows for e in r}))
    S = np.array([[abs(float(r.get(e, 0.0))) for e in effects] for r in rows], dtype=float)
    return S.reshape(len(rows), len(effects)), effects


def systematic_at(X, fit_result, parameters=None):
    """The correction's systematic bound at run inputs ``X`` (rad, shape (n,)): the largest
    shift of the correction that one effect the campaign could not rule out would cause, if
    present at the edge of its plausible range (:mod:`hse_opt.aliasing`), each parameter's
    shift carried through the correction's Jacobian and added in absolute value (the signs of
    the shifts are not kept: an upper bound),
    ``max_e sum_j |dcorr/dp_j| S[j, e]`` (:func:`systematic_shifts`). 0 when the fit
    carries no systematic budget."""
    _, Jd, use = _at(X, fit_result, parameters)
    S, _ = systematic_shifts(fit_result, use)
    if S.shape[1] == 0:
        return np.zeros(Jd.shape[0])
    return (np.abs(Jd) @ S).max(axis=1)


def domain_status(runs, fit_result, parameters=None):
    """Whether each run lies in the calibration's validity domain (:mod:`hse_opt.fit.domain`).

    Returns
    -------
    status : numpy.ndarray of int, shape (n,)
        0 inside, else the bitmask the exported C returns; -1 for every run when
        ``fit_result`` has no run inputs (a FitResult built without them).
    reasons : list of str
        Per run, what is outside and where the domain is (``''`` inside).
    """
    if fit_result.inputs is None:
        return np.full(len(runs), -1, dtype=np.int64), ["the calibration carries no run inputs"] * len(runs)
    domain = validity_domain(fit_result, parameters=parameters)
    X = fit_result.measurement.inputs_from_runs(runs)
    return domain.status(X), domain.reasons(X)


def compensate(runs, fit_result, parameters=None):
    """``runs`` with the compensated heading error and its 1-sigma added as columns.

    ``heading_err_comp_arcsec`` = ``heading_err_arcsec`` minus the :func:`compensation`;
    ``heading_comp_std_arcsec`` = the compensation's 1-sigma from the fit's covariance; for
    runs with their own heading (``heading_deg``, field campaigns) also ``heading_comp_deg`` =
    ``heading_deg`` minus the compensation, the compensated alignment heading; and
    ``heading_comp_sys_arcsec``, the correction's systematic bound (:func:`systematic_at`: what
    an effect the campaign could not rule out could add; 0 without a budget in the fit);
    ``comp_status``, the run's :func:`domain_status` (nonzero: the calibration never saw such
    a run, its correction is the model's extrapolation). At an unsurveyed
    position ``heading_err`` is relative to the position's mean heading (:mod:`hse_opt.data`),
    and so is its compensated value: there ``heading_err_comp_arcsec`` is no heading error but
    the compensated heading less the position's stand-in reference (the mean of its
    uncompensated headings), whose position mean is minus the position's mean correction
    (:data:`hse_opt.app.commands.compensate.UNSURVEYED_COMPENSATED`). The other columns are unchanged. Raises ``ValueError``
    when ``runs`` already has them.
    """
    for col in (COMPENSATED_COLUMN, COMPENSATION_STD_COLUMN, COMPENSATION_SYS_COLUMN, COMPENSATED_HEADING_COLUMN,
                DOMAIN_STATUS_COLUMN):
        if col in runs.covariates:
            raise ValueError(f"{runs.source}, column '{col}': already present; allowed: runs without "
                             "it (compensate the uncompensated runs)")
    correction, std = compensation(runs, fit_result, parameters)
    heading = {} if runs.heading is None else {
        COMPENSATED_HEADING_COLUMN: np.mod(runs.heading - correction, 2 * np.pi) / units.DEG}
    status, _ = domain_status(runs, fit_result, parameters)
    sys = systematic_at(fit_result.measurement.inputs_from_runs(runs), fit_result, parameters)
    return runs.replace(**{COMPENSATED_COLUMN: (runs.heading_err - correction) / units.ARCSEC,
                           COMPENSATION_STD_COLUMN: std / units.ARCSEC, COMPENSATION_SYS_COLUMN: sys / units.ARCSEC,
                           **heading, DOMAIN_STATUS_COLUMN: status})


def validity_domain(fit_result, inputs=None, parameters=None):
    """The validity domain (:class:`hse_opt.fit.domain.Domain`) of a
    :class:`~hse_opt.fit.FitResult` from its runs' inputs (or ``inputs``, (n_x, n)), for the
    correction of ``parameters`` (default: the compensated ones): bounded in what the
    correction depends on (:func:`correction_depends`)."""
    X = fit_result.inputs if inputs is None else inputs
    if X is None:
        raise ValueError("no run inputs to set the validity domain from; allowed: a FIT.json written by "
                         "this version of hse-opt fit -o (it stores them)")
    mm = fit_result.measurement
    return Domain.from_inputs(X, RUN_FIELDS + tuple(mm.covariates), fit_result.tilt_known,
                              correction_depends(fit_result, parameters))


def correction_depends(fit_result, parameters=None):
    """Whether the correction (or its sigma) depends on each input: from the measurement
    model's graph with the compensated parameters symbolic (numpy bool, shape (n_x,))."""
    import casadi as ca

    mm = fit_result.measurement
    use, p = compensation_point(fit_result, parameters)
    x = ca.SX.sym("x", mm.n_x)
    q = ca.SX.sym("q", int(use.sum()))
    p_expr = ca.SX(ca.DM(p))
    for j, i in enumerate(np.flatnonzero(use)):
        p_expr[int(i)] = p[i] + q[j] * mm.scale[i]
    h = mm.h(p_expr, x)
    return np.array([bool(ca.depends_on(h, x[k])) for k in range(mm.n_x)])
