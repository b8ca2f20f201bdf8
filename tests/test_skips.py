"""Static skips (docs/performance.md, "Static skips"): what a scene lacks costs nothing.

* a Newtonian or Bingham scene carries no structure parameter lambda and its step does no
  Coussot arithmetic (the rheology object is static: the step is traced for that model only);
* a 2D scene has 2D arrays and a 3 x 3 stencil, not a 3D one;
* a pipe pour steps only the released part of its particle pool (``_simulate.StagedAdvance``):
  the frames, the checkpoint and a resumed run are those of the run over the whole buffer.

The pour is 2D Newtonian at 2 cm cells: 35 layers of 4 particles (140 in all, none at
t = 0) leave a 4 cm pipe at 0.5 m/s between 0.1 s and 0.8 s; 9 frames of 0.1 s.
"""

import json

import h5py
import jax
import numpy as np
import pytest
from conftest import stub_result_pictures

import mpmjax
from mpmjax import _driver, _simulate
from mpmjax import build, load_scene, validate
from mpmjax._io import read_checkpoint, read_result
from mpmjax._simulate import StagedAdvance, capacity_schedule
from mpmjax._step import make_step
from mpmjax._transfer import _Stencil

POUR = """
name = "skips-pour"
description = "2D Newtonian pipe pour for tests/test_skips.py"
bodies = []
[domain]
dim = 2
lo_m = [0.0, 0.0]
hi_m = [1.0, 0.3]
cell_size_m = 0.02
[numerics]
ppc = 2
dtype = "float64"
[time]
t_end_s = 0.9
n_frames = 9
[material]
model = "newtonian"
density_kg_m3 = 1000.0
bulk_modulus_pa = 2e4
viscosity_pa_s = 0.5
[inflow]
point_m = [0.1, 0.04]
direction = [1.0, 0.0]
width_m = 0.04
flow_rate_m3_s = 0.02
t_start_s = 0.1
t_stop_s = 0.8
"""
MIN = 30  # stage down to 30 particles here (the default, 256, would not stage a pool this small)


@pytest.fixture(scope="module")
def pour_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("scene") / "pour.toml"
    p.write_text(POUR)
    return p


@pytest.fixture(scope="module")
def pour(pour_file):
    return build(load_scene(str(pour_file), []))


def _run(pour_file, out, staged, **kw):
    """run_scene with the test's stage size; the results are compared as result.h5 arrays, so the
    pictures are not drawn (conftest.stub_result_pictures)."""
    old = _simulate.MIN_STAGE
    _simulate.MIN_STAGE = MIN
    try:
        with pytest.MonkeyPatch.context() as mp:
            stub_result_pictures(mp)
            return mpmjax.run_scene(str(pour_file), out, [], quiet=True, staged=staged, **kw)
    finally:
        _simulate.MIN_STAGE = old


@pytest.fixture(scope="module")
def runs(pour_file, tmp_path_factory):
    staged = tmp_path_factory.mktemp("staged")
    full = tmp_path_factory.mktemp("full")
    return _run(pour_file, staged, True, checkpoint_every=0), staged, _run(pour_file, full, False), full


def _datasets(path):
    with h5py.File(path, "r") as f:
        out = {}
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
    return out


def test_schedule_holds_every_released_particle_and_halves_the_buffer(pour):
    sc = pour.scene
    inf = sc.inflow
    N = sc.n_particles
    assert (inf.first, inf.n_layers, inf.n_per_layer, N) == (0, 35, 4, 140)
    sched = capacity_schedule(sc, min_size=MIN)
    assert len(sched) == sc.n_frames
    # a few sizes N / 2^j, never shrinking, the last frames on the whole buffer
    assert sched == tuple(sorted(sched)) and sched[-1] == N
    assert set(sched) == {35, 70, 140}
    # every frame holds the layers due by its end (t_k < t_end of the frame), plus slack
    for i, n in enumerate(sched):
        t_end = (i + 1) * sc.steps_per_frame * sc.dt
        due = int(np.sum(inf.t_start + np.arange(inf.n_layers) * inf.layer_dt < t_end)) * inf.n_per_layer
        assert n >= due
    # without an inflow nothing is staged
    assert set(capacity_schedule(sc.replace(inflow=None), min_size=MIN)) == {N}


def test_staged_run_equals_the_full_buffer_run(runs):
    """Same frames to float64 rounding (the prefix programs are compiled for other array
    sizes, and XLA may order a few float operations differently: measured differences
    ~1e-14 m after 9 frames): same active set, positions within 1e-9 m, velocities
    within 1e-8 m/s; the released mass is exact."""
    s_st, d_st, s_full, d_full = runs
    a, b = _datasets(d_st / "result.h5"), _datasets(d_full / "result.h5")
    assert sorted(a) == sorted(b)
    fr = read_result(d_st / "result.h5")["frames"]
    assert fr["x_m"].shape == (10, 140, 2)  # frames stay full-size arrays
    np.testing.assert_array_equal(a["frames/active"], b["frames/active"])
    assert 0 < a["frames/active"][-1].sum() == 140  # all 35 layers released by 0.9 s
    # the pipe opens at 0.1 s (the end of frame 1, give or take the rounding of the running time)
    assert not a["frames/active"][0].any() and a["frames/active"][1].sum() <= 4 and a["frames/active"][2].sum() > 4
    np.testing.assert_allclose(a["frames/x_m"], b["frames/x_m"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(a["frames/v_m_s"], b["frames/v_m_s"], rtol=0, atol=1e-8)
    np.testing.assert_allclose(a["frames/J"], b["frames/J"], rtol=0, atol=1e-10)
    np.testing.assert_array_equal(a["frames/t_s"], b["frames/t_s"])
    # inactive particles as before: parked at the pipe, at rest
    park = a["frames/active"][3] == 0
    np.testing.assert_array_equal(a["frames/x_m"][3][park], b["frames/x_m"][3][park])
    assert s_st["mass_final_kg"] == s_full["mass_final_kg"] and s_st["n_lost"] == s_full["n_lost"] == 0


def test_staged_run_resumes_bit_for_bit(runs, pour_file, tmp_path):
    _, d_st, _, _ = runs

    def stop(frame, state):
        if frame == 3:  # mid-pour, on the middle stage
            raise KeyboardInterrupt

    with pytest.raises(mpmjax.Interrupted):
        _run(pour_file, tmp_path, True, checkpoint_every=2, on_frame=stop)
    state, frame, _, _ = read_checkpoint(tmp_path / "checkpoint.h5")
    assert frame == 3 and np.asarray(state.x).shape == (140, 2)  # the whole buffer is checkpointed
    old = _simulate.MIN_STAGE
    _simulate.MIN_STAGE = MIN
    try:
        mpmjax.run_scene(None, tmp_path, None, quiet=True, resume=True)
    finally:
        _simulate.MIN_STAGE = old
    a, b = _datasets(d_st / "result.h5"), _datasets(tmp_path / "result.h5")
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    sa, sb = (json.loads((p / "summary.json").read_text()) for p in (d_st, tmp_path))
    assert sa["final_runout_m"] == sb["final_runout_m"] and sa["mass_final_kg"] == sb["mass_final_kg"]


def test_a_short_prefix_falls_back_to_the_whole_buffer(pour, runs):
    """A prefix that misses a layer due in the frame (or an active particle beyond it) is never
    used: the frame is rerun on the whole buffer, so the result is the full run's, bit for bit."""
    sc, st0, p = pour.scene, pour.state, pour.params

    def compiled(n):  # the programs the command-line runs above compiled (process cache)
        return _driver._compiled_advance(sc, st0, p, n)

    full = compiled(sc.n_particles)
    adv = StagedAdvance(sc, min_size=MIN, compile=compiled)
    adv.schedule = (35,) * sc.n_frames  # frames 3.. release more than 35 particles
    a = b = st0
    for i in range(5):
        a, b = full(a, p, np.int32(sc.steps_per_frame)), adv(i, b, p)  # one chunk of a whole frame
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert int(np.asarray(b.active).sum()) > 35 and adv.fallbacks >= 1


def test_newtonian_and_bingham_carry_no_lambda_and_do_no_coussot_work():
    def step_prims(s):
        jaxpr = jax.make_jaxpr(make_step(s.scene))(s.state, s.params)
        return [e.primitive.name for e in jaxpr.jaxpr.eqns]

    base = ["time.t_end_s=0.01", "time.n_frames=1", "domain.cell_size_m=0.02"]
    sets = {
        "newtonian": ["material.model=newtonian", "material.viscosity_pa_s=4.0"],
        "bingham": ["material.model=bingham", "material.viscosity_pa_s=0.65", "material.yield_stress_pa=36.0"],
        "coussot": [],
    }
    setups = {m: build(load_scene("dambreak-lab", base + o)) for m, o in sets.items()}
    for m in ("newtonian", "bingham"):
        s = setups[m]
        assert s.state.internal == {} and s.scene.rheology.internal_fields == ()
        # one leaf fewer than the Coussot state: no per-particle lambda array anywhere
        assert len(jax.tree_util.tree_leaves(s.state)) == len(jax.tree_util.tree_leaves(setups["coussot"].state)) - 1
    assert set(setups["coussot"].state.internal) == {"lam"}
    # lambda^n (Coussot's mu = mu0 (1 + lambda^n)) is the only power in the step: traced only for Coussot
    assert "pow" in step_prims(setups["coussot"])
    for m in ("newtonian", "bingham"):
        assert "pow" not in step_prims(setups[m])
    # and the Coussot step is the longer program (lambda update, cap, gate hold)
    assert len(step_prims(setups["coussot"])) > len(step_prims(setups["newtonian"]))


def test_2d_has_no_third_dimension():
    s = build(validate({**json.loads(json.dumps(_2d_raw())), "name": "skips-2d"}))
    st = s.state
    assert st.x.shape[1] == 2 and st.C.shape[1:] == (2, 2) and st.tau.shape[1:] == (2, 2)
    assert len(s.scene.grid_shape) == 2
    # GIMP: 3 nodes per axis, 3^2 = 9 stencil nodes per particle (not 27)
    w = jax.eval_shape(lambda x: _Stencil(s.scene, x).w, st.x)
    assert w.shape == (st.x.shape[0], 9)


def _2d_raw():
    return {
        "domain": {"lo_m": [0.0, 0.0], "hi_m": [0.4, 0.2], "cell_size_m": 0.02},
        "numerics": {"ppc": 2, "shape": "gimp"},
        "time": {"t_end_s": 0.01, "n_frames": 1},
        "material": {"model": "newtonian", "density_kg_m3": 1000.0, "bulk_modulus_pa": 2e4, "viscosity_pa_s": 0.5},
        "bodies": [{"lo_m": [0.0, 0.0], "hi_m": [0.1, 0.1]}],
    }
