"""vmap batch of 16 vs 16 sequential runs, across particle counts, 1 vs 2 host devices.
usage: python batch.py H STEPS [shard]"""

import json
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from mpmjax import build, load_scene
from mpmjax._simulate import make_chunk

h = float(sys.argv[1])
steps = int(sys.argv[2])
shard = len(sys.argv) > 3
setup = build(load_scene("dambreak-lab", {"domain.cell_size_m": h}))
chunk = make_chunk(setup.scene, steps)


def one(mu0):
    p = setup.params._replace(material=setup.params.material._replace(mu0=mu0))
    return chunk(setup.state, p).x


mu0s = jnp.linspace(2.0, 8.0, 16).astype(jnp.float32)
single = jax.jit(one).lower(mu0s[0]).compile()
if shard:
    from jax.sharding import Mesh, NamedSharding
    from jax.sharding import PartitionSpec as P

    mesh = Mesh(np.array(jax.devices()), ("b",))
    mu0s = jax.device_put(mu0s, NamedSharding(mesh, P("b")))
batched = jax.jit(jax.vmap(one)).lower(mu0s).compile()


def timed(f, *a, reps=3):
    best = 1e9
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(f(*a))
        best = min(best, time.perf_counter() - t0)
    return best


ms = [mu0s[i] for i in range(16)] if not shard else list(jnp.linspace(2.0, 8.0, 16).astype(jnp.float32))
t_seq = timed(lambda: [single(m) for m in ms])
t_bat = timed(batched, mu0s)
xb = np.asarray(batched(mu0s))
xs = np.asarray(single(ms[-1]))
r = dict(
    h=h,
    n=setup.scene.n_particles,
    steps=steps,
    devices=len(jax.devices()),
    seq_s=t_seq,
    vmap_s=t_bat,
    speedup=t_seq / t_bat,
    maxdiff=float(np.abs(xb[-1] - xs).max()),
    load=os.getloadavg()[0],
)
print(json.dumps(r))
