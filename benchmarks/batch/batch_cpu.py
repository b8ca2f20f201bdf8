"""A vmap batch of 16 against 16 runs in a row: wall time and CPU time, 1 or 2 host devices (issue 18).

The default scene at ppc 2 (1600 particles, the issue's batch size), 16 values of mu0, STEPS steps.
MODE: ``seq`` (one compiled run called 16 times), ``vmap`` (one jitted vmap, one device) or
``shard`` (the same vmap with the batch axis sharded over every device: run it with
``XLA_FLAGS=--xla_force_host_platform_device_count=2``).  Best of 3 after compiling; one JSON line.
XLA's flags are per process, so ``side by side`` here means processes alternated by the caller:

    for r in 1 2; do for m in seq vmap shard; do
      [ $m = shard ] && export XLA_FLAGS=--xla_force_host_platform_device_count=2 || unset XLA_FLAGS
      .venv/bin/python benchmarks/batch/batch_cpu.py $m 300; done; done >> benchmarks/batch/batch_cpu.jsonl

With a third argument ``profile`` (MODE ``seq`` or ``vmap``) one call is traced with ``jax.profiler``
instead, and the durations of XLA's thunks (its compiled kernels: fusions, scatters, gathers) are
summed over both threads, the thread pool's own waits (``ThunkExecutor``, ``Slinky``) left out: the
work done, which process CPU time is not (waiting threads spin).  One JSON line, the total and the
largest thunks:

    for m in seq vmap; do .venv/bin/python benchmarks/batch/batch_cpu.py $m 100 profile; done >> benchmarks/batch/batch_profile.jsonl
"""

import collections
import glob
import json
import os
import sys
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
from mpmjax import build, load_scene  # noqa: E402
from mpmjax._simulate import make_chunk  # noqa: E402

mode = sys.argv[1]
steps = int(sys.argv[2])
setup = build(load_scene("dambreak-lab", {"numerics.ppc": 2}))
chunk = make_chunk(setup.scene, steps)


def one(mu0):
    p = setup.params._replace(material=setup.params.material._replace(mu0=mu0))
    return chunk(setup.state, p).x


mu0s = jnp.linspace(2.0, 8.0, 16).astype(jnp.float32)
if mode not in ("seq", "vmap", "shard"):
    sys.exit(f"MODE = {mode!r}: allowed seq, vmap, shard")
if mode == "seq":
    f = jax.jit(one).lower(mu0s[0]).compile()
    ms = [mu0s[i] for i in range(16)]

    def run():
        return [f(m) for m in ms]
else:
    from jax.sharding import Mesh, NamedSharding
    from jax.sharding import PartitionSpec as P

    if mode == "shard":
        mesh = Mesh(np.array(jax.devices()), ("b",))
        mu0s = jax.device_put(mu0s, NamedSharding(mesh, P("b")))
    f = jax.jit(jax.vmap(one)).lower(mu0s).compile()

    def run():
        return f(mu0s)




def profile():
    """Thunk durations of one traced call, summed by thunk name over XLA's threads (ms)."""
    with tempfile.TemporaryDirectory() as d:
        with jax.profiler.trace(d):
            jax.block_until_ready(run())
        pd = jax.profiler.ProfileData.from_file(glob.glob(d + "/**/*.xplane.pb", recursive=True)[0])
        tot = collections.Counter()
        for plane in pd.planes:
            for line in plane.lines:
                if "XLAEigen" in line.name:
                    for ev in line.events:
                        if not ev.name.startswith(("ThunkExecutor", "Slinky")):
                            tot[ev.name] += ev.duration_ns
    total = sum(tot.values())
    return {"mode": mode, "runs": 16, "steps": steps, "n_particles": setup.scene.n_particles,
            "thunk_ms_total": total / 1e6,
            "largest": [{"thunk": k, "ms": v / 1e6, "pct": 100 * v / total} for k, v in tot.most_common(8)]}


jax.block_until_ready(run())
if len(sys.argv) > 3 and sys.argv[3] == "profile":
    print(json.dumps(profile()), flush=True)
    sys.exit(0)
best = bc = float("inf")
for _ in range(3):
    t0, c0 = time.perf_counter(), time.process_time()
    jax.block_until_ready(run())
    best, bc = min(best, time.perf_counter() - t0), min(bc, time.process_time() - c0)
print(json.dumps(dict(mode=mode, flags=os.environ.get("XLA_FLAGS", ""), n=setup.scene.n_particles, runs=16, steps=steps,
                      best_wall_s=best, best_cpu_s=bc, devices=len(jax.devices()), load_avg=os.getloadavg()[0],
                      time_utc=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))), flush=True)
