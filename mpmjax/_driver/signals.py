"""SIGINT/SIGTERM during a run: ``Interrupted``, and ``Signals``, which holds them back while a
frame and its checkpoint are being written."""

from __future__ import annotations

import contextlib
import signal
import threading

from .._received import Interrupted, check, note

__all__ = ["Interrupted", "Signals", "check", "held"]


_ACTIVE: list = []  # the Signals installed now (a run's), for ``held``


def held() -> bool:
    """Whether a run is writing a frame, a checkpoint or its closing files now (signals held back)."""
    return any(s.depth for s in _ACTIVE)


class Signals:
    """Turn SIGINT/SIGTERM into ``Interrupted`` and hold them back while a frame and its
    checkpoint are being written (``with sig.hold():``), so that the files on disk always
    match the state in memory.  Only installed in the main thread (Python delivers signals
    there only)."""

    def __init__(self):
        self.pending = None
        self.depth = 0
        self.old = {}
        _ACTIVE.append(self)
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                self.old[s] = signal.signal(s, self._handler)

    def _handler(self, signum, frame):
        note(signum)  # also where the exception below is dropped (a gc callback): mpmjax._received
        if self.depth:
            self.pending = signum
        else:
            raise Interrupted(signum)

    def hold(self):
        @contextlib.contextmanager
        def cm():
            self.depth += 1
            try:
                yield
            finally:
                self.depth -= 1
            if not self.depth and self.pending is not None:
                signum, self.pending = self.pending, None
                raise Interrupted(signum)
            if not self.depth:
                check()  # a signal whose exception was dropped

        return cm()

    def restore(self):
        for s, h in self.old.items():
            signal.signal(s, h)
        self.old = {}
        if self in _ACTIVE:
            _ACTIVE.remove(self)
