"""The one map from an exception to an exit status and its one-line message, used by every command.

``run_command(command, args)`` runs a command's handler and turns what it raises into the exit
status of ``STATUSES`` (the first row whose classes match) with that row's message on stderr, no
traceback; anything else propagates (status 1: a bug).  A handler returns its status when it
ends normally: 0, or ``FAILED`` where a study's case missed its criteria.

A command adds to the map through its row of the command table (``_commands.Command``):
``invalid`` (more exception classes that count as invalid input there, e.g. ``ValueError`` for the
calibration commands, whose library reports bad values with it), ``interrupted`` and ``failed``
(what was kept on disk, formatted with the parsed options: ``{out}``).
"""

from __future__ import annotations

import sys
import threading
from argparse import Namespace

from calibration.data import DataError
from calibration.distributed import DistributedError

from .. import _received
from .._driver import Interrupted, OutputFailure
from .._health import RunFailure
from .._schema import SceneError
from . import _guard
from ._guard import UsageError

USAGE_ERROR = 2  # invalid input: the message names the key or option, the value and the allowed range
FAILED = 3  # a run stopped by a failed health check; a stress or validate case missed its criteria; a fit's
# model or its derivatives turned non-finite (FloatingPointError)
OUTPUT_FAILED = 4  # a run stopped because its output could not be written (OutputFailure)
SIGINT_STATUS = 130  # 128 + SIGINT: Ctrl-C outside a run's own handler (KeyboardInterrupt)


def _interrupted(e, notes):
    return f"\n{getattr(e, 'message', '') or notes['interrupted']}"


def _failed(e, notes):
    return f"\nmpmjax: {e}" + (f"\n{notes['failed']}" if notes["failed"] else "")


def _usage(e, notes):
    return f"mpmjax: error: {e}"


# (exception classes, exit status (or a function of the exception), message(exception, notes));
# the first row that matches wins, so a subclass stands above its base
STATUSES = (
    ((Interrupted,), lambda e: 128 + e.signum, _interrupted),  # SIGINT 130, SIGTERM 143
    ((KeyboardInterrupt,), SIGINT_STATUS, _interrupted),
    ((RunFailure, FloatingPointError), FAILED, _failed),
    ((OutputFailure,), OUTPUT_FAILED, lambda e, notes: f"\nmpmjax: {e}"),
    ((UsageError, SceneError, DataError, DistributedError), USAGE_ERROR, _usage),
)


def status_of(e: BaseException, invalid: tuple = ()) -> tuple[int, object] | None:
    """(exit status, message function) of ``e``, or None when ``e`` is a bug (status 1)."""
    for classes, status, message in STATUSES:
        if isinstance(e, classes):
            return (status(e) if callable(status) else status), message
    if invalid and isinstance(e, invalid):
        return USAGE_ERROR, _usage
    return None


def run_command(command, args: Namespace, program: bool = False) -> int:
    """Run ``command.handler(args)`` inside the shared hardening (``_guard``: the numeric options
    checked, the output probed and locked, SIGINT / SIGTERM as ``Interrupted``); return its
    status, or that of the exception it raises (``STATUSES``, plus ``command.invalid`` as invalid
    input) after printing the message.  ``program``: run as the ``mpmjax`` program, with the
    signal watchdog (``_guard.Watchdog``)."""
    # the watchdog's line is formatted when it fires: a handler may set args.out (run: runs/SCENE)
    watchdog = _guard.Watchdog(lambda: command.interrupted.format(**vars(args))) if program else None
    try:
        with _guard.interrupt_signals(f"mpmjax {command.name}"):
            _guard.check_options(args)
            with _guard.guarded_output(command, args):
                status = command.handler(args)
            # a signal whose exception was dropped (mpmjax._received) after the handler's last check:
            # the command did its work, but it was asked to stop, and says so
            _received.check(f"interrupted at the end of mpmjax {command.name}: its outputs were written in full")
            return status
    except (Exception, KeyboardInterrupt) as e:
        signum = _guard.interrupted_by()
        if signum is not None and not isinstance(e, KeyboardInterrupt):
            e = Interrupted(signum)  # raised inside a jax callback, it arrives as the callback's error
        found = status_of(e, command.invalid)
        if found is None:
            raise
        status, message = found
        if watchdog is not None and not watchdog.close():
            threading.Event().wait()  # the watchdog is ending the process with its own line
        notes = {k: getattr(command, k).format(**vars(args)) for k in ("interrupted", "failed")}  # args.out as set
        print(message(e, notes), file=sys.stderr)
        return status
