"""Command line: ``mpmjax scenes | run | rheometer | bench | stress | records | pareto | converge | validate |
study | calibrate | calibrate-coverage | design | sweep | sweep-merge``: argument parsing and dispatch
only; the work is done by the library (``mpmjax.run_scene``: ``mpmjax._driver``), ``mpmjax.rheometer``,
``mpmjax.studies`` and ``calibration``.

``_commands.COMMANDS`` is the command table (name, help, options, handler); each command's options
and handler are in one module (``_run``: scenes and run, ``_rheometer``, ``_studies``: bench, stress,
records, pareto and study, ``_validate``: converge and validate, ``_calibrate``, ``_design``,
``_sweep``: sweep and sweep-merge); ``_status`` maps what a handler raises to its exit status.

Exit status: 0 success, 2 invalid input (the message names the key, the value and the
allowed range; also a ``--resume`` that does not match, an ``--out`` that is a file or cannot be
created or written, a run refused by the memory estimate), 3 a run stopped by a failed health
check (NaN, absurd J, lost particles, CFL; frames already written stay readable; ``mpmjax
stress``: a case failed its criteria; ``mpmjax validate --size full``: a case missed its
tolerance), 4 a run stopped because its output could not be written (frames already written
stay readable), 130 interrupted by Ctrl-C, also while compiling (143 by SIGTERM; frames already
written stay readable and ``mpmjax run --resume DIR`` continues), 1 other errors (a bug).  Every
status but 1 comes with a one-line message, no traceback.

Nothing in the library (``mpmjax`` outside this package, ``calibration``) imports this package.
"""

from ._commands import COMMANDS, Command, main, make_parser
from ._status import FAILED, OUTPUT_FAILED, USAGE_ERROR, UsageError

__all__ = ["COMMANDS", "FAILED", "OUTPUT_FAILED", "USAGE_ERROR", "Command", "UsageError", "main", "make_parser"]
