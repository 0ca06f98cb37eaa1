"""Diagnose on field campaigns: a constant per position is not a missing effect.

The campaign is made from Eq. 14 plus an unknown constant per position (its true heading,
and on top an axis-bias-like offset that differs between positions) plus noise; the
reference is what such data can and cannot show.
"""
import numpy as np

from hse_opt import units
from hse_opt.diagnose import diagnose

from test_fit_field import _campaign


def test_constants_per_position_are_not_missing_effects():
    runs = _campaign(np.random.default_rng(21))
    # an axis-bias-like offset that differs between positions (tilt-coupled, rate-independent)
    offset = {"A": 40.0, "B": -25.0, "C": 10.0}
    runs = runs.replace(heading_err=runs.heading_err + units.ARCSEC * np.array(
        [offset[p] for p in runs.position.tolist()]))
    d = diagnose(runs)
    assert d.fits and not d.best, "\n".join(d.summary())
    untestable = {c.effect: c.reason for c in d.candidates if not c.testable}
    for name in ("axis_bias", "azimuth_harmonic2"):
        assert "constant within each position" in untestable[name]
    azimuth = next(t for t in d.factors if t.name == "azimuth")
    assert not azimuth.tested and "constant within each position" in azimuth.note
