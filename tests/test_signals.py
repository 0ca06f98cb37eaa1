"""Ctrl-C and SIGTERM end every command the same way (issue 27): one line on stderr, exit 130
(SIGINT) or 128 + the signal, nothing half-written -- also when the signal arrives inside a
solver written in C that swallows the KeyboardInterrupt (CasADi/IPOPT: the status
``NonIpopt_Exception_Thrown``; before, the fit failed with exit 1 and the demo exited 0 with
every output).

The subprocess tests send real signals at delays drawn from a seeded generator; a command
that happens to finish first must then have succeeded whole (exit 0, every output there).
"""
import io
import os
import signal
import subprocess
import sys
import time
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from hse_opt import interrupts
from hse_opt.cli import main
from hse_opt.data import TEMP_TAG
from hse_opt.datasets import paper_table1_path

FIX = ["--fix", "lambda2*tilt_const=0"]


class _Kick(ca.Callback):
    """An objective that sends this process SIGINT on its third evaluation: the signal then
    arrives inside IPOPT, as a Ctrl-C during a long solve does."""

    def __init__(self):
        ca.Callback.__init__(self)
        self.calls = 0
        self.construct("kick", {"enable_fd": True})

    def get_n_in(self):
        return 1

    def get_n_out(self):
        return 1

    def eval(self, arg):
        self.calls += 1
        if self.calls == 3:
            os.kill(os.getpid(), signal.SIGINT)
        return [arg[0] ** 2]


def _kicked_solver():
    kick, x = _Kick(), ca.MX.sym("x")
    solver = ca.nlpsol("kicked", "ipopt", {"x": x, "f": kick(x - 1)}, {
        "ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes",
        "ipopt.hessian_approximation": "limited-memory"})
    return solver, kick


def test_casadi_swallows_the_interrupt_and_check_raises_it():
    """The premise, on the real IPOPT: a KeyboardInterrupt raised inside the solve does not
    reach Python (IPOPT reports NonIpopt_Exception_Thrown); the handler remembered it and
    :func:`interrupts.check` raises it; CasADi's notice of it is not printed."""
    solver, kick = _kicked_solver()
    err = io.StringIO()
    with redirect_stderr(err), interrupts.handling() as handler:
        solver(x0=5.0)
        assert kick.calls >= 3 and solver.stats()["return_status"] == "NonIpopt_Exception_Thrown"
        assert handler.signum == signal.SIGINT
        with pytest.raises(KeyboardInterrupt):
            interrupts.check()
    assert "KeyboardInterruptException" not in err.getvalue()
    interrupts.check()  # outside the command line's handler: nothing pending


def test_ctrl_c_inside_the_fits_ipopt_solve_exits_130_without_output(tmp_path, monkeypatch):
    """A fit whose bound binds goes through IPOPT; a Ctrl-C inside the solve made IPOPT return
    NonIpopt_Exception_Thrown and the fit failed "IPOPT did not solve the fit" (exit 1). Now
    exit 130, one line, no FIT.json and no temporary file."""
    from hse_opt.fit import solvers
    real = solvers._nlp_solver

    class Interrupted:
        """The fit's own solver, with a Ctrl-C arriving inside IPOPT during the call."""

        def __init__(self, solver):
            self.solver, (self.kicked, self.kick) = solver, _kicked_solver()  # the callback kept alive

        def __call__(self, **args):
            self.kicked(x0=5.0)      # the signal arrives inside IPOPT and is swallowed there
            return self.solver(**args)

        def stats(self):
            return self.kicked.stats()  # what IPOPT reports after swallowing it

    monkeypatch.setattr(solvers, "_nlp_solver", lambda *a: Interrupted(real(*a)))
    err, out = io.StringIO(), io.StringIO()
    with redirect_stderr(err), redirect_stdout(out):
        code = main(["fit", str(paper_table1_path()), "--bound", "offset=5:10", *FIX,
                     "-o", str(tmp_path / "F.json")])
    assert code == 130, err.getvalue()
    assert err.getvalue() == "hse-opt fit: interrupted; no output was written\n"
    assert os.listdir(tmp_path) == []


def _command(name, out, plan):
    return {"demo": ["demo", "--out", str(out / "D"), "--no-progress"],
            "fit": ["fit", str(paper_table1_path()), *FIX, "--bound", "offset=5:10", "-o", str(out / "F.json"),
                    "--report", str(out / "R")],
            "diagnose": ["diagnose", str(paper_table1_path()), *FIX, "--report", str(out / "R")],
            "design": ["design", "-o", str(out / "P.csv"), "--budget-h", "6"],
            "simulate": ["simulate", str(plan), "-o", str(out / "S.csv"), "--seed", "1"],
            "calibrate": ["calibrate", str(plan.parent / "logs"), "--out", str(out / "CAL"), "--no-progress"]}[name]


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    path = tmp_path_factory.mktemp("plan") / "PLAN.csv"
    rows = ["run,rate_dps,azimuth_deg,t_start_s,duration_s"]
    rows += [f"{k + 1},{(40, -40, 60)[k % 3]},{(k * 37) % 360},{k * 700},600" for k in range(60)]
    path.write_text("\n".join(rows) + "\n")
    # six 12-s raw logs for calibrate (seconds of work: the signal lands in it)
    small = path.parent / "SMALL.csv"
    small.write_text("run,rate_dps,azimuth_deg,t_start_s,duration_s\n" + "".join(
        f"{k + 1},{60 * (-1) ** k},{45 * k},{600 + 100 * k},12\n" for k in range(6)))
    (path.parent / "logs").mkdir()
    with redirect_stderr(io.StringIO()):
        assert main(["simulate", str(small), "-o", str(path.parent / "R.csv"), "--raw-logs", str(path.parent / "logs"),
                     "--no-progress"]) == 0
    return path


def _signal_at(argv, sig, delay, out, wait_for_temp=False):
    """Run ``hse-opt argv`` in a subprocess, send ``sig`` after ``delay`` s (or as soon as a
    temporary output appears in ``out``); returns (exit status, stderr)."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    # as the installed hse-opt script runs it
    p = subprocess.Popen([sys.executable, "-c", "import sys; from hse_opt.cli import main; sys.exit(main())", *argv],
                         stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True, env=env)
    if wait_for_temp:
        t0 = time.monotonic()
        while p.poll() is None and time.monotonic() - t0 < 120 and not any(TEMP_TAG in n for n in os.listdir(out)):
            time.sleep(0.0005)
    else:
        time.sleep(delay)
    p.send_signal(sig)
    _, err = p.communicate(timeout=180)
    return p.returncode, err


def _check(name, code, err, sig, out):
    left = sorted(str(p.relative_to(out)) for p in out.rglob("*"))
    if code in (0, -int(sig)):  # finished before the signal (or killed by it on the way out, the
        # handlers restored after the outputs were written): whole
        assert left and not [p for p in left if TEMP_TAG in p], (name, left)
        return "finished"
    what = "interrupted" if sig == signal.SIGINT else f"terminated (signal {int(sig)})"
    assert code == 128 + int(sig), (name, code, err)
    lines = err.strip("\n").split("\n")
    # (before the outputs were checked, the line says nothing about them)
    assert lines[-1] in (f"hse-opt {name}: {what}; no output was written", f"hse-opt {name}: {what}"), (name, err)
    # the one line of the interrupt, after the command's own progress lines (never a traceback)
    assert "Traceback" not in err and "Exception ignored" not in err and "KeyboardInterrupt" not in err, err
    assert sum(what in line for line in lines) == 1, err
    assert left == [], (name, left)
    return "stopped"


@pytest.mark.slow
@pytest.mark.parametrize("name", ["demo", "calibrate", "fit", "diagnose", "design", "simulate"])
def test_signals_at_random_delays_stop_every_command_cleanly(tmp_path, plan, name):
    """Each command gets SIGINT or SIGTERM at a delay from a seeded generator (from start-up
    to well into the computation: the demo's IPOPT and report included)."""
    rng = np.random.default_rng(sum(map(ord, name)))
    long = name in ("demo", "calibrate")
    cases = [(signal.SIGINT, rng.uniform(0.5, 3.5))] + [(signal.SIGTERM, rng.uniform(0.5, 3.5))] * long
    if not long and rng.integers(2):
        cases = [(signal.SIGTERM, cases[0][1])]
    for k, (sig, delay) in enumerate(cases):
        out = tmp_path / f"case{k}"
        out.mkdir()
        code, err = _signal_at(_command(name, out, plan), sig, delay, out)
        outcome = _check(name, code, err, sig, out)
        assert outcome == "stopped" or not long  # these run for seconds: the signal lands in them


@pytest.mark.slow
def test_sigterm_as_simulate_writes_its_output(tmp_path, plan):
    """SIGTERM the moment simulate's temporary output appears (before: once in 10 'Exception
    ignored in: tqdm.__del__ ... Terminated: 15'): exit 143, one line, no file left."""
    for k in range(2):
        out = tmp_path / f"case{k}"
        out.mkdir()
        argv = ["simulate", str(plan), "-o", str(out / "S.csv"), "--seed", str(k)]
        code, err = _signal_at(argv, signal.SIGTERM, 0.0, out, wait_for_temp=True)
        _check("simulate", code, err, signal.SIGTERM, out)


@pytest.mark.slow
def test_python_dash_m_demo_exits_130_under_sigint_at_about_one_second(tmp_path):
    """``python -m hse_opt.cli demo`` with SIGINT at 0.85-1.15 s, where it lands in an import:
    before, one run in three printed the right line and then died by the signal (-2: CPython
    kills a ``python -m`` run whose code once let a KeyboardInterrupt escape); now exit 130
    each time (twelve runs: 0.8 % to pass by luck at the old rate), nothing written."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    for k, delay in enumerate(np.linspace(0.85, 1.15, 12)):
        out = tmp_path / f"case{k}"
        out.mkdir()
        p = subprocess.Popen([sys.executable, "-m", "hse_opt.cli", "demo", "--out", str(out / "D"), "--no-progress"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
        time.sleep(delay)
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=180)
        # (on a loaded machine the signal may land before the command is named: 'hse-opt: interrupted')
        assert p.returncode == 130, (delay, p.returncode, err)
        assert err.strip("\n").split("\n")[-1] in ("hse-opt demo: interrupted; no output was written",
                                                   "hse-opt demo: interrupted", "hse-opt: interrupted"), err
        assert "Traceback" not in err and list(out.rglob("*")) == [], (err, list(out.rglob("*")))
