"""XLA:CPU scatter-add by flat node index against row windows (``mpmjax._transfer._Stencil``), alone,
under vmap with batched indices (a batch of runs) and with unbatched ones (tangents of one run);
one JSON line per case, microseconds per call (median and range of 5 rounds of 50 calls, the
codes alternating within each round).

    XLA_FLAGS=--xla_cpu_experimental_ynn_fusion_type= taskset -c 1 \\
        .venv/bin/python benchmarks/transfer/row_windows.py >> benchmarks/transfer/row_windows.jsonl

Random particles on a 2D grid of N x N nodes, a quadratic stencil (k = 3, 9 nodes), C channels:
``flat`` one index per node (window (1, C), what ``_transfer.scatter_add`` does), ``rows`` one
index per row of k nodes along the last axis (window (k, C), what the CPU step does), ``rows_flat``
the same rows as one flat window of k C values, ``box`` one index per particle (window (k, k, C)).
Under vmap, ``flatten``: the batch folded into the row index by hand (what a batching rule could do).
"""

from __future__ import annotations

import json
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

K, C = 3, 5
MODE = lax.GatherScatterMode.PROMISE_IN_BOUNDS


def _dn(window, to):
    return lax.ScatterDimensionNumbers(
        update_window_dims=window, inserted_window_dims=(), scatter_dims_to_operand_dims=to
    )


def codes(N):
    L = N * N

    def flat(base, v):  # base (n, 2), v (n, 9, C)
        o = np.array([(a, b) for a in range(K) for b in range(K)])
        idx = (base[:, None, 0] + o[None, :, 0]) * N + base[:, None, 1] + o[None, :, 1]
        return jnp.zeros((L, C), v.dtype).at[idx.reshape(-1)].add(v.reshape(-1, C))

    def rows(base, v):
        st = ((base[:, None, 0] + jnp.arange(K)[None, :]) * N + base[:, None, 1]).reshape(-1, 1)
        return lax.scatter_add(jnp.zeros((L, C), v.dtype), st, v.reshape(-1, K, C), _dn((1, 2), (0,)), mode=MODE)

    def rows_flat(base, v):
        st = ((base[:, None, 0] + jnp.arange(K)[None, :]) * N + base[:, None, 1]).reshape(-1, 1) * C
        out = lax.scatter_add(jnp.zeros((L * C,), v.dtype), st, v.reshape(-1, K * C), _dn((1,), (0,)), mode=MODE)
        return out.reshape(L, C)

    def box(base, v):
        grid = jnp.zeros((N, N, C), v.dtype)
        return lax.scatter_add(grid, base, v.reshape(-1, K, K, C), _dn((1, 2, 3), (0, 1)), mode=MODE).reshape(L, C)

    return dict(flat=flat, rows=rows, rows_flat=rows_flat, box=box)


def timed(fns, args, reps=50, rounds=5):
    out = {k: [] for k in fns}
    ref = None
    for name, f in fns.items():
        r = np.asarray(f(*args))
        ref = r if ref is None else ref
        assert np.allclose(r, ref, rtol=0, atol=1e-4 * np.abs(ref).max()), name
    for _ in range(rounds):
        for name, f in fns.items():
            t0 = time.perf_counter()
            for _ in range(reps):
                r = f(*args)
            r.block_until_ready()
            out[name].append((time.perf_counter() - t0) / reps * 1e6)
    return {k: {"median_us": float(np.median(v)), "min_us": min(v), "max_us": max(v)} for k, v in out.items()}


def main():
    rng = np.random.default_rng(0)
    for n, N in ((8192, 130), (1600, 80)):
        base = jnp.asarray(rng.integers(0, N - K + 1, size=(n, 2)).astype(np.int32))
        v = jnp.asarray(rng.standard_normal((n, K * K, C)).astype(np.float32))
        fns = {k: jax.jit(f) for k, f in codes(N).items()}
        print(json.dumps({"case": "alone", "n": n, "N": N, "float": "32", **timed(fns, (base, v))}), flush=True)
    # a batch of 16 runs: indices and values batched
    B, n, N = 16, 1600, 80
    c = codes(N)
    base = jnp.asarray(rng.integers(0, N - K + 1, size=(B, n, 2)).astype(np.int32))
    v = jnp.asarray(rng.standard_normal((B, n, K * K, C)).astype(np.float32))

    def flatten(base, v):  # batch b's rows moved to lines b N .. (b + 1) N - 1 of one grid
        shifted = base.at[:, :, 0].add((jnp.arange(B, dtype=base.dtype) * N)[:, None])
        st = ((shifted[..., None, 0] + jnp.arange(K)) * N + shifted[..., None, 1]).reshape(-1, 1)
        grid = jnp.zeros((B * N * N, C), v.dtype)
        return lax.scatter_add(grid, st, v.reshape(-1, K, C), _dn((1, 2), (0,)), mode=MODE).reshape(B, N * N, C)

    fns = {"flat": jax.jit(jax.vmap(c["flat"])), "rows": jax.jit(jax.vmap(c["rows"])),
           "rows_flat": jax.jit(jax.vmap(c["rows_flat"])), "flatten": jax.jit(flatten)}
    line = {"case": "vmap, batched indices", "B": B, "n": n, "N": N, "float": "32", **timed(fns, (base, v), 20)}
    print(json.dumps(line), flush=True)
    # tangents of one run: values batched, indices not (float64, the calibration twin's size)
    jax.config.update("jax_enable_x64", True)
    B, n, N = 2, 300, 50
    c = codes(N)
    base = jnp.asarray(rng.integers(0, N - K + 1, size=(n, 2)).astype(np.int32))
    v = jnp.asarray(rng.standard_normal((B, n, K * K, C)))
    fns = {k: jax.jit(jax.vmap(c[k], in_axes=(None, 0))) for k in ("flat", "rows")}
    line = {"case": "vmap, unbatched indices", "B": B, "n": n, "N": N, "float": "64", **timed(fns, (base, v), 200)}
    print(json.dumps(line), flush=True)


if __name__ == "__main__":
    main()
