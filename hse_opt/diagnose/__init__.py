"""Model against measurements: where the model fails, which effect is missing, add it.

``diagnose(runs, model)`` fits ``model`` to ``runs`` and returns a frozen :class:`Diagnosis`:

Comparison
    per run: residual (measured - model), standardised residual (residual / sigma), externally
    studentised residual, leverage and Cook's distance; the runs the fit hinges on and the
    outliers.
Goodness of fit
    the chi-square test of the standardised residuals when the runs carry their own sigmas
    (``heading_std_arcsec``), and the pure-error lack-of-fit F test when settings (rate,
    azimuth, duration, latitude, tilt) are replicated.
Where it fails
    residual structure against every factor: bias rate, rotation sense, azimuth harmonics,
    rate x azimuth, the tilt of the rotation axis (C23, when pitch/roll are known), time since
    power-on (or run order standing in for it), run order, duration, latitude and every
    covariate column; one test per factor, ranked.
Which effect is missing
    every catalogue effect not in the model (and ``covariate:<column>`` for every covariate
    column), ranked: score (Lagrange-multiplier) test at the fit (no refit), Delta-BIC and
    residual RMS after refitting. Candidates that these runs cannot test (no heading signature,
    or confounded with the model) are named with the reason; candidates that explain the data
    equally well are reported as ambiguous, with the runs that would tell them apart (a
    T-optimal discrimination design by :mod:`hse_opt.design`, :func:`discriminating_runs`).
Structure in words
    a sparse (forward-stepwise) regression of the residuals over a library of factor
    functions, each selected term as a sentence a user can act on, with the catalogue effects
    whose signature it matches.
Verdict
    ``adequate`` when no test of the family (chi-square, lack of fit, factors, level shift and
    single run in run order, candidates) rejects at the family-wise level ``alpha``
    (Bonferroni: a test rejects when ``p < alpha / m``, ``m`` the number of tests); else
    ``unexplained structure`` when the strongest structure follows no catalogue effect and
    explains more than any significant candidate, or ``missing-effect``.

:meth:`Diagnosis.add` refits with one more effect and diagnoses again; :func:`compare` puts
two diagnoses side by side (RMS, chi-square, lack-of-fit p, BIC, parameters); :func:`refine`
adds the best significant candidate until the verdict is adequate, and stops (without picking)
on ambiguity or unexplained structure. Every candidate's refit is compared on one likelihood
scale, the base model's noise model (:class:`.statistics.LikelihoodScale`); fitted magnitudes
are judged against physical ranges (:mod:`.plausibility`).

Modules: :mod:`.statistics` (the fit as a weighted linear model; score, lack-of-fit and
chi-square tests; influence), :mod:`.factors`, :mod:`.candidates` (ranking, ambiguity),
:mod:`.structure` (in words), :mod:`.discrimination` (runs that tell candidates apart),
:mod:`.result` (:class:`Diagnosis`, :class:`Comparison`), :mod:`.pipeline` (:func:`diagnose`,
:func:`refine`).
"""
import sys
import types

from .candidates import Candidate
from .discrimination import discriminating_runs
from .pipeline import diagnose, refine
from .resolution import ResolvingPlan, resolving_plan
from .result import Comparison, Diagnosis, compare
from .statistics import ALPHA, Test
from .structure import Term

__all__ = ["ALPHA", "Candidate", "Comparison", "Diagnosis", "ResolvingPlan", "Term", "Test", "compare", "diagnose",
           "diagnostic_plan", "discriminating_runs", "model_runs", "refine", "resolving_plan"]


def __getattr__(name):
    # the synthetic plan and data generators moved to hse_opt.validation.synthetic (which sits
    # above the diagnosis); the old names still resolve
    if name in ("diagnostic_plan", "model_runs"):
        from ..validation import synthetic
        return getattr(synthetic, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class _CallableModule(types.ModuleType):
    """``hse_opt.diagnose(runs, ...)`` calls :func:`diagnose`: the package exports this module
    under the function's name."""

    def __call__(self, *args, **kwargs):
        return diagnose(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
