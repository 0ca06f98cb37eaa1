"""The symbolic error model (CasADi): paper Eqs. 1-16, the effect catalogue and the
heading-level measurement model."""
from . import closed_form, symbolic
from .effects import CATALOGUE, Covariate, Effect, Param, effect, register_effect
from .composition import Model, as_model, paper_model
from .measurement import MeasurementModel
from .symbolic import Geometry

__all__ = ["CATALOGUE", "Covariate", "Effect", "Geometry", "MeasurementModel", "Model", "Param",
           "as_model", "closed_form", "effect", "paper_model", "register_effect", "symbolic"]
