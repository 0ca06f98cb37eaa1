"""Plots and the self-contained HTML report of a fit, a diagnosis and a design.

A report is a list of :class:`Section` objects rendered into one HTML file that needs
nothing else to be viewed: no scripts, no web fonts, no network. Every plot is a matplotlib
figure saved as SVG and embedded as a ``data:`` URI in an ``<img>``, so it stays sharp at
any zoom, its internal ids cannot clash with another plot's, and the page opens offline.

Plots use matplotlib's object API (:class:`matplotlib.figure.Figure`, no ``pyplot`` and no
global state beyond a temporary ``rc_context``), so the library works on headless
machines and in worker processes. Each ``plot_*`` function returns the Figure, for
notebooks; each ``*_section`` function returns a :class:`Section`.

Units at the edge: heading errors and residuals in arcsec, rates in deg/s, azimuths in deg,
times in h, parameters in their display units (``Param.unit``).

Sections
--------
:func:`fit_section`
    parameter table (value, sigma, unit), fit statistics, the calibration line of heading
    error against bias rate (the paper's Fig. 2), heading error against azimuth with the
    model before and after compensation (Fig. 3), residuals against every factor.
:func:`comparison_section`
    the before/after of adding an effect: statistics and parameters side by side,
    residuals before and after against every factor.
:func:`diagnosis_section`
    verdict and goodness of fit, the ranking of candidate effects, residual structure
    against each factor and in words, ambiguities, influential runs and outliers.
:func:`noise_section`
    the sensors' noise from the raw logs (``hse-opt align --report``): Allan deviation curves
    with the fitted IEEE 952 terms as slope lines, the figures per log and pooled.
:func:`design_section`, :func:`evaluation_section`
    a plan's runs over time (rate, azimuth, tilt) and its predicted sigmas against the
    paper's plan.
:func:`write_report`
    renders sections into ``DIR/report.html``, written whole (temporary file + rename).

The page also carries every section's numbers as an inert JSON block
(``<script type="application/json" id="hse-opt-data">``) and marks table rows with
``data-key`` attributes, so that tests and scripts can read back what it shows.

The package: :mod:`~hse_opt.report.page` (:class:`Section`, :class:`Figure`, the HTML file),
:mod:`~hse_opt.report.cells` (HTML fragments), :mod:`~hse_opt.report.style` (matplotlib, SVG),
:mod:`~hse_opt.report.rules` (factors, groups, tilt setups), :mod:`~hse_opt.report.curves`
(the model on made-up runs, the calibration line's slope), the plots and sections of a fit
(:mod:`~hse_opt.report.fit_plots`, :mod:`~hse_opt.report.fit_sections`), a diagnosis
(:mod:`~hse_opt.report.diagnosis`), a plan (:mod:`~hse_opt.report.plan`) and the sensors'
noise (:mod:`~hse_opt.report.noise`); every public
name is re-exported here.
"""
from __future__ import annotations

from .curves import slope_caption, slope_parts
from .diagnosis import diagnosis_section, plot_candidates, plot_factor_tests
from .fit_plots import (FIELD_LINE_CAPTION, plot_azimuth, plot_before_after, plot_calibration_line,
                        plot_field_line, plot_residuals)
from .fit_sections import comparison_section, fit_section
from .noise import noise_section, plot_allan
from .page import REPORT_NAME, Figure, Section, render_html, text_section, write_report
from .plan import design_section, evaluation_section, plan_section, plot_plan, plot_sigmas
from .rules import SETUP_TOL, factors, tilt_setups

__all__ = ["Section", "Figure", "REPORT_NAME", "SETUP_TOL",
           "fit_section", "comparison_section", "diagnosis_section", "design_section",
           "evaluation_section", "plan_section", "text_section", "render_html", "write_report",
           "plot_calibration_line", "plot_azimuth", "plot_residuals", "plot_before_after",
           "plot_candidates", "plot_factor_tests", "plot_plan", "plot_sigmas", "plot_field_line",
           "FIELD_LINE_CAPTION", "factors", "tilt_setups", "slope_parts", "slope_caption", "noise_section",
           "plot_allan"]
