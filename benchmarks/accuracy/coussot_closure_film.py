"""The depth-averaged Coussot closure against the film from rest (docs/depth-averaged.md, "Closures").

``coussot_film.py`` compares the closure's steady state with the steady "flowing" layer, in which every height
above the flow curve's minimum stress tau_c flows.  A layer released from rest does not reach that state (the flow
curve's capped branch lets a height stand jammed: docs/coussot-film.md); its own transient is
``mpmjax.studies.film``.  Here both start from rest at lambda0 on the same incline: the film across the depth, and
the depth-averaged model of the same uniform layer, which has no gradients along the slope, so its step reduces to

    dU/dt = g sin(theta) - tau_b / (rho H),   tau_b = ``_basal.closure`` at (U, H, lambda),
    dlambda/dt = law.rate at the closure's basal rate 3 U / H,

solved with diffrax (Kvaerno5).  One JSON line per case: the two mean speeds at 1, 2, 4, 6, 12 and 30 s and their
ratio.

    .venv/bin/python benchmarks/accuracy/coussot_closure_film.py
"""

import json
import math
import time

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from coussot_film import MATERIALS  # this directory's script: the two built-in Coussot materials
from mpmjax import _basal, rheometer
from mpmjax._rheology import MODELS
from mpmjax.studies import film

jax.config.update("jax_enable_x64", True)
LAW = MODELS["coussot"]()
G = 9.81
TIMES = np.array([1.0, 2.0, 4.0, 6.0, 12.0, 30.0])


def params_of(material):
    m = MATERIALS[material]
    return rheometer.make_params(
        rho=m["rho"], mu0=m["mu0"], alpha=m["alpha"], T=m["T"], n=m["n"], mu_max=m["mu_max"], lambda0=1.5
    )


def depth_averaged(p, H, theta):
    g_s = G * math.sin(math.radians(theta))

    def rhs(t, y, args):
        U, lam = y
        tau_0, c, _ = _basal.closure(LAW, p, U, H, {"lam": lam})
        dU = g_s - (tau_0 + c * U) / (p.rho * H)
        return dU, LAW.rate(p, _basal.shear_rate(U, H), {"lam": lam})["lam"]

    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(rhs), diffrax.Kvaerno5(), 0.0, float(TIMES[-1]), 1e-6, (jnp.asarray(0.0), p.lambda0),
        saveat=diffrax.SaveAt(ts=jnp.asarray(TIMES)),
        stepsize_controller=diffrax.PIDController(rtol=1e-8, atol=1e-10), max_steps=1_000_000,
    )
    return np.asarray(sol.ys[0])


def case(material, H, r):
    p = params_of(material)
    tau_c = float(rheometer.critical_point(p)[1])
    theta = math.degrees(math.asin(r * tau_c / (float(p.rho) * G * H)))
    y, u, _, _ = film.film_profiles(p, H, theta, TIMES)
    U_film = film.mean_speed(y, u)
    U_da = depth_averaged(p, H, theta)
    return {
        "material": material, "H_m": H, "r": r, "theta_deg": round(theta, 4), "tau_c_pa": round(tau_c, 3),
        "t_s": TIMES.tolist(), "U_film_m_s": [round(float(v), 6) for v in U_film],
        "U_da_m_s": [round(float(v), 6) for v in U_da],
        "ratio": [round(float(a / b), 4) for a, b in zip(U_da, U_film)], "date": time.strftime("%Y-%m-%d"),
    }


if __name__ == "__main__":
    for material, H in (("dambreak-lab", 0.05), ("field-breach-da", 5.0)):
        for r in (1.5, 2.0, 4.0):
            print(json.dumps(case(material, H, r)), flush=True)
