"""One simulation on slabs of the grid across devices (``numerics.decomposition = "slab"``, ``mpmjax._slab``)."""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mpmjax as m
from mpmjax import _slab
from mpmjax._build import build, memory_estimate

ROOT = Path(__file__).resolve().parent.parent

# Runs in a fresh process with 3 host devices.  The lab dam break at h = 0.02 m, float64, 0.161 s
# (128 steps), from its state less the last particle (399), on one device and on 2 slabs:
# * "slab": rebalanced every REBALANCE_STEPS (32) steps, so 4 blocks of 32 (3 rebalancings after the
#   first dealing); no remainder block, which would compile a second block into each slab program;
# * "fixed": one block of 128 steps (REBALANCE_STEPS raised), the slab edges of t = 0 kept
#   throughout, so the particles that cross the edge reach the other device only by migration;
#   "crossed" counts them (the device they sit on under the first edges, at the start and at the end);
#   the final states of the gradient's programs below (its auxiliary output: the same forward pass);
# * "jbar": the J-bar volume averaging (a second grid sum through the halo) with the
#   boundary-modified quadratic B-spline (box-wall index arithmetic in the stencil);
# * "starved": slab_capacity 0.8, so 2 devices have slots for 2 x 160 = 320 of the 399: the rest are
#   dropped at the first dealing, which the lost count must say; 64 steps, 2 blocks: the rebalancing
#   at step 32 drops no more (measured: by step 96, with the column spread, 9 more are dropped);
# * "three": 3 slabs: the column fills a third of the grid, so the slab edges crowd into it.
# "slab", "starved" (its lost count) and "three" share one one-device run (the same program and state).
# And d(mean x)/d mu0 by reverse mode over the 128 steps with the t = 0 edges kept (so that particles
# migrate under the derivative), slabs against one device.
_CODE = """
import json, jax, jax.numpy as jnp, numpy as np
from mpmjax import _slab
from mpmjax._build import build, memory_estimate
from mpmjax._schema import load_scene
from mpmjax._simulate import make_chunk
ov = ["domain.cell_size_m=0.02", "time.t_end_s=0.161", "time.n_frames=1", "numerics.dtype=float64", "numerics.ppc=2",
      "numerics.devices=2", "numerics.decomposition=slab", "numerics.pressure=explicit"]
out = {"n_dev": jax.device_count()}
def cut(setup):
    n = setup.scene.n_particles
    return jax.tree_util.tree_map(lambda a: a[:-1] if a.ndim and a.shape[0] == n else a, setup.state)
def run(sc, s0, p, n=None):
    return jax.jit(make_chunk(sc, n or sc.n_steps))(s0, p)
def diff(one, two, s0):
    return {"dx": float(np.abs(np.asarray(two.x) - np.asarray(one.x)).max()),
            "dJ": float(np.abs(np.asarray(two.J) - np.asarray(one.J)).max()),
            "moved": float(np.abs(np.asarray(one.x) - np.asarray(s0.x)).max()),
            "lost": [int(one.n_lost), int(two.n_lost)], "t": [float(one.t), float(two.t)],
            "active": int(np.asarray(two.active).sum()), "sharded": len(two.x.sharding.device_set)}
setup = build(load_scene("dambreak-lab", ov))
sc, p, s0 = setup.scene, setup.params, cut(setup)
out["steps"], out["n"] = sc.n_steps, int(s0.x.shape[0])
one = run(sc.replace(devices=1), s0, p)
out["slab"] = diff(one, run(sc, s0, p), s0)
starved = sc.replace(slab_capacity=0.8)  # below the key's range: a direct test
two = run(starved, s0, p, 64)
out["starved"] = {"lost": [int(one.n_lost), int(two.n_lost)], "active": int(np.asarray(two.active).sum()),
                  "capacity": _slab.geometry(starved, out["n"]).capacity}
out["three"] = diff(one, run(sc.replace(devices=3), s0, p), s0)
jb = build(load_scene("dambreak-lab", ov + ["numerics.volume_averaging=jbar", "numerics.shape=quadratic_bm"]))
out["jbar"] = diff(run(jb.scene.replace(devices=1), cut(jb), jb.params), run(jb.scene, cut(jb), jb.params), cut(jb))
from mpmjax._hazard import HazardAdvance, HazardGrid
out["hazard"] = {}
for every in (1, 2):
    cfg = load_scene("dambreak-lab", ov + ["output.hazard_maps=true", f"output.hazard_every_steps={every}",
                                          "time.n_frames=2"])
    setup = build(cfg)
    maps = {}
    for d in (1, 2):
        sc_d = setup.scene.replace(devices=d)
        adv, st = HazardAdvance(sc_d, cut(setup), setup.params, HazardGrid.of(sc_d, cfg)), cut(setup)
        for i in range(sc_d.n_frames):
            st = adv(i, st, setup.params)
        maps[d] = {k: np.asarray(v) for k, v in adv.maps._asdict().items()}
    out["hazard"][str(every)] = {k: float(np.abs(maps[1][k] - maps[2][k]).max()) for k in maps[1]}
    out["hazard"][str(every)].update(steps=[int(maps[1]["steps"]), int(maps[2]["steps"])],
                                     wet=int((maps[1]["arrival"] >= 0).sum()), top=float(maps[1]["max_speed"].max()))
_slab.REBALANCE_STEPS = 1000
grads, ends = {}, {}
for d in (1, 2):
    def loss(mu0):
        q = p._replace(material=p.material._replace(mu0=mu0))
        end = make_chunk(sc.replace(devices=d), sc.n_steps)(s0, q)
        return jnp.mean(end.x[:, 0]), end
    (v, ends[d]), g = jax.jit(jax.value_and_grad(loss, has_aux=True))(p.material.mu0)
    grads[d] = [float(v), float(g)]
out["grad"] = grads
out["fixed"] = diff(ends[1], ends[2], s0)
geo = _slab.geometry(sc, out["n"])
edge = int(jax.jit(lambda s: _slab._distribute(sc, geo, s)[2])(s0)[1, 0])
dev = lambda s: np.asarray(_slab.first_plane(sc, s.x)) >= edge
out["fixed"]["crossed"] = int(np.sum(dev(s0) != dev(ends[2])))
out["fixed"]["edge"] = [edge, int(sc.grid_shape[0])]
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def two_device_run():
    flags = os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=3"
    env = dict(os.environ, XLA_FLAGS=flags, JAX_PLATFORMS="cpu")
    p = subprocess.run([sys.executable, "-c", _CODE], capture_output=True, text=True, env=env, cwd=ROOT, timeout=900)
    assert p.returncode == 0, p.stderr[-3000:]
    return json.loads(p.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("case", ["slab", "fixed", "jbar", "three"])
def test_slabs_give_the_one_device_positions(two_device_run, case):
    """The lab dam break (399 particles, float64, 128 steps) on 2 slabs ends where it ends on one
    device, to 1e-12 m in position and 1e-11 in J: rebalanced every 32 steps, with the first slab
    edges kept (particles cross only by migration), with J-bar's second grid sum, and on 3 slabs
    (the column fills a third of the grid: two slab edges inside it).

    As for the replicated layout (tests/test_parallel_shard.py), only the order of the additions that
    build the grid differs (the halo planes are summed from two partial grids), a few float64
    roundings per nodal sum, grown by the steps to the measured 2.2e-16 m (1.1-2.8e-15 in J).  A halo plane not
    added or not sent back, a particle on the wrong slab (its stencil outside the window the
    device holds) or one lost or duplicated in migration moves particles by at least
    O(dt^2 g) = 1e-5 m per step, 1e7 times more than the tolerance.
    """
    r = two_device_run
    c = r[case]
    assert r["n_dev"] == 3 and r["steps"] > 100 and r["n"] == 399, r
    assert c["sharded"] == (3 if case == "three" else 2), c
    assert c["moved"] > 1e-3, c  # the block has flowed: the comparison is not of a state at rest
    assert c["dx"] < 1e-12, c
    assert c["dJ"] < 1e-11, c
    assert c["lost"] == [0, 0] and c["t"][0] == c["t"][1] and c["active"] == 399, c


@pytest.mark.parametrize("every", ["1", "2"])
def test_hazard_maps_on_slabs_equal_one_device(two_device_run, every):
    """Hazard maps (output.hazard_maps) sampled inside the slab advance, each device binning its own
    particles and the bin sums added over devices, equal one device's maps: the lab dam break above,
    2 frames of 64 steps (each frame dealt out, and rebalanced at its step 32), sampled every step
    and every second step.  Tolerance as for the positions
    (1e-12 in m, m/s, m^2/s and s): the bins read positions and velocities equal to rounding, and a
    particle in the wrong bin, a device's particles left out or counted twice would change a bin's
    depth by a particle's rest volume per bin area, about 2e-2 m here."""
    c = two_device_run["hazard"][every]
    assert c["steps"][0] == c["steps"][1] > 100, c
    assert c["wet"] >= 10 and c["top"] > 0.1, c  # the maps saw the flow
    for k in ("max_depth", "max_speed", "max_depth_speed", "arrival"):
        assert c[k] < 1e-12, (k, c)


def test_particles_migrate_between_slabs(two_device_run):
    """With the slab edges of t = 0 kept for all 128 steps, particles that flow across the edge are
    carried to the other device by migration alone, and the result still equals one device's
    (previous test): the column collapses rightwards over the edge, which splits it in two halves
    by count, so a good share of the particles crosses (measured: 40 of 399)."""
    c = two_device_run["fixed"]
    assert 0 < c["edge"][0] < c["edge"][1], c
    assert c["crossed"] >= 10, c


def test_a_device_out_of_slots_counts_the_particles_it_drops(two_device_run):
    """With slots for 2 x 160 = 320 of 399 particles (slab_capacity 0.8), the 79 that do not fit at the
    first dealing are dropped, inactive, and counted in n_lost: the run reports them rather than
    carrying wrong physics on.  (The rebalancing at step 32 and the 32 steps after it lose no more:
    the survivors fit.)"""
    c = two_device_run["starved"]
    assert c["capacity"] == 160, c
    assert c["lost"][0] == 0 and c["lost"][1] == 399 - 2 * 160, c
    assert c["active"] == 2 * 160, c


def test_slabs_give_the_one_device_gradient(two_device_run):
    """Reverse mode through the slab advance (halo ppermutes, migration's packing and placing,
    the dealing and collecting by index): d(mean x)/d mu0 over the 128 steps, with the t = 0 slab
    edges kept so that the 40 particles that cross them carry their derivatives through migration,
    equals one device's to 1e-9 relative.  A migration that cut the derivative (as a first version
    did, sending floats bitcast to int32) was 4 % off."""
    g = two_device_run["grad"]
    (v1, g1), (v2, g2) = g["1"], g["2"]
    assert g1 != 0.0 and abs(g2 - g1) <= 1e-9 * abs(g1), g
    assert abs(v2 - v1) <= 1e-12, g


def _scene(overrides):
    return build(m.load_scene("dambreak-lab", ["domain.cell_size_m=0.02", "numerics.ppc=2"] + overrides)).scene


def test_slab_refuses_what_it_cannot_run():
    """A periodic x axis, Navier slip on an x wall and too few node planes per device are refused
    with a message naming the key and what is allowed."""
    sc = _scene([])
    slab = dict(devices=2, decomposition="slab")
    _slab.check(sc.replace(**slab))  # the plain scene is fine
    with pytest.raises(m.SceneError, match="periodic x axis"):
        _slab.check(sc.replace(periodic=(True, False), **slab))
    wall = sc.walls[0]
    assert abs(wall.normal[0]) > 0, wall
    slip = (dataclasses.replace(wall, slip_length=0.01),) + sc.walls[1:]
    with pytest.raises(m.SceneError, match="Navier slip wall facing along x"):
        _slab.check(sc.replace(walls=slip, **slab))
    nx = sc.grid_shape[0]
    with pytest.raises(m.SceneError, match=rf"numerics.devices = {nx} is invalid .* allowed range: 1 \.\. {nx // 2}"):
        _slab.check(sc.replace(devices=nx, decomposition="slab"))


def test_decomposition_key_is_validated():
    with pytest.raises(m.SceneError, match="numerics.decomposition"):
        m.load_scene("dambreak-lab", ["numerics.decomposition=cubes"])
    sc = _scene(["numerics.decomposition=slab", "numerics.devices=1"])
    assert (sc.decomposition, sc.slab_capacity) == ("slab", 1.5)  # the keys reach the Scene, with the default


def test_lost_particles_do_not_take_the_slots_of_active_ones():
    """Dealing particles out to slabs and collecting them back keeps every active particle where
    slots are short, as long as the active ones fit: 80 inactive (lost) particles at the front of
    the State give way to the 320 active ones in 2 x 190 slots (slab_capacity 0.95, 20 short of all
    400), and the slab edges balance the active particles only (the edge falls between node planes,
    so a slab may hold a plane's worth, here up to 20, over 160).  A first version dealt slots in
    State order and balanced all particles: there the inactive ones took the slots of 30 active ones.
    In-process: no shard_map, no devices needed."""
    setup = build(m.load_scene("dambreak-lab", ["domain.cell_size_m=0.02", "numerics.ppc=2"]))
    sc = setup.scene.replace(devices=2, decomposition="slab", slab_capacity=0.95)
    s0 = setup.state
    n = s0.x.shape[0]
    s0 = s0._replace(active=jnp.asarray(np.arange(n) >= n - 320))
    geo = _slab.geometry(sc, n)
    assert geo.capacity == 190 and n == 400, (geo, n)
    # jitted (as inside the slab advance): op by op, each operation compiles on its own, 2x the CPU
    slabs, ids, bounds = jax.jit(functools.partial(_slab._distribute, sc, geo))(s0)
    back = jax.jit(_slab._collect)(s0, slabs, ids)
    assert int(np.asarray(back.active).sum()) == 320 and int(back.n_lost) == 0
    assert np.array_equal(np.asarray(back.x), np.asarray(s0.x))
    b = np.asarray(bounds)
    assert b[0, 0] == 0 and b[0, 1] == b[1, 0] and b[1, 1] == sc.grid_shape[0], b


def test_memory_estimate_counts_the_devices_grids_and_slots():
    """The pre-run memory check counts one grid per device (the replicated grid, and slabs' windows,
    which span about the whole grid) and, with slabs, slab_capacity x the particles (the slots,
    empty ones included): on 2 devices 2x the grid bytes, with slabs also 1.5x the particle bytes."""
    explicit = ["numerics.pressure=explicit"]  # the slab decomposition's pressure (the grid solve is replicated)
    one = memory_estimate(m.load_scene("dambreak-lab", explicit))
    rep = memory_estimate(m.load_scene("dambreak-lab", explicit + ["numerics.devices=2"]))
    slab = memory_estimate(m.load_scene("dambreak-lab", explicit + ["numerics.devices=2", "numerics.decomposition=slab"]))
    assert rep["grid_bytes"] == 2 * one["grid_bytes"] and rep["particle_bytes"] == one["particle_bytes"]
    assert slab["grid_bytes"] == rep["grid_bytes"]
    assert slab["particle_bytes"] == pytest.approx(1.5 * one["particle_bytes"], rel=1e-12)


def test_a_run_that_drops_particles_for_want_of_slots_stops_and_says_so(tmp_path):
    """`mpmjax run --devices 2` on slabs with slab_capacity 1.0 (slots for exactly an even share,
    while the slab edges fall between node planes, so one device gets up to a plane's worth more)
    drops particles at the first dealing: the health check stops the run (exit status 3, as any
    run that loses particles through no open face) and its hint names numerics.slab_capacity."""
    out = tmp_path / "o"
    cmd = [sys.executable, "-m", "mpmjax.cli", "run", "dambreak-lab", "--devices", "2", "--quiet", "--out", str(out),
           "--set", "numerics.decomposition=slab", "--set", "numerics.pressure=explicit", "--set", "numerics.slab_capacity=1.0", "--set", "time.t_end_s=0.01"]
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)
    assert p.returncode == 3, p.stderr[-2000:]
    assert "particle(s) lost" in p.stderr and "raise numerics.slab_capacity (now 1)" in p.stderr, p.stderr[-2000:]
    assert json.loads((out / "summary.json").read_text())["status"] == "failed"


@pytest.mark.parametrize("n_ids", [1000, 2**30])
def test_migration_rows_round_trip_exactly(n_ids):
    """A migration packs a particle's leaves into rows and back (``_rows``, ``_unrows``) without
    changing a bit: floats stay floats, integers and flags ride in the float buffer when the dtype
    holds them exactly (ids below 2^24 in float32), in an int32 buffer otherwise (n_ids = 2^30)."""
    rng = np.random.default_rng(0)
    tree = {
        "x": jnp.asarray(rng.standard_normal((7, 2)), jnp.float32),
        "C": jnp.asarray(rng.standard_normal((7, 2, 2)), jnp.float32),
        "ids": jnp.asarray(rng.integers(-1, 2**23, 7), jnp.int32),
        "active": jnp.asarray(rng.integers(0, 2, 7), bool),
    }
    bufs = _slab._rows(tree, n_ids)
    assert len(bufs) == (1 if n_ids < 2**24 else 2)
    back = _slab._unrows(bufs, tree)
    for k in tree:
        assert back[k].dtype == tree[k].dtype and np.array_equal(np.asarray(back[k]), np.asarray(tree[k])), k
