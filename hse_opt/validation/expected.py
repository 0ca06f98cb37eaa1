"""What a campaign run to a plan could not rule out, known before it is run.

The alias budget (:mod:`hse_opt.aliasing`) depends on the runs' settings and sigmas, not on
their headings: the budget of a fit to headings the model makes for a plan is the budget the
diagnosis will report on the campaign's data if the model is right (exactly, for a model
linear in its parameters; else to the linearisation). The headings carry seeded noise only so
that a plan's repeats are distinct runs: noise-free repeats would be copies of one
measurement, which the fit counts once. The design prints it beside
its protection, so that a plan that protects an effect (power >= 0.8 at its plausible edge)
but lets a smaller, undetectable size of it move a parameter by more than its sigma says so
before the campaign, not only after it (``diagnose``'s ``inconclusive``).
"""
from __future__ import annotations

import numpy as np

from ..aliasing import alias_budget
from ..fit import fit
from ..model import as_model
from .synthetic import model_runs


def expected_budget(plan, model=None, *, stand=None, tilt_known=True, values=None, tests=None):
    """The alias budget a diagnosis of ``plan``'s campaign will report if ``model`` is right.

    Parameters
    ----------
    plan : hse_opt.data.Plan
        A stand plan, or a field plan (rows at unsurveyed positions: their headings unknown
        to the fit, as in the campaign's RUNS.csv).
    model : Model, str or sequence of str, optional
        The model the campaign will be fitted with (default ``hse``).
    stand : hse_opt.design.Stand, optional
        Latitude, base tilt and the runs' heading noise (default :class:`~hse_opt.design.Stand`).
    tilt_known : bool
    values : mapping name -> value (display units), optional
        The parameters where the model is linearised (default nominal).
    tests : int, optional
        The size of the diagnosis's test family (default
        :data:`hse_opt.aliasing.DEFAULT_TESTS`).

    Returns
    -------
    hse_opt.aliasing.AliasBudget
    """
    from ..design import Stand

    stand = Stand() if stand is None else stand
    model = as_model(model)
    sigma = stand.sigma(plan.duration)
    runs = model_runs(plan, dict(values or {}), np.random.default_rng(0), model=model, latitude=stand.latitude,
                      base_tilt=(stand.tilt[1], stand.tilt[0]), sigma=sigma)
    if plan.surveyed is not None and not np.all(plan.surveyed):
        runs = _as_field(runs, plan)
    f = fit(runs, model, tilt_known=tilt_known)
    return alias_budget(f, runs, tests=tests)


def describe_expected(budget):
    """Lines for a plan's summary: what its campaign would still not rule out."""
    lines = budget.sentences()
    if not lines:
        return ["a campaign of this plan could rule out every assessed effect at its plausible size "
                "(none would move a parameter beyond its sigma undetected), if the model is right"]
    return (["what a campaign of this plan could still not rule out, if the model is right (hse-opt diagnose "
             "would call it inconclusive; the shift an effect below the test's reach could cause):"]
            + [f"  {ln}" for ln in lines])


def _as_field(runs, plan):
    """The runs as the campaign's RUNS.csv will have them: at an unsurveyed position no stand
    azimuth, the alignment's own heading, and the position label."""
    from .. import units
    from ..data import Runs

    heading = np.mod(runs.azimuth + runs.heading_err, 2 * np.pi)
    azimuth = np.where(plan.surveyed, np.degrees(runs.azimuth), np.nan)
    cols = {"run": runs.run, "rate_dps": runs.rate / units.DEG_PER_S, "azimuth_deg": azimuth,
            "heading_deg": np.degrees(heading), "latitude_deg": np.degrees(runs.latitude),
            "duration_s": runs.duration, "t_start_s": runs.t_start, "pitch_arcsec": runs.pitch / units.ARCSEC,
            "roll_arcsec": runs.roll / units.ARCSEC, "heading_std_arcsec": runs.heading_std / units.ARCSEC,
            "position": np.asarray(plan.position)}
    return Runs.from_columns(cols, source=f"{plan.source}, as measured")
