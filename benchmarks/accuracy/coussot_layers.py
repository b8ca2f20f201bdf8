"""The depth-averaged step's Coussot column against the film from rest, one value per column against layers
across the depth (``numerics.depth_layers``; docs/depth-averaged.md, "Structure across the depth").

A layer ``H`` deep of a built-in Coussot material, released from rest over a long incline (16 m for the lab's
5 cm to 6 s, 750 m for the field's 5 m to 30 s; open at its lower end, a slip wall at its upper: its middle third
stays uniform for longer than the run, the disturbances from the ends travelling in at about sqrt(g H)), at the
slope whose bed stress is r tau_c (tau_c the flow curve's minimum, ``rheometer.critical_point``).  The columns in the middle third against ``mpmjax.studies.film`` (the same
layer solved across its depth, 100 layers): mean speeds at 1, 2, 4 and 6 s (and 12 and 30 s for the field) and
their ratio; the loop's CPU time.  One JSON line per
case and layer count; float64.

    .venv/bin/python benchmarks/accuracy/coussot_layers.py [LAYERS ...]      # default: 1 8 16 32 64
"""

import functools
import json
import math
import sys
import time

import jax
import numpy as np

from coussot_film import MATERIALS  # this directory's script: the two built-in Coussot materials
from mpmjax import rheometer
from mpmjax._build import build
from mpmjax._schema import validate
from mpmjax._simulate import simulate
from mpmjax.studies import film

jax.config.update("jax_enable_x64", True)
G = 9.81
CASES = (  # material, depth H [m], plan cell h [m], incline length [m], times [s]
    ("dambreak-lab", 0.05, 0.05, 16.0, (1.0, 2.0, 4.0, 6.0)),
    ("field-breach-da", 5.0, 5.0, 750.0, (1.0, 2.0, 4.0, 6.0, 12.0, 30.0)),
)


def material_of(name):
    m = MATERIALS[name]
    return {"model": "coussot", "density_kg_m3": m["rho"], "bulk_modulus_pa": 1e5, "mu0_pa_s": m["mu0"],
            "alpha": m["alpha"], "T_s": m["T"], "n": m["n"], "mu_max_pa_s": m["mu_max"], "lambda0": 1.5}


@functools.lru_cache(maxsize=None)
def film_speeds(name, H, r, times):
    """The film's mean speeds at ``times`` (one solve per material, depth and r)."""
    p, theta = params_and_slope(name, H, r)
    y, u, _, _ = film.film_profiles(p, H, theta, np.asarray(times), g_m_s2=G)
    return np.asarray(film.mean_speed(y, u))


def params_and_slope(name, H, r):
    mat = material_of(name)
    p = rheometer.make_params(rho=mat["density_kg_m3"], mu0=mat["mu0_pa_s"], alpha=mat["alpha"], T=mat["T_s"],
                              n=mat["n"], mu_max=mat["mu_max_pa_s"], lambda0=mat["lambda0"])
    tau_c = float(rheometer.critical_point(p)[1])
    return p, math.degrees(math.asin(r * tau_c / (mat["density_kg_m3"] * G * H)))


def run(name, H, r, layers, h, length, times):
    times = np.asarray(times)
    mat = material_of(name)
    _, theta = params_and_slope(name, H, r)
    raw = {
        "model": {"formulation": "depth-averaged"},
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [length, 4 * H], "cell_size_m": h},
        "boundary": {"x_lo": "slip", "x_hi": "open"},
        "numerics": {"shape": "quadratic", "ppc": 4, "dtype": "float64", "depth_layers": layers, "split_levels": 0},
        "gravity": {"g_m_s2": G, "slope_deg": theta},
        "material": mat,
        "time": {"t_end_s": float(times[-1]), "n_frames": int(times[-1])},  # a frame every second
        "bodies": [{"type": "box", "lo_m": [0.0, 0.0], "hi_m": [length, H]}],
    }
    s = build(validate(raw))
    run_ = jax.jit(simulate, static_argnums=(0, 3))
    run_.lower(s.scene, s.state, s.params).compile()
    t0 = time.process_time()
    _, frames = jax.block_until_ready(run_(s.scene, s.state, s.params))
    cpu = time.process_time() - t0
    x0 = np.asarray(s.state.x[:, 0])
    mid = (x0 > length / 3) & (x0 < 2 * length / 3)
    ft = np.asarray(frames.t)
    k = [int(np.argmin(np.abs(ft - t))) for t in times]
    assert np.allclose(ft[k], times), ft
    U = [float(np.mean(np.abs(np.asarray(frames.v[i, :, 0]))[mid])) for i in k]
    Uf = film_speeds(name, H, r, tuple(times))
    return {"material": name, "H_m": H, "r": r, "layers": layers, "h_m": h, "t_s": times.tolist(),
            "U_da_m_s": [round(v, 6) for v in U], "U_film_m_s": [round(float(v), 6) for v in Uf],
            "ratio": [round(a / float(b), 4) for a, b in zip(U, Uf)], "loop_cpu_s": round(cpu, 2),
            "date": time.strftime("%Y-%m-%d")}


if __name__ == "__main__":
    counts = [int(a) for a in sys.argv[1:]] or [1, 8, 16, 32, 64]
    for name, H, h, length, times in CASES:
        for r in (1.5, 2.0, 4.0):
            for k in counts:
                print(json.dumps(run(name, H, r, k, h, length, times)), flush=True)
