"""The exit statuses shared by the command layers (``mpmjax.cli`` and the ``cmd_*`` functions of
``mpmjax.studies``), and ``fail``, which prints an invalid-input message and returns its status."""

from __future__ import annotations

import sys

USAGE_ERROR = 2  # exit status of invalid input (the message names the key, the value and the allowed range)
FAILED = 3  # exit status of a run stopped by a failed health check (mpmjax._health)
OUTPUT_FAILED = 4  # exit status of a run stopped because writing its output failed (OutputFailure)


def fail(msg: str) -> int:
    """Print ``mpmjax: error: MSG`` on stderr; return the invalid-input exit status ``USAGE_ERROR``."""
    print(f"mpmjax: error: {msg}", file=sys.stderr)
    return USAGE_ERROR


class OutputFailure(Exception):
    """Writing the output failed during or after the run (the folder became unwritable, the
    disk filled up): exit status ``OUTPUT_FAILED``.  The message says what was kept."""


def os_reason(e: OSError) -> str:
    """An ``OSError`` in words for a message: its strerror and the file it names."""
    where = f" ({e.filename})" if getattr(e, "filename", None) else ""
    return f"{e.strerror or e}{where}"
