"""Reverse-mode gradient cost against the forward run, levers side by side (issue 18 item 3).

usage: python benchmarks/gradient/gradient_cost.py H STEPS ROUNDS VARIANT[,VARIANT...] >> benchmarks/gradient/gradient_cost.jsonl

Scene: ``dambreak-lab`` (GIMP, ppc 3, float32) with ``domain.cell_size_m = H``; the loss is the
mean x of the active particles after STEPS steps, differentiated w.r.t. mu0 (value_and_grad).
Every variant is compiled first (compile CPU seconds recorded), then the variants are timed in
turn, ROUNDS times, alternating, with ``time.process_time`` (CPU seconds of this process, both
cores counted); each line is one (variant, round).  Run it pinned to one core with one XLA
thread (``taskset -c 1`` and ``XLA_FLAGS="--xla_cpu_multi_thread_eigen=false
intra_op_parallelism_threads=1"``) on a shared machine: the CPU time is then that of the work,
not of threads waiting for each other.

Variants (each builds its own step and chunk; the library's ``make_chunk`` is ``base``):

* ``base``: ``_simulate.make_chunk`` (``jax.checkpoint`` around a ``lax.scan`` of 50 steps);
* ``cN``: the same with chunks of N steps;
* ``nocse``: ``jax.checkpoint(..., prevent_cse=False)`` (JAX's advice for a scan under checkpoint);
* ``perstep``: each step also under ``jax.checkpoint`` with ``nothing_saveable`` (the chunk's
  recomputation saves only the step inputs; each step is recomputed once more in the backward pass);
* ``g2pbarrier``: ``jax.lax.optimization_barrier`` on the G2P's outputs (v_pic, v_p, C, L); in the
  backward pass it becomes a barrier on their cotangents, which keeps XLA from fusing (and
  recomputing per stencil entry) the per-particle cotangent chain into the (n S, dim) cotangent of
  the gathered nodal velocities;
* ``slices``: the stencil's per-axis weight factors picked by static slices and a concatenate
  instead of ``jnp.take`` (a gather, whose transpose in the backward pass is a scatter-add).
"""

import json
import os
import sys
import time

import jax
import jax.numpy as jnp

from mpmjax import _step, _transfer, build, load_scene
from mpmjax._simulate import make_chunk

h, steps, rounds = float(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
variants = sys.argv[4].split(",")
setup = build(load_scene("dambreak-lab", {"domain.cell_size_m": h}))
sc = setup.scene


class _SlicesNumpy:
    """``jnp`` for ``_transfer`` with ``take(a, cols, axis=1)`` as static slices + concatenate."""

    def __getattr__(self, name):
        return getattr(jnp, name)

    @staticmethod
    def take(a, cols, axis):
        assert axis == 1
        return jnp.concatenate([a[:, int(c) : int(c) + 1] for c in cols], axis=1)


def make_run(variant):
    n = int(variant[1:]) if variant[:1] == "c" and variant[1:].isdigit() else 50
    if variant == "slices":
        _transfer.jnp = _SlicesNumpy()
    try:
        if variant == "g2pbarrier":
            g2p0 = _transfer.make_g2p

            def barrier_g2p(scene):
                g = g2p0(scene)
                return lambda *a: jax.lax.optimization_barrier(g(*a))

            _step.make_g2p = barrier_g2p
            try:
                step = _step.make_step(sc)
            finally:
                _step.make_g2p = g2p0

            def body(s, params):
                return jax.lax.scan(lambda c, _: (step(c, params), None), s, None, length=n)[0]

            chunk = jax.checkpoint(body)
        elif variant in ("nocse", "perstep"):
            step = _step.make_step(sc)
            if variant == "perstep":
                stp = jax.checkpoint(step, policy=jax.checkpoint_policies.nothing_saveable)
            else:
                stp = step

            def body(s, params):
                return jax.lax.scan(lambda c, _: (stp(c, params), None), s, None, length=n)[0]

            chunk = jax.checkpoint(body, prevent_cse=variant != "nocse")
        else:
            chunk = make_chunk(sc, n)

        def run(mu0):
            p = setup.params._replace(material=setup.params.material._replace(mu0=mu0))
            s = jax.lax.scan(lambda c, _: (chunk(c, p), None), setup.state, None, length=steps // n)[0]
            w = s.active.astype(s.x.dtype)
            return jnp.sum(s.x[:, 0] * w) / jnp.sum(w)

        mu0 = setup.params.material.mu0
        t = time.process_time()
        f = jax.jit(run).lower(mu0).compile()
        cf = time.process_time() - t
        t = time.process_time()
        g = jax.jit(jax.value_and_grad(run)).lower(mu0).compile()
        cg = time.process_time() - t
    finally:
        _transfer.jnp = jnp
    return f, g, cf, cg


mu0 = setup.params.material.mu0
built = {v: make_run(v) for v in variants}
first = {v: jax.block_until_ready(built[v][1](mu0)) for v in variants}
ref = float(first[variants[0]][1])


def cpu(fn):
    t = time.process_time()
    out = jax.block_until_ready(fn(mu0))
    return time.process_time() - t, out


for r in range(rounds):
    for v in variants:
        f, g, cf, cg = built[v]
        tf, val = cpu(f)
        tg, (val_g, grad) = cpu(g)
        row = dict(
            variant=v, round=r, h=h, n_particles=sc.n_particles, steps=steps,
            fwd_cpu_s=round(tf, 4), grad_cpu_s=round(tg, 4), ratio=round(tg / tf, 3),
            compile_fwd_s=round(cf, 2), compile_grad_s=round(cg, 2),
            value=float(val), value_in_grad=float(val_g), grad=float(grad),
            grad_rel_diff_vs_first=abs(float(grad) - ref) / abs(ref),
            threads=os.environ.get("XLA_FLAGS", "default"), load=os.getloadavg()[0],
        )  # fmt: skip
        print(json.dumps(row), flush=True)
