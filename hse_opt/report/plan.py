"""The report of a plan: its runs over time, its predicted sigmas against a baseline plan's, and
the sections of a design, an evaluation and a plan."""
from __future__ import annotations

import html

import numpy as np

from .. import units
from .cells import _fmt, _jsonable, _notes, _paragraph, _table
from .page import Section
from .style import _COLORS, _embed, _new_figure, _plotting


@_plotting
def plot_plan(plan, title="The plan's runs over time"):
    """A plan's runs over time: bias rate, stand azimuth and (when any) deliberate tilt of
    each alignment, as bars from its start to its end.

    Parameters
    ----------
    plan : hse_opt.data.Plan or hse_opt.data.Runs
        Needs ``t_start`` (time since power-on).

    Returns
    -------
    matplotlib.figure.Figure
    """
    t0 = np.asarray(plan.t_start if plan.t_start is not None
                    else np.concatenate([[0.0], np.cumsum(plan.duration[:-1])]), float)
    t1 = t0 + np.asarray(plan.duration, float)
    panels = [("bias rate [deg/s]", plan.rate / units.DEG_PER_S),
              ("stand azimuth [deg]", np.mod(plan.azimuth / units.DEG, 360.0))]
    tilt_x, tilt_y = getattr(plan, "tilt_x", None), getattr(plan, "tilt_y", None)
    if tilt_x is not None and (np.any(tilt_x != 0) or np.any(tilt_y != 0)):
        panels.append(("deliberate tilt [arcsec]", None))
    fig = _new_figure(7.5, 1.5 + 1.3 * len(panels))
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (label, v) in zip(axes, panels):
        if v is None:
            # pitch thin on top of roll: both show where they are equal
            ax.hlines(tilt_x / units.ARCSEC, t0 / units.HOUR, t1 / units.HOUR, color=_COLORS[0],
                      lw=6, label="x (roll)")
            ax.hlines(tilt_y / units.ARCSEC, t0 / units.HOUR, t1 / units.HOUR, color=_COLORS[1],
                      lw=2, label="y (pitch)")
            fig.legend(*ax.get_legend_handles_labels(), loc="outside right lower", frameon=False)
        else:
            ax.hlines(v, t0 / units.HOUR, t1 / units.HOUR, color=_COLORS[0], lw=4)
        ax.set_ylabel(label)
    axes[1].set_yticks(np.arange(0, 361, 90))
    axes[-1].set_xlabel("time since power-on [h]")
    fig.suptitle(f"{title}: {len(t0)} alignments, {t1.max() / units.HOUR:.1f} h")
    return fig


@_plotting
def plot_sigmas(evaluation, baseline=None, labels=("optimised plan", "paper's plan")):
    """Predicted 1-sigma of each parameter for a plan, against a baseline plan's.

    Parameters
    ----------
    evaluation, baseline : hse_opt.design.Evaluation
        ``names``, ``units``, ``std`` (display units); ``baseline`` optional.
    labels : tuple of 2 str

    Returns
    -------
    matplotlib.figure.Figure
    """
    names = list(evaluation.names)
    k = len(names)
    fig = _new_figure(7.5, 1.3 + 0.42 * k)
    ax = fig.add_subplot()
    y = np.arange(k)[::-1]
    h = 0.38 if baseline is not None else 0.6
    ax.barh(y + (h / 2 if baseline is not None else 0), evaluation.std, height=h,
            color=_COLORS[0], label=labels[0])
    if baseline is not None:
        base = np.array([baseline.std[list(baseline.names).index(n)] if n in baseline.names else np.nan
                         for n in names])
        ax.barh(y - h / 2, base, height=h, color="#7f7f7f", label=labels[1])
        for yi, a, b in zip(y, evaluation.std, base):
            if np.isfinite(b) and a > 0:
                ax.annotate(f"{b / a:.3g}x smaller" if a < b else f"{a / b:.3g}x larger", (max(a, b), yi),
                            xytext=(4, -3), textcoords="offset points", fontsize=8)
        ax.margins(x=0.25)  # room for the labels
    ax.set_xscale("log")
    ax.set_yticks(y, [f"{n} [{u}]" for n, u in zip(names, evaluation.units)])
    ax.set_xlabel("predicted 1-sigma (display unit of each parameter)")
    ax.legend(loc="best", frameon=False)
    ax.set_title("Predicted uncertainty of each parameter")
    return fig


def _evaluation_blocks(ev, plan, baseline, baseline_note, label):
    """Plan over time, predicted sigmas (plot and table) against a baseline plan's."""
    rows, keys = [], []
    for i, (n, u, sd) in enumerate(zip(ev.names, ev.units, ev.std)):
        b = None
        if baseline is not None and n in baseline.names:
            b = float(baseline.std[list(baseline.names).index(n)])
        rows.append([f"<code>{html.escape(n)}</code>", html.escape(u), _fmt(sd, 3), _fmt(b, 3),
                     _fmt(sd / b, 3) if b else "&ndash;", _fmt(ev.drift_bias[i], 3)])
        keys.append(f"sigma:{n}")
    return [
        _embed(plot_plan(plan, label), f"Each bar is one alignment of {label.lower()}, from its "
               "start to its end.", "the plan's runs over time"),
        _embed(plot_sigmas(ev, baseline, (label.lower(), "paper's plan")),
               f"Predicted 1-sigma of each parameter (log scale), {label.lower()}"
               + (" against the paper's plan in the same model; the labels: how many times smaller."
                  if baseline is not None else "."), "predicted sigmas"),
        _table(["parameter", "unit", "predicted sigma", "paper's plan", "ratio",
                "bias per arcsec/h of drift"], rows, keys=keys, cls="sigmas"),
        _paragraph(baseline_note) if baseline_note else "",
    ]


def design_section(result, baseline=None, title=None, baseline_note=None, label="The optimised plan"):
    """The report section of an optimised plan: its runs over time, its predicted sigmas
    against a baseline plan's (the paper's), efficiency and times.

    Parameters
    ----------
    result : hse_opt.design.DesignResult
    baseline : hse_opt.design.Evaluation, optional
        The baseline plan evaluated for the same model.
    title : str, optional
    baseline_note : str, optional
        Said instead of the comparison when there is no baseline (e.g. the paper's plan
        cannot identify the model).
    label : str
        The plan's name in the figures and their legends: say what it has that the baseline
        has not (e.g. "The optimised plan with the 0.5-deg tilt fixture").

    Returns
    -------
    Section
    """
    ev = result.evaluation
    title = title or f"Optimised plan for {' + '.join(ev.effects)} ({result.criterion})"
    stats = [("criterion", "criterion", html.escape(result.criterion)),
             ("alignments", "n_runs", _fmt(result.n_runs)),
             ("total time [h]", "total_time_h", _fmt(result.total_time / units.HOUR)),
             ("setup time [h]", "setup_time_h", _fmt(result.setup_time / units.HOUR)),
             ("efficiency (rounded + refined vs approximate optimum)", "efficiency",
              _fmt(result.efficiency)),
             ("efficiency against the whole budget", "budget_efficiency",
              _fmt(result.budget_efficiency)),
             ("refinement", "refinement", html.escape(result.refinement))]
    blocks = [_table(["statistic", "value"], [[lab, v] for lab, _, v in stats],
                     keys=[k for _, k, _ in stats], cls="stats")]
    protection = getattr(result, "protection", ())
    if protection:
        blocks.append(_paragraph("Protection: the power of the diagnosis against each catalogue effect outside "
                                 "the model at the edge of its plausible range (target 0.8), or why the plan "
                                 "does not protect against it."))
        blocks.append(_table(["effect", "at", "power", "protected"],
                             [[html.escape(p.effect), html.escape(p.sizes) or "&ndash;",
                               "&ndash;" if p.power is None else _fmt(p.power, 3),
                               "yes" if p.protected else html.escape(f"no: {p.reason}")] for p in protection],
                             keys=[f"power:{p.effect}" for p in protection], cls="protection"))
    blocks += _evaluation_blocks(ev, result.plan, baseline, baseline_note, label)
    blocks.append(_notes(list(result.notes)))
    data = {"design": _jsonable(result.to_dict()),
            "baseline": None if baseline is None else _jsonable(baseline.to_dict())}
    return Section(title, tuple(b for b in blocks if b), data)


def evaluation_section(evaluation, plan, baseline=None, title=None, baseline_note=None):
    """The report section of an existing plan's evaluation (``hse-opt design --evaluate``):
    its runs over time and predicted sigmas against a baseline plan's.

    Parameters
    ----------
    evaluation : hse_opt.design.Evaluation
    plan : hse_opt.data.Plan
    baseline : hse_opt.design.Evaluation, optional
    title, baseline_note : str, optional

    Returns
    -------
    Section
    """
    ev = evaluation
    title = title or f"The plan evaluated for {' + '.join(ev.effects)}"
    stats = [("alignments", "n_runs", _fmt(ev.n_runs)),
             ("total time [h]", "total_time_h", _fmt(ev.total_time / units.HOUR)),
             ("criterion", "criterion", html.escape(f"{ev.criterion} = {ev.criterion_value:.6g}")),
             ("condition number", "condition", _fmt(ev.condition, 3))]
    blocks = [_table(["statistic", "value"], [[lab, v] for lab, _, v in stats],
                     keys=[k for _, k, _ in stats], cls="stats")]
    blocks += _evaluation_blocks(ev, plan, baseline, baseline_note, "The plan")
    data = {"evaluation": _jsonable(ev.to_dict()),
            "baseline": None if baseline is None else _jsonable(baseline.to_dict())}
    return Section(title, tuple(b for b in blocks if b), data)


def plan_section(plan, title="The test plan", text=None):
    """A plan's runs over time (:func:`plot_plan`) with an optional paragraph.

    Returns
    -------
    Section
    """
    blocks = ([_paragraph(text)] if text else []) + [
        _embed(plot_plan(plan), "Each bar is one alignment, from its start to its end, against the "
               "time since power-on.", "the plan's runs over time")]
    return Section(title, tuple(blocks), {"n_runs": len(plan)})
