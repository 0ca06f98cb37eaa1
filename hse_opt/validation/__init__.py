"""Validation: checks of the model-based predictions against the independent numeric simulator
(:mod:`hse_opt.sim`), and synthetic plans and data with a known truth (:mod:`.synthetic`) for
studies, tests and benchmarks. It sits above :mod:`hse_opt.design`, :mod:`hse_opt.diagnose` and
:mod:`hse_opt.sim`; none of them imports it (``hse_opt.diagnose`` still resolves the old names
``diagnostic_plan`` / ``model_runs`` lazily)."""
