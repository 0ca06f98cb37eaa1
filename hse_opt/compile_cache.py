"""Compile a CasADi Function to C once, and keep the compiled library on disk.

:func:`compiled` turns a numeric CasADi Function (for instance a ``Function.map`` of the
measurement model over a chunk of runs) into the same Function evaluated by machine code:
CasADi generates its C source, the C compiler builds a shared library, and
``casadi.external`` loads it. The library is kept in a cache folder, named by a hash of

- the Function's serialisation (its whole expression graph, so a changed model, chunk size
  or parameter set is a new entry),
- the CasADi version, the compiler (its resolved path, size and modification time) and the
  compiler flags, and the platform,

so a model is compiled once per machine, not once per process. Within a process the loaded
Function is kept too: asking twice for the same Function compiles and loads it once.

Where
    ``$HSE_OPT_CACHE_DIR`` when set; otherwise the user's cache folder:
    ``$XDG_CACHE_HOME/hse_opt`` (default ``~/.cache/hse_opt``) on Linux,
    ``~/Library/Caches/hse_opt`` on macOS, ``%LOCALAPPDATA%\\hse_opt\\Cache`` on Windows.
    The libraries are in its ``casadi/`` folder (built measurement models in ``models/``,
    :mod:`hse_opt.model.cache`); deleting the folder empties the cache.
``HSE_OPT_NO_CACHE=1``
    Nothing is read from or written to the cache: every process compiles what it uses (in a
    temporary folder of the system's, removed once the library is loaded).
``CC``
    The C compiler (default ``gcc``, else ``cc``).

Safety: the C source, the object files and the library are written in a fresh temporary
folder inside the cache (never in the working folder) and the finished library is moved into
place with one atomic rename, so two processes that compile the same Function at once both
end with a whole library, and a killed compile leaves only its temporary folder, which a later
compile removes once it is an hour old. When no compiler works, :func:`compiled` warns and
returns the Function uncompiled (CasADi's virtual machine, the same numbers, slower).
"""
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path

import casadi as ca

#: compiler flags; part of the cache key
FLAGS = ("-O3", "-fPIC", "-shared")
#: a temporary build folder older than this (s) belongs to a killed compile
_STALE_S = 3600.0
_SUFFIX = {"win32": ".dll", "darwin": ".dylib"}.get(sys.platform, ".so")

_lock = threading.Lock()
_loaded = {}      # key -> loaded Function (this process)
_compiler = []    # [(path, identity)] once found


def cache_dir():
    """The cache folder (``$HSE_OPT_CACHE_DIR`` or the user's cache folder), not created."""
    env = os.environ.get("HSE_OPT_CACHE_DIR")
    if env:
        return Path(env).expanduser()
    home = Path.home()
    if sys.platform == "win32":
        return Path(os.environ.get("LOCALAPPDATA") or home / "AppData" / "Local") / "hse_opt" / "Cache"
    if sys.platform == "darwin":
        return home / "Library" / "Caches" / "hse_opt"
    return Path(os.environ.get("XDG_CACHE_HOME") or home / ".cache") / "hse_opt"


def enabled():
    """False when ``HSE_OPT_NO_CACHE`` is set to anything but ``""``/``0``."""
    return os.environ.get("HSE_OPT_NO_CACHE", "") in ("", "0")


def _find_compiler():
    """``(path, identity)`` of the C compiler; identity changes when the compiler does."""
    if not _compiler:
        for name in filter(None, (os.environ.get("CC"), "gcc", "cc")):
            path = shutil.which(name)
            if path:
                real = os.path.realpath(path)
                st = os.stat(real)
                _compiler.append((path, f"{real}:{st.st_size}:{st.st_mtime_ns}"))
                break
        else:
            _compiler.append((None, None))
    return _compiler[0]


def key(f, graph=None):
    """The cache key of Function ``f`` (hex digest; see the module docstring). ``graph``: a
    string that determines ``f`` as its serialisation does (e.g. the digest of a mapped
    Function's inner serialisation with the map's options), to spare serialising ``f``."""
    _, identity = _find_compiler()
    h = hashlib.sha256()
    for part in (ca.__version__, str(identity), " ".join(FLAGS), sys.platform, platform.machine(),
                 f.serialize() if graph is None else f"{f.name()}|{graph}"):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()[:40]


def available(f, graph=None):
    """Whether :func:`compiled` would return ``f`` without compiling: loaded in this process
    or in the disk cache (and the cache is on)."""
    k = key(f, graph)
    if k in _loaded:
        return True
    return enabled() and (cache_dir() / "casadi" / f"{f.name()}-{k}{_SUFFIX}").is_file()


def compiled(f, graph=None):
    """``f`` evaluated by compiled C: from this process's memory, else the disk cache, else
    compiled now (and cached). Returns ``f`` itself, with a warning, when compiling fails.
    ``graph``: see :func:`key`."""
    k = key(f, graph)
    with _lock:
        if k not in _loaded:
            _loaded[k] = _load_or_build(f, k)
        return _loaded[k]


def _load_or_build(f, k):
    compiler, _ = _find_compiler()
    use_cache = enabled()
    folder = cache_dir() / "casadi"
    lib = folder / f"{f.name()}-{k}{_SUFFIX}"
    if use_cache and lib.is_file():
        try:
            return ca.external(f.name(), str(lib))
        except RuntimeError:  # unreadable or truncated by hand: build it anew
            pass
    if compiler is None:
        warnings.warn("no C compiler (gcc or cc; set CC) found: CasADi Functions are evaluated "
                      "without compiling them", RuntimeWarning, stacklevel=4)
        return f
    try:
        if use_cache:
            folder.mkdir(parents=True, exist_ok=True)
            _remove_stale(folder)
            build = Path(tempfile.mkdtemp(prefix=".build-", dir=folder))
        else:
            build = Path(tempfile.mkdtemp(prefix="hse_opt-build-"))
    except OSError as err:
        warnings.warn(f"cannot write the compile cache {folder} ({err.strerror}); compiling in a "
                      f"temporary folder (set HSE_OPT_CACHE_DIR)", RuntimeWarning, stacklevel=4)
        use_cache = False
        build = Path(tempfile.mkdtemp(prefix="hse_opt-build-"))
    try:
        source = "code.c"
        gen = ca.CodeGenerator(source, {"with_header": False})
        gen.add(f)
        gen.generate(f"{build}{os.sep}")
        out = build / f"lib{_SUFFIX}"
        run = subprocess.run([compiler, *FLAGS, source, "-o", out.name, "-lm"], cwd=build,
                             capture_output=True, text=True)
        if run.returncode != 0:
            raise RuntimeError(f"{compiler} exited with {run.returncode}: {run.stderr.strip()[:500]}")
        if use_cache:
            os.replace(out, lib)  # atomic: a reader sees no library or the whole library
            out = lib
        return ca.external(f.name(), str(out))
    except (OSError, RuntimeError) as err:
        warnings.warn(f"compiling the CasADi Function {f.name()!r} failed, evaluating it without "
                      f"compiling: {err}", RuntimeWarning, stacklevel=4)
        return f
    finally:
        shutil.rmtree(build, ignore_errors=True)


def _remove_stale(folder):
    """Remove the temporary build folders that killed compiles left behind."""
    now = time.time()
    for entry in folder.glob(".build-*"):
        try:
            if now - entry.stat().st_mtime > _STALE_S:
                shutil.rmtree(entry, ignore_errors=True)
        except OSError:
            pass
