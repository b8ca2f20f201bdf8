"""Reverse-mode gradient against the forward run, through the library's ``simulate`` (what the
calibration differentiates), in whatever mpmjax ``import`` finds
(``gradient_ratio.sh`` points PYTHONPATH at two checkouts in turn); one JSON line.

    python benchmarks/gradient/gradient_ratio.py STEPS CHUNK REPEATS [KEY=VALUE ...]

Scene ``dambreak-lab`` (the default, ppc 3, float32) with ``--set``-style overrides, cut into
STEPS / CHUNK frames of CHUNK steps; the loss is the mean x of the active particles after STEPS steps,
differentiated w.r.t. mu0.  Forward, ``value_and_grad`` and ``jvp`` (one tangent) are compiled
first, then called in turn REPEATS times; the line gives each one's best wall time and the CPU
time (``time.process_time``, all threads) of that call, the ratios, and the derivatives.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time

import jax
import jax.numpy as jnp

from mpmjax import build, load_scene
from mpmjax._simulate import simulate

steps, chunk_n, repeats = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
setup = build(load_scene("dambreak-lab", sys.argv[4:]))
scene = dataclasses.replace(setup.scene, steps_per_frame=chunk_n, n_frames=steps // chunk_n)


def loss(mu0):
    p = setup.params._replace(material=setup.params.material._replace(mu0=mu0))
    s = simulate(scene, setup.state, p)[0]
    w = s.active.astype(s.x.dtype)
    return jnp.sum(s.x[:, 0] * w) / jnp.sum(w)


mu0 = setup.params.material.mu0
fns = {}
for name, fn in (("forward", loss), ("grad", jax.value_and_grad(loss)),
                 ("jvp", lambda m: jax.jvp(loss, (m,), (jnp.ones_like(m),)))):
    c0 = time.process_time()
    fns[name] = jax.jit(fn).lower(mu0).compile()
    fns[name + "_compile_cpu_s"] = time.process_time() - c0
best = {k: (float("inf"), 0.0) for k in ("forward", "grad", "jvp")}
out = {}
for _ in range(repeats):
    for name in ("forward", "grad", "jvp"):
        w0, c0 = time.perf_counter(), time.process_time()
        out[name] = jax.block_until_ready(fns[name](mu0))
        w, c = time.perf_counter() - w0, time.process_time() - c0
        if w < best[name][0]:
            best[name] = (w, c)
line = dict(code=os.environ.get("CODE", ""), steps=steps, chunk=chunk_n, n_particles=setup.scene.n_particles,
            dtype=str(setup.state.x.dtype), xla_flags=os.environ.get("XLA_FLAGS", ""))
for name in ("forward", "grad", "jvp"):
    line[name + "_wall_s"], line[name + "_cpu_s"] = best[name]
    line[name + "_compile_cpu_s"] = fns[name + "_compile_cpu_s"]
    line[name + "_xla_temp_mib"] = fns[name].memory_analysis().temp_size_in_bytes / 2**20
line["grad_over_forward_wall"] = best["grad"][0] / best["forward"][0]
line["grad_over_forward_cpu"] = best["grad"][1] / best["forward"][1]
line["jvp_over_forward_wall"] = best["jvp"][0] / best["forward"][0]
line["d_loss_d_mu0_grad"] = float(out["grad"][1])
line["d_loss_d_mu0_jvp"] = float(out["jvp"][1])
line["load_avg"] = os.getloadavg()[0]
line["time_utc"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
print(json.dumps(line), flush=True)
