"""Modules that moved (issue 26 item 5) keep their old import names: users' scripts work on."""
import importlib
import subprocess
import sys

import pytest

from hse_opt._moved import MOVED


@pytest.mark.parametrize("old", sorted(MOVED))
def test_an_old_name_imports_the_very_module_at_its_new_name(old):
    module = importlib.import_module(old)
    assert module is importlib.import_module(MOVED[old])
    assert module.__spec__.name == MOVED[old]          # the module keeps its own identity


def test_the_simulators_old_module_names_keep_its_function_names():
    """hse_opt.sim.align (the module, now hse_opt.align.processor) imports; hse_opt.sim.align the
    function stays the function."""
    code = ("import hse_opt.sim.align, hse_opt.sim.rawlog\nfrom hse_opt.sim.align import AlignConfig\n"
            "from hse_opt.sim import align\nfrom hse_opt.align import processor\n"
            "assert callable(align) and align is processor.align and hse_opt.sim.rawlog.load_rawlog\nprint('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "ok", out.stderr


def test_a_moved_package_takes_its_submodules_along():
    from hse_opt.commands import outputs as old
    from hse_opt.app.commands import outputs as new
    assert old is new


def test_the_readmes_imports_still_work():
    from hse_opt import compensation, demo, fit
    from hse_opt.field import position_lines
    from hse_opt.fit import compensate, load_fit
    assert callable(compensation) and callable(fit) and callable(compensate) and callable(load_fit)
    assert callable(position_lines) and demo.__name__ == "hse_opt.app.demo"


def test_python_dash_m_on_the_old_cli_name_runs_the_cli():
    out = subprocess.run([sys.executable, "-m", "hse_opt.cli", "--version"], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0 and out.stdout.startswith("hse-opt ")
