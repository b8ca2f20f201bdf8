"""Time one compiled chunk of a scene's steps, in whatever mpmjax ``import`` finds (so that
``compare_revisions.sh`` can point PYTHONPATH at another checkout); one JSON line.

    python benchmarks/speed/step_speed.py SCENE STEPS REPEATS [KEY=VALUE ...]

SCENE: a built-in scene, a TOML path, or ``mpm88`` (``mpmjax.studies.bench.MPM88``); KEY=VALUE as
``mpmjax run --set`` (``numerics.devices=N`` also makes N host devices).  The chunk is
compiled and run once first; the line gives the median CPU time (``time.process_time``, both cores)
and wall time of REPEATS calls, and the code's label from the environment variable CODE.
"""

from __future__ import annotations

import json
import os
import sys
import time

import jax

from mpmjax import build, load_scene, validate
from mpmjax._schema import parse_override
from mpmjax._simulate import make_chunk
from mpmjax.studies.bench import MPM88


def main(name: str, steps: int, repeats: int, sets: list[str]) -> None:
    items = [parse_override(o) for o in sets]
    devices = max([int(v) for k, v in items if k == "numerics.devices"] or [1])
    jax.config.update("jax_num_cpu_devices", devices)  # host devices, before JAX starts its backends
    if name == "mpm88":
        raw = json.loads(json.dumps(MPM88))
        for key, val in items:
            section, leaf = key.split(".", 1)
            raw.setdefault(section, {})[leaf] = val
        setup = build(validate(raw))
    else:
        setup = build(load_scene(name, sets))
    f = jax.jit(make_chunk(setup.scene, steps))
    jax.block_until_ready(f(setup.state, setup.params))
    cpu, wall = [], []
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        jax.block_until_ready(f(setup.state, setup.params))
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    n = int(setup.state.x.shape[0])
    med = lambda a: sorted(a)[len(a) // 2]  # noqa: E731
    print(json.dumps({"code": os.environ.get("CODE", ""), "scene": name, "sets": sets, "n_particles": n,
                      "steps": steps, "cpu_s": med(cpu), "wall_s": med(wall),
                      "M_particle_steps_per_s_wall": n * steps / med(wall) / 1e6, "load_avg": os.getloadavg()[0],
                      "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}), flush=True)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4:])
