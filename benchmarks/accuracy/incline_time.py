"""The near-yield incline of ``mpmjax validate`` (``bingham-incline``) in time: how long a layer started from
rest takes to reach the steady film, and whether it stays there.

The layer of ``mpmjax.studies.validate.incline_config`` (H = 0.1 m, 30 degrees, periodic along the slope,
mu = 20 Pa s, Papanastasiou m = 1000 s, no-slip bed, ppc 2), tau_y = tau_b / r.  One JSON line per run: the
plug speed (mean of the particles that start in the top fifth) at every frame against the exact steady film
rho g sin(theta) delta^2 / (2 mu), delta = H (1 - 1/r), as a relative error; the first frame from which it
stays within 1 % (None: never); steps, dt and CPU.  ``jitter_h=F``: every particle starts displaced by up to
F h along each axis (uniform, seeded), the perturbation that float32 rounding otherwise supplies.

    .venv/bin/python benchmarks/accuracy/incline_time.py R CELLS T_END N_FRAMES [section.key=value ...]
    .venv/bin/python benchmarks/accuracy/incline_time.py 1.1 20 6 30 numerics.pressure=incompressible
    .venv/bin/python benchmarks/accuracy/incline_time.py 1.2 20 16 16 numerics.pressure=incompressible numerics.ppc=3
    .venv/bin/python benchmarks/accuracy/incline_time.py 1.2 20 16 16 numerics.pressure=incompressible numerics.dtype=float64 jitter_h=1e-3

The lines of 2026-12-06 in incline_time.jsonl are docs/incompressible.md's "The incline in time".
"""

import json
import sys
import time

import jax.numpy as jnp
import numpy as np

from mpmjax import build
from mpmjax._simulate import make_advance
from mpmjax.studies.validate import incline_config, incline_plug_speed, incline_top, settle_time

r, cells, t_end, n_frames = float(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
over, jitter = {}, 0.0
for item in sys.argv[5:]:
    if item.startswith("jitter_h="):
        jitter = float(item.split("=", 1)[1])
        continue
    key, val = item.split("=", 1)
    try:
        val = json.loads(val)
    except ValueError:
        pass
    over[key] = val
cfg = incline_config(cells, r, t_end, {**over, "time.n_frames": n_frames})
s = build(cfg)
adv = make_advance(s.scene)
top = incline_top(s)
exact = incline_plug_speed(r)
st, times, errs = s.state, [], []
if jitter:
    x0 = np.asarray(st.x)
    x0 = x0 + jitter * s.scene.h * np.random.default_rng(0).uniform(-1.0, 1.0, x0.shape)
    st = st._replace(x=jnp.asarray(x0, st.x.dtype))
c0 = time.process_time()
for _ in range(n_frames):
    st = adv(st, s.params)
    times.append(round(float(st.t), 6))
    errs.append(float(np.asarray(st.v)[top, 0].mean()) / exact - 1.0)
cpu = time.process_time() - c0
print(json.dumps({
    "date": time.strftime("%Y-%m-%d"), "r": r, "cells": cells, "t_end_s": t_end, "overrides": over, "jitter_h": jitter,
    "dtype": s.scene.dtype, "dt_s": s.scene.dt, "steps": int(s.scene.n_steps), "cpu_s": round(cpu, 1),
    "exact_m_s": exact, "frame_times_s": times, "error_pct": [round(100 * e, 3) for e in errs],
    "within_1pct_from_s": settle_time(times, errs),
}))
