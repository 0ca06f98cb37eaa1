"""Outputs of the commands (hse_opt/commands/outputs.py): every output checked before anything
runs, inputs never overwritten, several outputs written together or not at all, temporary
files removed on errors and signals, leftovers of SIGKILL removed by the next run.

References are the files on disk: checksums before and after, directory listings."""
import hashlib
import io
import os
import signal
import subprocess
import sys
import textwrap
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import pytest

from hse_opt.cli import main
from hse_opt.commands.outputs import FILE, REPORT, Transaction
from hse_opt.data import TEMP_TAG, temp_path
from hse_opt.datasets import paper_table1_path

TABLE1 = str(paper_table1_path())
FIX = ["--fix", "lambda2*tilt_const=0"]
PLAN = "run,rate_dps,azimuth_deg,t_start_s,duration_s\n1,40,0,0,60\n2,-40,90,100,60\n"


def snapshot(folder):
    """{relative path: sha256} of every file under ``folder``."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(Path(folder).rglob("*")) if p.is_file()}


def run(argv):
    err, out = io.StringIO(), io.StringIO()
    with redirect_stderr(err), redirect_stdout(out):
        code = main([str(a) for a in argv])
    return code, err.getvalue()


@pytest.fixture
def work(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "T1.csv").write_bytes(Path(TABLE1).read_bytes())
    (tmp_path / "P.csv").write_text(PLAN)
    os.link(tmp_path / "T1.csv", tmp_path / "hard.csv")
    os.symlink("T1.csv", tmp_path / "sym.csv")
    (tmp_path / "AFILE").write_text("a file\n")
    (tmp_path / "adir").mkdir()
    assert run(["fit", "T1.csv", *FIX, "-o", "F.json"])[0] == 0
    return tmp_path


# (argv, option named in the message, what the message says)
REFUSED = [
    (["fit", "T1.csv", *FIX, "-o", "T1.csv"], "-o T1.csv", "would overwrite the input"),
    (["fit", "T1.csv", *FIX, "-o", "hard.csv"], "-o hard.csv", "would overwrite the input"),  # hard link
    (["fit", "T1.csv", *FIX, "-o", "sym.csv"], "-o sym.csv", "would overwrite the input"),    # symlink
    (["fit", "T1.csv", *FIX, "-o", "X.json", "--prior", "F.json", "--report", "F.json"], "--report F.json",
     "is a file"),
    (["fit", "T1.csv", *FIX, "-o", "N.json", "--report", "N.json"], "--report N.json", "also the output of -o"),
    (["fit", "T1.csv", *FIX, "-o", "N.json", "--report", "AFILE"], "--report AFILE", "is a file"),
    (["fit", "T1.csv", *FIX, "-o", "nodir/X.json"], "-o nodir/X.json", "nodir does not exist"),
    (["fit", "T1.csv", *FIX, "-o", "adir"], "-o adir", "is a folder"),
    (["fit", "T1.csv", *FIX, "-o", "/dev/null"], "-o /dev/null", "not a regular file"),
    (["compensate", "T1.csv", "--fit", "F.json", "-o", "F.json"], "-o F.json", "would overwrite the input"),
    (["compensate", "T1.csv", "--fit", "F.json", "-o", "nodir/X.csv"], "-o nodir/X.csv", "does not exist"),
    (["compensate", "T1.csv", "--fit", "F.json", "-o", ""], "-o ''", "allowed: a file path"),
    (["simulate", "P.csv", "-o", "S.csv", "--write-truth", ""], "--write-truth ''", "allowed: a file path"),
    (["simulate", "P.csv", "-o", "P.csv"], "-o P.csv", "would overwrite the input"),
    (["simulate", "P.csv", "-o", "S.csv", "--write-truth", "S.csv"], "--write-truth S.csv",
     "also the output of -o"),
    (["simulate", "P.csv", "-o", "S.csv", "--write-truth", "nodir/T.toml"], "--write-truth nodir/T.toml",
     "does not exist"),
    (["design", "--budget-h", "2", "-o", "N.csv", "--report", "AFILE"], "--report AFILE", "is a file"),
    (["design", "--budget-h", "2", "-o", "nodir/P.csv"], "-o nodir/P.csv", "does not exist"),
    (["design", "--budget-h", "2", "-o", "F.json", "--prior", "F.json"], "-o F.json", "would overwrite"),
    (["diagnose", "T1.csv", *FIX, "--report", "AFILE"], "--report AFILE", "is a file"),
    (["demo", "--out", "AFILE"], "--out AFILE", "is a file"),
    (["demo", "--out", "nodir/demo"], "--out nodir/demo", "does not exist"),
]


@pytest.mark.parametrize("argv, option, text", REFUSED, ids=[" ".join(a) for a, _, _ in REFUSED])
def test_bad_outputs_are_refused_before_anything_is_written(work, argv, option, text):
    before = snapshot(work)
    code, err = run(argv)
    assert code == 2
    assert err.count("\n") == 1 and f"error: {option}: " in err and text in err, err
    assert "None" not in err
    assert snapshot(work) == before  # inputs unchanged, nothing new (no temporary file either)


def test_several_outputs_appear_together(work):
    code, _ = run(["fit", "T1.csv", *FIX, "-o", "N.json", "--report", "rep"])
    assert code == 0
    assert (work / "N.json").is_file() and (work / "rep" / "report.html").is_file()
    assert not [p for p in os.listdir(work) if TEMP_TAG in p]


def test_a_failure_after_one_output_was_written_leaves_none(tmp_path):
    """The transaction itself: one output staged and written, then an error -- nothing appears;
    the same with success -- both appear, a new folder by one rename."""
    tx = Transaction([], [("output", "-o", tmp_path / "a.csv", FILE), ("report", "--report", tmp_path / "r", REPORT)])
    with pytest.raises(RuntimeError), tx.check():
        Path(tx.path("output")).write_text("a")
        raise RuntimeError("solver failed after the first output")
    assert os.listdir(tmp_path) == []
    with Transaction([], [("output", "-o", tmp_path / "a.csv", FILE),
                          ("report", "--report", tmp_path / "r", REPORT)]).check() as tx:
        Path(tx.path("output")).write_text("a")
        Path(tx.path("report"), "report.html").write_text("r")
    assert sorted(os.listdir(tmp_path)) == ["a.csv", "r"] and os.listdir(tmp_path / "r") == ["report.html"]


def test_an_existing_folder_gets_its_declared_files_replaced_and_stale_ones_removed(tmp_path):
    out = tmp_path / "demo"
    out.mkdir()
    for name, text in (("RUNS.csv", "old"), ("NEXT_PLAN.csv", "old"), ("notes.txt", "mine")):
        (out / name).write_text(text)
    files = ("RUNS.csv", "NEXT_PLAN.csv")
    with Transaction([], [("out", "--out", out, files)]).check() as tx:
        Path(tx.path("out"), "RUNS.csv").write_text("new")   # NEXT_PLAN.csv not written this time
        assert (out / "RUNS.csv").read_text() == "old"      # nothing moves before the end
    assert snapshot(out).keys() == {"RUNS.csv", "notes.txt"}
    assert (out / "RUNS.csv").read_text() == "new" and (out / "notes.txt").read_text() == "mine"


def _child(code, tmp_path):
    """Run ``code`` in a fresh interpreter in ``tmp_path``; return (exit status, stderr)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).parents[1]),
                                                        os.environ.get("PYTHONPATH", "")])}
    p = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=600)
    return p.returncode, p.stderr


@pytest.mark.parametrize("signame, status", [("SIGINT", 130), ("SIGTERM", 143)])
def test_a_signal_while_writing_removes_the_temporary_files_and_exits_with_one_line(tmp_path, signame, status):
    """The signal is sent by the command to itself right after the first output (RUNS.csv) was
    written to its temporary file, before the second (--write-truth): a real signal, delivered
    at a known point."""
    (tmp_path / "P.csv").write_text(PLAN)
    code, err = _child(f"""
        import os, signal, sys
        import hse_opt.data as data
        from hse_opt.cli import main
        save = data.save_runs
        def save_then_signal(runs, path):
            save(runs, path)
            assert os.path.exists(path)
            os.kill(os.getpid(), signal.{signame})
        data.save_runs = save_then_signal
        sys.exit(main(["simulate", "P.csv", "-o", "S.csv", "--write-truth", "T.toml", "--no-progress"]))
        """, tmp_path)
    assert code == status
    assert err.count("\n") == 1 and "no output was written" in err and "Traceback" not in err, err
    assert sorted(os.listdir(tmp_path)) == ["P.csv"]


def test_leftovers_of_a_killed_run_are_removed_by_the_next_one(tmp_path, work):
    code, _ = _child("""
        import os, signal, sys
        import hse_opt.data as data
        from hse_opt.cli import main
        save = data.save_runs
        def save_then_die(runs, path):
            save(runs, path)
            os.kill(os.getpid(), signal.SIGKILL)
        data.save_runs = save_then_die
        main(["compensate", "T1.csv", "--fit", "F.json", "-o", "C.csv"])
        """, work)
    assert code == -signal.SIGKILL
    left = [p for p in os.listdir(work) if TEMP_TAG in p]
    assert len(left) == 1 and left[0].startswith(".C.csv" + TEMP_TAG) and left[0].endswith(".csv")
    mine = Path(temp_path(work / "C.csv"))  # a live process's (ours) temporary file stays
    mine.write_text("being written")
    assert run(["compensate", "T1.csv", "--fit", "F.json", "-o", "C.csv"])[0] == 0
    assert [p for p in os.listdir(work) if TEMP_TAG in p] == [mine.name]
    assert (work / "C.csv").is_file()
