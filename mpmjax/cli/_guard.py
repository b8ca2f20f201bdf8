"""The hardening every command shares (issue 35), applied by ``_status.run_command`` around each
handler, in this order, before anything is built:

1. every numeric option checked against the range declared with it (``number``: the option, its
   type and its range in one place; a NaN, an infinity or a value out of range is exit status 2
   with one line naming the option, the value and the allowed range);
2. the output of the command (``Command.output``: ``"folder"`` or ``"file"``) probed:
   ``--out ""``, an existing file given as a folder, a path under a file, an uncreatable or
   unwritable path are exit status 2 naming ``--out`` (``_driver.check_output_folder``, the
   probe of ``mpmjax run``);
3. an output folder locked for the whole command (``_driver.OutputLock``, the lock of ``mpmjax
   run``): a second command into the same folder is refused (exit 2) before it writes anything.
   ``run`` takes its own lock in the driver (it must be taken after a resumed checkpoint is
   read); jobs of a ``--shard`` array and processes of one ``jax.distributed`` job write one
   folder together by design and are not locked against each other;
4. SIGINT and SIGTERM raise ``Interrupted`` (exit 130 / 143 with the command's one line; ``run``'s
   driver installs its own handler inside, which holds them back while a frame is written).

As the program (``mpmjax ...``, not ``main([...])`` from Python) two more things hold
(``program_exit``, ``Watchdog``): an interrupted command ends with ``os._exit`` and a watchdog
ends a command whose main thread does not see a signal within ``GRACE_S`` (a long XLA call).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import os
import select
import signal
import sys
import threading
from pathlib import Path

from .. import _received
from .._driver import Interrupted, OutputError, OutputLock, check_output_folder
from .._driver.folder import make_output_folder
from .._driver.signals import held


class UsageError(Exception):
    """Invalid input found while a handler converts its options: exit status ``USAGE_ERROR``
    (``_status``, which re-exports it)."""


RANGES = "_option_ranges"  # the Namespace attribute that carries the declared ranges (dest -> (flag, Range))


@dataclasses.dataclass(frozen=True)
class Range:
    """The allowed values of a numeric option: ``lo`` / ``hi`` (None: unbounded), open or closed,
    always finite, in ``unit``."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    unit: str = ""
    integer: bool = False

    def text(self) -> str:
        parts = []
        if self.lo is not None:
            parts.append(f"{'>' if self.lo_open else '>='} {self.lo:g}")
        if self.hi is not None:
            parts.append(f"{'<' if self.hi_open else '<='} {self.hi:g}")
        if not self.integer:
            parts.append("finite")
        return ("integer " if self.integer else "") + " and ".join(parts) + (f" [{self.unit}]" if self.unit else "")

    def holds(self, x) -> bool:
        try:
            x = float(x)
        except (TypeError, ValueError, OverflowError):
            return False
        if not math.isfinite(x):
            return False
        if self.lo is not None and (x <= self.lo if self.lo_open else x < self.lo):
            return False
        return not (self.hi is not None and (x >= self.hi if self.hi_open else x > self.hi))


def number(p, *flags, type=float, lo=None, hi=None, lo_open=False, hi_open=False, unit="", **kw):
    """``p.add_argument(*flags, type=type, **kw)`` with the option's allowed range, checked by
    ``check_options`` before the handler runs (also on each value of an ``nargs`` option)."""
    action = p.add_argument(*flags, type=type, **kw)
    ranges = dict(p.get_default(RANGES) or {})
    ranges[action.dest] = (flags[0], Range(lo, hi, lo_open, hi_open, unit, integer=type is int))
    p.set_defaults(**{RANGES: ranges})
    return action


def check_options(args) -> None:
    """``UsageError`` naming the first numeric option whose value is outside its declared range."""
    for dest, (flag, rng) in (getattr(args, RANGES, None) or {}).items():
        value = getattr(args, dest, None)
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if v is not None and not rng.holds(v):
                raise UsageError(f"{flag} = {v!r} is invalid: allowed range: {rng.text()}")


def _out(command, args):
    """The command's ``--out`` (or, where it defaults to another option's value, that value)."""
    out = getattr(args, "out", None)
    if out is None and command.out_default:
        out = getattr(args, command.out_default, None)
        if out is not None and not Path(out).is_dir():
            raise UsageError(f"{out}: not a folder; allowed: an existing folder ({command.out_default})")
    return out


def _check_file(out: str) -> None:
    path = Path(out)
    if path.is_dir():
        raise OutputError(f"--out {out} is an existing folder; allowed: a file (existing, or one to create)")
    check_output_folder(path.parent if str(path.parent) else Path("."))


def _shared_folder(args) -> bool:
    """Whether other processes write the same folder by design (``--shard`` jobs, a distributed job)."""
    return any(getattr(args, k, None) not in (None, False) for k in
               ("shard", "coordinator", "num_processes", "process_id", "distributed"))


@contextlib.contextmanager
def guarded_output(command, args):
    """Probe the command's output (``Command.output``) and, for a folder, create and lock it for
    the duration; a folder created here that holds nothing but the lock afterwards (a command
    refused after the probe) is removed again."""
    out = _out(command, args)
    if out is not None and str(out).strip() == "":
        raise UsageError(f"--out {out!r} is empty: allowed: a path (give a folder name, or leave --out out)")
    if not command.output or out is None:
        yield
        return
    if command.output == "file":
        _check_file(str(out))
        yield
        return
    folder = Path(out)
    check_output_folder(folder)
    lock = None
    created = not folder.exists()
    if not _shared_folder(args):
        make_output_folder(folder)
        lock = OutputLock(folder)
        lock.acquire()
    try:
        yield
    finally:
        if lock is not None:
            lock.release()
            if created:
                with contextlib.suppress(OSError):
                    (folder / ".mpmjax.lock").unlink()
                    folder.rmdir()  # only if empty: the command wrote nothing


_LAST: list = [None]  # the signal noted in the command that ran last (kept past its scope)


def interrupted_by() -> int | None:
    """The signal that interrupted the command, if one did.  An ``Interrupted`` raised inside a
    ``jax.pure_callback`` (the calibration's model evaluations) reaches the command as the
    callback's ``XlaRuntimeError``; ``_status.run_command`` maps it back through this."""
    return _received.received() or _LAST[0]


class _QuietAfterSignal(logging.Filter):
    """Drops jax's "callback failed" traceback once a signal has been received (the interrupt it
    reports is the command's, which prints its own line)."""

    def filter(self, record):
        return _received.received() is None


@contextlib.contextmanager
def interrupt_signals(name: str = "the command"):
    """SIGINT and SIGTERM raise ``Interrupted`` (``_status`` maps it to 128 + the signal) while the
    command runs; the previous handlers afterwards.  Only in the main thread (Python delivers
    signals there only).  Each signal is noted first (``mpmjax._received``: a handler's exception
    can be dropped, and the loops check the note); one noted while the program started (its
    imports) stops the command here, before anything is written."""
    _LAST[0] = None
    with _received.scope():
        if threading.current_thread() is not threading.main_thread():
            yield
            return

        def handler(signum, frame):
            _received.note(signum)
            raise Interrupted(signum)

        quiet = _QuietAfterSignal()
        logging.getLogger("jax._src.callback").addFilter(quiet)

        old = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            _received.check(f"interrupted before {name} started: nothing was written")
            yield
        finally:
            _LAST[0] = _received.received()  # the scope clears the note on its way out
            for s, h in old.items():
                signal.signal(s, h)
            logging.getLogger("jax._src.callback").removeFilter(quiet)


GRACE_S = 5.0  # the time the main thread has to act on a signal before the watchdog ends the process


class Watchdog:
    """Ends the program within ``GRACE_S`` of SIGINT / SIGTERM when the main thread cannot act on it.

    Python runs a signal handler only when the main thread next executes Python code; inside one
    long XLA call (a sweep's batch, a frame of millions of steps, a compilation) that can be
    minutes away.  The signal also reaches this thread at once, through ``signal.set_wakeup_fd``;
    if the main thread has not finished the command ``GRACE_S`` later (and is not writing a frame
    or checkpoint: ``_driver.signals.held``), the watchdog prints the command's interrupted line,
    flushes and ends the process with 128 + the signal (``os._exit``: the main thread is inside
    XLA and cannot unwind).  Only for the program: from Python (tests, notebooks) nothing here runs."""

    def __init__(self, note):
        self.note = note
        self.finished = threading.Lock()  # whoever takes it first (main thread or watchdog) ends the command
        self.r, self.w = os.pipe()
        os.set_blocking(self.w, False)
        self.old_fd = signal.set_wakeup_fd(self.w, warn_on_full_buffer=False)
        threading.Thread(target=self._watch, name="mpmjax-signal-watchdog", daemon=True).start()

    def _watch(self):
        while True:
            select.select([self.r], [], [])
            data = os.read(self.r, 64)
            sigs = [b for b in data if b in (signal.SIGINT, signal.SIGTERM)]
            if sigs:
                break
        signum = sigs[0]
        waited = 0.0
        while waited < GRACE_S or held():
            threading.Event().wait(0.1)
            waited += 0.1
        if not self.finished.acquire(blocking=False):
            return  # the main thread is ending the command itself
        with contextlib.suppress(Exception):
            sys.stderr.write(f"\n{self.note()} (stopped inside a computation, {GRACE_S:g} s after the signal)\n")
            sys.stderr.flush()
            sys.stdout.flush()
        os._exit(128 + signum)

    def close(self) -> bool:
        """The main thread ends the command: False when the watchdog already does."""
        return self.finished.acquire(blocking=False)


def program_exit(status: int) -> int:
    """The end of the program after a command returned ``status``.  After an interrupt (status
    > 128) the process ends here with ``os._exit``: the files are closed and the message printed,
    but XLA's thread pools may still be running the computation the signal cut short, and the
    interpreter's normal exit, which tears them down, waited for that computation (minutes) or
    crashed in it (segmentation fault, status 139, issue 35).  ``os._exit`` skips that teardown;
    stdout and stderr are flushed first."""
    if status > 128:
        with contextlib.suppress(Exception):
            sys.stdout.flush()
            sys.stderr.flush()
        os._exit(status)
    return status
