"""How a run's output failure is reported: ``OutputFailure`` (the command line's exit status 4,
``mpmjax.cli._status``) and ``os_reason``, an ``OSError`` in words."""

from __future__ import annotations


class OutputFailure(Exception):
    """Writing the output failed during or after the run (the folder became unwritable, the
    disk filled up): exit status 4 of ``mpmjax run``.  The message says what was kept."""


def os_reason(e: OSError) -> str:
    """An ``OSError`` in words for a message: its strerror and the file it names."""
    where = f" ({e.filename})" if getattr(e, "filename", None) else ""
    return f"{e.strerror or e}{where}"
