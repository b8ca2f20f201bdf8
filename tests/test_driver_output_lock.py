"""One run per output folder (issue 17, item 1).

Two runs into the same ``--out`` used to corrupt each other: the second run's truncating create
wiped the first's result.h5.  A run now holds an exclusive lock on the folder
(``_driver.OutputLock``: ``flock`` on ``OUT/.mpmjax.lock``) for its whole duration and takes it
before it creates or truncates anything; a second run gets exit status 2 and a one-line message
naming the folder and the process that holds it.  The kernel drops a flock when its process
dies, so a run killed with SIGKILL leaves no stale lock.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

import mpmjax
from mpmjax._driver import LOCK_NAME, OutputBusy, OutputLock

ROOT = Path(__file__).resolve().parent.parent
SMALL = ["domain.cell_size_m=0.04", "time.t_end_s=0.3", "time.n_frames=3", "numerics.pressure=explicit"]
SENTINEL = b"an earlier result that must survive"


def _cli(out: Path, *extra: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "mpmjax.cli", "run", "dambreak-lab", "--out", str(out), "--quiet", "--no-animation"]
    cmd += [a for o in SMALL for a in ("--set", o)] + list(extra)
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    return subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)


def _hold_lock(out: Path) -> subprocess.Popen:
    """A process that holds the folder's lock (as a running ``mpmjax run`` does) until killed."""
    code = (
        "import sys, time; from mpmjax._driver import OutputLock; "
        f"OutputLock({str(out)!r}).acquire(); print('held', flush=True); time.sleep(600)"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_second_run_into_a_held_folder_exits_2_and_touches_nothing(tmp_path, no_result_pictures):
    """The refusals go through the CLI in a process of their own (exit status 2, one line); the
    run that takes the folder over after the holder was killed runs in this process (the lock is
    per process either way; the CLI's exit 0 for a complete run is tested elsewhere), which
    saves a third interpreter start and compilation."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "result.h5").write_bytes(SENTINEL)
    holder = _hold_lock(out)
    try:
        r = _cli(out)
        assert r.returncode == 2, r.stderr
        err = r.stderr.strip()
        assert "Traceback" not in err and len(err.splitlines()) == 1, err
        assert str(out) in err and f"process {holder.pid}" in err, err
        # nothing created or truncated
        assert (out / "result.h5").read_bytes() == SENTINEL
        assert sorted(p.name for p in out.iterdir()) == sorted([LOCK_NAME, "result.h5"])
        # --resume is refused the same way, before the checkpoint is read
        r = _cli(out, "--resume", str(out))
        assert r.returncode == 2 and f"process {holder.pid}" in r.stderr, r.stderr
    finally:
        holder.send_signal(signal.SIGKILL)  # like a crashed run: no clean-up
        holder.wait(timeout=60)
    # the killed holder's lock is gone with it: a new run takes the folder over and completes
    mpmjax.run_scene("dambreak-lab", out, SMALL, quiet=True)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "complete" and summary["n_lost"] == 0
    assert (out / "result.h5").read_bytes()[:8] == b"\x89HDF\r\n\x1a\n"


def test_run_scene_raises_output_busy_from_python(tmp_path):
    lock = OutputLock(tmp_path)
    lock.acquire()  # a second open file description: flock conflicts within one process too
    try:
        with pytest.raises(OutputBusy, match=rf"another mpmjax run \(process {os.getpid()}\)"):
            mpmjax.run_scene("dambreak-lab", tmp_path, SMALL, quiet=True)
        assert not (tmp_path / "result.h5").exists() and not (tmp_path / "checkpoint.h5").exists()
        assert isinstance(OutputBusy("x"), mpmjax.SceneError)  # the CLI's exit status 2
    finally:
        lock.release()
    mpmjax.run_scene("dambreak-lab", tmp_path, SMALL, quiet=True)  # released: the folder is free
    assert json.loads((tmp_path / "summary.json").read_text())["status"] == "complete"
