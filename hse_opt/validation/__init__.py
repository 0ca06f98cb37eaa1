"""Validation: checks of the model-based predictions against the independent numeric simulator
(:mod:`hse_opt.sim`). It sits above :mod:`hse_opt.design` and :mod:`hse_opt.sim`; neither imports it."""
