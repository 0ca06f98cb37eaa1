"""Whole-or-nothing output files for the simulator (TRUTH.toml, raw logs): the one
implementation, :func:`hse_opt.data.atomic_path`."""
from hse_opt.data import atomic_path

__all__ = ["atomic_path"]
