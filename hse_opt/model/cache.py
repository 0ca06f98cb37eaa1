"""Keep built measurement models on disk, so a new process does not build them again.

Building a :class:`~hse_opt.model.measurement.MeasurementModel` (the symbolic chain of every
effect, its Jacobian, the tilt-coupling check) takes 25-30 ms for the paper's model, more
than a fit of 10,000 runs once it is built. :func:`load_or_build` keeps the built model's
CasADi Functions (serialised) and records in the compile cache's folder
(:mod:`hse_opt.compile_cache`: ``models/`` beside ``casadi/``; ``HSE_OPT_CACHE_DIR`` moves
it, ``HSE_OPT_NO_CACHE=1`` turns it off) and loads them in later processes.

An entry is found by a hash of everything the built model depends on:

- the hse_opt version and a stamp of every source file of the installed package (path,
  size, modification time), the CasADi and Python versions;
- per effect: its class (module and name), its state (pickled: name, parameter records,
  columns, orders) and, for an effect defined outside hse_opt, a stamp of its module's file;
- the geometry (r_zb^s, K_g) and the tilt mode.

A model whose effects cannot be stamped (a class defined interactively, without a source
file, or with state that does not pickle) is built every time and never cached. Entries are
written to a temporary file and renamed into place (two processes may write the same entry);
an unreadable entry is rebuilt.
"""
import hashlib
import os
import pickle
import sys
import tempfile
from pathlib import Path

import casadi as ca

from .. import __version__
from ..compile_cache import cache_dir, enabled

__all__ = ["load_or_build", "fingerprint"]

_PACKAGE = Path(__file__).resolve().parents[1]
_stamp = []


def _file_stamp(path):
    st = os.stat(path)
    return f"{path}:{st.st_size}:{st.st_mtime_ns}"


def _package_stamp():
    """A hash of every ``.py`` file of the installed hse_opt (path, size, mtime); once per process."""
    if not _stamp:
        h = hashlib.sha256()
        for root, dirs, files in os.walk(_PACKAGE):
            dirs[:] = sorted(d for d in dirs if d != "__pycache__")
            for name in sorted(files):
                if name.endswith(".py"):
                    h.update(_file_stamp(os.path.join(root, name)).encode())
        _stamp.append(h.hexdigest())
    return _stamp[0]


def fingerprint(model, tilt_known):
    """The cache key of ``model.measurement(tilt_known)``, or None when it cannot be stamped."""
    h = hashlib.sha256()
    for part in (__version__, ca.__version__, sys.version, _package_stamp(), str(bool(tilt_known)),
                 model.geometry.r_zb_s.tobytes().hex(), model.geometry.K_g.tobytes().hex()):
        h.update(str(part).encode())
        h.update(b"\0")
    for e in model.effects:
        cls = type(e)
        module = sys.modules.get(cls.__module__)
        path = getattr(module, "__file__", None)
        if path is None or "<locals>" in cls.__qualname__:
            return None
        path = Path(path).resolve()
        try:
            state = pickle.dumps(e, protocol=4)
        except Exception:  # noqa: BLE001 - any effect state that does not pickle: no caching
            return None
        h.update(f"{cls.__module__}.{cls.__qualname__}".encode())
        if _PACKAGE not in path.parents:
            h.update(_file_stamp(path).encode())
        h.update(state)
        h.update(b"\0")
    return h.hexdigest()[:40]


def load_or_build(build, model, tilt_known):
    """``build(model, tilt_known)`` or its cached result (a MeasurementModel)."""
    key = fingerprint(model, tilt_known) if enabled() else None
    if key is None:
        return build(model, tilt_known)
    path = cache_dir() / "models" / f"{key}.pkl"
    try:
        with open(path, "rb") as f:
            return pickle.load(f).attach(model)
    except FileNotFoundError:
        pass
    except Exception:  # noqa: BLE001 - a truncated or foreign entry: build it anew
        pass
    built = build(model, tilt_known)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".model-", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as f:
                pickle.dump(built, f, protocol=4)
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    except OSError:
        pass  # a read-only or full cache folder: the model is still built
    return built
