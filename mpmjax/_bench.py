"""``mpmjax bench``: particle-steps per second, measured (not asserted).

Configurations:

* ``default-scene``: the built-in ``dambreak-lab`` scene at its default resolution.
* ``mpm88-equivalent``: 2D, 128 x 128 cells on the unit square, 8192 particles, quadratic
  B-spline, APIC, a weakly compressible Newtonian fluid under gravity (the configuration
  of Taichi's ``mpm88`` example, written with this package's general step).

Each measurement compiles first (reported separately), then times ``--steps`` steps,
best of three repetitions.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time

MPM88 = {
    "name": "mpm88-equivalent",
    "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [1.0, 1.0], "cell_size_m": 1.0 / 128},
    "boundary": {"x_lo": "slip", "x_hi": "slip", "y_lo": "slip", "y_hi": "slip"},
    "numerics": {"shape": "quadratic", "transfer": "apic", "ppc": 2},
    "time": {"t_end_s": 1.0, "n_frames": 1},
    "material": {"model": "newtonian", "density_kg_m3": 1000.0, "bulk_modulus_pa": 4.0e5, "viscosity_pa_s": 1e-3},
    "gravity": {"g_m_s2": 9.81},
    # 64 x 128 particles at 2 per cell per axis: 8192 particles
    "bodies": [{"lo_m": [0.1, 0.1], "hi_m": [0.35, 0.6]}],
}


def _measure(setup, steps: int, reps: int = 3) -> dict:
    import jax

    from ._simulate import make_chunk

    t0 = time.perf_counter()
    f = jax.jit(make_chunk(setup.scene, steps)).lower(setup.state, setup.params).compile()
    compile_s = time.perf_counter() - t0
    best = float("inf")
    state = setup.state
    for _ in range(reps):
        t0 = time.perf_counter()
        out = f(state, setup.params)
        jax.block_until_ready(out.x)
        best = min(best, time.perf_counter() - t0)
    n = setup.scene.n_particles
    return {
        "n_particles": n,
        "steps": steps,
        "best_wall_s": best,
        "compile_s": compile_s,
        "particle_steps_per_s": n * steps / best,
        "n_lost": int(out.n_lost),
        "grid_shape": list(setup.scene.grid_shape),
        "shape": setup.scene.shape,
        "transfer": setup.scene.transfer,
    }


def run_bench(args) -> int:
    import jax

    from ._config import build, load_scene, validate

    if args.steps < 1:
        raise ValueError(f"--steps = {args.steps} is invalid: allowed range >= 1")
    dt_over = [f"numerics.dtype={args.dtype!r}".replace("'", '"')]
    results = {}
    cfg = load_scene("dambreak-lab", dt_over)
    results["default-scene"] = _measure(build(cfg), args.steps)
    raw = json.loads(json.dumps(MPM88))
    raw["numerics"]["dtype"] = args.dtype
    setup = build(validate(raw))
    assert setup.scene.n_particles == 8192
    results["mpm88-equivalent"] = _measure(setup, args.steps)
    meta = {
        "machine": platform.machine(),
        "processor": platform.processor(),
        "cpus": os.cpu_count(),
        "python": sys.version.split()[0],
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "dtype": args.dtype,
    }
    doc = {"meta": meta, "results": results}
    with open(args.out, "w") as f:
        json.dump(doc, f, indent=2)
    print(f"{'configuration':20s} {'particles':>9s} {'steps':>6s} {'compile s':>9s} {'wall s':>8s} {'p-steps/s':>10s}")
    for k, r in results.items():
        print(
            f"{k:20s} {r['n_particles']:9d} {r['steps']:6d} {r['compile_s']:9.2f} {r['best_wall_s']:8.3f} "
            f"{r['particle_steps_per_s']:10.3g}"
        )
    print(f"({meta['backend']}, {meta['cpus']} cpus, jax {meta['jax']}, {args.dtype}); wrote {args.out}")
    return 0
