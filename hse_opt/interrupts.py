"""Interrupts that stick: Ctrl-C and termination signals end a command even when they arrive
inside a solver written in C.

Python runs a signal handler between bytecodes; an exception it raises inside a call into C
reaches whatever that C code does with it. CasADi turns it into its own exception, which IPOPT
catches and reports as the status ``NonIpopt_Exception_Thrown`` (the fit then failed "with a
solver status", not interrupted); a KeyboardInterrupt raised in a weak-reference callback or a
destructor (matplotlib's transforms, tqdm) is printed as "Exception ignored" and dropped, and
the command went on to write every output and exit 0.

So the command line installs a :class:`Handler` for SIGINT, SIGTERM and SIGHUP
(:func:`handling`) that raises *and remembers* the signal, and the signal is raised again
where it may have been swallowed:

* :func:`check` after each call into a solver in C (CasADi's ``nlpsol``, cvxpy's ``solve``),
  so the command stops there;
* the command line calls it when the command returns or fails, before any output is renamed
  into place (:mod:`hse_opt.commands.outputs`): the exit status is 130 (Ctrl-C) or 128 + the
  signal, and nothing is written.

Without the command line's handler (the library used from Python) :func:`check` does nothing:
a KeyboardInterrupt is then the caller's.
"""
from __future__ import annotations

import contextlib
import signal
import sys
import threading

__all__ = ["Terminated", "Handler", "handling", "check", "pending", "forget_escaped_interrupt"]

#: the signals a command turns into exceptions (those the platform has)
SIGNALS = tuple(s for s in (getattr(signal, n, None) for n in ("SIGINT", "SIGTERM", "SIGHUP")) if s is not None)


class Terminated(BaseException):
    """A termination signal (SIGTERM, SIGHUP) turned into an exception, so that temporary
    outputs are removed on the way out (like KeyboardInterrupt for SIGINT)."""

    def __init__(self, signum):
        super().__init__(signum)
        self.signum = signum


class Handler:
    """A signal handler that raises (KeyboardInterrupt for SIGINT, :class:`Terminated` for the
    others) and remembers the first signal it got in :attr:`signum`."""

    def __init__(self):
        self.signum = None

    def __call__(self, signum, frame):
        if self.signum is None:
            self.signum = signum
        raise self.exception()

    def exception(self):
        """The exception of the signal received (call only when :attr:`signum` is set)."""
        return KeyboardInterrupt() if self.signum == signal.SIGINT else Terminated(self.signum)


class _WithoutSolverNotice:
    """``sys.stderr`` without CasADi's notice of the interrupt it swallowed (``CasADi - <time>
    WARNING("KeyboardInterruptException") [...]``, written through Python's stderr in pieces):
    the command line says "interrupted" in its one line. Text that starts a CasADi line is held
    until its newline; everything else passes through as written."""

    _START = "CasADi - "

    def __init__(self, stream):
        self._stream, self._held = stream, ""

    def write(self, text):
        if self._held or text.startswith(self._START):
            self._held += text
            line, newline, rest = self._held.partition("\n")
            if not newline:
                return len(text)
            self._held = ""
            if "KeyboardInterruptException" not in line:
                self._stream.write(line + newline)
            if rest:
                self.write(rest)
            return len(text)
        return self._stream.write(text)

    def flush(self):
        self._stream.flush()

    def __getattr__(self, name):
        return getattr(self._stream, name)


@contextlib.contextmanager
def handling():
    """Install one :class:`Handler` for :data:`SIGNALS` while the block runs (main thread only;
    elsewhere a no-op), with ``sys.stderr`` quiet about the interrupts CasADi swallows;
    yields the handler (None off the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        yield None
        return
    handler = Handler()
    old = {s: signal.signal(s, handler) for s in SIGNALS}
    stderr = sys.stderr
    sys.stderr = _WithoutSolverNotice(stderr)
    try:
        yield handler
    finally:
        if isinstance(sys.stderr, _WithoutSolverNotice):
            sys.stderr = stderr
        for s, h in old.items():
            signal.signal(s, h)


def pending():
    """The exception of a signal the installed :class:`Handler` received, or None."""
    for s in SIGNALS:
        h = signal.getsignal(s)
        if isinstance(h, Handler) and h.signum is not None:
            return h.exception()
    return None


def forget_escaped_interrupt():
    """Clear CPython's record that a KeyboardInterrupt escaped some code it ran: call it when
    the command has handled the interrupt (printed its line, chosen exit 130) and is about to
    exit from a ``python -m`` run.

    When the handler's KeyboardInterrupt leaves a piece of code the interpreter runs on its own
    (seen: during an import at about 1 s into ``hse-opt demo``) CPython notes an "unhandled
    KeyboardInterrupt", and at the end of ``python -m`` (``Py_RunMain``) it then kills the
    process with SIGINT, however the command ended: exit -2 instead of 130, one run in three.
    The installed script and ``python -c`` exit through ``sys.exit`` before that check. Any run
    of code through the C API's ``PyRun_SimpleString`` resets the record (CPython; elsewhere a
    no-op)."""
    try:
        import ctypes
        run = ctypes.pythonapi.PyRun_SimpleString
    except (ImportError, AttributeError, OSError):
        return
    run.argtypes, run.restype = [ctypes.c_char_p], ctypes.c_int
    run(b"pass")


def check():
    """Raise the signal the command line's :class:`Handler` received, if any: call it after a
    call into C that may have swallowed the exception the handler raised there."""
    err = pending()
    if err is not None:
        raise err
