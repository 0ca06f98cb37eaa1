"""Weighted least squares of the measurement model to alignment results -> :class:`FitResult`.

``fit(runs, model)`` minimises the sum of squared standardised residuals
``(heading_err - h(p; run)) / sigma`` over the model's free parameters, plus a Gaussian prior
term when one is given, subject to bounds and linear constraints.

Solvers (``FitResult.method``)
------------------------------
``qr``, ``gauss-newton``
    No inequality constraints: Gauss-Newton steps, each solved by QR on the weighted,
    column-scaled Jacobian in the null space of the equalities, with step halving; one batch
    call of the model gives the residuals and the Jacobian of a step. Models linear in their
    free parameters (``qr``; the atan2 of the gyrocompass makes them very slightly nonlinear:
    two or three steps converge) and nonlinear ones (``gauss-newton``, e.g. ``warmup_tau``).
    Bounds (nonlinear parameters get their declared range, :class:`~hse_opt.model.Param`
    ``lower``/``upper``, by default) are kept when every step stays strictly inside them: a
    minimum inside the bounds is the bounded problem's, and no bound binds.
``ipopt``
    Inequality constraints, a bound that binds, or Gauss-Newton stepping out of the bounds:
    CasADi ``nlpsol``/IPOPT with a Gauss-Newton Hessian ``J'J`` (built once per model, run
    count and constraint shape, then reused), followed by the same Gauss-Newton/QR polish
    on the active set IPOPT finds, so bounds that bind hold exactly and a fit whose bounds
    do not bind equals the unconstrained one.

Weights (``FitResult.weighting``)
---------------------------------
``heading_std``
    the runs' own 1-sigma (``heading_std_arcsec``); the covariance is not rescaled.
``pure-error``
    no sigmas but replicated settings (same rate, azimuth, tilt, duration, latitude) with at
    least :data:`~hse_opt.fit.weights.PURE_ERROR_MIN_DOF` (8) replicate degrees of freedom:
    one sigma from the scatter within replicate groups, independent of the model.
``residual``
    neither: one sigma from the residuals, ``s^2 = RSS / dof`` (chi2_red is then 1 by
    construction; replicates, if any, still test the fit).

With replicates, ``FitResult.lack_of_fit`` is the pure-error lack-of-fit F test, the goodness
of fit of ``pure-error`` and ``residual`` weighting and the same test ``hse-opt diagnose``
makes (docs/weights.md: the rule and why).
``robust-scale``
    ``robust=True`` without ``heading_std``: one sigma from the median absolute deviation of
    the residuals, ``1.4826 MAD``.

Copies of one measurement (:meth:`hse_opt.data.Runs.copies`: rows of one setting whose
headings agree within 1e-6 arcsec, e.g. rows written twice under new run ids) count once,
surveyed or field: each of ``c`` copies gets ``sqrt(c)`` times its sigma, the degrees of
freedom, AIC/BIC and a sigma from the residuals or the pure error count measurements, not
rows, and a note names the copies (:func:`~hse_opt.fit.weights.multiplicity`).

Robust fits (``robust=True``) minimise Huber's loss (quadratic within ``huber_c`` sigma,
linear beyond) by iteratively reweighted least squares; runs with weight below 1 are named
in ``FitResult.downweighted``, and the covariance is Huber's ``H1`` form
``K^2 [sum psi^2 / (n - k)] / mean(psi')^2 (A'A)^-1``.

AIC and BIC are ``chi2 + 2k`` and ``chi2 + k ln n`` when sigma is given or from pure error
(model-independent), and ``n ln(RSS/n) + 2k`` / ``+ k ln n`` when it is from the residuals;
``k`` counts the free parameters less the active constraints.

A prior (``prior=``: a :class:`~hse_opt.information.Prior` or a previous
:class:`FitResult`) adds ``(z - mu)' C^-1 (z - mu)`` to chi2 (``FitResult.chi2_prior``) and
its rank to the degrees of freedom; for a model linear in its parameters and known sigmas,
updating a fit with new runs this way gives the batch fit of all the runs.

The package: :mod:`~hse_opt.fit.least_squares` (:func:`fit`), :mod:`~hse_opt.fit.problem`
(the least-squares problem), :mod:`~hse_opt.fit.profile` (nonlinear parameters profiled), :mod:`~hse_opt.fit.solvers`, :mod:`~hse_opt.fit.weights`,
:mod:`~hse_opt.fit.result` (:class:`FitResult`, :class:`Constraint`, :class:`SolverError`) and
:mod:`~hse_opt.fit.summary` (the fit as a report shows it). Applying a calibration is
:mod:`hse_opt.fit.correction`, FIT.json is :mod:`hse_opt.fit.file`; both are re-exported here.
"""
from ..information import Prior, UnidentifiableError
from ..model.composition import as_model
from .least_squares import fit
from .profile import fit_profiled
from .result import Constraint, FitResult, SolverError
from .summary import report_data
from .weights import HUBER_C, pure_error, replicate_groups, run_sigma

#: re-exported on first use (they import this package): name -> module
_LAZY = {name: "hse_opt.fit.correction" for name in
         ("compensate", "compensation", "compensated_parameters", "COMPENSATED_COLUMN",
          "COMPENSATION_STD_COLUMN")}
_LAZY.update({name: "hse_opt.fit.file" for name in ("save_fit", "load_fit", "FIT_FORMAT", "FIT_VERSION")})

__all__ = ["FitResult", "Constraint", "Prior", "SolverError", "UnidentifiableError", "fit", "fit_profiled",
           "compensate", "compensation", "compensated_parameters", "save_fit", "load_fit", "as_model",
           "replicate_groups", "pure_error", "run_sigma", "report_data", "COMPENSATED_COLUMN",
           "COMPENSATION_STD_COLUMN", "HUBER_C"]


def __getattr__(name):
    import importlib

    if name not in _LAZY:
        raise AttributeError(f"module 'hse_opt.fit' has no attribute {name!r}")
    return getattr(importlib.import_module(_LAZY[name]), name)


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
