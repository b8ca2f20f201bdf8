"""mpmjax's mpm88-equivalent with ``numerics.force = "mls"`` against the default nodal force and the
minimal JAX port (issue 18 item 2), timed in turn, each code first in turn; one JSON line per call.

    .venv/bin/python benchmarks/speed/mpm88_mls.py [STEPS [ROUNDS]] >> benchmarks/speed/mpm88_mls.jsonl
"""

from __future__ import annotations

import json
import os
import sys
import time

import jax
import jax.numpy as jnp

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from static_skips import minimal_mpm88  # noqa: E402

from mpmjax import build  # noqa: E402
from mpmjax._schema import validate  # noqa: E402
from mpmjax._simulate import make_chunk  # noqa: E402
from mpmjax.studies.bench import MPM88  # noqa: E402


def main(steps: int = 500, rounds: int = 6) -> None:
    progs, fall = {}, {}
    for force in ("gradient", "mls"):
        raw = json.loads(json.dumps(MPM88))
        raw["numerics"]["force"] = force
        s = build(validate(raw))
        f = jax.jit(make_chunk(s.scene, steps))
        progs[f"mpmjax force={force}"] = lambda f=f, s=s: f(s.state, s.params).x
        fall[f"mpmjax force={force}"] = float(jnp.mean(s.state.x[:, 1]))
    m_state, m_adv = minimal_mpm88(steps)
    progs["minimal JAX port"] = lambda: m_adv(m_state).x
    fall["minimal JAX port"] = float(jnp.mean(m_state.x[:, 1]))
    for k, f in progs.items():
        fall[k] -= float(jnp.mean(jax.block_until_ready(f())[:, 1]))
    keys = list(progs)
    for rnd in range(rounds):
        for k in keys[rnd % len(keys):] + keys[: rnd % len(keys)]:
            load = os.getloadavg()[0]
            c0, w0 = time.process_time(), time.perf_counter()
            jax.block_until_ready(progs[k]())
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
            print(json.dumps({"code": k, "round": rnd + 1, "steps": steps, "n_particles": 8192, "cpu_s": cpu,
                              "wall_s": wall, "particle_steps_per_s_wall": 8192 * steps / wall,
                              "mean_fall_m": fall[k], "load_avg_start": load,
                              "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}), flush=True)


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:3]))
