"""Thin pipe-fed deposit: how much denser the particles sit than their J says (docs/scenarios.md).

Runs ``flume-deposition`` (or another 2D pipe scene) shortened to T seconds and poured for all of
them, in float64, then prints one JSON line: the deposited volume sum(J V0), the area under the
free surface (per cell-wide column: the top particle + half a particle spacing), their ratio
(1 for a deposit whose particles fill the volume their J gives them), the most particles found in
one cell (nominal ppc^2), the front position and the wall time.
usage: python benchmarks/accuracy/thin_deposit.py SCENE T [KEY=VALUE ...]   (scene overrides, as --set)
"""

import json
import sys
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from mpmjax import _simulate  # noqa: E402
from mpmjax import build, load_scene  # noqa: E402

scene_name, t_end, extra = sys.argv[1], float(sys.argv[2]), sys.argv[3:]
over = [f"time.t_end_s={t_end}", "time.n_frames=4", "numerics.dtype=float64"] + extra
if scene_name == "flume-deposition":
    over.append(f"inflow.t_stop_s={t_end}")
cfg = load_scene(scene_name, over)
setup = build(cfg)
sc = setup.scene
t0 = time.perf_counter()
final, _ = jax.jit(lambda s, p: _simulate.simulate(sc, s, p))(setup.state, setup.params)
jax.block_until_ready(final)
wall = time.perf_counter() - t0
a = np.asarray(final.active).astype(bool)
x, J, vol0 = np.asarray(final.x)[a], np.asarray(final.J)[a], np.asarray(final.vol0)[a]
h, sp = sc.h, sc.h / cfg["numerics.ppc"]
ix = np.floor((x[:, 0] - sc.lo[0]) / h).astype(int)
iy = np.floor((x[:, 1] - sc.lo[1]) / h).astype(int)
area = sum((x[ix == i, 1].max() - sc.lo[1] + sp / 2) * h for i in np.unique(ix))
_, count = np.unique(ix * 1_000_000 + iy, return_counts=True)
vol = float((J * vol0).sum())
print(
    json.dumps(
        {
            "scene": scene_name,
            "t_s": t_end,
            "overrides": extra,
            "h_m": h,
            "dt_s": sc.dt,
            "n_active": int(a.sum()),
            "sum_J_V0_m2": vol,
            "area_under_surface_m2": float(area),
            "ratio": vol / float(area),
            "max_particles_in_a_cell": int(count.max()),
            "nominal_per_cell": cfg["numerics.ppc"] ** 2,
            "J_min": float(J.min()),
            "front_m": float(x[:, 0].max()),
            "n_lost": int(final.n_lost),
            "wall_s": wall,
            "backend": jax.default_backend(),
        }
    )
)
