"""Measure the static skips of docs/performance.md, "Static skips" (issue 6).

Run from the repository root: ``.venv/bin/python docs/bench/static_skips.py [part ...]`` with parts
``rheology``, ``dim``, ``grid``, ``staged`` (default: all).  Appends one JSON line per measurement
to docs/bench/static_skips.jsonl.  Timings are of compiled code (compile reported apart), best of
``reps`` repetitions; the load average at the start of each measurement is recorded with it.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import jax

from mpmjax import _simulate, load_scene, run_scene
from mpmjax import build
from mpmjax._simulate import _split, make_chunk
from mpmjax.studies.bench import _measure

OUT = Path(__file__).with_name("static_skips.jsonl")


def record(**row):
    row.update(load_avg_1min=os.getloadavg()[0], cpus=os.cpu_count(), time_utc=time.strftime("%H:%M:%S", time.gmtime()))
    with OUT.open("a") as f:
        f.write(json.dumps(row) + "\n")
    print(json.dumps(row), flush=True)


def measure(setup, steps, reps=3):
    load = os.getloadavg()[0]
    r = _measure(setup, steps, reps)
    r["load_avg_start"] = load
    r["steps_per_s"] = steps / r["best_wall_s"]
    r["n_nodes"] = setup.scene.n_nodes
    return r


def rheology():
    """Same dam break (dambreak-lab, 1600 particles) with Newtonian, Bingham and Coussot material."""
    common = ["numerics.dt_s=2e-4"]  # one step size for all three (below every model's limit)
    models = {
        "newtonian": ["material.model=newtonian", "material.viscosity_pa_s=4.0"],
        "bingham": ["material.model=bingham", "material.viscosity_pa_s=0.65", "material.yield_stress_pa=36.0"],
        "coussot": [],
    }
    for m, over in models.items():
        s = build(load_scene("dambreak-lab", common + over))
        r = measure(s, 400)
        record(part="rheology", model=m, internal=sorted(s.state.internal), **r)


# the dam-break block as a thin 3D slab: one cell thick, periodic in y (the "no 3D cost in 2D" case)
SLAB_3D = [
    "domain.dim=3",
    "domain.lo_m=[0.0, 0.0, 0.0]",
    "domain.hi_m=[2.0, 0.01, 0.24]",
    'boundary.y_lo="periodic"',
    'boundary.y_hi="periodic"',
    'boundary.z_lo="noslip"',
    'boundary.z_hi="noslip"',
    'bodies=[{type = "box", lo_m = [0.0, 0.0, 0.0], hi_m = [0.2, 0.01, 0.2]}]',
]


def dim():
    """2D dam break against a thin 3D slab (periodic y, one cell thick) of the same block."""
    s2 = build(load_scene("dambreak-lab", ["numerics.dt_s=2e-4"]))
    record(part="dim", case="2D", **measure(s2, 400))
    over3 = SLAB_3D + ["numerics.dt_s=2e-4"]
    s3 = build(load_scene("dambreak-lab", over3))
    record(part="dim", case="3D slab (periodic y, 1 cell)", **measure(s3, 400))


def interleaved(progs: dict, steps: int, rounds: int = 10) -> dict:
    """Best wall time [s] per program, the programs timed in turn round after round."""
    best = {k: float("inf") for k in progs}
    for _ in range(rounds):
        for k, (s, g) in progs.items():
            t0 = time.perf_counter()
            jax.block_until_ready(g(s.state, s.params).x)
            best[k] = min(best[k], time.perf_counter() - t0)
    return best


def rheology_dim_interleaved():
    """The rheology and 2D/3D cases compiled first, then timed in turn (best of 10 rounds)."""
    common = ["numerics.dt_s=2e-4"]
    cases = {
        "newtonian": ["material.model=newtonian", "material.viscosity_pa_s=4.0"],
        "bingham": ["material.model=bingham", "material.viscosity_pa_s=0.65", "material.yield_stress_pa=36.0"],
        "coussot": [],
        "coussot 3D slab": SLAB_3D,
    }
    steps = 400
    progs = {}
    for k, over in cases.items():
        s = build(load_scene("dambreak-lab", common + over))
        progs[k] = (s, jax.jit(make_chunk(s.scene, steps)).lower(s.state, s.params).compile())
    load = os.getloadavg()[0]
    best = interleaved(progs, steps)
    for k, (s, _) in progs.items():
        n = s.scene.n_particles
        record(
            part="rheology_dim_interleaved",
            case=k,
            n_particles=n,
            n_nodes=s.scene.n_nodes,
            internal=sorted(s.state.internal),
            steps=steps,
            best_wall_s=best[k],
            steps_per_s=steps / best[k],
            particle_steps_per_s=n * steps / best[k],
            load_avg_start=load,
        )


def grid():
    """Step time against the grid size with the same particles: x extent of the domain x0.5, x1, x2."""
    cases = {
        "field-dambreak-2d": ([3000.0, 24.0], 40),
        "field-dambreak-3d": ([3000.0, 300.0, 24.0], 10),
        "field-pipe-3d": ([150.0, 25.0, 2.0], 10),
    }
    for name, (hi, steps) in cases.items():
        for f in (0.5, 1.0, 2.0):
            h = [hi[0] * f] + hi[1:]
            s = build(load_scene(name, [f"domain.hi_m={h}"]))
            r = measure(s, steps, reps=2)
            record(part="grid", scene=name, x_factor=f, **r)


def grid_interleaved():
    """As ``grid``, but the three grid sizes of a scene are compiled first and then timed in turn,
    round after round (best of 5 rounds each), so that load drift hits all three alike."""
    cases = {
        "field-dambreak-2d": ([3000.0, 24.0], 40),
        "field-dambreak-3d": ([3000.0, 300.0, 24.0], 6),
        "field-pipe-3d": ([150.0, 25.0, 2.0], 10),
    }
    for name, (hi, steps) in cases.items():
        progs = {}
        for f in (0.5, 1.0, 2.0):
            s = build(load_scene(name, [f"domain.hi_m={[hi[0] * f] + hi[1:]}"]))
            progs[f] = (s, jax.jit(make_chunk(s.scene, steps)).lower(s.state, s.params).compile())
        best = {f: float("inf") for f in progs}
        load = os.getloadavg()[0]
        for _ in range(5):
            for f, (s, g) in progs.items():
                t0 = time.perf_counter()
                jax.block_until_ready(g(s.state, s.params).x)
                best[f] = min(best[f], time.perf_counter() - t0)
        for f, (s, _) in progs.items():
            record(
                part="grid_interleaved",
                scene=name,
                x_factor=f,
                n_nodes=s.scene.n_nodes,
                n_particles=s.scene.n_particles,
                steps=steps,
                best_wall_s=best[f],
                ms_per_step=1e3 * best[f] / steps,
                load_avg_start=load,
            )


def grid_particles():
    """Step time against both the grid size (x extent x0.5, x1) and the particle count (the whole
    buffer and a prefix of a quarter of it), interleaved: separates the grid, particle and fixed
    parts of a step for the 3D field scenes."""
    cases = {
        "field-dambreak-3d": ([3000.0, 300.0, 24.0], 6),
        "field-pipe-3d": ([150.0, 25.0, 2.0], 10),
    }
    for name, (hi, steps) in cases.items():
        progs = {}
        for f in (0.5, 1.0):
            s = build(load_scene(name, [f"domain.hi_m={[hi[0] * f] + hi[1:]}"]))
            for frac in (1.0, 0.25):
                n = int(s.scene.n_particles * frac)
                st = _split(s.state, n)[0] if frac < 1 else s.state
                sub = dataclasses.replace(s, state=st)
                progs[(f, n)] = (sub, jax.jit(make_chunk(s.scene, steps)).lower(st, s.params).compile())
        load = os.getloadavg()[0]
        best = interleaved(progs, steps, rounds=5)
        for (f, n), (s, _) in progs.items():
            record(
                part="grid_particles",
                scene=name,
                x_factor=f,
                n_nodes=s.scene.n_nodes,
                n_particles_stepped=n,
                steps=steps,
                best_wall_s=best[(f, n)],
                ms_per_step=1e3 * best[(f, n)] / steps,
                load_avg_start=load,
            )


def staged():
    """Pipe pours through the command-line runner, staged against the whole buffer."""
    cases = {
        "flume-deposition": ["time.t_end_s=400.0", "time.n_frames=40", "inflow.t_stop_s=400.0"],
        "field-pipe-3d": ["time.t_end_s=30.0", "time.n_frames=10", "inflow.t_stop_s=30.0"],
    }

    _simulate.MIN_STAGE = 64  # stage these small pools too (the default stops at 256 particles)
    if len(sys.argv) > 2:
        cases = {k: v for k, v in cases.items() if k in sys.argv[2:]}
    for name, over in cases.items():
        walls = {}
        for st in (False, True):
            load = os.getloadavg()[0]
            out = Path(f"/tmp/static_skips_{name}_{st}")
            s = run_scene(name, out, over, quiet=True, staged=st, checkpoint_every=0)
            walls[st] = s["wall_s"]
            record(
                part="staged",
                scene=name,
                overrides=over,
                staged=st,
                wall_s=s["wall_s"],
                compile_s=s["compile_s"],
                n_particles=s["n_particles"],
                n_steps=s["n_steps"],
                load_avg_start=load,
                final_runout_m=s["final_runout_m"],
                mass_final_kg=s["mass_final_kg"],
                min_stage=_simulate.MIN_STAGE,
            )


if __name__ == "__main__":
    parts = sys.argv[1:2] or ["rheology", "dim", "grid", "staged"]
    for p in parts:
        globals()[p]()
