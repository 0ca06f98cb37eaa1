"""The numeric alignment simulator (independent of :mod:`hse_opt.model`)."""
