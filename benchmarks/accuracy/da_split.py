"""Column splitting (``numerics.split_levels``) of the depth-averaged step on its exact and resolved cases:
what it changes and what it costs.  float64, 2 shared cores; one JSON line per run on stdout.

Cases (the geometry of tests/test_depth_averaged.py):

* ``ritter``: frictionless dam break, H0 = 0.1 m, t = 0.4 s, h = 1 cm, 8 columns a cell; the farthest column
  against the exact front x0 + 2 c0 t, where the nodal depth falls to H0/5 and H0/20 against the exact
  parabola, the L1 error of the depth over the wave;
* ``current``: Huppert's viscous gravity current (q = 0.01 m^2, nu = 0.01 m^2/s, 10 s): farthest column +
  half a spacing against 1.411 (g q^3 t / (3 nu))^(1/5);
* ``lubrication``: the inertia-free Bingham slump B = 0.05, H0 = L = 0.1 m, h = 5 mm, 4 columns a cell,
  100 s: headline front (10 % of the deepest) against x_inf = 0.2823 m, and the largest speed;
* ``fast``: the twin's fast Bingham slump (0.3 m x 0.1 m, mu = 0.5 Pa s) at TAU_Y and COLUMNS a cell, 4 s:
  the fronts at 1-4 s and the largest speed at 4 s.

    .venv/bin/python benchmarks/accuracy/da_split.py CASE LEVELS [POOL] [TAU_Y COLUMNS]
    for L in 0 1 2 4 6; do .venv/bin/python benchmarks/accuracy/da_split.py ritter $L 1; done

The lines of 2026-12-06 in da_split.jsonl are the docs' table (docs/depth-averaged.md, "Column splitting").
"""

import json
import math
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from mpmjax._build import build  # noqa: E402
from mpmjax._observables import free_surface_front  # noqa: E402
from mpmjax._schema import validate  # noqa: E402
from mpmjax._shallow import plan_depth  # noqa: E402
from mpmjax._simulate import simulate  # noqa: E402

G = 9.81
case, levels = sys.argv[1], int(sys.argv[2])
pool = float(sys.argv[3]) if len(sys.argv) > 3 else 1.0


def scene(material, body, t_end, h, ppc, length, n_frames, x_hi="open"):
    return validate({
        "model": {"formulation": "depth-averaged"},
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [length, 0.2], "cell_size_m": h},
        "boundary": {"x_lo": "slip", "x_hi": x_hi},
        "numerics": {"shape": "quadratic", "ppc": ppc, "dtype": "float64", "split_levels": levels,
                     "split_pool": pool},
        "material": dict(material, density_kg_m3=1000.0, bulk_modulus_pa=1e5),
        "time": {"t_end_s": t_end, "n_frames": n_frames},
        "bodies": [{"type": "box", "lo_m": body[0], "hi_m": body[1]}],
    })


def run(cfg):
    s = build(cfg)
    f = jax.jit(simulate, static_argnums=(0, 3))
    f(s.scene, s.state, s.params)[0].x.block_until_ready()  # compile
    t0 = time.process_time()
    fin, fr = f(s.scene, s.state, s.params)
    fin.x.block_until_ready()
    return s, fin, fr, time.process_time() - t0


out = {"case": case, "levels": levels, "pool": pool, "date": time.strftime("%Y-%m-%d")}
if case == "ritter":
    H0, X0, T = 0.1, 1.0, 0.4
    s, fin, fr, cpu = run(scene({"model": "newtonian", "viscosity_pa_s": 1e-12}, ([0, 0], [X0, H0]), T, 0.01, 8, 2.0, 4))
    H, xn = plan_depth(s.scene, fin)
    H, xn = np.asarray(H), xn[:, 0]
    c0 = math.sqrt(G * H0)
    travel = 2 * c0 * T
    xi = (xn - X0) / T
    exact = np.where(xi > 2 * c0, 0.0, np.clip(np.where(xi < -c0, H0, (2 * c0 - xi) ** 2 / (9 * G)), 0.0, H0))
    wave = (xi > -c0) & (xi < 2 * c0)
    out["depth_l1_wave"] = float(np.abs(H - exact)[wave].sum() / exact[wave].sum())
    for frac in (0.2, 0.05, 0.01):
        i = np.nonzero(H >= frac * H0)[0][-1]
        x_num = xn[i] + (H[i] - frac * H0) / (H[i] - H[i + 1]) * s.scene.h
        x_ex = X0 + c0 * T * (2 - 3 * math.sqrt(frac))
        out[f"front_H0/{round(1 / frac)}_of_travel"] = (x_num - x_ex) / travel
    a = np.asarray(fin.active)
    out["farthest_of_travel"] = (float(np.asarray(fin.x[a, 0]).max()) - X0 - travel) / travel
    out["dam_site_depth_rel"] = float(np.interp(X0, xn, H)) / (4 / 9 * H0) - 1
elif case == "current":
    s, fin, fr, cpu = run(scene({"model": "newtonian", "viscosity_pa_s": 10.0}, ([0, 0], [0.1, 0.1]), 10.0, 0.01, 8,
                                1.0, 2))
    a = np.asarray(fin.active)
    x_n = float(np.asarray(fin.x[a, 0]).max()) + 0.5 * s.scene.h / 8
    out["front_rel"] = x_n / (1.411 * (G * 0.01**3 * 10.0 / (3 * 0.01)) ** 0.2) - 1
elif case == "lubrication":
    rho, h0, length, b = 1000.0, 0.1, 0.1, 0.05
    tau = b * rho * G * h0**2 / length
    xinf = (9 * rho * G * h0**2 * length**2 / (8 * tau)) ** (1 / 3)
    mat = {"model": "bingham", "viscosity_pa_s": math.sqrt(rho**2 * G * h0**3), "yield_stress_pa": tau}
    s, fin, fr, cpu = run(scene(mat, ([0, 0], [length, h0]), 100.0, 0.005, 4, 0.4, 2, x_hi="slip"))
    front = float(free_surface_front(fin.x, fin.vol0, fin.active, bandwidth=0.005, x_lo=0.0, x_hi=0.4))
    out["front_rel"] = front / xinf - 1
    out["vmax_m_s"] = float(jnp.abs(fin.v).max())
elif case == "fast":
    tau_y, cols = float(sys.argv[4]), int(sys.argv[5])
    mat = {"model": "bingham", "viscosity_pa_s": 0.5, "yield_stress_pa": tau_y}
    s, fin, fr, cpu = run(scene(mat, ([0, 0], [0.3, 0.1]), 4.0, 0.005, cols, 1.2, 4))
    out.update(tau_y=tau_y, columns_a_cell=cols)
    out["fronts_m"] = [float(free_surface_front(fr.x[i], fr.vol0[i], fr.active[i], bandwidth=0.01, x_lo=0.0,
                                                x_hi=1.2)) for i in range(4)]
    out["vmax_m_s"] = float(jnp.abs(fin.v).max())
else:
    sys.exit(f"CASE = {case!r}; allowed: ritter, current, lubrication, fast")
out["columns"] = int(np.asarray(fin.active).sum())
out["slots"] = int(s.scene.n_particles)
out["mass_rel"] = float(jnp.sum(fin.vol0 * fin.active) / jnp.sum(s.state.vol0 * s.state.active)) - 1
out["steps"] = int(s.scene.n_steps)
out["loop_cpu_s"] = round(cpu, 2)
print(json.dumps(out))
