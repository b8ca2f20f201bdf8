"""``mpmjax bench``: particle-steps per second, gradient cost and batching, measured (not asserted).

Configurations:

* ``default-scene``: the built-in ``dambreak-lab`` scene at its default resolution.
* ``mpm88-equivalent``: 2D, 128 x 128 cells on the unit square, 8192 particles, quadratic
  B-spline, APIC, a weakly compressible Newtonian fluid under gravity (the configuration
  of Taichi's ``mpm88`` example, written with this package's general step).
* ``scaling``: the same fluid as a block filling [0, 0.5]^dim of the unit box (2 particles per
  cell per axis) at about 1e3, 1e4 and 1e5 particles (1e6 with ``--large``), 2D and 3D,
  float32 and float64.  The cell size is 1/k with k = n^(1/dim), so the particle count is k^dim
  and the grid has (k + 7)^dim nodes.
* ``gradient``: reverse mode (``jax.value_and_grad``) of the final centroid x of the default scene
  with respect to the Coussot mu0, through ``simulate`` (checkpointed scan, 50 steps per
  checkpointed chunk), against the forward run of the same function, at a few step counts; also
  forward mode (``jax.jvp``, the cheaper choice for one parameter; its tangent must equal the
  gradient).  With XLA's compiled memory estimate (``Compiled.memory_analysis()``: temporary
  buffers, not the process peak).
* ``batch``: 16 runs of the default scene with 16 values of mu0 as one ``vmap`` batch, against
  the same 16 runs one after another (one compiled function, reused).

Each measurement compiles first (reported separately), then times the compiled call, best of
``reps`` repetitions.  ``--quick`` shrinks everything (1e3 particles, few steps, one
repetition) so that a test can check the output in seconds; its figures are not benchmarks.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from .._build import build
from .._schema import load_scene, validate
from .._simulate import make_chunk, simulate
from .._step import make_step

MPM88 = {
    "name": "mpm88-equivalent",
    "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [1.0, 1.0], "cell_size_m": 1.0 / 128},
    "boundary": {"x_lo": "slip", "x_hi": "slip", "y_lo": "slip", "y_hi": "slip"},
    # the per-particle (weakly compressible) pressure, as Taichi's mpm88 has: the side by side is like for like
    "numerics": {"shape": "quadratic", "transfer": "apic", "ppc": 2, "pressure": "explicit"},
    "time": {"t_end_s": 1.0, "n_frames": 1},
    "material": {"model": "newtonian", "density_kg_m3": 1000.0, "bulk_modulus_pa": 4.0e5, "viscosity_pa_s": 1e-3},
    "gravity": {"g_m_s2": 9.81},
    # 64 x 128 particles at 2 per cell per axis: 8192 particles
    "bodies": [{"lo_m": [0.1, 0.1], "hi_m": [0.35, 0.6]}],
}


def _step_traffic(setup) -> dict:
    """Bytes per particle-step: XLA's count for one compiled step, and the state's own.

    ``xla_bytes_per_particle_step``: ``Compiled.cost_analysis()["bytes accessed"]`` of one jitted
    step (every HLO op's operands and results, as XLA materialises them between its fusions;
    cache-oblivious, so an upper bound on the memory traffic), divided by the particle count.
    ``state_bytes_per_particle_step``: the state read once and written once (every leaf but the
    constant ``vol0`` written), per particle: the traffic no implementation of this step avoids
    while the particles do not fit in cache.  The grid is left out of both floors' reasoning: it is
    read and written through the stencil, in cache while it fits there.
    """
    n = setup.scene.n_particles
    ca = jax.jit(make_step(setup.scene)).lower(setup.state, setup.params).compile().cost_analysis()
    ca = ca[0] if isinstance(ca, (list, tuple)) else ca
    leaves = jax.tree_util.tree_leaves_with_path(setup.state)
    read = sum(x.nbytes for _, x in leaves)
    written = sum(x.nbytes for k, x in leaves if "vol0" not in jax.tree_util.keystr(k))
    xla = float(ca.get("bytes accessed", float("nan"))) if ca else float("nan")
    return {
        "xla_bytes_per_particle_step": xla / n,
        "xla_flops_per_particle_step": float(ca.get("flops", float("nan"))) / n if ca else float("nan"),
        "state_bytes_per_particle_step": (read + written) / n,
    }


def memory_bandwidth(mib: int = 256, reps: int = 5) -> dict:
    """The machine's sustained memory bandwidth [GB/s], measured on 3 arrays of ``mib`` MiB each
    (float32, far beyond any cache), bytes counted as STREAM counts them (2 arrays read, 1 written):

    * ``numpy_add_gb_s``: STREAM's add, ``numpy.add(b, c, out=a)``, one thread: what the memory
      delivers to one core's plain loop;
    * ``xla_triad_gb_s``: STREAM's triad a = b + 3 c as one jitted XLA program (the output buffer
      donated, so no fresh allocation is timed) on the default device, with XLA's threads as the step
      uses them: the figure the traffic floors are read against (docs/performance.md, "Scaling"); on
      a GPU, its memory's bandwidth.

    Best of ``reps``."""
    n = mib * 2**20 // 4
    b = np.arange(n, dtype=np.float32)
    c = np.ones(n, np.float32)
    a = np.empty_like(b)
    moved = 3 * n * 4
    best_n = _timed(lambda: np.add(b, c, out=a), reps=reps)
    # keep_unused: without it jit drops the unused ``a`` and the donation never happens, so every call
    # would allocate (and page-fault) a fresh output array
    triad = jax.jit(lambda a, b, c: b + 3.0 * c, donate_argnums=0, keep_unused=True)
    ja, jb, jc = jax.device_put(a), jax.device_put(b), jax.device_put(c)
    ja = first = jax.block_until_ready(triad(ja, jb, jc))
    best_x = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        ja = jax.block_until_ready(triad(ja, jb, jc))
        best_x = min(best_x, time.perf_counter() - t0)
    donated = first.is_deleted()  # the buffer passed in was consumed: no fresh allocation was timed
    return {
        "array_mib": mib,
        "numpy_add_gb_s": moved / best_n / 1e9,
        "xla_triad_gb_s": moved / best_x / 1e9,
        "xla_output_donated": bool(donated),
    }


def _measure(setup, steps: int, reps: int = 3) -> dict:
    t0 = time.perf_counter()
    f = jax.jit(make_chunk(setup.scene, steps)).lower(setup.state, setup.params).compile()
    compile_s = time.perf_counter() - t0
    best = float("inf")
    best_cpu = float("inf")
    state = setup.state
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        out = f(state, setup.params)
        jax.block_until_ready(out.x)
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    n = setup.scene.n_particles
    r = {
        "n_particles": n,
        "steps": steps,
        "best_wall_s": best,
        "best_cpu_s": best_cpu,
        "compile_s": compile_s,
        "particle_steps_per_s": n * steps / best,
        "n_lost": int(out.n_lost),
        "grid_shape": list(setup.scene.grid_shape),
        "shape": setup.scene.shape,
        "transfer": setup.scene.transfer,
    }
    r.update(_step_traffic(setup))
    # what the XLA program's own traffic moved per second (an upper bound: XLA counts every
    # intermediate as if it went to memory)
    r["xla_gb_s"] = r["xla_bytes_per_particle_step"] * r["particle_steps_per_s"] / 1e9
    return r


def _fluid(dim: int, n_target: int, dtype: str):
    """The mpm88 fluid as a block filling [0, 0.5]^dim of the unit box, about n_target particles."""
    k = max(4, 2 * round(n_target ** (1.0 / dim) / 2))  # even: the block edge 0.5 is a whole cell count
    raw = json.loads(json.dumps(MPM88))
    raw["name"] = f"fluid-{dim}d"
    raw["domain"] = {"dim": dim, "lo_m": [0.0] * dim, "hi_m": [1.0] * dim, "cell_size_m": 1.0 / k}
    raw["boundary"] = {f"{a}_{s}": "slip" for a in "xyz"[:dim] for s in ("lo", "hi")}
    raw["numerics"]["dtype"] = dtype
    raw["bodies"] = [{"lo_m": [0.0] * dim, "hi_m": [0.5] * dim}]
    return build(validate(raw))


COMBOS = ((2, "float32"), (2, "float64"), (3, "float32"), (3, "float64"))


def bench_scaling(sizes, combos=COMBOS, target=1e7, min_steps=20, reps=3, log=print, rows=None):
    """Particle-steps/s against the particle count, per (dim, dtype); steps ~ target / n.

    Rows are appended to ``rows`` (a new list if None) as they are measured."""
    rows = [] if rows is None else rows
    for dim, dtype in combos:
        for n in sizes:
            setup = _fluid(dim, int(n), dtype)
            steps = max(min_steps, int(target // setup.scene.n_particles))
            r = _measure(setup, steps, reps)
            r.update(dim=dim, dtype=dtype, n_target=int(n), grid_nodes=setup.scene.n_nodes)
            rows.append(r)
            log(
                f"scaling {dim}D {dtype} n = {r['n_particles']:8d} ({r['grid_nodes']} nodes), {steps} steps: "
                f"{r['particle_steps_per_s']:.3g} particle-steps/s (compile {r['compile_s']:.1f} s)"
            )
    return rows


def _timed(f, *a, reps=3):
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(f(*a))
        best = min(best, time.perf_counter() - t0)
    return best


def _mem(compiled) -> dict:
    try:
        m = compiled.memory_analysis()
        return {
            "temp_bytes": int(m.temp_size_in_bytes),
            "argument_bytes": int(m.argument_size_in_bytes),
            "output_bytes": int(m.output_size_in_bytes),
        }
    except Exception:  # noqa: BLE001  (not every backend implements it)
        return {"temp_bytes": None, "argument_bytes": None, "output_bytes": None}


# --quick's gradient and batch sections: the lab scene at h = 0.02 m with the particles' pressure.  Their
# compilation through the grid pressure's solve (its transposed solve too) was 20 of the quick bench's 46 s;
# the quick figures are no benchmark (the module docstring), and the full bench measures the scene as it is
QUICK_OVERRIDES = {"domain.cell_size_m": 0.02, "numerics.pressure": "explicit"}


def _default_setup(dtype: str, coarse: bool):
    ov = {"numerics.dtype": dtype}
    if coarse:
        ov.update(QUICK_OVERRIDES)
    return build(load_scene("dambreak-lab", ov))


def bench_gradient(step_counts, dtype="float32", chunk=50, reps=3, coarse=False, log=print):
    """Forward and reverse-mode (jax.grad w.r.t. mu0) time of the final centroid x, per step count."""
    setup = _default_setup(dtype, coarse)
    rows = []
    for steps in step_counts:
        spf = min(chunk, steps)
        if steps % spf:
            raise ValueError(f"gradient step count {steps} is not a multiple of the chunk {spf}")
        sc = setup.scene.replace(steps_per_frame=spf, n_frames=steps // spf)

        def loss(mu0, sc=sc):
            params = setup.params._replace(material=setup.params.material._replace(mu0=mu0))
            final, _ = simulate(sc, setup.state, params)
            w = final.active.astype(final.x.dtype)
            return jnp.sum(final.x[:, 0] * w) / jnp.sum(w)

        mu0 = setup.params.material.mu0
        t0 = time.perf_counter()
        fwd = jax.jit(loss).lower(mu0).compile()
        c_fwd = time.perf_counter() - t0
        t0 = time.perf_counter()
        grd = jax.jit(jax.value_and_grad(loss)).lower(mu0).compile()
        c_grd = time.perf_counter() - t0
        t0 = time.perf_counter()
        jvp = jax.jit(lambda m, loss=loss: jax.jvp(loss, (m,), (jnp.ones_like(m),))).lower(mu0).compile()
        c_jvp = time.perf_counter() - t0
        t_f = _timed(fwd, mu0, reps=reps)
        t_g = _timed(grd, mu0, reps=reps)
        t_j = _timed(jvp, mu0, reps=reps)
        val, g = grd(mu0)
        g_fwd = jvp(mu0)[1]
        r = {
            "steps": steps,
            "steps_per_checkpoint": spf,
            "n_particles": sc.n_particles,
            "forward_s": t_f,
            "gradient_s": t_g,
            "gradient_over_forward": t_g / t_f,
            "compile_forward_s": c_fwd,
            "compile_gradient_s": c_grd,
            "jvp_s": t_j,
            "jvp_over_forward": t_j / t_f,
            "compile_jvp_s": c_jvp,
            "centroid_x_m": float(val),
            "d_centroid_d_mu0_m_per_pa_s": float(g),
            "d_centroid_d_mu0_jvp_m_per_pa_s": float(g_fwd),
            "jvp_memory": _mem(jvp),
            "forward_memory": _mem(fwd),
            "gradient_memory": _mem(grd),
        }
        rows.append(r)
        log(
            f"gradient {steps:5d} steps: forward {t_f:.3f} s, value_and_grad {t_g:.3f} s, ratio {t_g / t_f:.2f}, "
            f"jvp {t_j:.3f} s, ratio {t_j / t_f:.2f}; "
            f"XLA temp memory {_fmt_bytes(r['forward_memory']['temp_bytes'])} / "
            f"{_fmt_bytes(r['gradient_memory']['temp_bytes'])}"
        )
    return rows


def _fmt_bytes(b):
    return "n/a" if b is None else f"{b / 2**20:.1f} MiB"


def bench_batch(steps: int, batch: int = 16, dtype="float32", reps=3, coarse=False, log=print):
    """``vmap`` over ``batch`` values of mu0 against ``batch`` sequential calls of one compiled run."""
    setup = _default_setup(dtype, coarse)
    chunk = make_chunk(setup.scene, steps)

    def one(mu0):
        params = setup.params._replace(material=setup.params.material._replace(mu0=mu0))
        return chunk(setup.state, params).x

    mu0s = jnp.linspace(2.0, 8.0, batch).astype(setup.params.material.mu0.dtype)
    t0 = time.perf_counter()
    single = jax.jit(one).lower(mu0s[0]).compile()
    c_single = time.perf_counter() - t0
    t0 = time.perf_counter()
    batched = jax.jit(jax.vmap(one)).lower(mu0s).compile()
    c_batch = time.perf_counter() - t0

    def sequential(ms):
        return [single(m) for m in ms]

    t_seq = _timed(sequential, list(mu0s), reps=reps)
    t_bat = _timed(batched, mu0s, reps=reps)
    xb = batched(mu0s)
    spread = float(jnp.max(jnp.abs(xb[-1] - single(mu0s[-1]))))
    r = {
        "batch": batch,
        "steps": steps,
        "n_particles": setup.scene.n_particles,
        "sequential_s": t_seq,
        "batched_s": t_bat,
        "sequential_over_batched": t_seq / t_bat,
        "compile_single_s": c_single,
        "compile_batched_s": c_batch,
        "max_abs_diff_batched_vs_single_m": spread,
    }
    log(f"batch {batch} x {steps} steps: sequential {t_seq:.3f} s, vmap {t_bat:.3f} s, speed-up {t_seq / t_bat:.2f}")
    return r


SECTIONS = ("scenes", "scaling", "gradient", "batch")


def _sections(text: str) -> tuple:
    got = tuple(t.strip() for t in text.split(",") if t.strip())
    bad = [t for t in got if t not in SECTIONS]
    if bad or not got:
        raise ValueError(f"--only = {text!r} is invalid: allowed sections {', '.join(SECTIONS)} (comma-separated)")
    return got


def _meta(dtype: str, reps: int, steps: int, only: str, quick: bool, large: bool) -> dict:
    sizes = [1e3] if quick else [1e3, 1e4, 1e5] + ([1e6] if large else [])
    return {
        "machine": platform.machine(),
        "processor": platform.processor(),
        "cpus": os.cpu_count(),
        "python": sys.version.split()[0],
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "dtype": dtype,
        "quick": quick,
        # what --quick sets on the lab scene of the gradient and batch sections (QUICK_OVERRIDES)
        "quick_overrides": dict(QUICK_OVERRIDES) if quick else {},
        "reps": 1 if quick else reps,
        "steps": steps,
        "only": only,
        "load_avg_start": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
        "scaling_sizes": sizes,
        "memory_source": "XLA Compiled.memory_analysis(): temporary buffer bytes of the compiled function",
        "note_1e6": None
        if large
        else "1e6 particles skipped (pass --large): on 2 CPU cores one step of 1e6 "
        "particles takes ~0.3-1 s, so a measurement of a few dozen steps takes minutes per point",
    }


def _write_json(path, doc) -> None:
    tmp = f"{path}.part"
    with open(tmp, "w") as f:
        json.dump(doc, f, indent=2)
    os.replace(tmp, path)


def run_bench(
    out="bench.json",
    *,
    steps: int = 2000,
    dtype: str = "float32",
    reps: int = 3,
    quick: bool = False,
    large: bool = False,
    only: str = ",".join(SECTIONS),
) -> int:
    """``mpmjax bench``: measure the sections ``only`` (comma-separated, of ``SECTIONS``), write the
    JSON ``out`` after each and print the table; the arguments are the command's options.  Raises
    ``ValueError`` naming the option for an invalid value."""
    if steps < 1:
        raise ValueError(f"--steps = {steps} is invalid: allowed range >= 1")
    quick = bool(quick)
    large = bool(large)
    sections = _sections(only)

    def log(*a):
        print(*a, file=sys.stderr, flush=True)

    if reps < 1:
        raise ValueError(f"--reps = {reps} is invalid: allowed range >= 1")
    doc = {"meta": _meta(dtype, reps, steps, only, quick, large), "results": {}, "complete": False}
    results = doc["results"]
    reps = 1 if quick else reps
    steps = min(steps, 20) if quick else steps

    def save():
        # after every section, atomically: an interrupted or killed bench keeps what it measured
        _write_json(out, doc)

    if "scenes" in sections or "scaling" in sections:
        # the machine's memory bandwidth, the floor the traffic figures of each row are read against
        doc["meta"]["memory_bandwidth"] = memory_bandwidth(16 if quick else 256, 1 if quick else 5)
        log(f"memory bandwidth (STREAM add in numpy, triad in XLA): {doc['meta']['memory_bandwidth']}")
    if "scenes" in sections:
        cfg = load_scene("dambreak-lab", {"numerics.dtype": dtype})
        results["default-scene"] = _measure(build(cfg), steps, reps)
        raw = json.loads(json.dumps(MPM88))
        raw["numerics"]["dtype"] = dtype
        setup = build(validate(raw))
        assert setup.scene.n_particles == 8192
        results["mpm88-equivalent"] = _measure(setup, steps, reps)
        for k, r in results.items():
            log(f"{k}: {r['particle_steps_per_s']:.3g} particle-steps/s")
        save()
    scaling = []
    if "scaling" in sections:
        sizes = doc["meta"]["scaling_sizes"]
        # --quick: one size and two (dim, dtype) pairs that still cover both dims and both dtypes
        combos = ((2, "float32"), (3, "float64")) if quick else COMBOS
        scaling = doc["scaling"] = []

        def log_row(*a):
            log(*a)
            save()

        # at least 5 steps per timed call: at 1e6 particles the target's 1e7 particle-steps is 10 steps
        bench_scaling(sizes, combos, target=1e4 if quick else 1e7, min_steps=5, reps=reps, log=log_row, rows=scaling)
    gradient = []
    if "gradient" in sections:
        gsteps = [10] if quick else [100, 400, 1600]
        gradient = doc["gradient"] = bench_gradient(
            gsteps, dtype, chunk=10 if quick else 50, reps=reps, coarse=quick, log=log
        )
        save()
    batch = None
    if "batch" in sections:
        batch = doc["batch"] = bench_batch(5 if quick else 400, 16, dtype, reps=reps, coarse=quick, log=log)
    doc["complete"] = True
    save()
    meta = doc["meta"]
    print(f"{'configuration':20s} {'particles':>9s} {'steps':>6s} {'compile s':>9s} {'wall s':>8s} {'p-steps/s':>10s}"
          f" {'XLA B/p-step':>12s} {'XLA GB/s':>8s}")
    rows = [(k, r) for k, r in results.items()] + [(f"fluid {r['dim']}D {r['dtype']}", r) for r in scaling]
    for k, r in rows:
        print(
            f"{k:20s} {r['n_particles']:9d} {r['steps']:6d} {r['compile_s']:9.2f} {r['best_wall_s']:8.3f} "
            f"{r['particle_steps_per_s']:10.3g} {r['xla_bytes_per_particle_step']:12.0f} {r['xla_gb_s']:8.2f}"
        )
    if "memory_bandwidth" in meta:
        bw = meta["memory_bandwidth"]
        print(f"memory bandwidth: {bw['numpy_add_gb_s']:.1f} GB/s (STREAM add, numpy, one thread), "
              f"{bw['xla_triad_gb_s']:.1f} GB/s (STREAM triad, XLA)")
    for r in gradient:
        print(
            f"grad/forward at {r['steps']} steps: {r['gradient_s']:.3f} / {r['forward_s']:.3f} s = "
            f"{r['gradient_over_forward']:.2f}; XLA temp {_fmt_bytes(r['gradient_memory']['temp_bytes'])} vs "
            f"{_fmt_bytes(r['forward_memory']['temp_bytes'])}"
        )
    if batch is not None:
        print(
            f"batch of {batch['batch']} (vmap) vs {batch['batch']} sequential runs, {batch['steps']} steps: "
            f"{batch['batched_s']:.3f} vs {batch['sequential_s']:.3f} s, sequential/batched = "
            f"{batch['sequential_over_batched']:.2f}"
        )
    print(f"({meta['backend']}, {meta['cpus']} cpus, jax {meta['jax']}, {dtype}); wrote {out}")
    return 0
