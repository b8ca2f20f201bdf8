"""Interrupted runs: checkpoint, resume and the files left behind (docs/output.md).

A coarse dam break (h = 2 cm, 400 particles, 20 frames of 0.03 s, 24 steps each) is run once without
interruption; interrupted runs (an exception raised from the per-frame hook, a simulated
crash, a real SIGINT to the command line) are resumed and must give the same result.h5
arrays bit for bit: the resumed run starts from the exact checkpointed state and runs the
same compiled frame advance, so there is no tolerance.
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import stub_result_pictures

import mpmjax
from mpmjax import cli
from mpmjax._io import read_checkpoint, read_result

ROOT = Path(__file__).resolve().parents[1]
SCENE = "dambreak-lab"
OVER = ["time.t_end_s=0.6", "time.n_frames=20", "domain.cell_size_m=0.02", "numerics.ppc=2"]  # ppc 2: 400 particles
N_FRAMES = 20


def _datasets(path) -> dict:
    with h5py.File(path, "r") as f:
        out = {}
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
    return out


def _assert_same_result(a, b):
    da, db = _datasets(a), _datasets(b)
    assert sorted(da) == sorted(db)
    for k in da:
        assert da[k].dtype == db[k].dtype and da[k].shape == db[k].shape, k
        np.testing.assert_array_equal(da[k], db[k], err_msg=k)


def _same_summary(a, b):
    sa, sb = (json.loads((p / "summary.json").read_text()) for p in (a, b))
    timing = {"wall_s", "compile_s", "particle_steps_per_s"}
    assert {k: v for k, v in sa.items() if k not in timing} == {k: v for k, v in sb.items() if k not in timing}


@pytest.fixture(scope="module", autouse=True)
def _no_pictures():
    """The in-process runs here compare result.h5 and summary.json only: no result.png (the
    command-line runs in subprocesses still draw theirs)."""
    with pytest.MonkeyPatch.context() as mp:
        stub_result_pictures(mp)
        yield


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref")
    s = mpmjax.run_scene(SCENE, out, OVER, quiet=True, checkpoint_every=3)
    assert s["status"] == "complete" and s["complete"]
    assert not (out / "checkpoint.h5").exists()  # a complete run leaves nothing to resume
    return out


def _stop_at(k, exc):
    def hook(frame, state):
        if frame == k:
            raise exc

    return hook


def test_same_input_twice_gives_identical_results(reference, tmp_path):
    mpmjax.run_scene(SCENE, tmp_path, OVER, quiet=True, checkpoint_every=0)
    _assert_same_result(reference / "result.h5", tmp_path / "result.h5")
    _same_summary(reference, tmp_path)
    assert read_result(tmp_path / "result.h5")["frames"]["x_m"].shape == (N_FRAMES + 1, 400, 2)


def test_interrupt_then_resume_is_bit_for_bit(reference, tmp_path):
    with pytest.raises(mpmjax.Interrupted) as e:
        mpmjax.run_scene(SCENE, tmp_path, OVER, quiet=True, checkpoint_every=3, on_frame=_stop_at(7, KeyboardInterrupt()))
    assert e.value.signum == signal.SIGINT
    assert f"mpmjax run --resume {tmp_path}" in e.value.message and "frame 7/20" in e.value.message
    # the partial file is readable and holds exactly frames 0..7 of the uninterrupted run
    part = read_result(tmp_path / "result.h5")
    ref = read_result(reference / "result.h5")
    assert part["attrs"]["status"] == "interrupted" and not part["attrs"]["complete"]
    assert part["frames"]["t_s"].shape == (8,)
    for k in ref["frames"]:
        np.testing.assert_array_equal(part["frames"][k], ref["frames"][k][:8], err_msg=k)
    summ = json.loads((tmp_path / "summary.json").read_text())
    assert summ["status"] == "interrupted" and summ["frames_written"] == 7
    # the interrupt itself checkpointed frame 7 (the periodic one was at frame 6)
    state, frame, _, meta = read_checkpoint(tmp_path / "checkpoint.h5")
    assert frame == 7 and meta["scene_source"] == SCENE and meta["overrides"] == OVER
    np.testing.assert_array_equal(state.x, ref["frames"]["x_m"][7])

    s = mpmjax.run_scene(None, tmp_path, None, quiet=True, resume=True)  # scene and overrides from the checkpoint
    assert s["status"] == "complete"
    _assert_same_result(reference / "result.h5", tmp_path / "result.h5")
    _same_summary(reference, tmp_path)
    assert not (tmp_path / "checkpoint.h5").exists()


def test_crash_after_a_checkpoint_resumes_from_it(reference, tmp_path):
    # a crash (here an error raised after frame 11) does not write a checkpoint: the last
    # periodic one (frame 9) is used and result.h5, which holds frames 0..11, is cut back to 0..9
    with pytest.raises(RuntimeError, match="power cut"):
        mpmjax.run_scene(
            SCENE, tmp_path, OVER, quiet=True, checkpoint_every=3, on_frame=_stop_at(11, RuntimeError("power cut"))
        )
    assert read_result(tmp_path / "result.h5")["frames"]["t_s"].shape == (12,)
    assert read_checkpoint(tmp_path / "checkpoint.h5")[1] == 9
    mpmjax.run_scene(SCENE, tmp_path, OVER, quiet=True, resume=True)  # same scene and overrides given again
    _assert_same_result(reference / "result.h5", tmp_path / "result.h5")
    _same_summary(reference, tmp_path)


def test_resume_refuses_another_scene(tmp_path, capsys):
    with pytest.raises(mpmjax.Interrupted):
        mpmjax.run_scene(SCENE, tmp_path, OVER, quiet=True, on_frame=_stop_at(2, KeyboardInterrupt()))
    other = OVER + ["material.mu0_pa_s=5"]
    argv = ["run", SCENE, "--quiet", "--no-animation", "--resume", str(tmp_path)] + [
        a for o in other for a in ("--set", o)
    ]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "material.mu0_pa_s: 4.0 in the checkpoint, 5.0 now" in err and "Traceback" not in err
    # nothing was touched: the checkpoint and the partial result are still there
    assert read_checkpoint(tmp_path / "checkpoint.h5")[1] == 2
    assert read_result(tmp_path / "result.h5")["frames"]["t_s"].shape == (3,)


def test_resume_of_a_complete_run_or_empty_folder_is_an_input_error(reference, tmp_path, capsys):
    assert cli.main(["run", "--quiet", "--resume", str(reference)]) == 2
    assert "already complete" in capsys.readouterr().err
    assert cli.main(["run", "--quiet", "--resume", str(tmp_path)]) == 2
    assert "no checkpoint.h5" in capsys.readouterr().err
    assert cli.main(["run", "--quiet", "--checkpoint-every", "-1", "--out", str(tmp_path)]) == 2
    assert "--checkpoint-every" in capsys.readouterr().err


def _start_cli_run_until_checkpoint(out):
    """Start ``mpmjax run`` in a subprocess and return it once checkpoint.h5 (frame 2) is on disk."""
    cmd = [sys.executable, "-m", "mpmjax.cli", "run", SCENE, "--out", str(out), "--checkpoint-every", "2"]
    cmd += ["--quiet", "--no-animation"] + [a for o in OVER for a in ("--set", o)]
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stderr=subprocess.PIPE, text=True)
    t0 = time.time()
    while not (out / "checkpoint.h5").exists():
        assert proc.poll() is None, proc.stderr.read()
        assert time.time() - t0 < 120
        time.sleep(0.01)
    return proc


def test_ctrl_c_on_the_command_line_exits_130_and_resumes(reference, tmp_path):
    out = tmp_path / "run"
    proc = _start_cli_run_until_checkpoint(out)
    proc.send_signal(signal.SIGINT)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 130, err
    assert f"Resume with: mpmjax run --resume {out}" in err and "Traceback" not in err
    n = read_result(out / "result.h5")["frames"]["t_s"].shape[0]
    assert 3 <= n < N_FRAMES + 1  # interrupted after frame 2, before the end
    assert read_checkpoint(out / "checkpoint.h5")[1] == n - 1
    assert cli.main(["run", "--quiet", "--no-animation", "--resume", str(out)]) == 0
    _assert_same_result(reference / "result.h5", out / "result.h5")


def test_kill_9_leaves_readable_frames_and_resumes(reference, tmp_path):
    # the file of a running run can be read (the writer holds the HDF5 lock: read without it);
    # after SIGKILL nothing is closed, yet every flushed frame reads back, and --resume cuts
    # result.h5 back to the last periodic checkpoint and gives the uninterrupted result
    out = tmp_path / "run"
    proc = _start_cli_run_until_checkpoint(out)
    # freeze the run first: under load it could otherwise finish its remaining frames while the
    # live file is read, before the kill arrives (seen once on the loaded 2-core VM)
    proc.send_signal(signal.SIGSTOP)
    live = read_result(out / "result.h5")
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    ref = read_result(reference / "result.h5")
    part = read_result(out / "result.h5")
    n, n_live = part["frames"]["t_s"].shape[0], live["frames"]["t_s"].shape[0]
    assert 3 <= n_live <= n < N_FRAMES + 1 and "status" not in part["attrs"] and not part["attrs"]["complete"]
    for k in ref["frames"]:
        np.testing.assert_array_equal(part["frames"][k], ref["frames"][k][:n], err_msg=k)
        np.testing.assert_array_equal(live["frames"][k], ref["frames"][k][:n_live], err_msg=k)
    k_ckpt = read_checkpoint(out / "checkpoint.h5")[1]
    assert k_ckpt % 2 == 0 and k_ckpt <= n - 1
    assert cli.main(["run", "--quiet", "--no-animation", "--resume", str(out)]) == 0
    _assert_same_result(reference / "result.h5", out / "result.h5")
