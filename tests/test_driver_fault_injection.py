"""File-system and runtime faults of ``mpmjax run`` (issue 17, item 2): each gets one line on
stderr (no traceback), a documented exit status (docs/output.md) and loses no earlier result.

* an existing file as ``--out``, a path that cannot be created, a folder without write
  permission: exit 2 before the scene is built or compiled;
* a run the memory estimate says cannot fit: exit 2 before anything is built;
* Ctrl-C while compiling: exit 130, no result written or changed;
* the folder becoming unwritable mid-run: exit 4, result.h5 ``status = failed`` with the reason,
  summary.json ``status: failed`` with what was written, the last checkpoint kept.

Concurrent runs into one folder: tests/test_driver_output_lock.py; kill -9 and resume bit for bit:
tests/test_driver_resume.py.  As root a ``chmod`` does not stop writes, so the "unwritable" cases use
/proc (root cannot create files there) and a write that fails with EACCES by fault injection;
the real ``chmod`` variants run when the suite is not root.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import h5py
import pytest
from conftest import signal_in_compile_script

import mpmjax
from mpmjax import _driver
from mpmjax._io import read_result

ROOT = Path(__file__).resolve().parent.parent
SMALL = ["domain.cell_size_m=0.04", "time.t_end_s=0.4", "time.n_frames=4", "numerics.pressure=explicit"]
SENTINEL = b"an earlier result that must survive"
ROOT_USER = os.geteuid() == 0


def _cmd(out, *extra, scene="dambreak-lab", sets=SMALL):
    cmd = [sys.executable, "-m", "mpmjax.cli", "run", scene, "--out", str(out), "--no-animation"]
    return cmd + [a for o in sets for a in ("--set", o)] + list(extra)


def _env(**kw):
    return dict(os.environ, JAX_PLATFORMS="cpu", **kw)


def _run(cmd, **env):
    return subprocess.run(cmd, cwd=ROOT, env=_env(**env), capture_output=True, text=True, timeout=600)


def _one_line(err: str) -> str:
    err = err.strip()
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    return lines[0]


def test_out_is_a_file_or_cannot_be_created(tmp_path):
    f = tmp_path / "afile"
    f.write_bytes(SENTINEL)
    r = _run(_cmd(f, "--quiet"))
    assert r.returncode == 2
    assert _one_line(r.stderr) == f"mpmjax: error: --out {f} is an existing file; allowed: a folder (existing, or one to create)"
    assert f.read_bytes() == SENTINEL
    r = _run(_cmd(f / "sub", "--quiet"))
    assert r.returncode == 2
    assert f"--out {f / 'sub'} cannot be created: {f} is a file" in _one_line(r.stderr)
    assert f.read_bytes() == SENTINEL


def test_unwritable_out_is_refused_before_compiling(tmp_path):
    if ROOT_USER:
        out = Path("/proc")  # root cannot create files there
        if not out.is_dir():
            pytest.skip("no /proc")
    else:
        out = tmp_path / "ro"
        out.mkdir()
        (out / "result.h5").write_bytes(SENTINEL)
        out.chmod(0o555)
    try:
        r = _run(_cmd(out))  # not --quiet: "compiled in" would show that it compiled
    finally:
        if not ROOT_USER:
            out.chmod(0o755)
    assert r.returncode == 2
    line = _one_line(r.stderr)
    assert line.startswith(f"mpmjax: error: --out {out} is not writable: cannot create a file there"), line
    if not ROOT_USER:
        assert (out / "result.h5").read_bytes() == SENTINEL
        assert sorted(p.name for p in out.iterdir()) == ["result.h5"]


def test_memory_refusal_before_building(tmp_path):
    """field-dambreak-3d at h = 1 m: 7.9e6 particles and 2.2e7 grid nodes, about 23 GB by the
    estimate; with 1 GB available it is refused at once, without seeding a particle."""
    out = tmp_path / "big"
    cfg = mpmjax.load_scene("field-dambreak-3d", ["domain.cell_size_m=1.0"])
    est = mpmjax._build.memory_estimate(cfg)
    assert est["particles"] == pytest.approx(1200 * 200 * 33, rel=0.01)
    assert 5e9 < est["device_bytes"] + est["host_bytes"] < 1e11
    r = _run(_cmd(out, "--quiet", scene="field-dambreak-3d", sets=["domain.cell_size_m=1.0"]), MPMJAX_MEMORY_LIMIT_GB="1")
    assert r.returncode == 2
    line = _one_line(r.stderr)
    assert "the run needs about" in line and "GB of memory" in line, line
    assert "1 GB is available (MPMJAX_MEMORY_LIMIT_GB = 1)" in line and "domain.cell_size_m" in line, line
    assert not out.exists()


def test_memory_estimate_covers_the_state_it_builds():
    """The estimate's particle part holds at least 4 copies of the particle state actually built."""
    setup = mpmjax.build(mpmjax.load_scene("dambreak-lab", SMALL))
    state_bytes = sum(a.nbytes for a in __import__("jax").tree_util.tree_leaves(setup.state))
    est = mpmjax._build.memory_estimate(setup.cfg)
    assert est["particles"] == setup.scene.n_particles
    assert est["grid_nodes"] == setup.scene.n_nodes
    assert est["particle_bytes"] >= 4 * state_bytes
    with pytest.raises(_driver.MemoryRefused, match="needs about"):
        os.environ[_driver.MEMORY_ENV] = "1e-6"
        try:
            _driver.check_memory(setup.cfg)
        finally:
            del os.environ[_driver.MEMORY_ENV]


# the child: ``mpmjax run`` whose compile step first receives SIGINT, as from a Ctrl-C in the
# terminal.  A signal sent from here once the child logs "scene " raced the compiler: on CI's
# machine the small scene compiled in 0.8 s, before the signal came, and the run was interrupted at
# frame 0 instead (stop 39).  Sending it from inside the compile step makes the case deterministic.
_CTRL_C_IN_COMPILE = signal_in_compile_script("SIGINT")


def test_ctrl_c_while_compiling_exits_130_and_keeps_the_earlier_result(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "result.h5").write_bytes(SENTINEL)
    cmd = [sys.executable, "-c", _CTRL_C_IN_COMPILE] + _cmd(out)[3:]
    r = subprocess.run(cmd, cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=600)
    assert r.returncode == 130, r.stderr
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
    assert lines[0].startswith("scene ") and "compiled in" not in r.stderr, r.stderr
    assert _one_line(lines[-1]) == f"interrupted while compiling: no result in {out} was written or changed"
    assert (out / "result.h5").read_bytes() == SENTINEL
    # nothing else written: only the folder's lock file (the flock the run held, left by design)
    assert sorted(p.name for p in out.iterdir()) == [_driver.folder.LOCK_NAME, "result.h5"]


def _deny(*args, **kw):
    raise PermissionError(errno.EACCES, "Permission denied", str(args[0]))


def test_folder_unwritable_mid_run_marks_failed_and_keeps_frames(tmp_path, monkeypatch):
    """From frame 2 on no new file can be created in the folder (fault injection: every
    checkpoint and atomic write fails with EACCES, as in a folder that lost its write
    permission).  The frame-3 checkpoint fails: the run stops with OutputFailure, result.h5
    (open, still writable) is marked failed with the reason, summary.json is rewritten in
    place, and the frame-2 checkpoint resumes the run once the folder is fixed."""
    out = tmp_path / "run"

    def on_frame(k, st):
        if k == 2:
            monkeypatch.setattr(_driver.resume, "_write_ckpt", _deny)  # the checkpoints
            monkeypatch.setattr(_driver.summary, "atomic_write_text", _deny)  # summary.json

    with pytest.raises(_driver.OutputFailure) as e:
        mpmjax.run_scene("dambreak-lab", out, SMALL, quiet=True, checkpoint_every=1, on_frame=on_frame)
    msg = str(e.value)
    assert "Permission denied" in msg and "checkpoint.h5" in msg and "resume" in msg, msg
    res = read_result(out / "result.h5")
    assert res["attrs"]["status"] == "failed" and "Permission denied" in res["attrs"]["error"]
    assert len(res["frames"]["t_s"]) == 4  # frames 0..3
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "failed" and s["failure"]["kind"] == "output" and s["frames_written"] == 3
    assert len(s["runout_m"]) == 4
    monkeypatch.undo()
    s = mpmjax.run_scene(None, out, None, quiet=True, resume=True)
    assert s["status"] == "complete" and len(s["runout_m"]) == 5


_MIDRUN = """
import errno, sys
from mpmjax import cli
from mpmjax._driver import resume
real = resume._write_ckpt
def ckpt(path, st, frame, *a):
    if frame >= 3:
        raise PermissionError(errno.EACCES, "Permission denied", str(path))
    return real(path, st, frame, *a)
resume._write_ckpt = ckpt
sys.exit(cli.main(sys.argv[1:]))
"""


def test_cli_mid_run_write_failure_exits_4_with_one_line(tmp_path):
    out = tmp_path / "run"
    cmd = [sys.executable, "-c", _MIDRUN] + _cmd(out, "--quiet", "--checkpoint-every", "1")[3:]
    r = _run(cmd)
    assert r.returncode == 4, r.stderr
    line = _one_line(r.stderr)
    assert line.startswith(f"mpmjax: writing the output in {out} failed after frame 3/4"), line
    with h5py.File(out / "result.h5") as f:
        assert f.attrs["status"] == "failed" and f["frames/t_s"].shape == (4,)
    assert json.loads((out / "summary.json").read_text())["status"] == "failed"


@pytest.mark.skipif(ROOT_USER, reason="root writes into a read-only folder anyway")
def test_real_chmod_mid_run(tmp_path):
    out = tmp_path / "run"

    def on_frame(k, st):
        if k == 2:
            out.chmod(0o555)

    try:
        with pytest.raises(_driver.OutputFailure, match="Permission denied"):
            mpmjax.run_scene("dambreak-lab", out, SMALL, quiet=True, checkpoint_every=1, on_frame=on_frame)
    finally:
        out.chmod(0o755)
    assert read_result(out / "result.h5")["attrs"]["status"] == "failed"
    assert json.loads((out / "summary.json").read_text())["status"] == "failed"
