"""A block on a flat Coulomb terrain under gravity tilted 20 degrees (the block of tests/test_pressure.py and
tests/test_boundary_slopes.py): its mean velocity along the slope per frame against the Coulomb law
g (sin 20 - friction cos 20) t, and the particles lost.  One JSON line per run to coulomb_slide.jsonl.

    python benchmarks/accuracy/coulomb_slide.py PRESSURE FRICTION G_PA [KAPPA_PA] [H_M] [CFL]

PRESSURE explicit or incompressible; G_PA numerics.maxwell_shear_modulus_pa (0: the default, G = kappa with the
explicit pressure, rho v^2 for this law with the grid pressure); 0.4 s, 8 frames, float64, ppc 2, mu = 1e4 Pa s.
docs/incompressible-default.md, "The fourth trial" (stop 66).
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import mpmjax as m  # noqa: E402

OUT = Path(__file__).with_name("coulomb_slide.jsonl")


def main(argv):
    pressure, friction, G = argv[0], float(argv[1]), float(argv[2])
    kappa = float(argv[3]) if len(argv) > 3 else 1e5
    h = float(argv[4]) if len(argv) > 4 else 0.02
    cfl = float(argv[5]) if len(argv) > 5 else 0.4
    raw = {
        "domain": {"lo_m": [0.0, 0.0], "hi_m": [1.6, 0.4], "cell_size_m": h},
        "numerics": {"ppc": 2, "dtype": "float64", "pressure": pressure, "maxwell_shear_modulus_pa": G, "cfl": cfl},
        "time": {"t_end_s": 0.4, "n_frames": 8},
        "material": {"model": "newtonian", "density_kg_m3": 1000.0, "bulk_modulus_pa": kappa, "viscosity_pa_s": 1e4},
        "gravity": {"slope_deg": 20.0},
        "terrain": {"type": "coulomb", "heights_m": [0.1, 0.1, 0.1], "spacing_m": 0.8, "friction": friction},
        "bodies": [{"type": "box", "lo_m": [0.2, 0.1], "hi_m": [0.4, 0.2]}],
    }
    s = m.build(m.validate(raw))
    t0 = time.process_time()
    final, fr = m.run(s.scene, s.state, s.params)
    cpu = time.process_time() - t0
    th = math.radians(20.0)
    a = 9.81 * (math.sin(th) - friction * math.cos(th))
    t = np.asarray(fr.t)
    v = np.asarray(fr.v)[:, :, 0].mean(axis=1)
    rec = {"pressure": pressure, "friction": friction, "maxwell_G_pa": G, "kappa_pa": kappa, "h_m": h, "cfl": cfl,
           "dt_s": s.scene.dt, "t_s": t.round(4).tolist(), "v_m_s": v.round(5).tolist(),
           "coulomb_law_m_s": (a * t).round(5).tolist() if a > 0 else None, "lost": int(final.n_lost),
           "cpu_s": round(cpu, 1), "date": time.strftime("%Y-%m-%d")}
    print(json.dumps(rec))
    with OUT.open("a") as f:
        f.write(json.dumps(rec) + "\n")


if __name__ == "__main__":
    main(sys.argv[1:])
