"""Modules that moved keep their old import names, so users' scripts go on working.

``import hse_opt.export`` gives the very module object of ``hse_opt.fit.export`` (same
functions, same private names, a patch applies to both names): a finder on ``sys.meta_path``
maps each old name (and, for a package, every name below it) to its new home.
``python -m hse_opt.cli`` runs the new module's code as ``__main__``.
"""
import importlib
import importlib.machinery
import importlib.util
import sys

#: old name -> new name (a package's submodules follow it)
MOVED = {
    "hse_opt.cli": "hse_opt.app.cli",
    "hse_opt.commands": "hse_opt.app.commands",
    "hse_opt.demo": "hse_opt.app.demo",
    "hse_opt.compensation": "hse_opt.fit.correction",
    "hse_opt.export": "hse_opt.fit.export",
    "hse_opt.fit_file": "hse_opt.fit.file",
    "hse_opt.field": "hse_opt.fit.field",
    "hse_opt.paper_procedure": "hse_opt.fit.paper_procedure",
    "hse_opt.sim.rawlog": "hse_opt.align.rawlog",
    "hse_opt.sim.rotations": "hse_opt.align.rotations",
    "hse_opt.sim.align": "hse_opt.align.processor",
}


def new_name(name):
    """The module's name today, or None when ``name`` did not move."""
    for old, new in MOVED.items():
        if name == old or name.startswith(old + "."):
            return new + name[len(old):]
    return None


class _Alias:
    """Finder and loader in one: an old name loads as the module at its new name."""

    def find_spec(self, name, path=None, target=None):
        target_name = new_name(name) if name.startswith("hse_opt.") else None
        if target_name is None:
            return None
        real = importlib.util.find_spec(target_name)
        if real is None:
            return None
        spec = importlib.machinery.ModuleSpec(name, self, is_package=real.submodule_search_locations is not None)
        spec.loader_state = target_name
        return spec

    def create_module(self, spec):
        module = importlib.import_module(spec.loader_state)
        spec.loader_state = (spec.loader_state, module.__spec__)
        return module

    def exec_module(self, module):
        # the import system gave the module the alias's spec: it keeps its own
        module.__spec__ = module.__spec__.loader_state[1]

    def get_code(self, name):
        """For ``python -m OLD``: the new module's code, run as ``__main__``."""
        target_name = new_name(name)
        spec = importlib.util.find_spec(target_name)
        return spec.loader.get_code(target_name)


def install():
    """Put the finder first on ``sys.meta_path``: an old name is an alias even where a stale
    file of that name is left on the path (an older install, an editable checkout)."""
    if not any(isinstance(f, _Alias) for f in sys.meta_path):
        sys.meta_path.insert(0, _Alias())
