"""The run driver: ``run_scene`` runs a scene frame by frame and writes it to disk (what
``mpmjax run`` does), with checkpoint and resume, SIGINT/SIGTERM handling, the compiled-advance
cache, progress on stderr, the summary.json metrics and the animation.

What stops a run is an exception: ``SceneError`` (and its ``OutputBusy``, ``OutputError``,
``MemoryRefused``) for invalid input, ``_health.RunFailure``, ``OutputFailure`` and
``Interrupted``; ``mpmjax.cli._status`` maps each to the command line's exit status.

One module a concept: ``run`` (``run_scene``, the order of a run), ``folder`` (the output folder's
probe and lock), ``memory`` (the estimate's refusal), ``resume`` (checkpoints), ``advance`` (the
compiled frame), ``signals``, ``loop`` (frames, health, failures), ``progress``, ``summary``
(summary.json for every status), ``outputs`` (the files and pictures of a complete run) and
``status`` (``OutputFailure``).
"""

from .advance import _compiled_advance
from .folder import LOCK_NAME, OutputBusy, OutputError, OutputLock, check_output_folder
from .memory import MEMORY_ENV, MemoryRefused, check_memory
from .outputs import ANIMATION_DPI, ANIMATION_MAX_FRAMES
from .progress import Progress
from .resume import CHECKPOINT_EVERY, resume_command
from .run import run_scene
from .signals import Interrupted
from .status import OutputFailure

__all__ = [
    "ANIMATION_DPI",
    "ANIMATION_MAX_FRAMES",
    "CHECKPOINT_EVERY",
    "LOCK_NAME",
    "MEMORY_ENV",
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
    "resume_command",
    "run_scene",
]
