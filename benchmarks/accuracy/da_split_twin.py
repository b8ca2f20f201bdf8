"""A twin back-analysis of the yield stress from the final (arrested) deposit of the depth-averaged step,
with and without column splitting (docs/depth-averaged.md, "Column splitting").

Truth: the Bingham dam break of tests/test_depth_averaged.py's twin (tau_y = 20 Pa, mu = 0.5 Pa s, 0.3 m x
0.1 m against a slip wall) at h = 5 mm, 8 columns a cell, run to T_END s (arrested near 1.5-2 s); its outline
(kernel height profile at 2 cm stations where over 2 mm, bandwidth 2 cm, sigma 2 mm) and headline runout.
Fit: the same scene at h = 10 mm, COLUMNS a cell, split_levels LEVELS, Levenberg-Marquardt through
``calibration.fit`` from tau_y = 40 and 10 Pa, at most MAX_ITER iterations (default 60; stop 55's lines used 15,
which stopped both starts before their optimum).  One JSON line per start, with the fit's loss, iterations and stop
reason.  SCAN (optional, "lo,hi,n"): the loss at n yield stresses from lo to hi Pa first, one line each
(MAX_ITER 0: the scan alone).

    .venv/bin/python benchmarks/accuracy/da_split_twin.py T_END COLUMNS LEVELS [POOL [MAX_ITER [SCAN]]]

(POOL: numerics.split_pool, default 0.5.)
"""

import json
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from calibration.data import Profile  # noqa: E402
from calibration.experiments import ProfileExperiment, joint_loss  # noqa: E402
from calibration.fit import fit  # noqa: E402
from calibration.params import ParameterSet  # noqa: E402
from mpmjax._build import build  # noqa: E402
from mpmjax._observables import free_surface_front, height_profile  # noqa: E402
from mpmjax._schema import validate  # noqa: E402
from mpmjax._simulate import simulate  # noqa: E402

t_end, cols, levels = float(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
pool = float(sys.argv[4]) if len(sys.argv) > 4 else 0.5
max_iter = int(sys.argv[5]) if len(sys.argv) > 5 else 60
scan = [float(a) for a in sys.argv[6].split(",")] if len(sys.argv) > 6 else None


def setup(h, ppc, lev):
    return build(validate({
        "model": {"formulation": "depth-averaged"},
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [1.2, 0.2], "cell_size_m": h},
        "boundary": {"x_lo": "slip", "x_hi": "open"},
        "numerics": {"shape": "quadratic", "ppc": ppc, "dtype": "float64", "split_levels": lev, "split_pool": pool},
        "material": {"model": "bingham", "viscosity_pa_s": 0.5, "yield_stress_pa": 20.0, "density_kg_m3": 1000.0,
                     "bulk_modulus_pa": 1e5},
        "time": {"t_end_s": t_end, "n_frames": 1},
        "bodies": [{"type": "box", "lo_m": [0.0, 0.0], "hi_m": [0.3, 0.1]}],
    }))


truth = setup(0.005, 8, 0)
fin, _ = jax.jit(simulate, static_argnums=(0, 3))(truth.scene, truth.state, truth.params)
xs = np.arange(0.01, 1.2, 0.02)
hp = np.asarray(height_profile(fin.x, fin.vol0, fin.active, jnp.asarray(xs), bandwidth=0.02))
on = hp > 0.002
runout = float(free_surface_front(fin.x, fin.vol0, fin.active, bandwidth=0.01, x_lo=0.0, x_hi=1.2))
coarse = setup(0.01, cols, levels)
exp = ProfileExperiment(coarse, [Profile(x_m=xs[on], h_m=hp[on])], bandwidth_m=0.02, sigma_m=0.002, runout_m=runout)
if scan is not None:
    mat = coarse.params.material
    loss_at = jax.jit(lambda t: joint_loss([exp], {**{k: getattr(mat, k) for k in mat._fields}, "tau_y": t}))
    for t in np.linspace(scan[0], scan[1], int(scan[2])):
        print(json.dumps({"t_end_s": t_end, "columns": cols, "levels": levels, "pool": pool, "scan_tau_y_pa": float(t),
                          "loss": float(loss_at(jnp.asarray(t)))}), flush=True)
for start in (40.0, 10.0) if max_iter > 0 else ():  # MAX_ITER 0: the scan alone
    ps = ParameterSet.from_names(["tau_y"], coarse.params.material, init={"tau_y": start})
    t0 = time.process_time()
    r = fit([exp], ps, method="lm", max_iter=max_iter, progress=False)
    fin_c, _ = jax.jit(simulate, static_argnums=(0, 3))(coarse.scene, coarse.state, coarse.params._replace(
        material=coarse.params.material._replace(tau_y=r.params["tau_y"])))
    spare = int(np.sum(~np.asarray(fin_c.active) & (np.asarray(fin_c.vol0) == 0)))
    print(json.dumps({"t_end_s": t_end, "columns": cols, "levels": levels, "pool": pool, "start_pa": start,
                      "spare_left_at_fit": spare, "vmax_at_fit_m_s": float(jnp.abs(fin_c.v).max()),
                      "truth_runout_m": runout, "truth_vmax_m_s": float(jnp.abs(fin.v).max()),
                      "tau_y_fit_pa": float(r.params["tau_y"]), "rel": float(r.params["tau_y"]) / 20.0 - 1,
                      "loss_ratio": float(r.loss_final / r.loss_initial), "loss_final": float(r.loss_final),
                      "iterations": int(r.iterations), "stop_reason": r.reason, "max_iter": max_iter,
                      "cpu_s": round(time.process_time() - t0, 1),
                      "date": time.strftime("%Y-%m-%d")}))
