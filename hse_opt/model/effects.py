"""The effect catalogue: physical error sources, each declared once where it acts.

An effect is a small class with named parameters and one required hook,
``act(p, op, errors)``: ``p`` maps its parameter names to SI CasADi symbols, ``op`` is the
:class:`~hse_opt.model.symbolic.Operating` point (rate, heading, tilt, latitude, time,
covariates) and ``errors`` the :class:`~hse_opt.model.symbolic.ErrorModel` it adds to. The
symbolic model carries every contribution to the heading error; no effect writes a heading
formula unless it is an error of the heading reference itself.

Declaring a new effect takes a few lines::

    import casadi as ca
    from hse_opt.model import Effect, Param, paper_model
    from hse_opt import units

    class TableBiasX(Effect):
        '''A gyro bias fixed in the table top along x_b (it turns with the table).'''
        name = "table_bias_x"
        params = (Param("bias_xb", "deg/h", units.DEG_PER_H, 0.0, -1.0, 1.0,
                        "gyro bias along x_b"),)

        def act(self, p, op, errors):
            errors.add_gyro_bias_b(ca.vertcat(p["bias_xb"], 0, 0))

    model = paper_model() + TableBiasX()
"""
from dataclasses import dataclass

import casadi as ca
import numpy as np

from .. import frames, units
from ..names import check_name


@dataclass(frozen=True)
class Param:
    """A model parameter record.

    Attributes
    ----------
    name : str
        Unique name within a model.
    unit : str
        Display unit (reports, files, bounds given by users).
    scale : float
        SI value of one display unit (``value_si = value * scale``).
    nominal, lower, upper : float
        Nominal value and default bounds, in the display unit.
    description : str
        One line: what the parameter is physically.
    """

    name: str
    unit: str
    scale: float
    nominal: float
    lower: float
    upper: float
    description: str

    def __post_init__(self):
        if not (self.lower <= self.nominal <= self.upper):
            raise ValueError(f"parameter {self.name!r}: need lower <= nominal <= upper, got "
                             f"{self.lower} <= {self.nominal} <= {self.upper}")


class Effect:
    """Base class of an effect: set ``name``, ``description`` (the class docstring's first
    line by default), ``params`` and implement :meth:`act`."""

    name: str = ""
    params: tuple = ()
    #: level where the effect acts: sensor, encoder, processing, reference or thermal
    level: str = ""
    #: parameters entering the model nonlinearly (kept at nominal in linearised use)
    nonlinear: tuple = ()
    #: catalogue effects without which this one has no heading signature (it acts only in a
    #: product with theirs)
    needs: tuple = ()

    @property
    def description(self):
        return (type(self).__doc__ or "").strip().splitlines()[0]

    def act(self, p, op, errors):  # pragma: no cover - the required hook
        raise NotImplementedError

    def __repr__(self):
        return f"<effect {self.name}: {self.description}>"


class HSE(Effect):
    """The paper's model: K_g non-orthogonality lambda2 = eps1+eps2+eps3 and a heading offset."""

    name = "hse"
    level = "processing"
    params = (
        Param("offset", "arcsec", units.ARCSEC, 0.0, -7200.0, 7200.0,
              "constant heading offset: b0 zero mark against the stand's reference"),
        Param("lambda2", "arcsec", units.ARCSEC, 0.0, -200.0, 200.0,
              "eps1+eps2+eps3 of the K_g calibration error Lambda (Eq. 1), spread equally"),
    )

    def act(self, p, op, errors):
        errors.add_lambda(ca.vertcat(1, 1, 1) * p["lambda2"] / 3)
        errors.add_reference_error(-p["offset"])


class AxisBias(Effect):
    """Gyro bias along the rotation axis: not modulated by the turn, reaches heading through tilt."""

    name = "axis_bias"
    level = "sensor"
    params = (Param("bias_z", "deg/h", units.DEG_PER_H, 0.0, -1.0, 1.0,
                    "component of the gyro bias vector along z_b (down the rotation axis)"),)

    def act(self, p, op, errors):
        errors.add_gyro_bias_b(ca.vertcat(0, 0, p["bias_z"]))


class SyncDelay(Effect):
    """Gyro-encoder time offset: the encoder angle that projects the gyros into b0 is late."""

    name = "sync_delay"
    level = "encoder"
    params = (Param("delay", "us", units.MICROSECOND, 0.0, -2000.0, 2000.0,
                    "encoder sampling late against gyro sampling"),)

    def act(self, p, op, errors):
        errors.add_encoder_delay(p["delay"])


class ScaleNonlinearity(Effect):
    """Gyro scale-factor nonlinearity in input rate: output = w (1 + n |w|) on every gyro."""

    name = "scale_nonlinearity"
    level = "sensor"
    params = (Param("sf_nonlin", "ppm/(deg/s)", units.PPM / units.DEG_PER_S, 0.0, -1.0, 1.0,
                    "scale-factor change per deg/s of input rate, common to the three gyros"),)

    def act(self, p, op, errors):
        errors.add_gyro_output_term(lambda w_g, sign_g: p["sf_nonlin"] * sign_g * w_g * w_g, 2)


class Warmup(Effect):
    """Thermal warm-up after power-on: the IMU mount turns about the rotation axis, decaying."""

    name = "warmup"
    level = "thermal"
    nonlinear = ("warmup_tau",)
    params = (
        Param("warmup_amp", "arcsec", units.ARCSEC, 0.0, -600.0, 600.0,
              "mount rotation about z_b (xi_z) at power-on, decaying to zero"),
        Param("warmup_tau", "s", 1.0, 1200.0, 30.0, 36000.0,
              "time constant of the warm-up transient"),
    )

    def act(self, p, op, errors):
        tau, t0, T = p["warmup_tau"], op.t_start, op.duration
        # mean of exp(-t/tau) over the alignment window [t0, t0 + T], in closed form
        window_mean = tau / T * (ca.exp(-t0 / tau) - ca.exp(-(t0 + T) / tau))
        errors.add_xi(ca.vertcat(0, 0, p["warmup_amp"] * window_mean))


class AzimuthHarmonic2(Effect):
    """Periodic error of the test stand's azimuth reading at twice the stand azimuth."""

    name = "azimuth_harmonic2"
    level = "reference"
    params = (
        Param("az_c2", "arcsec", units.ARCSEC, 0.0, -600.0, 600.0,
              "stand reading error, cos(2 x azimuth) coefficient"),
        Param("az_s2", "arcsec", units.ARCSEC, 0.0, -600.0, 600.0,
              "stand reading error, sin(2 x azimuth) coefficient"),
    )

    def act(self, p, op, errors):
        errors.add_reference_error(p["az_c2"] * ca.cos(2 * op.psi) + p["az_s2"] * ca.sin(2 * op.psi))


class EncoderHarmonic(Effect):
    """Encoder periodic angle error (1st and 2nd harmonics of the table angle).

    It turns the projection of the gyro outputs into b0 by delta(alpha), whose revolution
    mean is zero, so alone it has no heading signature. Its 1st harmonic reaches heading
    through the processed table rate's horizontal part in b: a rate fixed in the table top,
    ``Omega h`` with ``h = (-xi_y, xi_x)`` for a mount error xi (Eq. 2), projected with the
    erroneous angle, keeps a revolution mean ``-Omega (c1 + i s1) (xi_x + i xi_y) / 2`` in b0
    (complex horizontal components): a heading error
    ``Omega Im(exp(i psi) (c1 + i s1) (xi_x + i xi_y)) / (2 w_ie cos L)``
    (:func:`hse_opt.model.closed_form.heading_error_encoder_mount`), up to 0.26 arcsec per
    arcsec of encoder error per 10 arcsec of misalignment at 40 deg/s. The model carries it
    for every source of that horizontal part: declare the mount's with :class:`MountXi`
    (a rotation-axis calibration error acts the same way, :meth:`MountXi.from_axis_error`);
    lambda2 (``hse``) adds its own. The 2nd harmonic has no revolution mean with it; the
    alignment filter leaves a start-up transient of it (up to ~0.08 arcsec at 20 deg/s for
    30 arcsec of encoder error and 140 arcsec of misalignment in 10 minutes, falling as
    1/duration), which no revolution mean holds (``studies/encoder_coupling.py``).
    """

    name = "encoder_harmonic"
    level = "encoder"
    params = tuple(
        Param(f"enc_{cs}{k}", "arcsec", units.ARCSEC, 0.0, -600.0, 600.0,
              f"encoder angle error, {'cos' if cs == 'c' else 'sin'}({k} alpha) coefficient")
        for k in (1, 2) for cs in ("c", "s"))

    def act(self, p, op, errors):
        def delta(alpha):
            return sum(p[f"enc_c{k}"] * ca.cos(k * alpha) + p[f"enc_s{k}"] * ca.sin(k * alpha)
                       for k in (1, 2))
        errors.add_encoder_error(delta, 2)


class MountXi(Effect):
    """IMU mount misaligned about x_b, y_b (xi_x, xi_y of Eq. 2): heading only with an encoder error.

    The lab calibration C~_s^b = (I - [xi x]) C_s^b (Eq. 2) with a horizontal xi tilts the
    processed rotation axis: the table rate leaks into the horizontal of b as ``Omega (-xi_y,
    xi_x)``, which turns with the table and averages out over a revolution; so does the
    Earth-rate term. Alone it moves the heading only at second order (products with lambda2:
    < 1e-4 arcsec at xi = (3, -2) arcsec and lambda2 = 4.2 arcsec, < 0.01 at 100 arcsec); with
    the encoder's 1st harmonic (:class:`EncoderHarmonic`) it gives a heading error
    proportional to the rate. A rotation-axis calibration error (r_zb^s) tilts the processed
    axis the same way: declare its equivalent, :meth:`from_axis_error`.
    """

    name = "mount_xi"
    level = "processing"
    needs = ("encoder_harmonic",)
    params = (
        Param("xi_x", "arcsec", units.ARCSEC, 0.0, -600.0, 600.0,
              "mount rotation about x_b left in the calibrated C~_s^b (Eq. 2)"),
        Param("xi_y", "arcsec", units.ARCSEC, 0.0, -600.0, 600.0,
              "mount rotation about y_b left in the calibrated C~_s^b (Eq. 2)"),
    )

    def act(self, p, op, errors):
        errors.add_xi(ca.vertcat(p["xi_x"], p["xi_y"], 0))

    @staticmethod
    def from_axis_error(r_zb_s_true, r_zb_s_calibrated):
        """``{"xi_x": .., "xi_y": ..}`` (arcsec) that tilt the processed rotation axis as
        the calibrated axis ``r_zb_s_calibrated`` does when the true one is
        ``r_zb_s_true`` (unit vectors in s): with ``d = C_s^b (r_true - r_cal)`` the
        processed table rate leaks into b as ``Omega (d_x, d_y)``, the leak of
        ``xi = (d_y, -d_x)``. (The axis error also turns x_b about the axis: a heading
        offset, which ``offset`` absorbs.)"""
        r_true = np.asarray(r_zb_s_true, dtype=float)
        r_cal = np.asarray(r_zb_s_calibrated, dtype=float)
        d = frames.c_b_s(r_cal).T @ (r_true / np.linalg.norm(r_true) - r_cal / np.linalg.norm(r_cal))
        return {"xi_x": float(d[1] / units.ARCSEC), "xi_y": float(-d[0] / units.ARCSEC)}


class Covariate(Effect):
    """Heading offset following a recorded covariate (e.g. temperature) linearly."""

    level = "reference"

    def __init__(self, column):
        check_name(column, "covariate column")
        self.column = column
        self.name = f"covariate:{column}"
        self.params = (Param(f"k_{column}", f"arcsec per {column} unit", units.ARCSEC, 0.0,
                             -1e4, 1e4, f"heading offset per unit of {column}"),)

    @property
    def description(self):
        return f"Heading offset following the covariate {self.column} linearly."

    def act(self, p, op, errors):
        if self.column not in op.covariates:
            raise ValueError(f"effect {self.name!r} needs the covariate column {self.column!r}; "
                             f"the runs have {sorted(op.covariates) or 'no covariates'}")
        errors.add_reference_error(-p[self.params[0].name] * op.covariates[self.column])


CATALOGUE = {cls.name: cls for cls in
             (HSE, AxisBias, SyncDelay, ScaleNonlinearity, Warmup, AzimuthHarmonic2, EncoderHarmonic,
              MountXi)}


def register_effect(cls):
    """Add an :class:`Effect` class to :data:`CATALOGUE` under its ``name`` (a class
    decorator; returns the class): the tools then know it by name, and the diagnosis tests
    it as a candidate. Its twin in the simulator is declared in
    :mod:`hse_opt.validation.twins`. Raises when the name is taken."""
    if not (isinstance(cls, type) and issubclass(cls, Effect)) or not cls.name:
        raise ValueError(f"register_effect needs an Effect class with a name, got {cls!r}")
    check_name(cls.name, "effect name")
    if cls.name in CATALOGUE or cls.name.startswith("covariate:"):
        raise ValueError(f"effect name {cls.name!r} is taken; the catalogue has {', '.join(CATALOGUE)}")
    CATALOGUE[cls.name] = cls
    return cls


def effect(name):
    """The catalogue effect called ``name`` (``'covariate:<column>'`` for a covariate)."""
    if isinstance(name, Effect):
        return name
    if isinstance(name, str) and name.startswith("covariate:"):
        return Covariate(name.split(":", 1)[1])
    if name not in CATALOGUE:
        raise ValueError(f"unknown effect {name!r}; allowed: {', '.join(CATALOGUE)}, covariate:<column>")
    return CATALOGUE[name]()
