import json
import os
import sys
import time

import jax
import jax.numpy as jnp

from mpmjax import build, load_scene
from mpmjax._step import make_step

h = float(sys.argv[1])
steps = int(sys.argv[2])
variant = sys.argv[3]
chunk_n = int(sys.argv[4]) if len(sys.argv) > 4 else 50
setup = build(load_scene("dambreak-lab", {"domain.cell_size_m": h}))
sc = setup.scene
step = make_step(sc)


def run(mu0):
    p = setup.params._replace(material=setup.params.material._replace(mu0=mu0))
    st = setup.state
    if variant == "base":
        inner = jax.checkpoint(lambda s: jax.lax.scan(lambda c, _: (step(c, p), None), s, None, length=chunk_n)[0])
    elif variant == "perstep":
        stp = jax.checkpoint(lambda c: step(c, p))
        inner = jax.checkpoint(lambda s: jax.lax.scan(lambda c, _: (stp(c), None), s, None, length=chunk_n)[0])
    elif variant == "nocse":
        inner = jax.checkpoint(
            lambda s: jax.lax.scan(lambda c, _: (step(c, p), None), s, None, length=chunk_n)[0], prevent_cse=False
        )
    elif variant == "unroll2":
        inner = jax.checkpoint(
            lambda s: jax.lax.scan(lambda c, _: (step(c, p), None), s, None, length=chunk_n, unroll=2)[0]
        )
    s = jax.lax.scan(lambda c, _: (inner(c), None), st, None, length=steps // chunk_n)[0]
    w = s.active.astype(s.x.dtype)
    return jnp.sum(s.x[:, 0] * w) / jnp.sum(w)


mu0 = setup.params.material.mu0
f = jax.jit(run).lower(mu0).compile()
g = jax.jit(jax.value_and_grad(run)).lower(mu0).compile()


def timed(fn, reps=3):
    best = 1e9
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(mu0))
        best = min(best, time.perf_counter() - t0)
    return best


tf = timed(f)
tg = timed(g)
print(
    json.dumps(
        dict(
            variant=variant,
            h=h,
            steps=steps,
            chunk=chunk_n,
            fwd_s=tf,
            grad_s=tg,
            ratio=tg / tf,
            grad=float(g(mu0)[1]),
            load=os.getloadavg()[0],
        )
    )
)
