"""Measure the static skips of docs/performance.md, "Static skips" (issue 6).

Run from the repository root: ``.venv/bin/python benchmarks/speed/static_skips.py [part ...]`` with parts
``rheology``, ``dim``, ``grid``, ``staged`` (default: all), ``mpm88_minimal`` (issue 18 item 2).  Appends one JSON line per measurement
to benchmarks/speed/static_skips.jsonl.  Timings are of compiled code (compile reported apart), best of
``reps`` repetitions; the load average at the start of each measurement is recorded with it.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from pathlib import Path
from typing import NamedTuple

import jax

from mpmjax import _simulate, build, load_scene, run_scene, validate
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


class _Minimal(NamedTuple):
    x: jax.Array
    v: jax.Array
    C: jax.Array
    J: jax.Array


def minimal_mpm88(steps: int):
    """``(state, advance)``: a minimal JAX port of the mpm88 step (issue 18 item 2's yardstick).

    The MLS-MPM of benchmarks/speed/taichi_mlsmpm.py written in jax.numpy with nothing else: 128^2
    nodes, 8192 particles, quadratic B-spline, APIC with the pressure impulse p = kappa (1 - J) in
    the affine term, gravity, free-slip walls three cells thick, one scatter-add P2G (mass and
    momentum stacked), float32; ``advance`` runs ``steps`` steps in a ``lax.scan``.
    """
    import jax.numpy as jnp

    n_grid, dx, dt = 128, 1.0 / 128, 1e-4
    rho, kappa, g, bound = 1000.0, 4.0e5, 9.81, 3
    nx, ny = 64, 128
    p_vol = (0.5 * dx) ** 2
    p_mass = rho * p_vol
    k = jnp.arange(nx * ny)
    x0 = jnp.stack([0.1 + (k % nx + 0.5) * 0.5 * dx, 0.1 + (k // nx + 0.5) * 0.5 * dx], axis=1).astype(jnp.float32)
    n = x0.shape[0]
    state = _Minimal(x0, jnp.zeros_like(x0), jnp.zeros((n, 2, 2), jnp.float32), jnp.ones((n,), jnp.float32))
    offs = [(a, b) for a in range(3) for b in range(3)]
    gi, gj = jnp.meshgrid(jnp.arange(n_grid), jnp.arange(n_grid), indexing="ij")
    gi, gj = gi.reshape(-1), gj.reshape(-1)

    def stencil(x):
        xi = x / dx
        base = jnp.floor(xi - 0.5).astype(jnp.int32)
        f = xi - base
        w = [0.5 * (1.5 - f) ** 2, 0.75 - (f - 1.0) ** 2, 0.5 * (f - 0.5) ** 2]
        idx = jnp.stack([(base[:, 0] + a) * n_grid + base[:, 1] + b for a, b in offs], axis=1)
        wt = jnp.stack([w[a][:, 0] * w[b][:, 1] for a, b in offs], axis=1)
        r = jnp.stack([(jnp.array([a, b], jnp.float32)[None] - f) * dx for a, b in offs], axis=1)
        return idx, wt, r

    def step(s, _):
        idx, wt, r = stencil(s.x)
        impulse = -dt * 4.0 * kappa * p_vol * (1.0 - s.J) / dx**2
        affine = -impulse[:, None, None] * jnp.eye(2, dtype=jnp.float32)[None] + p_mass * s.C
        mom = wt[..., None] * (p_mass * s.v[:, None, :] + jnp.einsum("nij,nsj->nsi", affine, r))
        chans = jnp.concatenate([mom, (wt * p_mass)[..., None]], axis=-1).reshape(-1, 3)
        grid = jnp.zeros((n_grid * n_grid, 3), jnp.float32).at[idx.reshape(-1)].add(chans)
        m = grid[:, 2]
        gv = jnp.where(m[:, None] > 0, grid[:, :2] / jnp.where(m > 0, m, 1.0)[:, None], 0.0)
        gv = gv.at[:, 1].add(-dt * g)
        vx = jnp.where(((gi < bound) & (gv[:, 0] < 0)) | ((gi > n_grid - bound) & (gv[:, 0] > 0)), 0.0, gv[:, 0])
        vy = jnp.where(((gj < bound) & (gv[:, 1] < 0)) | ((gj > n_grid - bound) & (gv[:, 1] > 0)), 0.0, gv[:, 1])
        gv = jnp.where(m[:, None] > 0, jnp.stack([vx, vy], axis=1), 0.0)
        gvp = gv[idx]  # (n, 9, 2)
        nv = jnp.sum(wt[..., None] * gvp, axis=1)
        nC = 4.0 / dx**2 * jnp.einsum("ns,nsi,nsj->nij", wt, gvp, r)
        J = s.J * (1.0 + dt * (nC[:, 0, 0] + nC[:, 1, 1]))
        return _Minimal(s.x + dt * nv, nv, nC, J), None

    return state, jax.jit(lambda s: jax.lax.scan(step, s, None, length=steps)[0])


def mpm88_minimal(steps: int = 500, rounds: int = 6):
    """mpmjax's mpm88-equivalent (every skip the scene allows) against ``minimal_mpm88``, timed in turn
    (CPU time and wall time per call, each code first in turn), issue 18 item 2."""
    from mpmjax.studies.bench import MPM88

    setup = build(validate(json.loads(json.dumps(MPM88))))
    full = jax.jit(make_chunk(setup.scene, steps))
    m_state, m_adv = minimal_mpm88(steps)
    progs = {
        "mpmjax mpm88-equivalent": lambda: full(setup.state, setup.params).x,
        "minimal JAX port": lambda: m_adv(m_state).x,
    }
    for f in progs.values():
        jax.block_until_ready(f())
    names = list(progs)
    for rnd in range(rounds):
        for k in names[rnd % 2 :] + names[: rnd % 2]:
            load = os.getloadavg()[0]
            c0, w0 = time.process_time(), time.perf_counter()
            jax.block_until_ready(progs[k]())
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
            record(part="mpm88_minimal", code=k, round=rnd + 1, n_particles=8192, steps=steps, cpu_s=cpu,
                   wall_s=wall, particle_steps_per_s_wall=8192 * steps / wall, load_avg_start=load)


if __name__ == "__main__":
    parts = sys.argv[1:2] or ["rheology", "dim", "grid", "staged"]
    for p in parts:
        globals()[p]()
