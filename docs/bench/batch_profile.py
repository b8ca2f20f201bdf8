"""Where a vmap batch of 16 spends its time against 16 runs in a row: XLA:CPU thunk durations.

The default scene at ppc 2 (1600 particles), 16 values of mu0, 100 steps each, both XLA threads.
MODE ``seq`` (one compiled run called 16 times) or ``vmap`` (one jitted vmap, one device). Each call is
traced with ``jax.profiler`` and the durations of XLA's thunks (its compiled kernels: fusions, scatters,
gathers) are summed over both threads; the thread pool's own waits (``ThunkExecutor``, ``Slinky``) are
left out, so the total is the work done, which process CPU time is not (waiting threads spin).
One JSON line: the total and the largest thunks.

    for m in seq vmap; do .venv/bin/python docs/bench/batch_profile.py $m; done >> docs/bench/batch_profile.jsonl
"""

import collections
import glob
import json
import os
import sys
import tempfile

import jax
import jax.numpy as jnp

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
from mpmjax import build, load_scene  # noqa: E402
from mpmjax._simulate import make_chunk  # noqa: E402

mode = sys.argv[1]
if mode not in ("seq", "vmap"):
    sys.exit(f"MODE = {mode!r}: allowed seq, vmap")
steps = 100
setup = build(load_scene("dambreak-lab", {"numerics.ppc": 2}))
chunk = make_chunk(setup.scene, steps)


def one(mu0):
    p = setup.params._replace(material=setup.params.material._replace(mu0=mu0))
    return chunk(setup.state, p).x


mu0s = jnp.linspace(2.0, 8.0, 16).astype(jnp.float32)
if mode == "seq":
    f = jax.jit(one).lower(mu0s[0]).compile()

    def run():
        return [f(m) for m in mu0s]
else:
    f = jax.jit(jax.vmap(one)).lower(mu0s).compile()

    def run():
        return f(mu0s)


jax.block_until_ready(run())
with tempfile.TemporaryDirectory() as d:
    with jax.profiler.trace(d):
        jax.block_until_ready(run())
    pd = jax.profiler.ProfileData.from_file(glob.glob(d + "/**/*.xplane.pb", recursive=True)[0])
    tot = collections.Counter()
    for plane in pd.planes:
        for line in plane.lines:
            if "XLAEigen" not in line.name:
                continue
            for ev in line.events:
                if not ev.name.startswith(("ThunkExecutor", "Slinky")):
                    tot[ev.name] += ev.duration_ns
total = sum(tot.values())
print(json.dumps({"mode": mode, "runs": 16, "steps": steps, "n_particles": setup.scene.n_particles,
                  "thunk_ms_total": total / 1e6,
                  "largest": [{"thunk": k, "ms": v / 1e6, "pct": 100 * v / total} for k, v in tot.most_common(8)]}))
