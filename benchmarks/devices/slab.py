"""One run over 2 host devices: the replicated grid against slabs with halo exchange (issue 18 item 4).

usage: python benchmarks/devices/slab.py [ROUNDS] [STEPS] >> benchmarks/devices/slab.jsonl

Runs in one process with 2 host devices (``jax_num_cpu_devices``).  Per scene, three codes run
``STEPS`` steps per call (``make_chunk``), alternating, each first in turn:
* ``one``: ``numerics.devices = 1``;
* ``replicated``: ``numerics.devices = 2``, the whole grid on each device, summed every step (``_shard``);
* ``slab``: ``numerics.devices = 2``, ``numerics.decomposition = "slab"`` (``_slab``: slabs along
  x, halos exchanged, particles migrating, rebalanced every 32 steps), 1.5 x an even share of
  particle slots per device (``numerics.slab_capacity``, its default);
* ``slab_capacity_1.25``: the same with 1.25 x.
Scenes: mpm88 (2D, 128^2 cells, 8192 particles, float32), the default scene (``dambreak-lab``,
1600 particles) and ``field-dambreak-3d`` (39 600 particles, 507 x 57 x 11 nodes, float32).
One JSON line per call: CPU time (``time.process_time``, both cores counted), wall time, the
largest position difference from ``one``, the particles lost and the load average.
"""

import json
import os
import sys
import time

import jax

jax.config.update("jax_num_cpu_devices", 2)

import numpy as np  # noqa: E402

from mpmjax import build, validate  # noqa: E402
from mpmjax._schema import load_scene  # noqa: E402
from mpmjax._simulate import make_chunk  # noqa: E402
from mpmjax.studies.bench import MPM88  # noqa: E402


def scenes():
    yield "mpm88", build(validate(json.loads(json.dumps(MPM88))))
    yield "default", build(load_scene("dambreak-lab"))
    yield "field-dambreak-3d", build(load_scene("field-dambreak-3d"))


def main(rounds: int, steps: int):
    for name, setup in scenes():
        sc = setup.scene
        codes = {
            "one": sc.replace(devices=1),
            "replicated": sc.replace(devices=2, decomposition="replicated"),
            "slab": sc.replace(devices=2, decomposition="slab"),
            "slab_capacity_1.25": sc.replace(devices=2, decomposition="slab", slab_capacity=1.25),
        }
        fns = {c: jax.jit(make_chunk(s, steps)) for c, s in codes.items()}
        ref = None
        compile_s = {}
        for c, f in fns.items():
            t0 = time.perf_counter()
            out = jax.block_until_ready(f(setup.state, setup.params))
            x = np.asarray(out.x)
            first = time.perf_counter() - t0
            ref = x if ref is None else ref
            compile_s[c] = (first, float(np.abs(x - ref).max()), int(out.n_lost))
        names = list(fns)
        for rnd in range(rounds):
            for code in names[rnd % len(names) :] + names[: rnd % len(names)]:
                c0, w0 = time.process_time(), time.perf_counter()
                # one call in flight at a time (cross-device collectives: docs/performance.md)
                jax.block_until_ready(fns[code](setup.state, setup.params))
                cpu, wall = time.process_time() - c0, time.perf_counter() - w0
                n = sc.n_particles
                print(json.dumps({"scene": name, "n_particles": n, "grid_shape": list(sc.grid_shape), "code": code,
                                  "round": rnd + 1, "steps": steps, "cpu_s": cpu, "wall_s": wall,
                                  "M_particle_steps_per_s_wall": n * steps / wall / 1e6,
                                  "first_call_s": compile_s[code][0], "max_abs_dx_vs_one_m": compile_s[code][1],
                                  "n_lost": compile_s[code][2],
                                  "load": os.getloadavg()[0]}), flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 4, int(sys.argv[2]) if len(sys.argv) > 2 else 200)
