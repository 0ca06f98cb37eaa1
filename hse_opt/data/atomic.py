"""Outputs written whole or not at all: a temporary file beside the target, fsync, rename; the
leftovers of killed processes recognised and removed."""
from __future__ import annotations

import contextlib
import os
import re
import secrets

__all__ = ["atomic_path", "write_text_atomic", "temp_path", "remove_leftovers", "fsync_folder", "TEMP_TAG"]


def write_text_atomic(path, text):
    """Write ``text`` (UTF-8) to ``path`` whole or not at all (temporary file, fsync, rename)."""
    _atomic(path, lambda fh: fh.write(text))


#: marks the temporary files and folders of a write in progress: ``.NAME.hse-opt-tmp-PID-TOKEN``
#: (+ the target's suffix), beside the target; :func:`remove_leftovers` removes those of dead processes
TEMP_TAG = ".hse-opt-tmp-"
_LEFTOVER = re.compile(r"^\..*" + re.escape(TEMP_TAG) + r"(\d+)-[0-9a-f]{12}(\.[^.]*)?$")


def temp_path(target):
    """A fresh temporary path beside ``target`` (same folder, same suffix), recognisable as ours:
    the pid of the writer is in the name, so a file left by a killed process can be told from
    one being written (:func:`remove_leftovers`)."""
    directory, name = os.path.split(os.path.abspath(os.fspath(target)))
    return os.path.join(directory, f".{name}{TEMP_TAG}{os.getpid()}-{secrets.token_hex(6)}"
                                   f"{os.path.splitext(name)[1]}")


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # e.g. another user's process
        return True
    return True


def remove_leftovers(directory):
    """Remove the temporary files and folders (:func:`temp_path`) that processes killed with
    SIGKILL (which no program can catch) left in ``directory``; those of running processes stay.

    Returns
    -------
    list of str
        The paths removed.
    """
    import shutil
    removed = []
    try:
        names = os.listdir(directory)
    except OSError:
        return removed
    for name in names:
        m = _LEFTOVER.match(name)
        if m is None or _alive(int(m.group(1))):
            continue
        path = os.path.join(directory, name)
        with contextlib.suppress(OSError):
            if os.path.isdir(path) and not os.path.islink(path):
                shutil.rmtree(path)
            else:
                os.unlink(path)
            removed.append(path)
    return removed


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path next to ``path`` (same suffix, :func:`temp_path`) to write; on
    success it is fsynced and renamed over ``path``, on any error (and on KeyboardInterrupt or
    a signal turned into an exception) removed, ``path`` untouched. The file gets the mode of
    the file it replaces, else the usual one (0666 less the umask)."""
    target = os.path.abspath(os.fspath(path))
    directory = os.path.dirname(target)
    if not os.path.isdir(directory):
        raise FileNotFoundError(f"{os.fspath(path)}: cannot write: the folder {directory} does not exist; "
                                "allowed: a path in an existing folder")
    tmp = temp_path(target)
    try:  # created inside: a signal that lands right after the creation still removes it
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        with contextlib.suppress(FileNotFoundError):
            os.chmod(tmp, os.stat(target).st_mode & 0o7777)
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    fsync_folder(directory)


def fsync_folder(directory):
    """Make renames in ``directory`` durable where the platform allows it."""
    with contextlib.suppress(OSError):
        dir_fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)


def _atomic(path, write):
    """Call ``write(fh)`` on a text file written through :func:`atomic_path`."""
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        write(fh)

