"""Taichi's CPU backend on the mpm88 configuration: the reference side of the speed target.

Not part of the package and not a dependency: run it in its own environment
(``python -m venv tv && tv/bin/pip install taichi``), through ``benchmarks/speed/side_by_side.sh``,
which times this and ``mpmjax``'s mpm88-equivalent one after the other under the same load.

The algorithm is MLS-MPM as in Taichi's ``mpm88`` example (written here from the method, Hu et
al. 2018, not copied): 2D, 128 x 128 cells on the unit square, 8192 particles at 2 per cell per
axis, quadratic B-spline, APIC, a weakly compressible fluid p = kappa (1 - J), gravity, free-slip
box walls three cells thick.  The particle block and the material are those of
``mpmjax.studies.bench.MPM88`` (rho = 1000 kg/m^3, kappa = 4e5 Pa); the step dt = 1e-4 s.  Cost per
particle-step does not depend on dt.

Prints one JSON line: particle-steps per second (best of ``reps``), threads, compile time.
usage: [TAICHI_ARCH=cpu|cuda] python taichi_mlsmpm.py [STEPS] [THREADS]
"""

import json
import os
import sys
import time

import taichi as ti

STEPS = int(sys.argv[1]) if len(sys.argv) > 1 else 2000
THREADS = int(sys.argv[2]) if len(sys.argv) > 2 else 2
# TAICHI_ARCH=cuda runs the same kernels on an NVIDIA GPU (THREADS is then ignored)
ARCH = os.environ.get("TAICHI_ARCH", "cpu")
if ARCH not in ("cpu", "cuda"):
    raise SystemExit(f"TAICHI_ARCH = {ARCH!r} is invalid: allowed 'cpu' or 'cuda'")
ti.init(arch=getattr(ti, ARCH), cpu_max_num_threads=THREADS, default_fp=ti.f32, offline_cache=False)

N_GRID = 128
DX = 1.0 / N_GRID
DT = 1e-4
RHO, KAPPA, G = 1000.0, 4.0e5, 9.81
NX, NY = 64, 128  # the block [0.1, 0.35] x [0.1, 0.6] at spacing DX / 2
N = NX * NY
P_VOL = (0.5 * DX) ** 2
P_MASS = RHO * P_VOL
BOUND = 3

x = ti.Vector.field(2, ti.f32, N)
v = ti.Vector.field(2, ti.f32, N)
C = ti.Matrix.field(2, 2, ti.f32, N)
J = ti.field(ti.f32, N)
grid_v = ti.Vector.field(2, ti.f32, (N_GRID, N_GRID))
grid_m = ti.field(ti.f32, (N_GRID, N_GRID))


@ti.kernel
def seed():
    for p in x:
        i, j = p % NX, p // NX
        x[p] = ti.Vector([0.1 + (i + 0.5) * 0.5 * DX, 0.1 + (j + 0.5) * 0.5 * DX])
        v[p] = ti.Vector([0.0, 0.0])
        C[p] = ti.Matrix.zero(ti.f32, 2, 2)
        J[p] = 1.0


@ti.kernel
def step():
    for i, j in grid_m:
        grid_v[i, j] = ti.Vector([0.0, 0.0])
        grid_m[i, j] = 0.0
    # particles to grid: mass and APIC momentum with the pressure impulse folded into the affine term
    for p in x:
        xi = x[p] / DX
        base = ti.cast(xi - 0.5, ti.i32)
        f = xi - base
        w = [0.5 * (1.5 - f) ** 2, 0.75 - (f - 1.0) ** 2, 0.5 * (f - 0.5) ** 2]
        pressure_impulse = -DT * 4.0 * KAPPA * P_VOL * (1.0 - J[p]) / DX**2
        affine = ti.Matrix([[-pressure_impulse, 0.0], [0.0, -pressure_impulse]]) + P_MASS * C[p]
        for a, b in ti.static(ti.ndrange(3, 3)):
            off = ti.Vector([a, b])
            r = (off - f) * DX
            wt = w[a][0] * w[b][1]
            grid_v[base + off] += wt * (P_MASS * v[p] + affine @ r)
            grid_m[base + off] += wt * P_MASS
    # grid update: momentum to velocity, gravity, free-slip walls
    for i, j in grid_m:
        if grid_m[i, j] > 0.0:
            gv = grid_v[i, j] / grid_m[i, j]
            gv[1] -= DT * G
            if (i < BOUND and gv[0] < 0.0) or (i > N_GRID - BOUND and gv[0] > 0.0):
                gv[0] = 0.0
            if (j < BOUND and gv[1] < 0.0) or (j > N_GRID - BOUND and gv[1] > 0.0):
                gv[1] = 0.0
            grid_v[i, j] = gv
    # grid to particles: velocity, affine matrix, J, position
    for p in x:
        xi = x[p] / DX
        base = ti.cast(xi - 0.5, ti.i32)
        f = xi - base
        w = [0.5 * (1.5 - f) ** 2, 0.75 - (f - 1.0) ** 2, 0.5 * (f - 0.5) ** 2]
        nv = ti.Vector.zero(ti.f32, 2)
        nC = ti.Matrix.zero(ti.f32, 2, 2)
        for a, b in ti.static(ti.ndrange(3, 3)):
            off = ti.Vector([a, b])
            r = (off - f) * DX
            wt = w[a][0] * w[b][1]
            gv = grid_v[base + off]
            nv += wt * gv
            nC += 4.0 * wt * gv.outer_product(r) / DX**2
        v[p] = nv
        C[p] = nC
        J[p] *= 1.0 + DT * nC.trace()
        x[p] += DT * nv


def run(n):
    for _ in range(n):
        step()
    ti.sync()


seed()
t0 = time.perf_counter()
run(1)
compile_s = time.perf_counter() - t0
best = float("inf")
for _ in range(3):
    t0 = time.perf_counter()
    run(STEPS)
    best = min(best, time.perf_counter() - t0)
xs = x.to_numpy()
print(
    json.dumps(
        {
            "code": f"taichi {'.'.join(map(str, ti.__version__))} MLS-MPM (mpm88 configuration)",
            "arch": ARCH,
            "threads": THREADS,
            "n_particles": N,
            "steps": STEPS,
            "best_wall_s": best,
            "particle_steps_per_s": N * STEPS / best,
            "compile_s": compile_s,
            "finite": bool((xs == xs).all()),
            "y_mean_m": float(xs[:, 1].mean()),
        }
    )
)
