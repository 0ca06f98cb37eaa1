"""Import independence: the simulator (the model's independent reference) loads neither the
model's CasADi stack nor cvxpy, the package and the command line load nothing heavy before a
command needs it, and the package's API names stay what they are whatever was imported."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("casadi", "cvxpy", "scipy", "matplotlib", "hse_opt.model", "hse_opt.frames")


def _loaded(code):
    """The heavy modules in ``sys.modules`` after ``code`` runs in a fresh interpreter."""
    probe = f"{code}\nimport json, sys\nprint(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in "\
            f"{sorted({h.split('.')[0] for h in HEAVY})!r} or m in {list(HEAVY)!r})))"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True,
                         cwd=ROOT).stdout
    return set(json.loads(out.splitlines()[-1]))


def _roots(mods):
    return {m for m in HEAVY if m in mods or any(n.startswith(m + ".") for n in mods)}


def test_simulator_loads_neither_casadi_nor_cvxpy_nor_the_model():
    mods = _loaded("import hse_opt.sim; from hse_opt.sim import generate, align, run_campaign")
    assert _roots(mods) == set(), sorted(mods)


def test_data_path_loads_neither_the_simulator_nor_the_model():
    """hse_opt.align (raw logs, the processor) stands below the simulator: importing and using it
    loads no heavy module and no part of hse_opt.sim."""
    code = "import hse_opt.align; from hse_opt.align import align, align_logs, load_rawlog"
    mods = _loaded(code)
    assert _roots(mods) == set(), sorted(mods)
    probe = f"{code}\nimport sys; print(sorted(m for m in sys.modules if m.startswith('hse_opt.sim')))"
    out = subprocess.run([sys.executable, "-c", probe], env={**os.environ, "PYTHONPATH": str(ROOT)},
                         capture_output=True, text=True, check=True, cwd=ROOT).stdout
    assert out.strip() == "[]", out


@pytest.mark.parametrize("code", ["import hse_opt", "import hse_opt.cli; hse_opt.cli.build_parser()",
                                  "import hse_opt.data, hse_opt.units"])
def test_package_and_command_line_load_nothing_heavy(code):
    assert _roots(_loaded(code)) == set()


def test_fit_loads_casadi_but_not_cvxpy_matplotlib_or_scipy():
    mods = _loaded("import hse_opt; hse_opt.fit")
    assert "casadi" in mods and not _roots(mods) & {"cvxpy", "matplotlib", "scipy"}


@pytest.mark.parametrize("std_arcsec", [None, 2.0])
def test_fit_command_loads_neither_cvxpy_nor_matplotlib_nor_scipy(tmp_path, std_arcsec):
    """The fit command with its run checks loads no scipy (scipy.stats alone costs a second of
    start-up): Table 1 passes the chi-square check with the sigma from pure error and fails it
    with a heading_std of 2 arcsec (its scatter is ~8 arcsec); no run is an outlier."""
    table = ROOT / "hse_opt" / "datasets" / "paper_table1.csv"
    std = "None" if std_arcsec is None else f"np.full(len(runs), {std_arcsec} * units.ARCSEC)"
    mods = _loaded("import contextlib, io, numpy as np, hse_opt.cli\n"
                   "from hse_opt import units\n"
                   "from hse_opt.data import load_runs, save_runs\n"
                   f"runs = load_runs({str(table)!r})\n"
                   f"save_runs(runs.replace(heading_std={std}), {str(tmp_path / 'RUNS.csv')!r})\n"
                   "with contextlib.redirect_stdout(io.StringIO()) as out:\n"
                   f"    assert hse_opt.cli.main(['fit', {str(tmp_path / 'RUNS.csv')!r}, '--fix', "
                   "'lambda2*tilt_const=0']) == 0\n"
                   f"assert ('far from 1' in out.getvalue()) == {std_arcsec is not None}, out.getvalue()")
    assert "casadi" in mods and not _roots(mods) & {"cvxpy", "matplotlib", "scipy"}


def test_api_names_stay_functions_after_their_modules_are_imported():
    import hse_opt
    from hse_opt.fit import FitResult  # noqa: F401 - binds the module hse_opt.fit in a plain package

    assert callable(hse_opt.fit) and hse_opt.fit.__name__ == "fit"
    assert hse_opt.compensate.__name__ == "compensate"
    assert hse_opt.__all__ and all(hasattr(hse_opt, name) for name in hse_opt.__all__)
    assert sys.modules["hse_opt.fit"].__name__ == "hse_opt.fit"
