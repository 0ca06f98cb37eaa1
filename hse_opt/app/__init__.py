"""The application: the command line (:mod:`~hse_opt.app.cli`, one module per command in
:mod:`~hse_opt.app.commands`) and the demo (:mod:`~hse_opt.app.demo`).

The only layer besides :mod:`hse_opt.validation` that uses both the model side and the
simulator; nothing in the library imports it. The old names (``hse_opt.cli``,
``hse_opt.commands``, ``hse_opt.demo``) still import these modules (:mod:`hse_opt._moved`).
"""
