"""The run driver: ``run_scene`` runs a scene frame by frame and writes it to disk (what
``mpmjax run`` does), with checkpoint and resume, SIGINT/SIGTERM handling, the compiled-advance
cache, progress on stderr, the summary.json metrics and the animation.

Also the exit statuses shared by the command layers (``mpmjax.cli`` and the ``cmd_*`` functions of
``mpmjax.studies``): 0 success, 1 other errors, 2 invalid input (``USAGE_ERROR``, printed by
``fail``; also an output folder that cannot be used and a run refused by the memory estimate),
3 a run stopped by a failed health check (``FAILED``), 4 a run stopped because its output could
not be written (``OUTPUT_FAILED``: the folder became unwritable, the disk is full), 128 + the
signal number for an interrupted run (130 Ctrl-C, 143 SIGTERM).

One module a concept: ``run`` (``run_scene``, the order of a run), ``folder`` (the output folder's
probe and lock), ``memory`` (the estimate's refusal), ``resume`` (checkpoints), ``advance`` (the
compiled frame), ``signals``, ``loop`` (frames, health, failures), ``progress``, ``summary``
(summary.json for every status), ``outputs`` (the files and pictures of a complete run) and
``status`` (exit statuses).
"""

from .advance import _compiled_advance
from .folder import LOCK_NAME, OutputBusy, OutputError, OutputLock, check_output_folder
from .memory import MEMORY_ENV, MemoryRefused, check_memory
from .outputs import ANIMATION_DPI, ANIMATION_MAX_FRAMES
from .progress import Progress
from .resume import CHECKPOINT_EVERY, resume_command
from .run import run_scene
from .signals import Interrupted
from .status import FAILED, OUTPUT_FAILED, USAGE_ERROR, OutputFailure, fail

__all__ = [
    "ANIMATION_DPI",
    "ANIMATION_MAX_FRAMES",
    "CHECKPOINT_EVERY",
    "FAILED",
    "LOCK_NAME",
    "MEMORY_ENV",
    "OUTPUT_FAILED",
    "USAGE_ERROR",
    "Interrupted",
    "MemoryRefused",
    "OutputBusy",
    "OutputError",
    "OutputFailure",
    "OutputLock",
    "Progress",
    "_compiled_advance",
    "check_memory",
    "check_output_folder",
    "fail",
    "resume_command",
    "run_scene",
]
