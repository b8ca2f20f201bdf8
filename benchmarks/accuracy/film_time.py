"""A Newtonian film on an incline in time: does the discrete sheared state stay on the exact film?

The layer of ``mpmjax.studies.validate.incline_config`` (H = 0.1 m, 30 degrees, periodic along the slope over
4 cells, no-slip bed, free surface, ppc 2, rho = 1000 kg/m^3) with a Newtonian law of viscosity MU instead of
the Bingham one: no yield stress, so nothing near a yield limit.  Exact steady film (Nusselt):
u(y) = U_s (2 eta - eta^2), eta = y / H, U_s = rho g sin(theta) H^2 / (2 mu); the particles that start in the
top fifth move at 0.98667 U_s on average.  One JSON line per run: that mean against it at every frame, as a
relative error, and the rms of the particles' dv_y/dx (APIC's C_yx) in the four rows over the bed, the
first thing to grow when the layer leaves the film (docs/incompressible-default.md, "Long shear").
At MU = 120 Pa s the bed shear rate is 6.1 /s, as in the Bingham ``bingham-incline-long`` (r = 1.2).

    .venv/bin/python benchmarks/accuracy/film_time.py CELLS T_END N_FRAMES MU [section.key=value ...] [jitter_h=F]
    .venv/bin/python benchmarks/accuracy/film_time.py 20 12 12 120 numerics.pressure=incompressible
    .venv/bin/python benchmarks/accuracy/film_time.py 20 12 12 120 numerics.pressure=explicit

The lines of 2026-12-06 in film_time.jsonl are the docs' table.
"""

import json
import math
import sys
import time

import jax.numpy as jnp
import numpy as np

from mpmjax import build
from mpmjax._schema.validate import validate
from mpmjax._simulate import make_advance
from mpmjax.studies import validate as V

cells, t_end, n_frames, mu = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
over, jitter = {}, 0.0
for item in sys.argv[5:]:
    key, val = item.split("=", 1)
    if key == "jitter_h":
        jitter = float(val)
        continue
    try:
        val = json.loads(val)
    except ValueError:
        pass
    over[key] = val
h = V.INCLINE_H / cells
raw = {
    "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [4 * h, V.INCLINE_H + 5 * h], "cell_size_m": h},
    "boundary": {"x_lo": "periodic", "x_hi": "periodic", "y_lo": "noslip", "y_hi": "slip"},
    "numerics": {"ppc": 2},
    "time": {"t_end_s": t_end, "n_frames": n_frames},
    "material": {"model": "newtonian", "density_kg_m3": V.RHO, "bulk_modulus_pa": 2e5, "viscosity_pa_s": mu},
    "gravity": {"g_m_s2": V.G, "slope_deg": V.INCLINE_SLOPE},
    "bodies": [{"lo_m": [0.0, 0.0], "hi_m": [4 * h, V.INCLINE_H]}],
}
s = build(validate(V._nested(raw, over)))
adv = make_advance(s.scene)
st = s.state
y0 = np.asarray(st.x)[:, 1]
top, bed = y0 > 0.8 * V.INCLINE_H, y0 < 4 * h
u_s = V.RHO * V.G * math.sin(math.radians(V.INCLINE_SLOPE)) * V.INCLINE_H**2 / (2.0 * mu)
exact = u_s * ((1.0 - 1.0 / 3.0) - (0.8**2 - 0.8**3 / 3.0)) / 0.2  # mean of u over eta in [0.8, 1]
if jitter:
    x0 = np.asarray(st.x) + jitter * h * np.random.default_rng(0).uniform(-1.0, 1.0, st.x.shape)
    st = st._replace(x=jnp.asarray(x0, st.x.dtype))
times, errs, cyx = [], [], []
c0 = time.process_time()
for _ in range(n_frames):
    st = adv(st, s.params)
    times.append(round(float(st.t), 6))
    errs.append(round(100.0 * (float(np.asarray(st.v)[top, 0].mean()) / exact - 1.0), 3))
    cyx.append(float(f"{float(np.sqrt((np.asarray(st.C)[bed, 1, 0] ** 2).mean())):.3g}"))
cpu = time.process_time() - c0
print(json.dumps({
    "date": time.strftime("%Y-%m-%d"), "cells": cells, "mu_pa_s": mu, "t_end_s": t_end, "overrides": over,
    "jitter_h": jitter, "dtype": s.scene.dtype, "dt_s": s.scene.dt, "steps": int(s.scene.n_steps),
    "cpu_s": round(cpu, 1), "exact_top_m_s": exact, "frame_times_s": times, "error_pct": errs,
    "bed_rms_dvy_dx_per_s": cyx,
}))
