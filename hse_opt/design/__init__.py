"""Experiment design: the calibration test plan that calibrates best in limited stand time.

A plan (``PLAN.csv``) is a sequence of alignments. Each run has a *setting* -- signed bias
rate Omega, stand azimuth psi, deliberate tilt of the turntable base (a tilt fixture, fixed in
b0) and alignment duration -- and adds ``a a^T`` to the Fisher information of the model's
parameters, ``a = (dh/dp) / sigma`` in display units (:mod:`hse_opt.information`; ``sigma``
is :func:`~hse_opt.information.heading_sigma` of the duration). A :class:`Criterion` turns
the information matrix into a loss; :func:`design` minimises it within a test-time budget:

1. **Candidates** -- every combination of the :class:`DesignSpace` factors (rate levels
   within the limits, one or both rotation senses, stand azimuths, tilt-fixture settings,
   durations).
2. **Approximate design** -- a convex program (cvxpy) over the number of runs ``w_i >= 0`` of
   every candidate, the alignment time linear: ``sum w_i (T_i + overhead) <= budget -
   warm-up``, ``sum w_i <= max_runs``. Certified by the general equivalence theorem: the
   Frank-Wolfe gap of the (Lagrangian) objective over all candidates bounds the loss of
   optimality (``ApproximateDesign.certified_efficiency``). Each conic solution is re-solved
   on its support with IPOPT (conic solvers leave ~1e-4 in the weights; not with the power
   floors of the default criterion, where the conic solution is certified as it is). The solver's
   ``problem.status`` is checked: a failure raises :class:`DesignError` (a
   :class:`~hse_opt.fit.SolverError`) with it; an ``optimal_inaccurate`` end is judged by the
   certificate (kept at >= 0.99, and said in the result's notes below 0.999), and below that
   the even design and IPOPT from it are tried before the error (``IllConditioned``, also an
   :class:`~hse_opt.information.UnidentifiableError`, when even every candidate together barely
   separates some parameters).
3. **Exact design** -- the approximate design's support is first reduced (the same
   information matrices on few stand positions, then Caratheodory: on fewer candidates),
   then rounded efficiently (Pukelsheim & Rieder 1992, :func:`apportion`) to ``n`` whole
   runs, ``n`` the largest for which the plan with its setup times (:class:`Costs`) fits the
   budget (with time slots: slot by slot, each slot's runs ending within it), then polished
   by one-run exchanges. Setups are not linear in the run numbers: a greedy search drops
   stand positions while the rounded plan gets better (``prune``). The *efficiency* is
   measured against the approximate optimum for the same alignment time (in each time slot;
   ``efficiency``) and for the whole budget (``budget_efficiency``, which also counts the
   time the setups take). Ties between candidates (symmetric ones tie exactly) are broken
   canonically, within stated tolerances, by the candidates' settings, so that the plan does
   not depend on floating-point noise (:mod:`.ties`).
4. **Refinement** -- IPOPT (CasADi) moves the exact design's rates and azimuths off the
   candidate grid (runs sharing an azimuth or a rate keep sharing it, so setups do not grow).
5. **Run order** -- runs sharing a setting run together and settings are grouped by their
   most expensive factor, which keeps setup time low; among such orders (and folded ones,
   ABBA-like, where the budget has room for the extra setups) the one least sensitive to a
   slow linear heading drift is taken (``order='trend-robust'``), or the quickest
   (``'min-setup'``). The plan's start times ``t_start_s`` follow from the costs.
6. **Evaluation** -- :func:`evaluate` gives each parameter's predicted sigma for the final
   plan and the bias a linear heading drift of 1 arcsec/h would put on it.

Tilt modes. With the tilt known (``tilt_known=True``: pitch and roll from the alignments'
own leveling, as in the paper's step 3 and in simulated RUNS) lambda2 is a model parameter
and its heading signature is proportional to ``lambda1 C23``: the tilt of the base (the
:class:`Stand`'s own plus the fixture's) and the rate set its size. With the tilt unknown
the tilt-coupled parameters are free C23 coefficients (``lambda2*tilt_cos`` ...; see
:mod:`hse_opt.model.measurement`), which assume one tilt fixed in b0 for every run: a tilt
fixture is then not allowed.

Nonlinear parameters (e.g. ``warmup_tau``) enter the information at their nominal values
(``nominal``) or, robustly, the criterion is averaged over a prior sample of them
(``prior_sample``). Time since power-on is a factor when ``DesignSpace.time_slots`` > 1
(needed for ``warmup``): each candidate is seen at the middle of its slot; else at the middle
of the test. The final plan is always evaluated at its real start times.

The package's modules, one step each: :mod:`.criteria`, :mod:`.space` (stand, costs, design
space), :mod:`.problem` (information rows, the problem object), :mod:`.approximate`,
:mod:`.reduction`, :mod:`.rounding`, :mod:`.refine`, :mod:`.resolution`, :mod:`.order`,
:mod:`.evaluation`, :mod:`.plans`, :mod:`.ties` and :mod:`.pipeline` (:func:`design`). Monte Carlo validation of a plan with the simulator is
:func:`hse_opt.validation.monte_carlo.monte_carlo` (validation sits above design and sim).
"""
import sys
import types

from .approximate import ApproximateDesign, DesignError, approximate_design
from .criteria import A, C, Criterion, D, Discrimination, E, LackOfFit, Protect, as_criterion
from .evaluation import DRIFT_UNIT, Evaluation, evaluate
from .field import FieldDesign, continue_campaign, design_field, field_plan
from .pipeline import DesignResult, design
from .plans import paper_plan, plan_lines
from .reduction import SUPPORT_TOL
from .rounding import apportion
from .space import Candidates, Costs, DesignSpace, Resolution, Stand

__all__ = ["A", "ApproximateDesign", "C", "Candidates", "Costs", "Criterion", "D", "DRIFT_UNIT", "DesignError",
           "DesignResult", "DesignSpace", "Discrimination", "E", "Evaluation", "FieldDesign", "LackOfFit", "Protect", "Resolution", "SUPPORT_TOL", "Stand",
           "apportion", "approximate_design", "as_criterion", "continue_campaign", "design", "design_field", "evaluate",
           "field_plan", "paper_plan", "plan_lines"]


class _CallableModule(types.ModuleType):
    """``hse_opt.design(model, criterion, budget=...)`` calls :func:`design`: the package
    exports this module under the function's name."""

    def __call__(self, *args, **kwargs):
        return design(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
