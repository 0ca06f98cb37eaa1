"""The numeric alignment simulator (independent of :mod:`hse_opt.model`).

Work in progress (issue 3): the truth configuration, the raw-data generator and the
alignment processor are here but not yet tested or benchmarked; the campaign runner and
the symbolic-vs-numeric tests are still to come. Do not rely on its API yet.
"""
