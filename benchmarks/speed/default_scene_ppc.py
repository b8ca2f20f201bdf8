"""Default scene at ppc 3 (the default since 2026-12-01) against ppc 2, side by side, alternating (docs/performance.md)."""
import json, os, time, jax
from mpmjax import build, load_scene
from mpmjax._simulate import make_chunk
steps = 2000
cases = {}
for ppc in (2, 3):
    s = build(load_scene("dambreak-lab", [f"numerics.ppc={ppc}"]))
    t0 = time.perf_counter(); c0 = time.process_time()
    f = jax.jit(make_chunk(s.scene, steps)).lower(s.state, s.params).compile()
    cases[ppc] = dict(f=f, s=s, compile_s=time.perf_counter() - t0, compile_cpu_s=time.process_time() - c0,
                      wall=[], cpu=[], n=s.scene.n_particles, grid=list(s.scene.grid_shape))
for r in range(4):
    for ppc in ((2, 3) if r % 2 == 0 else (3, 2)):
        c = cases[ppc]
        t0 = time.perf_counter(); c0 = time.process_time()
        jax.block_until_ready(c["f"](c["s"].state, c["s"].params).x)
        c["wall"].append(time.perf_counter() - t0); c["cpu"].append(time.process_time() - c0)
out = {f"ppc{p}": {k: v for k, v in c.items() if k not in ("f", "s")} | {
    "best_wall_s": min(c["wall"]), "particle_steps_per_s_best": c["n"] * steps / min(c["wall"])} for p, c in cases.items()}
out["steps"] = steps; out["load_average"] = os.getloadavg(); out["jax"] = jax.__version__
print(json.dumps(out, indent=1))
