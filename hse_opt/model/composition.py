"""Model composition: a :class:`Model` is a set of effects of the catalogue
(:mod:`hse_opt.model.effects`) for one calibrated geometry; ``paper_model() + "sync_delay"``
adds one. :meth:`Model.measurement` gives its heading-level measurement model
(:mod:`hse_opt.model.measurement`)."""
from .effects import effect as make_effect
from .measurement import _measurement
from .symbolic import Geometry


class Model:
    """A composition of effects; ``Model + effect`` adds one (by object or catalogue name).

    Parameters
    ----------
    effects : sequence of Effect or str
    geometry : Geometry, optional
        The calibrated axis r_zb^s and K_g the symbolic model is built for.
    """

    def __init__(self, effects, geometry=None):
        effects = tuple(make_effect(e) for e in effects)
        names = [e.name for e in effects]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ValueError(f"effects {sorted(dup)} appear more than once in the model; allowed: each effect once")
        pnames = [p.name for e in effects for p in e.params]
        dup = {n for n in pnames if pnames.count(n) > 1}
        if dup:
            raise ValueError(f"parameter names {sorted(dup)} are declared by more than one effect")
        self.effects = effects
        self.geometry = geometry or Geometry()

    def __add__(self, other):
        if isinstance(other, Model):
            return Model(self.effects + other.effects, self.geometry)
        if isinstance(other, (list, tuple)):
            return Model(self.effects + tuple(other), self.geometry)
        return Model(self.effects + (other,), self.geometry)

    def __radd__(self, other):  # effect + model
        return Model((other,), self.geometry) + self

    def __repr__(self):
        return f"Model({[e.name for e in self.effects]})"

    @property
    def effect_names(self):
        return tuple(e.name for e in self.effects)

    @property
    def params(self):
        return tuple(p for e in self.effects for p in e.params)

    @property
    def covariates(self):
        """Covariate columns the effects need, in order."""
        return tuple(e.column for e in self.effects if hasattr(e, "column"))

    def measurement(self, tilt_known=True):
        """The :class:`MeasurementModel` for runs with (``True``) or without pitch/roll."""
        return _measurement(self, bool(tilt_known))

    def __eq__(self, other):
        return isinstance(other, Model) and self._key() == other._key()

    def __hash__(self):
        return hash(self._key())

    def _key(self):
        return (tuple((type(e), e.name) for e in self.effects), tuple(self.geometry.r_zb_s),
                tuple(self.geometry.K_g.ravel()))


def paper_model(geometry=None):
    """The paper's model: ``hse`` (offset and lambda2)."""
    return Model(["hse"], geometry)


def as_model(model=None):
    """A :class:`Model` from ``None`` (the paper's), a Model, or effect names (``"hse,warmup"``
    or a list; ``hse`` is added when missing)."""
    if model is None:
        return paper_model()
    if isinstance(model, Model):
        return model
    names = [s.strip() for s in model.split(",")] if isinstance(model, str) else list(model)
    names = [n for n in names if n]
    if "hse" not in names:
        names = ["hse"] + names
    return Model(names)
