"""The slump test (``output.slump_test = true``; docs/slump-test.md): slump height, spread
diameter and the yield stress back-calculated with the relation of Pashias et al. (1996),

    s' = 1 - 2 tau' (1 - ln(2 tau')),   s' = s / H,   tau' = tau_y / (rho g H),

for a cylinder of height H lifted off the material (s: the slump, H minus the height of the
slumped material at its centre).  s' falls monotonically from 1 to 0 as tau' rises from 0 to 1/2
(ds'/dtau' = 2 ln(2 tau') < 0), so tau' is found by bisection (``pashias_tau``).

Measurements on the final frame (rest volumes V0 = mass / rho, as the plan-view thickness;
``mirror`` = 2 for each symmetry face the cylinder's axis lies on: a quarter model has 4):

``height``
    The centre height: the top of the material over the square of half-width 2 h (two cells)
    around the axis, clipped to the domain: that square cut into bins of one cell h, in each bin
    the highest active particle plus half a particle spacing, averaged over the bins holding
    material.  On the initial lattice it is H exactly.  (The top surface rather than the rest
    volume per area: the few particle columns near the axis carry J of 0.85-1.3 in a slumped
    deposit, which made the rest-volume height scatter by up to 8 mm at h = 6.25 mm.)
``spread diameter``
    2 r_f, r_f the radius where the radial thickness profile (rest volume per annulus of width h,
    divided by the annulus area / ``mirror``) last falls to ``SPREAD_FRACTION`` of the centre
    height, linear between annulus centres (the 10 % convention of the runout and lobe width).
    On the initial cylinder it reads R + 0.4 h (a vertical edge: the profile drops from H to 0
    between the annuli either side of R), so the initial reading is reported beside it.
"""

from __future__ import annotations

import json
import math

import numpy as np

from ._io import frame_volumes

SPREAD_FRACTION = 0.1
RELATION = "s' = 1 - 2 tau' (1 - ln(2 tau')), s' = slump / H, tau' = tau_y / (rho g H) (Pashias et al. 1996)"


def pashias_slump(tau_prime: float) -> float:
    """Dimensionless slump s' of the Pashias relation for 0 <= tau' <= 1/2 (s'(0) = 1, s'(1/2) = 0)."""
    t = float(tau_prime)
    if not 0.0 <= t <= 0.5:
        raise ValueError(f"tau' = {t} is outside [0, 0.5], where the Pashias relation holds")
    return 1.0 if t == 0.0 else 1.0 - 2.0 * t * (1.0 - math.log(2.0 * t))


def pashias_tau(s_prime: float, tol: float = 1e-13) -> float:
    """tau' from s' (bisection on [0, 1/2], where s'(tau') falls monotonically from 1 to 0).
    s' >= 1 gives 0 (no yield stress), s' <= 0 gives 1/2 (no slump: tau' >= 1/2); nan in, nan out."""
    s = float(s_prime)
    if math.isnan(s):
        return math.nan
    if s >= 1.0:
        return 0.0
    if s <= 0.0:
        return 0.5
    a, b = 0.0, 0.5  # s'(a) - s > 0 > s'(b) - s
    while b - a > tol:
        m = 0.5 * (a + b)
        if pashias_slump(m) > s:
            a = m
        else:
            b = m
    return 0.5 * (a + b)


def coussot_critical_stress(mu0: float, alpha: float, T: float, n: float) -> float | None:
    """The minimum of the Coussot steady flow curve tau_ss(gdot) = mu0 gdot (1 + (alpha T gdot)^-n)
    [Pa] (standard shear measure): below it no steady flow exists, so it is the stress a slumping
    Coussot material stops at once it is sheared.  At gdot_c = (n - 1)^(1/n) / (alpha T):
    tau_c = mu0 gdot_c n / (n - 1).  None for n <= 1 (the flow curve rises monotonically)."""
    if n <= 1.0:
        return None
    gc = (n - 1.0) ** (1.0 / n) / (alpha * T)
    return mu0 * gc * n / (n - 1.0)


def _mirror(cfg: dict, base) -> int:
    h = float(cfg["domain.cell_size_m"])
    m = 1
    for a in (0, 1):
        for side, wall in (("lo", cfg["domain.lo_m"][a]), ("hi", cfg["domain.hi_m"][a])):
            if cfg[f"boundary.{'xyz'[a]}_{side}"] == "symmetry" and abs(base[a] - wall) <= 1e-6 * h:
                m *= 2
    return m


def measure(x, vol0, active, cfg: dict) -> dict:
    """Centre height and spread radius [m] of one frame (module docstring)."""
    body = cfg["bodies"][0]
    base = np.asarray(body["base_m"], float)
    h = float(cfg["domain.cell_size_m"])
    lo, hi = np.asarray(cfg["domain.lo_m"], float), np.asarray(cfg["domain.hi_m"], float)
    x = np.asarray(x, float)
    act = np.asarray(active, bool)
    v = np.where(act, np.asarray(vol0, float), 0.0)
    d = x[:, :2] - base[:2]
    spacing = h / float(cfg["numerics.ppc"])
    wlo, whi = np.maximum(base[:2] - 2 * h, lo[:2]), np.minimum(base[:2] + 2 * h, hi[:2])
    inside = act & np.all((x[:, :2] >= wlo) & (x[:, :2] <= whi), axis=1)
    tops = {}
    for key, z in zip(map(tuple, np.floor((x[inside, :2] - wlo) / h).astype(int)), x[inside, 2]):
        tops[key] = max(tops.get(key, -np.inf), z)
    height = float(np.mean(list(tops.values())) + 0.5 * spacing - base[2]) if tops else 0.0
    mirror = _mirror(cfg, base)
    r = np.sqrt(np.einsum("ij,ij->i", d, d))
    r_max = float(r[act].max()) if act.any() else 0.0
    edges = h * np.arange(int(math.ceil(r_max / h)) + 2)
    vol_bin = np.histogram(r[act], bins=edges, weights=v[act])[0]
    thick = vol_bin / (math.pi * (edges[1:] ** 2 - edges[:-1] ** 2) / mirror)
    centres = 0.5 * (edges[1:] + edges[:-1])
    thr = SPREAD_FRACTION * height
    above = np.nonzero(thick >= thr)[0]
    if height <= 0 or not above.size:
        return {"height_m": height, "spread_radius_m": 0.0, "mirror": mirror}
    k = int(above[-1])
    if k + 1 < thick.size:
        t0, t1 = thick[k], thick[k + 1]
        frac = (t0 - thr) / (t0 - t1) if t0 > t1 else 0.0
        rf = centres[k] + frac * (centres[k + 1] - centres[k])
    else:
        rf = centres[k]
    return {"height_m": height, "spread_radius_m": float(rf), "mirror": mirror}


def input_yield_stress(cfg: dict) -> tuple[float | None, str]:
    """The material's yield stress [Pa] to set the back-calculated one beside, and what it is."""
    model = cfg["material.model"]
    if model in ("bingham", "herschel_bulkley"):
        return float(cfg["material.yield_stress_pa"]), "material.yield_stress_pa"
    if model == "coussot" and cfg.get("material.shear_measure", "standard") == "standard":
        tc = coussot_critical_stress(
            float(cfg["material.mu0_pa_s"]), float(cfg["material.alpha"]), float(cfg["material.T_s"]),
            float(cfg["material.n"]),
        )  # fmt: skip
        return tc, "Coussot critical stress: the minimum of the steady flow curve (no yield-stress key)"
    return None, f"material.model = {model!r} has no yield stress"


def back_calculate(height_m: float, cfg: dict) -> tuple[float, float, float | None]:
    """(s', tau', the yield stress back-calculated [Pa], None when s' <= 0 or s' >= 1) of the slumped centre
    height ``height_m`` [m] of ``cfg``'s cylinder, by the Pashias relation."""
    H = float(cfg["bodies"][0]["height_m"])
    s_prime = (H - height_m) / H
    tau_prime = pashias_tau(s_prime)
    rho_g_h = float(cfg["material.density_kg_m3"]) * float(cfg["gravity.g_m_s2"]) * H
    return s_prime, tau_prime, (tau_prime * rho_g_h if 0.0 < tau_prime < 0.5 else None)


def summary(result) -> dict:
    """summary.json's ``slump_test`` of a run (``result``: ``mpmjax._io.read_result``'s dict)."""
    cfg = json.loads(result["attrs"]["scene_config_json"])
    body = cfg["bodies"][0]
    H, R = float(body["height_m"]), float(body["radius_m"])
    fr = result["frames"]
    vol = frame_volumes(result)  # each frame's (a depth-averaged run's columns may split)
    first = measure(fr["x_m"][0], vol[0], fr["active"][0], cfg)
    heights = [measure(fr["x_m"][k], vol[k], fr["active"][k], cfg)["height_m"] for k in range(len(fr["t_s"]))]
    last = measure(fr["x_m"][-1], vol[-1], fr["active"][-1], cfg)
    slump = H - last["height_m"]
    s_prime, tau_prime, back = back_calculate(last["height_m"], cfg)
    given, given_is = input_yield_stress(cfg)
    rel = (back - given) / given if back is not None and given else None
    return {
        "initial_height_m": H,
        "initial_diameter_m": 2.0 * R,
        "final_height_m": last["height_m"],
        "slump_m": slump,
        "slump_ratio": s_prime,
        "height_m_per_frame": heights,
        "spread_diameter_m": 2.0 * last["spread_radius_m"],
        "spread_diameter_initial_reading_m": 2.0 * first["spread_radius_m"],
        "tau_prime": tau_prime,
        "yield_stress_back_calculated_pa": back,
        "yield_stress_input_pa": given,
        "yield_stress_input_is": given_is,
        "relative_difference": rel,
        "relation": RELATION,
        "mirror": last["mirror"],
        "definition": (
            "height: the mean over bins of one cell h within 2 h of the axis of the highest particle + half a "
            "spacing; slump = H - height; spread diameter: 2 x the radius where the radial thickness (annuli of "
            f"width h) last falls to {SPREAD_FRACTION:g} x the centre height; back-calculated yield stress = "
            "tau' rho g H, null when s' <= 0 (no slump: tau' >= 1/2) or s' >= 1"
        ),
    }
