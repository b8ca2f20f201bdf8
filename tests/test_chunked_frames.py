"""A frame stepped in chunks (issue 35): the driver steps a long frame as calls of about a second
(``_simulate.make_steps``, ``Pacer``, ``run_chunked``) so that Ctrl-C / SIGTERM is acted on within
seconds, where a frame of many steps used to be one XLA call that ran on after "interrupted at frame
0/1 ... Resume with" was printed.  The chunks must not change the results: any chunking gives the
frame of the one-call advance bit for bit, with and without hazard maps."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np

import mpmjax
from mpmjax import _hazard
from mpmjax._simulate import Pacer, StagedAdvance, make_frame_program

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["domain.cell_size_m=0.04", "time.t_end_s=0.2", "time.n_frames=2", "numerics.pressure=explicit"]


class Pattern(Pacer):
    """Chunks of the given lengths, over and over (whatever the time they take)."""

    def __init__(self, lengths):
        super().__init__()
        self.lengths, self.i, self.calls = list(lengths), 0, 0

    def next(self, left):
        n = self.lengths[self.i % len(self.lengths)]
        self.i += 1
        self.calls += 1
        return max(1, min(n, left))

    def took(self, n, seconds):
        pass


def _same(a, b):
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_any_chunking_gives_the_one_call_frame_bit_for_bit():
    s = mpmjax.build(mpmjax.load_scene("dambreak-lab", SMALL))
    sc, st, p = s.scene, s.state, s.params
    one_call = mpmjax.make_advance(sc)  # a frame as one lax.scan, as the driver stepped it before chunks
    prog = make_frame_program(sc, sc.n_particles)  # one program (compiled once) for every chunking
    chunked = {k: StagedAdvance(sc, compile=lambda n: prog, pacer=Pattern(k)) for k in ((1,), (3, 7, 1), (10**9,))}
    ref = st
    states = dict.fromkeys(chunked, st)
    for i in range(sc.n_frames):
        ref = one_call(ref, p)
        for k, adv in chunked.items():
            states[k] = adv(i, states[k], p)
            _same(ref, states[k])
    assert chunked[(1,)].pacer.calls == sc.n_steps  # one step a call: the most a frame is ever cut
    assert float(ref.t) > 0.19 and bool(np.any(np.asarray(ref.v) != 0))  # it moved


def test_hazard_maps_are_the_same_whatever_the_chunks():
    cfg = mpmjax.load_scene("dambreak-lab", SMALL + ["output.hazard_maps=true", "output.hazard_every_steps=3"])
    s = mpmjax.build(cfg)
    grid = _hazard.HazardGrid.of(s.scene, cfg)
    whole = _hazard.HazardAdvance(s.scene, s.state, s.params, grid, pacer=Pattern((10**9,)))
    cut = _hazard.HazardAdvance(s.scene, s.state, s.params, grid, pacer=Pattern((2, 5)))
    a = b = s.state
    for i in range(s.scene.n_frames):
        a, b = whole(i, a, s.params), cut(i, b, s.params)
    _same(a, b)
    _same(whole.maps, cut.maps)
    one_call = mpmjax.make_advance(s.scene)
    _same(a, one_call(one_call(s.state, s.params), s.params))
    assert int(cut.maps.steps) == s.scene.n_steps and float(np.max(np.asarray(cut.maps.max_speed))) > 0


def test_the_pacer_aims_at_a_second_a_chunk():
    pc = Pacer(target_s=1.0)
    assert pc.next(1000) == 1
    pc.took(1, 0.001)
    assert pc.next(10**6) == 4  # grows at most fourfold a chunk (the first call may include a compilation)
    for _ in range(10):
        pc.took(pc.next(10**6), pc.next(10**6) * 0.001)  # a millisecond a step
    assert pc.next(10**6) == 1000 and pc.next(37) == 37
    pc.took(1000, 10.0)  # slower now: ten times shorter chunks
    assert pc.next(10**6) == 100


def test_sigint_inside_a_long_frame_stops_the_run_within_seconds(tmp_path):
    """One frame of ten seconds or more: SIGINT a second into it ends the run by its own handler
    (between two chunks) within a few seconds, before the watchdog's 5 s, with the run's line and
    summary.json 'interrupted'; the checkpoint is frame 0's, from which --resume continues."""
    env = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "mpmjax.cli", "run", "dambreak-lab", "--no-animation", "--out", "o",
           "--set", "domain.cell_size_m=0.02", "--set", "time.t_end_s=30", "--set", "time.n_frames=1"]
    p = subprocess.Popen(cmd, cwd=tmp_path, env=env, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    err = ""
    while "compiled in" not in err:
        line = p.stderr.readline()
        assert line or p.poll() is None, err
        err += line
    time.sleep(1.0)
    p.send_signal(signal.SIGINT)
    t0 = time.perf_counter()
    try:
        err += p.communicate(timeout=30)[1]
    except subprocess.TimeoutExpired:
        p.kill()
        raise AssertionError("still running 30 s after the signal") from None
    waited = time.perf_counter() - t0
    assert p.returncode == 130, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("interrupted at frame 0/1") and "Resume with: mpmjax run --resume o" in last, err
    assert waited < 4.5 and "stopped inside a computation" not in err, (waited, err)
    doc = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert doc["status"] == "interrupted" and not doc["complete"]
    assert (tmp_path / "o" / "checkpoint.h5").is_file()
