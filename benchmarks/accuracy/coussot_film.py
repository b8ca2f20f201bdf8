"""The depth-averaged Coussot closure against the steady uniform layer (docs/depth-averaged.md, "Closures").

A layer of depth H flowing steadily down a plane at angle theta carries the shear stress
tau(y) = rho g sin(theta) (H - y) at height y over the bed.  With the structure at its steady value at every
height (lambda = 1 / (alpha T gdot), ``Coussot.steady_internal``) the law's steady flow curve tau(gdot) =
mu(lambda_ss(gdot)) gdot (``Coussot.mu``, with its cap mu_max) gives the shear rate at each height, and the
exact depth-averaged speed U = (1/H) int_0^H u dy follows by integration (4001 heights).  Where tau(gdot) is not
monotone (n > 1: it falls from the cap's peak to its minimum tau_c at gdot_c and rises after), a height whose
stress exceeds tau_c flows on the rising branch past gdot_c and the rest creeps on the capped branch tau / mu_max
(the flowing state; thixotropic shear banding).

The depth-averaged step's closure (``mpmjax._basal``) takes the basal shear rate 3U/H with the column's structure
advanced by it, so in the same steady state its basal stress is tau(3U/H) on the flowing branch, and its speed
U_da = gdot_w H / 3, gdot_w the rate at the bed's stress rho g H sin(theta).  One JSON line per case:
U exact, U_da and their ratio, tau_w / tau_c.

    .venv/bin/python benchmarks/accuracy/coussot_film.py
"""

import json
import time

import jax
import jax.numpy as jnp
import numpy as np

from mpmjax._rheology import MODELS

jax.config.update("jax_enable_x64", True)
LAW = MODELS["coussot"]()
G = 9.81
# the two built-in Coussot materials: field-breach-da / field-breach-3d, and dambreak-lab
MATERIALS = {
    "field-breach-da": {"rho": 1850.0, "mu0": 50.0, "alpha": 0.36, "T": 1.0, "n": 1.25, "mu_max": 25000.0},
    "dambreak-lab": {"rho": 1850.0, "mu0": 4.0, "alpha": 1.0, "T": 0.5, "n": 2.5, "mu_max": 5000.0},
}


def flow_curve(m):
    """(gdot, tau) on a log grid, the steady flow curve of the law at material ``m``."""
    p = LAW.params_type(**{nm: jnp.asarray(m.get(nm, 0.0)) for nm in LAW.params_type._fields})
    gd = np.logspace(-10, 5, 30001)
    lam = LAW.steady_internal(p, jnp.asarray(gd))
    tau = np.asarray(LAW.mu(p, jnp.asarray(gd), lam)) * gd
    return gd, tau


def extrema(tau):
    """(k_peak, k_min): the capped branch's peak and the flow curve's minimum tau_c after it; (0, 0) where
    the curve rises throughout."""
    falls = np.nonzero(np.diff(tau) < 0)[0]
    if falls.size == 0:
        return 0, 0
    k_peak = int(falls[0])
    return k_peak, k_peak + int(np.argmin(tau[k_peak:]))


def rate(gd, tau, t):
    """Shear rate [1/s] at stress t [Pa] in the flowing state (module docstring)."""
    k_peak, k_min = extrema(tau)
    if t >= tau[k_min]:
        return float(np.interp(t, tau[k_min:], gd[k_min:]))
    return float(np.interp(t, tau[: k_peak + 1], gd[: k_peak + 1]))


def case(material, H, theta_deg):
    m = MATERIALS[material]
    gd, tau = flow_curve(m)
    tw = m["rho"] * G * H * np.sin(np.radians(theta_deg))
    y = np.linspace(0.0, H, 4001)
    g = np.array([rate(gd, tau, tw * (1 - yy / H)) for yy in y])
    u = np.concatenate([[0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * np.diff(y))])
    U = float(np.sum(0.5 * (u[1:] + u[:-1]) * np.diff(y)) / H)
    U_da = rate(gd, tau, tw) * H / 3.0
    k_min = extrema(tau)[1]
    return {"material": material, "H_m": H, "theta_deg": theta_deg, "tau_w_pa": tw, "tau_c_pa": float(tau[k_min]),
            "tau_w_over_tau_c": tw / float(tau[k_min]), "U_exact_m_s": U, "U_da_m_s": U_da, "ratio": U_da / U,
            "date": time.strftime("%Y-%m-%d")}


if __name__ == "__main__":
    for H, th in ((5.0, 1.0), (2.0, 3.0), (1.0, 3.0), (0.5, 3.0), (0.3, 3.0), (0.2, 5.0), (0.15, 5.0)):
        print(json.dumps(case("field-breach-da", H, th)))
    for H, th in ((0.1, 5.0), (0.05, 10.0), (0.02, 10.0), (0.01, 10.0), (0.005, 15.0)):
        print(json.dumps(case("dambreak-lab", H, th)))
