"""Column splitting of the depth-averaged step (``numerics.split_levels``, ``mpmjax._split``): a column
whose neighbours are more than a cell away is split into 2^k columns of equal volume.

* one split, on a hand-made state: mass, momentum and the volume centroid unchanged to round-off
  (the children sit symmetrically about the parent with its velocity), the children carry the
  parent's internal variables, only never-used spare slots are taken (a column that left the domain
  is not one), with too few slots the sparse columns split in order until they run out, and reverse
  mode through a split is finite;
* the fast Bingham slump of tests/test_depth_averaged.py (tau_y = 40 Pa, 4 columns a cell), whose
  under-resolved tip creeps after arrest there (a strict xfail: 0.774 m at 3 s, 0.780 m at 4 s, 5-9 cm/s),
  with one level of splitting: at rest (under 1e-6 m/s at 4 s, the other test's bound; measured 8e-8),
  its front fixed from 3 to 4 s (under 0.1 mm) and within 1 mm of the resolved run's (8 columns a cell,
  no splitting: 0.7443 m; measured 0.74443 m with splitting);
* the sensitivity of the volume centroid to the yield stress through the arrest (20 Pa, 4 columns a
  cell, 3 s), forward mode against a central difference: 3.6 times off without splitting (jvp -2.30e-2
  against -6.4e-3 m/Pa, docs/depth-averaged.md "Creep after arrest"), with two levels -5.77e-3 against
  -5.92e-3 (2.6 %); bound 10 %: a split is a jump in the state, so the derivative between splits and the
  difference across them differ by the splits that move (as for columns crossing the front threshold);
* a run through the driver, interrupted and resumed: result.h5 keeps each frame's volumes, so
  ``mpmjax.plotting.runout`` of the saved run equals summary.json's series, the mass is the initial one to
  round-off, and a pool too small for the splits is used up and said in the summary's warnings (a resumed
  run with splits equals the uninterrupted one bit for bit: measured on the same scene, 10 frames,
  interrupted at 7; the resume tests of tests/test_driver_resume.py hold that for the full model).
"""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mpmjax import _split
from mpmjax._build import build
from mpmjax._observables import free_surface_front
from mpmjax._scene import State
from mpmjax._schema import SceneError, validate
from mpmjax._simulate import simulate


def _state(x, vol, v, active, lam):
    n, dim = x.shape
    f = jnp.float64
    return State(
        x=jnp.asarray(x, f), v=jnp.asarray(v, f), C=jnp.zeros((n, dim, dim), f), tau=jnp.zeros((n, dim, dim), f),
        J=jnp.ones((n,), f), vol0=jnp.asarray(vol, f), mu=jnp.ones((n,), f), internal={"lam": jnp.asarray(lam, f)},
        active=jnp.asarray(active, bool), gate=jnp.zeros((n,), bool), t=jnp.asarray(0.0, f),
        n_lost=jnp.asarray(0, jnp.int32),
    )


@pytest.mark.parametrize("dim", [2, 3])
def test_a_split_conserves_mass_momentum_and_the_centroid(dim):
    k, h = dim - 1, 0.1
    m = 2**k
    rng = np.random.default_rng(3)
    # columns 0-2 seeded, 3 a column that has left the domain (inactive, volume > 0), 4.. spare slots: two splits' worth
    n = 4 + 2 * (m - 1)
    x = np.zeros((n, dim))
    x[:3, :k] = 0.5 + rng.uniform(-0.2, 0.2, (3, k))
    x[:, k] = 0.05
    vol = np.array([2e-3, 1e-3, 4e-3, 5e-3] + [0.0] * (n - 4))
    v = np.zeros((n, dim))
    v[:4, :k] = rng.normal(size=(4, k))
    active = np.array([True] * 3 + [False] * (n - 3))
    lam = np.arange(n, dtype=float)
    H = np.array([2.0, 0.5, 0.1] + [0.0] * (n - 3)) * vol / h**k  # column 0 dense (H h^k > V); 1 and 2 sparse
    st = _state(x, vol, v, active, lam)

    def split(state, H_p, v_min=1e-6):  # compiled: op by op it takes seconds
        run = jax.jit(lambda s_, H_: _split.split(s_, H_, k=k, h=h, v_min=v_min, lo=[0.0] * k, hi=[1.0] * k))
        return run(state, jnp.asarray(H_p))

    new = split(st, H)

    def totals(s):
        w = np.asarray(s.vol0) * np.asarray(s.active)
        return w.sum(), (w[:, None] * np.asarray(s.v)).sum(0), (w[:, None] * np.asarray(s.x)[:, :k]).sum(0) / w.sum()

    for a, b in zip(totals(st), totals(new)):
        np.testing.assert_allclose(b, a, rtol=1e-13, atol=1e-15)
    assert int(np.asarray(new.active).sum()) == 3 + 2 * (m - 1)  # both sparse columns split, m children each
    assert float(new.vol0[3]) == 5e-3 and not bool(new.active[3])  # the departed column's slot is not reused
    assert float(new.vol0[0]) == 2e-3 and np.array_equal(np.asarray(new.x[0]), x[0])  # the dense one untouched
    kids = np.asarray(new.active) & ~active
    assert set(np.asarray(new.internal["lam"])[kids]) == {1.0, 2.0}  # the parents' internal variables
    np.testing.assert_allclose(np.asarray(new.vol0)[kids], np.repeat([1e-3 / m, 4e-3 / m], m - 1))

    # one slot short: the first sparse column splits, the second waits (nothing else changes)
    short = _state(x[:-1], vol[:-1], v[:-1], active[:-1], lam[:-1])
    new = split(short, H[:-1])
    assert float(new.vol0[1]) == pytest.approx(1e-3 / m) and float(new.vol0[2]) == 4e-3
    # reverse mode through a split is finite, in float64 and float32: a spare slot's volume 0 under the footprint's
    # root gave NaN in 2-D, and in float32 so did the departed column (volume > 0, depth 0: 1 / 1e-30^2 = inf)
    for dt in (jnp.float64, jnp.float32):
        s_ = jax.tree_util.tree_map(lambda a: a.astype(dt) if jnp.issubdtype(a.dtype, jnp.floating) else a, st)
        grad = jax.jit(jax.grad(lambda vol, H_, s_=s_: jnp.sum(_split.split(
            s_._replace(vol0=vol), H_, k=k, h=h, v_min=1e-6, lo=[0.0] * k, hi=[1.0] * k).x), argnums=(0, 1)))
        for g in grad(s_.vol0, jnp.asarray(H, dt)):
            assert np.all(np.isfinite(np.asarray(g))), dt
    # children smaller than v_min: no split
    new = split(st, H, v_min=1e-3)
    assert float(new.vol0[1]) == 1e-3 and float(new.vol0[2]) == pytest.approx(4e-3 / m)


def _slump(tau_y, ppc, levels, t_end, pool=0.25):
    return validate({
        "model": {"formulation": "depth-averaged"},
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [1.2, 0.2], "cell_size_m": 0.005},
        "boundary": {"x_lo": "slip", "x_hi": "open"},
        "numerics": {"shape": "quadratic", "ppc": ppc, "dtype": "float64", "split_levels": levels, "split_pool": pool},
        "material": {"model": "bingham", "viscosity_pa_s": 0.5, "yield_stress_pa": tau_y, "density_kg_m3": 1000.0,
                     "bulk_modulus_pa": 1e5},
        "time": {"t_end_s": t_end, "n_frames": int(t_end)},
        "bodies": [{"type": "box", "lo_m": [0.0, 0.0], "hi_m": [0.3, 0.1]}],
    })


def test_a_split_tip_stays_at_rest_after_arrest():
    s = build(_slump(40.0, 4, 1, 4.0))
    fin, fr = jax.jit(simulate, static_argnums=(0, 3))(s.scene, s.state, s.params)
    assert fr.vol0 is not None  # the frames keep their volumes where columns split (None elsewhere)
    fronts = [float(free_surface_front(fr.x[i], fr.vol0[i], fr.active[i], bandwidth=0.01, x_lo=0.0, x_hi=1.2))
              for i in range(4)]
    assert float(jnp.abs(fin.v).max()) < 1e-6
    assert abs(fronts[3] - fronts[2]) < 1e-4
    assert fronts[3] == pytest.approx(0.7443, abs=1e-3)
    assert float(jnp.sum(fin.vol0 * fin.active)) == pytest.approx(0.03, rel=1e-12)
    assert int(fin.active.sum()) > 240  # columns were split (240 seeded)


def test_the_sensitivity_through_arrest_with_split_columns():
    s = build(_slump(20.0, 4, 2, 3.0))

    def centroid(t):
        p = s.params._replace(material=s.params.material._replace(tau_y=t))
        fin, _ = simulate(s.scene, s.state, p)
        w = fin.vol0 * fin.active
        return jnp.sum(w * fin.x[:, 0]) / jnp.sum(w)

    f = jax.jit(centroid)
    t = jnp.asarray(20.0)
    _, jv = jax.jit(lambda t: jax.jvp(centroid, (t,), (jnp.ones_like(t),)))(t)
    fd = (float(f(t + 0.1)) - float(f(t - 0.1))) / 0.2
    assert fd < 0
    assert float(jv) == pytest.approx(fd, rel=0.10)


def test_split_levels_is_refused_in_the_full_model():
    raw = {
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [1.0, 0.2], "cell_size_m": 0.05},
        "material": {"model": "newtonian", "viscosity_pa_s": 1.0, "density_kg_m3": 1000.0, "bulk_modulus_pa": 1e5},
        "numerics": {"split_levels": 1},
        "time": {"t_end_s": 0.1},
        "bodies": [{"type": "box", "lo_m": [0.0, 0.0], "hi_m": [0.2, 0.1]}],
    }
    with pytest.raises(SceneError, match="numerics.split_levels = 1 is invalid with model.formulation = 'full'"):
        validate(raw)
    # unset, the depth-averaged default (3) falls back to 0 in the full model, and the saved scene says so
    del raw["numerics"]
    assert validate(raw)["numerics.split_levels"] == 0
    assert validate(dict(raw, model={"formulation": "depth-averaged"}))["numerics.split_levels"] == 3


def test_a_run_with_split_columns_saves_its_volumes(tmp_path):
    import mpmjax
    from mpmjax._io import read_result
    from mpmjax.plotting import runout

    scene = tmp_path / "split.toml"
    scene.write_text(
        'name = "split"\n[model]\nformulation = "depth-averaged"\n'
        '[domain]\ndim = 2\nlo_m = [0.0, 0.0]\nhi_m = [1.2, 0.2]\ncell_size_m = 0.01\n'
        '[boundary]\nx_lo = "slip"\nx_hi = "open"\n'
        '[numerics]\nshape = "quadratic"\nppc = 2\ndtype = "float64"\nsplit_levels = 2\nsplit_pool = 0.05\n'
        '[material]\nmodel = "bingham"\nviscosity_pa_s = 0.5\nyield_stress_pa = 20.0\ndensity_kg_m3 = 1000.0\n'
        'bulk_modulus_pa = 1e5\n[time]\nt_end_s = 1.0\nn_frames = 4\n'
        '[[bodies]]\ntype = "box"\nlo_m = [0.0, 0.0]\nhi_m = [0.3, 0.1]\n'
    )
    out = tmp_path / "run"

    def stop(frame, state):
        if frame == 2:
            raise KeyboardInterrupt()

    with pytest.raises(mpmjax.Interrupted):  # interrupted and resumed: result.h5's volumes reopen with the rest
        mpmjax.run_scene(str(scene), out, [], quiet=True, checkpoint_every=1, on_frame=stop)
    mpmjax.run_scene(str(scene), out, [], quiet=True, checkpoint_every=1, resume=True)
    summary = json.loads((out / "summary.json").read_text())
    res = read_result(out / "result.h5")
    vols = np.asarray(res["frames"]["vol0_m3"])
    assert vols.shape == (5, 60 + 3)  # 60 columns, 3 spare slots
    assert summary["split_columns"]["spare_slots"] == 3 == summary["split_columns"]["slots_used"]
    assert any("used 3 of its 3 spare slots" in w for w in summary["warnings"])
    assert summary["mass_final_kg"] == pytest.approx(summary["mass_initial_kg"], rel=1e-12)
    assert (vols[-1] * res["frames"]["active"][-1]).sum() == pytest.approx(0.03, rel=1e-12)
    np.testing.assert_allclose(runout(out)[1], summary["runout_m"], rtol=0, atol=1e-9)


def test_the_command_line_steps_only_the_spare_slots_in_use():
    """The command line's frame advance (``_simulate.StagedAdvance`` given the scene's pool) steps the seeded columns
    and the part of the spare slots in use, on a few prefix sizes, and reruns a frame on the next size up where its
    splits filled the prefix: the fast slump (20 Pa, 4 columns a cell, two levels, a pool of 0.5: 240 columns and 120
    slots), 8 frames of 0.25 s, against the same frames on the whole buffer.  Equal to 1e-12 m (float64; programs
    compiled for other array sizes may round differently), and both paths of the staging taken: frames on a prefix
    short of the buffer and at least one rerun on a larger one (measured: 32 of the 120 slots used by 2 s,
    on prefixes of 255 to 300, one rerun)."""
    from mpmjax._simulate import StagedAdvance

    cfg = _slump(20.0, 4, 2, 2.0, pool=0.5)
    cfg["time.n_frames"] = 8
    s = build(cfg)
    N, pool = s.scene.n_particles, int(s.info["split_pool"])
    assert (N, pool) == (360, 120)
    staged = StagedAdvance(s.scene, min_size=8, split_pool=pool)
    assert staged.split_sizes == (255, 270, 300)  # the seeded 240 and the pool's first eighth, quarter and half
    whole = StagedAdvance(s.scene, staged=False)
    a = b = s.state
    for i in range(8):
        a, b = whole(i, a, s.params), staged(i, b, s.params)
        np.testing.assert_allclose(np.asarray(b.x), np.asarray(a.x), rtol=0, atol=1e-12)
        np.testing.assert_array_equal(np.asarray(b.vol0), np.asarray(a.vol0))
        np.testing.assert_array_equal(np.asarray(b.active), np.asarray(a.active))
    assert int(a.active.sum()) > 240  # it split
    assert min(staged.schedule) < N and staged.fallbacks >= 1, (staged.schedule, staged.fallbacks)
