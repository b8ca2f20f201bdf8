"""Signals received but not yet acted on (issue 35): the one record that the signal handlers of
the command line (``mpmjax.cli._guard``) and of the run driver (``_driver.signals``) write, and
that the long loops check between their chunks of work (``check``).

A handler that raises ``Interrupted`` cannot always stop the program: Python runs it in whatever
Python code the main thread executes next, and where that is a garbage-collector callback (jax
registers one), a ``__del__`` or a weakref callback, the exception is printed as "Exception
ignored in ..." and dropped; the command went on and, in ``mpmjax run``'s first second, overwrote
its folder and exited 0.  So every handler first notes the signal here (``note``), and the loops
check the note at points where raising is safe: between chunks of steps, between frames, before
the output folder is touched, between the outputs of a finished run.

Started as the ``mpmjax`` program, ``hold_startup_signals`` (called first thing by
``mpmjax/__init__``) notes SIGINT and SIGTERM from the start of the import on, without raising
(raised inside the import of jaxlib they turn into ImportError tracebacks or are dropped by that
callback); the command's own handler, installed once the command starts, acts on them at once.
Only this module's standard-library imports run before that: it must stay free of jax."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading


class Interrupted(KeyboardInterrupt):
    """A command or run stopped by SIGINT (Ctrl-C) or SIGTERM; ``message`` says what was kept."""

    def __init__(self, signum: int, message: str = ""):
        super().__init__(message)
        self.signum, self.message = signum, message


_RECEIVED: list = []  # signals noted and not yet cleared (the first one counts)
_SCOPES = [0]  # nesting depth of ``scope``


def note(signum: int) -> None:
    """Record a received signal (from a handler, before it raises)."""
    _RECEIVED.append(int(signum))


def received() -> int | None:
    """The first signal noted in the current scope, if any."""
    return _RECEIVED[0] if _RECEIVED else None


def check(message: str = "") -> None:
    """Raise ``Interrupted`` (with ``message``) if a signal was noted: a handler's exception may have
    been dropped (module docstring), so the loops call this where stopping is safe."""
    if _RECEIVED:
        raise Interrupted(_RECEIVED[0], message)


@contextlib.contextmanager
def scope():
    """A command (``mpmjax.cli``) or a run (``run_scene``): when the outermost scope ends, the
    record is cleared, so that a signal that stopped one run does not stop the next one in the
    same process.  Entering keeps what was noted (a signal during the program's start counts)."""
    _SCOPES[0] += 1
    try:
        yield
    finally:
        _SCOPES[0] -= 1
        if not _SCOPES[0]:
            _RECEIVED.clear()


def _started_as_program() -> bool:
    """Whether this process is the ``mpmjax`` program (the console script, or ``python -m
    mpmjax.cli``), not a Python session that imports mpmjax."""
    if sys.argv and os.path.basename(sys.argv[0]) == "mpmjax":
        return True
    argv = list(getattr(sys, "orig_argv", []))
    return any(a == "-m" and b in ("mpmjax.cli", "mpmjax.cli.__main__") for a, b in zip(argv, argv[1:]))


def hold_startup_signals() -> bool:
    """Started as the program, with Python's default handlers (or the signals ignored) still in
    place: note SIGINT and SIGTERM from now on instead of acting on them (the command's handler
    acts on the note).
    Returns whether the handlers were installed."""
    if not _started_as_program() or threading.current_thread() is not threading.main_thread():
        return False
    # SIG_IGN too: a job started in the background by a non-interactive shell inherits SIGINT
    # ignored, and the command's own handler takes the signals over anyway once it starts (so a
    # Ctrl-C in the first second would be lost where one a second later stops the command)
    if signal.getsignal(signal.SIGINT) not in (signal.default_int_handler, signal.SIG_IGN):
        return False  # someone else (an embedding program) handles Ctrl-C
    if signal.getsignal(signal.SIGTERM) not in (signal.SIG_DFL, signal.SIG_IGN):
        return False
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda signum, frame: note(signum))
    return True
