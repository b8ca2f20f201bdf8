"""P2G alternatives on the CPU, side by side (issue 18 item 1), and one run over 2 host devices (item 4).

usage: python benchmarks/transfer/p2g_alternatives.py [p2g|scatter|step|check] [ROUNDS] >> benchmarks/transfer/p2g_alternatives.jsonl

Runs in one process with 2 host devices (``jax_num_cpu_devices``), alternating the codes in each
round, and prints one JSON line per measurement: CPU time (``time.process_time``, both cores
counted) and wall time per call.

* ``p2g``: the P2G alone (``_transfer.make_p2g``: stencil, channels, scatter), mass, momentum
  and force of every node, on the mpm88 configuration (``studies.bench.MPM88``: 2D, 128^2 cells,
  8192 particles, quadratic, float32) and the default scene (``dambreak-lab``, 1600 particles,
  GIMP):
  - ``scatter``: the reference, XLA's scatter-add (``_transfer.scatter_add``), on one device;
  - ``sharded``: the particles split over the 2 host devices with ``shard_map``, each scatters
    into its own grid, the grids summed (``psum``): ``make_p2g(scene, axis)``, the code of
    ``numerics.devices``;
  - ``warp``: the scatter-add as a Warp kernel with atomic adds called from jitted JAX through
    XLA's FFI (``warp.jax_kernel``), everything else as in ``scatter``; skipped when warp-lang is
    not installed.
* ``scatter``: the scatter-add alone (XLA against Warp), on each scene's stencil indices and
  random channel values.
* ``step``: whole steps (``make_chunk``, 200 steps per call) of the same two scenes with
  ``numerics.devices`` 1 and 2, and on one device with the Warp scatter in the P2G.
* ``check``: the Warp scatter against the reference: float32 and float64 values, ``vmap``
  (``vmap_method="sequential"``) and ``grad`` through a ``custom_vjp`` whose transpose is a gather.
"""

import json
import os
import sys
import time

import jax

jax.config.update("jax_num_cpu_devices", 2)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import NamedSharding, PartitionSpec  # noqa: E402

from mpmjax import build, validate  # noqa: E402
from mpmjax import _step  # noqa: E402
from mpmjax._schema import load_scene  # noqa: E402
from mpmjax._shard import AXIS, _specs, particle_mesh  # noqa: E402
from mpmjax._simulate import make_chunk  # noqa: E402
from mpmjax._transfer import make_p2g, scatter_add  # noqa: E402
from mpmjax.studies.bench import MPM88  # noqa: E402

try:
    if os.environ.get("P2G_NO_WARP"):
        raise ImportError
    import warp as wp

    wp.config.quiet = True
    wp.init()
except ImportError:
    wp = None


def scenes(dtype="float32"):
    raw = json.loads(json.dumps(MPM88))
    raw["numerics"]["dtype"] = dtype
    yield "mpm88", build(validate(raw))
    yield "default", build(load_scene("dambreak-lab", [f"numerics.dtype={dtype}"]))


# ------------------------------------------------------------------------------------------ Warp scatter
_KERNELS = {}


def _warp_call(dtype, S, C):
    """The FFI call ``(idx (n, S) int32, vals (n, S, C), grid (N, C)) -> grid + scatter`` for one dtype
    (the stencil size S and the channel count C compiled in as constants, so the loops unroll)."""
    key = (np.dtype(dtype), S, C)
    if key not in _KERNELS:
        wdt = {np.dtype("float32"): wp.float32, np.dtype("float64"): wp.float64}[np.dtype(dtype)]

        # one thread per particle, looping over its stencil and channels (Warp's CPU backend runs the
        # threads one after another, so plain adds are safe there; measured 2x faster than one thread per
        # (particle, node) with atomic adds).  CPU only: on a GPU this would need atomic adds.
        @wp.kernel(module="unique")
        def scatter(idx: wp.array2d(dtype=wp.int32), vals: wp.array3d(dtype=wdt), grid: wp.array2d(dtype=wdt)):
            p = wp.tid()
            for s in range(S):
                i = idx[p, s]
                for c in range(C):
                    grid[i, c] = grid[i, c] + vals[p, s, c]

        _KERNELS[key] = wp.jax_kernel(scatter, num_outputs=1, in_out_argnames=["grid"], vmap_method="sequential")
    return _KERNELS[key]


@jax.custom_vjp
def _warp_scatter(idx, vals, zeros):
    return _warp_call(vals.dtype, idx.shape[1], vals.shape[2])(idx, vals, zeros, launch_dims=(idx.shape[0],))[0]


def _fwd(idx, vals, zeros):
    return _warp_scatter(idx, vals, zeros), idx


def _bwd(idx, g):
    # the transpose of a scatter-add is the gather: d vals[p, s] = g[idx[p, s]]
    return None, g[idx], None


_warp_scatter.defvjp(_fwd, _bwd)


def warp_scatter(idx, vals, n_nodes):
    return _warp_scatter(idx, vals, jnp.zeros((n_nodes, vals.shape[-1]), vals.dtype))


# ------------------------------------------------------------------------------------------ timing
def timed(f, args, calls):
    out = f(*args)
    jax.block_until_ready(out)
    c0, w0 = time.process_time(), time.perf_counter()
    for _ in range(calls):
        # one call in flight at a time: many queued calls of a program with a cross-device all-reduce
        # deadlock XLA:CPU's rendezvous on this 2-core machine (each waits for a thread the others hold)
        out = jax.block_until_ready(f(*args))
    return (time.process_time() - c0) / calls, (time.perf_counter() - w0) / calls


def p2g_codes(setup):
    sc = setup.scene

    def grid_of(p2g):
        return lambda s, p: p2g(s, p)[:3]

    codes = {"scatter": (jax.jit(grid_of(make_p2g(sc))), setup.state)}
    mesh = particle_mesh(2)
    spec = _specs(setup.state, sc.n_particles)
    pspec = jax.tree_util.tree_map(lambda _: PartitionSpec(), setup.params)
    sharded = jax.shard_map(
        grid_of(make_p2g(sc, AXIS)), mesh=mesh, in_specs=(spec, pspec), out_specs=PartitionSpec()
    )
    state2 = jax.tree_util.tree_map(lambda a, s: jax.device_put(a, NamedSharding(mesh, s)), setup.state, spec)
    codes["sharded"] = (jax.jit(sharded), state2)
    if wp is not None:
        codes["warp"] = (jax.jit(grid_of(make_p2g(sc, flat=warp_scatter))), setup.state)
    return codes


def bench_p2g(rounds, calls=200):
    for name, setup in scenes():
        codes = p2g_codes(setup)
        ref = [np.asarray(a) for a in codes["scatter"][0](codes["scatter"][1], setup.params)]
        err = {}
        for code, (f, st) in codes.items():
            got = [np.asarray(a) for a in f(st, setup.params)]
            err[code] = max(float(np.abs(g - r).max() / max(np.abs(r).max(), 1e-30)) for g, r in zip(got, ref))
        for rnd in range(rounds):
            for code, (f, st) in codes.items():
                cpu, wall = timed(f, (st, setup.params), calls)
                print(json.dumps({"what": "p2g", "scene": name, "n_particles": setup.scene.n_particles,
                                  "code": code, "round": rnd + 1, "cpu_us": cpu * 1e6, "wall_us": wall * 1e6,
                                  "max_rel_diff_vs_scatter": err[code], "load": os.getloadavg()[0]}), flush=True)


def bench_scatter(rounds, calls=200):
    """The scatter-add alone, on the stencil indices of each scene and random channels (n, S, 1 + 2 dim)."""
    from mpmjax._transfer import _Stencil

    for name, setup in scenes():
        sc = setup.scene
        idx = jax.jit(lambda x: _Stencil(sc, x).idx)(setup.state.x)
        vals = jnp.asarray(np.random.default_rng(0).standard_normal(idx.shape + (1 + 2 * sc.dim,)), sc.dtype)
        codes = {"scatter": jax.jit(lambda i, v: scatter_add(i, v, sc.n_nodes))}
        if wp is not None:
            codes["warp"] = jax.jit(lambda i, v: warp_scatter(i, v, sc.n_nodes))
        for rnd in range(rounds):
            for code, f in codes.items():
                cpu, wall = timed(f, (idx, vals), calls)
                print(json.dumps({"what": "scatter", "scene": name, "n_particles": sc.n_particles, "code": code,
                                  "round": rnd + 1, "cpu_us": cpu * 1e6, "wall_us": wall * 1e6,
                                  "load": os.getloadavg()[0]}), flush=True)


def bench_step(rounds, steps=200):
    for name, setup in scenes():
        sc = setup.scene
        codes = {}
        for d in (1, 2):
            s = sc.replace(devices=d)
            st = setup.state
            if d > 1:
                mesh = particle_mesh(d)
                st = jax.tree_util.tree_map(
                    lambda a, p: jax.device_put(a, NamedSharding(mesh, p)), st, _specs(st, sc.n_particles)
                )
            codes[f"devices={d}"] = (jax.jit(make_chunk(s, steps)), st)
        if wp is not None:
            # the step with the Warp scatter in its P2G: make_step's make_p2g swapped for this measurement only
            real = _step.make_p2g
            _step.make_p2g = lambda scene, axis=None: real(scene, axis, flat=warp_scatter)
            try:
                codes["warp"] = (jax.jit(make_chunk(sc, steps)), setup.state)
            finally:
                _step.make_p2g = real
        outs = {c: f(st, setup.params).x for c, (f, st) in codes.items()}
        diff = {c: float(np.abs(np.asarray(x) - np.asarray(outs["devices=1"])).max()) for c, x in outs.items()}
        over = {c: len(x.sharding.device_set) for c, x in outs.items()}
        names = list(codes)
        for rnd in range(rounds):
            for code in names[rnd % len(names) :] + names[: rnd % len(names)]:  # each code first in turn
                f, st = codes[code]
                cpu, wall = timed(f, (st, setup.params), 1)
                n = sc.n_particles
                print(json.dumps({"what": "step", "scene": name, "n_particles": n, "code": code, "round": rnd + 1,
                                  "steps": steps, "cpu_s": cpu, "wall_s": wall,
                                  "M_particle_steps_per_s_wall": n * steps / wall / 1e6,
                                  "max_abs_dx_vs_devices_1_m": diff[code], "result_on_devices": over[code],
                                  "load": os.getloadavg()[0]}), flush=True)


def check_warp():
    if wp is None:
        print(json.dumps({"what": "check", "warp": "not installed"}))
        return
    jax.config.update("jax_enable_x64", True)
    rng = np.random.default_rng(0)
    n, S, C, N = 1000, 9, 5, 400
    idx = jnp.asarray(rng.integers(0, N, (n, S)), jnp.int32)
    for dt in ("float32", "float64"):
        vals = jnp.asarray(rng.standard_normal((n, S, C)), dt)
        a, b = scatter_add(idx, vals, N), warp_scatter(idx, vals, N)
        w = jnp.asarray(rng.standard_normal((N, C)), dt)
        ga = jax.grad(lambda v: jnp.sum(w * scatter_add(idx, v, N) ** 2))(vals)
        gb = jax.grad(lambda v: jnp.sum(w * warp_scatter(idx, v, N) ** 2))(vals)
        vb = jnp.stack([vals, 2 * vals])
        va = jax.vmap(lambda v: scatter_add(idx, v, N))(vb)
        vw = jax.vmap(lambda v: warp_scatter(idx, v, N))(vb)
        print(json.dumps({"what": "check", "dtype": dt,
                          "value_max_abs_diff": float(jnp.abs(a - b).max()),
                          "grad_max_abs_diff": float(jnp.abs(ga - gb).max()),
                          "vmap_max_abs_diff": float(jnp.abs(va - vw).max()),
                          "value_scale": float(jnp.abs(a).max())}), flush=True)


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "p2g"
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    {"p2g": lambda: bench_p2g(rounds), "scatter": lambda: bench_scatter(rounds), "step": lambda: bench_step(rounds), "check": check_warp}[what]()
