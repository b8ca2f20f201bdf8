"""The output folder: the write probe that vets ``--out`` before anything is built
(``check_output_folder``, ``OutputError``) and the lock held on it for a whole run
(``OutputLock``, ``OutputBusy``)."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

from .._schema import SceneError
from .status import os_reason

LOCK_NAME = ".mpmjax.lock"  # in the output folder: held (flock) by the run writing there


class OutputBusy(SceneError):
    """The output folder is being written by another run (exit status 2, like invalid input)."""


class OutputLock:
    """An exclusive lock on an output folder, held for a whole run: ``flock`` on
    ``OUT/.mpmjax.lock``, which holds the owner's process id.  The kernel releases a flock when
    its process ends, however it ends, so a lock left by a killed run is never stale: the
    next run takes it over.  A second run into a held folder gets ``OutputBusy`` before it
    creates or truncates anything there."""

    def __init__(self, out: Path):
        self.out = Path(out)
        self.fd = None

    def acquire(self) -> None:
        if self.fd is not None:
            return
        path = self.out / LOCK_NAME
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise OutputBusy(
                f"--out {self.out}: another mpmjax run (process {holder}) is writing to this folder; "
                "wait for it to finish, or choose another --out"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self.fd = fd

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)  # closing the descriptor releases the flock
            self.fd = None


class OutputError(SceneError):
    """``--out`` cannot hold a run's files: an existing file, a folder that cannot be created,
    or one without write permission (exit status 2; found before anything is built)."""


def check_output_folder(out: Path) -> None:
    """Raise ``OutputError`` unless ``out`` is, or can be created as, a folder we can write to.
    Creates nothing (a probe file is created and removed in the nearest existing folder)."""
    out = Path(out)
    try:
        if out.exists() and not out.is_dir():
            raise OutputError(f"--out {out} is an existing file; allowed: a folder (existing, or one to create)")
        base = out
        while not base.exists() and base != base.parent:
            base = base.parent
        if not base.is_dir():
            raise OutputError(f"--out {out} cannot be created: {base} is a file, not a folder")
    except OSError as e:  # e.g. a parent without search permission
        raise OutputError(f"--out {out} cannot be used: {e.strerror or e}") from None
    probe = base / f".mpmjax-write-test-{os.getpid()}"
    try:
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        os.unlink(probe)
    except OSError as e:
        what = "is not writable" if base == out else f"cannot be created in {base}"
        raise OutputError(f"--out {out} {what}: cannot create a file there ({e.strerror or e})") from None


def make_output_folder(out: Path) -> None:
    """Create ``out`` (and its parents); ``OutputError`` where that fails."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"--out {out} cannot be created: {os_reason(e)}") from None
