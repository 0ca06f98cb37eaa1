"""The outputs of one command, as one transaction: checked before anything runs, written
together or not at all.

A command module declares what it reads and writes::

    INPUTS = ("runs", "prior")                    # argparse dests holding input paths
    OUTPUTS = {"output": FILE, "report": REPORT}  # dest -> FILE, or the file names a folder gets
                                                  # (or a function returning them; a name
                                                  # ending in "/" is a subfolder, replaced whole)

and :func:`hse_opt.cli.main` opens a :class:`Transaction` around ``run(args)``:

* Before the command runs, every output given is checked: a path (a file output names a file;
  a folder output is a folder or does not exist yet), in an existing, writable folder, not an
  existing non-regular file (``/dev/null``), not an input (same resolved path or the same file
  through a hard link), and distinct from every other output (a folder's files included).
  A failure is a ``ValueError`` naming the option and what is allowed (exit 2): nothing has
  been computed or written.
* The command writes each output to ``args.tx.path(dest)``: a temporary file, or a temporary
  folder, beside the target (:func:`hse_opt.data.temp_path`, recognisable names).
* When the command returns, all of them are renamed into place in one burst with the
  termination signals blocked; a new folder appears whole by one rename, an existing folder
  gets its files replaced (files of its declared set that were not written this time are
  removed; other files in it are left alone). On any error, Ctrl-C or SIGTERM the temporary
  files are removed and no target is touched. Leftovers of a process killed with SIGKILL are
  removed by the next command writing into the same folder (:func:`hse_opt.data.remove_leftovers`).
"""
from __future__ import annotations

import contextlib
import os
import shutil
import signal
import stat

#: an output that is one file
FILE = None
#: the ``--report DIR`` folder
REPORT = ("report.html",)
#: signals blocked while the outputs are renamed into place
_SIGNALS = {s for s in (getattr(signal, n, None) for n in ("SIGINT", "SIGTERM", "SIGHUP")) if s is not None}


def _label(parser, dest):
    """How the user names the option of ``dest`` (``-o``, ``--report``, ``RUNS.csv``)."""
    for action in parser._actions:
        if action.dest == dest:
            return action.option_strings[0] if action.option_strings else (action.metavar or dest)
    return dest


def _same(a, b):
    """Whether paths ``a`` and ``b`` are one file: equal resolved paths, or one inode (hard links)."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _replace_folder(src, dst):
    """Put folder ``src`` (when it exists) in the place of folder ``dst`` (removed when ``src``
    does not exist): the old one is renamed aside first, then removed."""
    from ...data import temp_path
    old = None
    if os.path.isdir(dst):
        old = temp_path(dst)
        os.rename(dst, old)
    if os.path.isdir(src):
        os.rename(src, dst)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


class Transaction:
    """The outputs of one command run (see the module docstring).

    Parameters
    ----------
    inputs : list of (str, str)
        (option label, path) of every input file given.
    outputs : list of (str, str, str, tuple or None)
        (dest, option label, path, FILE or a folder's file names) of every output given.
    """

    def __init__(self, inputs, outputs):
        self.inputs = [(opt, os.fspath(p)) for opt, p in inputs]
        self.outputs = {dest: (opt, os.fspath(p), files) for dest, opt, p, files in outputs}
        self._staged = {}
        self.committed = False

    @classmethod
    def from_args(cls, args, module, parser):
        """The transaction of ``module``'s declared INPUTS / OUTPUTS with the values in ``args``."""
        inputs = []
        for dest in getattr(module, "INPUTS", ()):
            value = getattr(args, dest, None)
            for path in value if isinstance(value, (list, tuple)) else [value]:
                if path:
                    inputs.append((_label(parser, dest), path))
        outputs = [(dest, _label(parser, dest), getattr(args, dest), files() if callable(files) else files)
                   for dest, files in getattr(module, "OUTPUTS", {}).items() if getattr(args, dest, None) is not None]
        return cls(inputs, outputs)

    # -- before the command runs ---------------------------------------------------------
    def check(self):
        """Raise ``ValueError`` naming the first output that cannot be written, and remove the
        leftovers of killed runs in the output folders."""
        from ...data import remove_leftovers
        claimed = []  # (option, path): every output path and every file a folder output gets

        def claim(opt, path, w):
            for other_opt, other in claimed:
                if _same(w, other):
                    raise ValueError(f"{opt} {path}: is also the output of {other_opt}; allowed: distinct paths")
            claimed.append((opt, w))

        for opt, path, files in self.outputs.values():
            what = "a file path" if files is FILE else "a folder (created when missing)"
            if not path.strip() or path.endswith(os.sep) and files is FILE:
                raise ValueError(f"{opt} {path!r}: allowed: {what}")
            target = os.path.abspath(path)
            folder = os.path.dirname(target)
            if not os.path.isdir(folder):
                raise ValueError(f"{opt} {path}: the folder {folder} does not exist; allowed: {what} in an "
                                 "existing folder")
            if not os.access(folder, os.W_OK | os.X_OK):
                raise ValueError(f"{opt} {path}: the folder {folder} is not writable; allowed: {what} in a "
                                 "folder you can write")
            if files is FILE:
                if os.path.isdir(target):
                    raise ValueError(f"{opt} {path}: is a folder; allowed: a file path")
                written = [target]
            else:
                if os.path.exists(target) and not os.path.isdir(target):
                    raise ValueError(f"{opt} {path}: is a file; allowed: a folder (created when missing)")
                if os.path.isdir(target) and not os.access(target, os.W_OK | os.X_OK):
                    raise ValueError(f"{opt} {path}: the folder is not writable; allowed: a folder you can "
                                     "write")
                claim(opt, path, target)
                written = [os.path.join(target, f) for f in files]
            for w in written:
                with contextlib.suppress(FileNotFoundError):
                    if w.endswith("/"):  # a subfolder of a folder output
                        if not stat.S_ISDIR(os.stat(w).st_mode):
                            raise ValueError(f"{opt} {path}: {w.rstrip('/')} exists and is not a folder; allowed: "
                                             "a new path or a folder to replace")
                        continue
                    if not stat.S_ISREG(os.stat(w).st_mode):
                        raise ValueError(f"{opt} {path}: {w} exists and is not a regular file; allowed: a "
                                         "new path or a regular file to replace")
                for in_opt, in_path in self.inputs:
                    if _same(w, in_path):
                        raise ValueError(f"{opt} {path}: would overwrite the input {in_path} ({in_opt}); "
                                         "allowed: another path")
                claim(opt, path, w)
        for opt, path, files in self.outputs.values():
            remove_leftovers(os.path.dirname(os.path.abspath(path)))
            if files is not FILE and os.path.isdir(path):
                remove_leftovers(path)
        return self

    # -- while it runs -------------------------------------------------------------------
    def path(self, dest):
        """Where the command writes output ``dest`` (a temporary file, or a temporary folder
        that exists): it is renamed into place at :meth:`commit`."""
        from ...data import temp_path
        if dest not in self._staged:
            opt, target, files = self.outputs[dest]
            tmp = temp_path(target)
            self._staged[dest] = tmp  # first: a signal right after the mkdir still removes it
            if files is not FILE:
                os.mkdir(tmp)
        return self._staged[dest]

    def target(self, dest):
        """The path the user gave for output ``dest``."""
        return self.outputs[dest][1]

    # -- after -------------------------------------------------------------------------------
    def commit(self):
        """Rename every staged output into place, the termination signals held meanwhile."""
        from ...data import fsync_folder
        old = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS) if _SIGNALS else None
        try:
            for dest, tmp in self._staged.items():
                opt, target, files = self.outputs[dest]
                if files is FILE:
                    if os.path.exists(tmp):
                        os.replace(tmp, target)
                elif not os.path.exists(target):
                    os.rename(tmp, target)
                else:
                    for name in files:
                        src = os.path.join(tmp, name)
                        if name.endswith("/"):
                            _replace_folder(src.rstrip("/"), os.path.join(target, name.rstrip("/")))
                        elif os.path.exists(src):
                            os.replace(src, os.path.join(target, name))
                        else:
                            with contextlib.suppress(FileNotFoundError):
                                os.unlink(os.path.join(target, name))
                    for name in os.listdir(tmp):  # anything the command wrote beyond its declared set
                        os.replace(os.path.join(tmp, name), os.path.join(target, name))
                    os.rmdir(tmp)
                fsync_folder(os.path.dirname(os.path.abspath(target)))
            self._staged.clear()
            self.committed = True
        finally:
            if old is not None:
                signal.pthread_sigmask(signal.SIG_SETMASK, old)

    def abort(self):
        """Remove whatever was staged, the termination signals held meanwhile (a second Ctrl-C
        does not leave half of it); no target is touched."""
        old = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS) if _SIGNALS else None
        try:
            for tmp in self._staged.values():
                with contextlib.suppress(OSError):  # FileNotFoundError too: staged, not yet created
                    if os.path.isdir(tmp):
                        shutil.rmtree(tmp)
                    else:
                        os.unlink(tmp)
            self._staged.clear()
        finally:
            if old is not None:
                signal.pthread_sigmask(signal.SIG_SETMASK, old)

    def __enter__(self):
        return self

    def __exit__(self, kind, value, tb):
        if kind is None or issubclass(kind, BrokenPipeError):  # a closed stdout: the work is done
            self.commit()
        else:
            self.abort()
        return False
