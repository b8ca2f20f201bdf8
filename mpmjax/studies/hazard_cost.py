"""The cost of hazard maps per time step, measured (not asserted): ``python -m mpmjax.studies.hazard_cost``.

For a scene (default: the built-in ``field-breach-3d``) the frame advance of the forward driver
without hazard maps (``_simulate.make_chunk``, what a scene that does not ask for them runs) and with
them (``_hazard.make_hazard_advance``, sampling every k steps) are compiled for the same frame of
``--steps`` steps, then run alternately ``--reps`` times each from the same initial state; the CPU
time (``time.process_time``, all threads) and the wall time of each call are recorded and the best
of each is compared.  The map update alone (one sample: binning and maxima) is also timed over
20 x ``--steps`` calls, since the difference of whole frames is within a shared machine's noise.
Prints one JSON object (docs/scenarios.md, field-breach-3d, has the figures).
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np

from .._build import build
from .._hazard import HazardGrid, init_maps, make_hazard_advance, update
from .._schema import load_scene
from .._simulate import chunkable, make_chunk


def measure(scene: str, overrides: list[str], steps: int, reps: int, every: list[int]) -> dict:
    cfg = load_scene(scene, overrides)
    setup = build(cfg)
    sc = setup.scene.replace(steps_per_frame=steps)
    st, pr = setup.state, setup.params
    progs = {"plain": jax.jit(make_chunk(sc)).lower(st, pr).compile()}
    for k in every:
        grid = HazardGrid.of(sc, dict(cfg, **{"output.hazard_every_steps": k}))
        maps = init_maps(grid, st.x.dtype)
        if chunkable(sc):  # the driver's advance takes the number of steps (one program for any count)
            n = np.int32(steps)
            compiled = make_hazard_advance(sc, grid).lower(st, maps, pr, n).compile()
            progs[f"hazard_every_{k}"] = (lambda c, m, n: (lambda s, p: c(s, m, p, n)))(compiled, maps, n)
        else:
            compiled = make_hazard_advance(sc, grid).lower(st, maps, pr).compile()
            progs[f"hazard_every_{k}"] = (lambda c, m: (lambda s, p: c(s, m, p)))(compiled, maps)
    cpu = {k: [] for k in progs}
    wall = {k: [] for k in progs}
    for _ in range(reps):
        for name, prog in progs.items():  # alternating, so that load from other processes hits all alike
            c0, w0 = time.process_time(), time.perf_counter()
            jax.block_until_ready(prog(st, pr))
            cpu[name].append(time.process_time() - c0)
            wall[name].append(time.perf_counter() - w0)
    best = {k: min(v) / steps for k, v in cpu.items()}
    # the map update alone (the binning and maxima of one sample), timed over many calls: the
    # difference of two whole frames above is within the noise of a shared machine
    grid = HazardGrid.of(sc, cfg)
    upd = jax.jit(lambda m, s: update(m, s, grid)).lower(init_maps(grid, st.x.dtype), st).compile()
    maps = init_maps(grid, st.x.dtype)
    jax.block_until_ready(upd(maps, st))
    n_upd = 20 * steps
    c0 = time.process_time()
    for _ in range(n_upd):
        maps = upd(maps, st)
    jax.block_until_ready(maps)
    update_cpu = (time.process_time() - c0) / n_upd
    return {
        "scene": scene,
        "overrides": overrides,
        "particles": sc.n_particles,
        "grid_nodes": sc.n_nodes,
        "hazard_bins": HazardGrid.of(sc, cfg).n_bins,
        "steps_per_call": steps,
        "reps": reps,
        "cpu_s_per_step_best": best,
        "wall_s_per_step_best": {k: min(v) / steps for k, v in wall.items()},
        "hazard_cpu_overhead": {k: best[k] / best["plain"] - 1.0 for k in best if k != "plain"},
        "update_alone_cpu_s": update_cpu,
        "update_alone_fraction_of_a_step": update_cpu / best["plain"],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default="field-breach-3d")
    ap.add_argument("--set", action="append", default=[], help="scene key=value override")
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--every", default="1,10", help="comma-separated k of output.hazard_every_steps")
    a = ap.parse_args(argv)
    print(json.dumps(measure(a.scene, a.set, a.steps, a.reps, [int(k) for k in a.every.split(",")]), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
