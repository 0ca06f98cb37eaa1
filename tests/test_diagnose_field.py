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


def test_a_signature_the_model_and_positions_absorb_is_not_testable():
    """One surveyed position (B, 150 deg) and two without a reference: the stand's 2nd azimuth
    harmonic is a constant at B (the offset's column there) and a constant at A and C (their
    unknown headings) - checked here by projecting its two columns on those indicators. The
    candidate was listed as testable with every figure '-' and no reason (dof 0); it is not
    testable, with the reason."""
    runs = _campaign(np.random.default_rng(21), surveyed_b=True)
    labels = np.asarray(runs.position.tolist())
    psi = np.asarray(runs.azimuth, float)
    at_b = labels == "B"
    Z = np.column_stack([np.where(at_b, np.cos(2 * psi), 0.0), np.where(at_b, np.sin(2 * psi), 0.0)])
    B = np.column_stack([(labels == k).astype(float) for k in ("A", "B", "C")])
    assert np.abs(Z - B @ np.linalg.lstsq(B, Z, rcond=None)[0]).max() < 1e-12
    d = diagnose(runs)
    c = next(c for c in d.candidates if c.effect == "azimuth_harmonic2")
    assert not c.testable and "cannot tell it apart" in c.reason, c
    assert "azimuth_harmonic2" in "\n".join(line for line in d.summary() if "not testable" in line)
