"""The twin of every effect in the numeric simulator: the ``TRUTH.toml`` keys that switch it on
there and how the model's parameter values become changes of the simulator's truth.

An effect's physics lives once, in its class (:mod:`hse_opt.model.effects`); its twin lives
here, once, with the sign conventions between the two sides:

* the model's reference-level coefficients are the stand reading's error (reading - true);
  the simulator's ``[[stand.azimuth_harmonics]]`` and ``azimuth_offset_arcsec`` are
  true - reading, and its harmonics are ``a sin(k x + phi)`` where the model has
  ``c cos(k x) + s sin(k x)``;
* ``lambda2`` is spread equally over the simulator's ``gyro.eps_arcsec`` (eps1..eps3);
* the model's common scale-factor nonlinearity is the same on each of the three gyros;
* ``mount_xi`` writes the simulator's whole ``mount.xi_arcsec`` with ``xi_z = 0`` (the
  warm-up and the temperature covariate turn the mount about z through their own keys).

:func:`effect_names` is the list of effects that the demo, the studies, the tests and the
benchmarks use: the catalogue's, then the covariate the simulator records. A catalogue
effect without a twin stops it (and every list derived from it) with a message that names
the effect. ``tests/test_twins.py`` holds every twin against the simulator.

Declaring an effect with its twin (the README shows it reaching the fit, the design, the
diagnosis and the demo)::

    @register_effect
    class AzimuthHarmonic1(Effect): ...

    register_twin(Twin("azimuth_harmonic1", ("stand.azimuth_harmonics",),
                  lambda v: {"stand": {"azimuth_harmonics": [harmonic(1, -v["az_c1"], -v["az_s1"])]}}))
"""
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..model.effects import CATALOGUE, effect

__all__ = ["Twin", "TWINS", "SIMULATED_COVARIATES", "effect_names", "hideable", "harmonic", "hidden",
           "truth_changes", "register_twin", "twin"]

#: covariate effects whose column the simulator writes (``temp_c``: mean IMU temperature)
SIMULATED_COVARIATES = ("covariate:temp_c",)


@dataclass(frozen=True)
class Twin:
    """An effect's twin in the simulator.

    Attributes
    ----------
    effect : str
        The effect's name (catalogue name or ``covariate:<column>``).
    keys : tuple of str
        ``TRUTH.toml`` keys (``section.key``, or a whole ``section``) that switch it on.
    to_truth : callable
        ``values -> changes``: the effect's parameter values (display units, by name) as
        ``TruthConfig.updated`` changes (TOML-shaped, the simulator's units).
    """

    effect: str
    keys: tuple
    to_truth: Callable

    def truth_changes(self, values):
        """The simulator's truth changes for the parameter ``values`` (display units)."""
        return self.to_truth(dict(values))


def harmonic(order, c, s):
    """``c cos(k x) + s sin(k x)`` as the simulator's harmonic ``a sin(k x + phi)`` (a
    ``[[...harmonics]]`` table: order, amplitude_arcsec, phase_deg)."""
    return {"order": order, "amplitude_arcsec": float(np.hypot(c, s)),
            "phase_deg": float(np.degrees(np.arctan2(c, s)))}


TWINS = {t.effect: t for t in (
    Twin("hse", ("gyro.eps_arcsec", "stand.azimuth_offset_arcsec"),
         lambda v: {"gyro": {"eps_arcsec": [v["lambda2"] / 3] * 3},
                    "stand": {"azimuth_offset_arcsec": v["offset"]}}),
    Twin("axis_bias", ("gyro.axis_bias_dph",), lambda v: {"gyro": {"axis_bias_dph": v["bias_z"]}}),
    Twin("sync_delay", ("encoder.sync_delay_us",), lambda v: {"encoder": {"sync_delay_us": v["delay"]}}),
    Twin("scale_nonlinearity", ("gyro.sf_nonlinearity_ppm_per_dps",),
         lambda v: {"gyro": {"sf_nonlinearity_ppm_per_dps": [v["sf_nonlin"]] * 3}}),
    Twin("warmup", ("mount.warmup_xi_z_arcsec", "mount.warmup_tau_s"),
         lambda v: {"mount": {"warmup_xi_z_arcsec": v["warmup_amp"], "warmup_tau_s": v["warmup_tau"]}}),
    Twin("azimuth_harmonic2", ("stand.azimuth_harmonics",),
         lambda v: {"stand": {"azimuth_harmonics": [harmonic(2, -v["az_c2"], -v["az_s2"])]}}),
    Twin("encoder_harmonic", ("encoder.harmonics",),
         lambda v: {"encoder": {"harmonics": [harmonic(k, v[f"enc_c{k}"], v[f"enc_s{k}"]) for k in (1, 2)]}}),
    Twin("mount_xi", ("mount.xi_arcsec",),
         lambda v: {"mount": {"xi_arcsec": [v["xi_x"], v["xi_y"], 0.0]}}),
    Twin("covariate:temp_c", ("mount.xi_z_tempco_arcsec_per_c", "thermal"),
         lambda v: {"mount": {"xi_z_tempco_arcsec_per_c": v["k_temp_c"]}}),
)}


def register_twin(t):
    """Add the twin of a newly declared effect; returns it. Raises when the effect has one."""
    if t.effect in TWINS:
        raise ValueError(f"effect {t.effect!r} already has a twin in the simulator")
    TWINS[t.effect] = t
    return t


def twin(name):
    """The twin of the effect ``name``; raises ``LookupError`` naming it when there is none."""
    try:
        return TWINS[name]
    except KeyError:
        raise LookupError(
            f"effect {name!r} has no twin in the simulator: declare one with "
            f"hse_opt.validation.twins.register_twin(Twin({name!r}, keys, to_truth)) -- the TRUTH.toml keys "
            "that switch it on and its parameter values as truth changes") from None


def effect_names():
    """Every effect the model and the simulator share, in catalogue order, then
    :data:`SIMULATED_COVARIATES`. Raises ``LookupError`` for a catalogue effect without a twin."""
    names = (*CATALOGUE, *SIMULATED_COVARIATES)
    for name in names:
        twin(name)
    return names


def hideable():
    """The effects of :func:`effect_names` that the paper's model (``hse``) lacks and that
    show in the heading on their own (no ``Effect.needs``; ``mount_xi`` acts only with
    ``encoder_harmonic``): what a campaign can hide from it."""
    return tuple(n for n in effect_names() if n != "hse" and not effect(n).needs)


def hidden(sizes, pairs=()):
    """``{name: values}`` for hiding each of :func:`hideable`, sized by ``sizes`` (effect -> its
    parameter values, display units), then each pair of ``pairs`` as ``"a+b"`` (values
    merged). Raises ``LookupError`` naming the effects ``sizes`` leaves out: a new effect needs
    its size where a study hides it."""
    names = hideable()
    missing = [n for n in names if n not in sizes]
    if missing:
        raise LookupError(f"no size for the effects {missing}; allowed: a size for every one of {names}")
    out = {n: dict(sizes[n]) for n in names}
    for pair in pairs:
        out["+".join(pair)] = {k: v for n in pair for k, v in sizes[n].items()}
    return out


def truth_changes(name, values):
    """The simulator's truth changes for an effect, or effects ``"a+b"`` together, at the
    parameter ``values`` (display units, by name; each twin takes its own)."""
    out = {}
    for n in name.split("+"):
        own = {q.name for q in effect(n).params}
        _merge(out, twin(n).truth_changes({k: v for k, v in values.items() if k in own}))
    return out


def _merge(into, changes):
    for k, v in changes.items():
        if isinstance(v, dict) and isinstance(into.get(k), dict):
            _merge(into[k], v)
        else:
            into[k] = v
