"""Inertia-free Bingham slump (Galileo number 1) against the lubrication static front
x_inf (REFERENCE.md: Balmforth et al. 2006, Matson & Hogg 2007): a block H0 = 0.1 m high and
L = aspect H0 long against a symmetry wall, no-slip bed, tau_y from the Bingham number
B = tau_y L/(rho g H0^2); prints the front per frame and its error as one JSON line
(docs/validation.md, "Incompressible limit"), and against the lubrication solution at the frames' times
(``lubrication_fronts``, ``err_vs_lubrication_pct``: the reference while the slump still moves).

    .venv/bin/python benchmarks/accuracy/incompressible_slump.py B ASPECT CELLS_OVER_H0 T_END [key=value ...]
    .venv/bin/python benchmarks/accuracy/incompressible_slump.py 0.05 1 16 20 numerics.pressure=incompressible

With MPMJAX_SLUMP_DUMP=FILE.npz the final particles (positions, volumes, deviatoric stress) are saved
for benchmarks/accuracy/deposit_shape.py.
"""
import json
import math
import os
import sys
import time

import numpy as np, jax
import mpmjax as m
from mpmjax._metrics import RunoutGauge
# usage: slump.py B aspect(L/H0) cells_over_H0 t_end [key=val ...]
B, asp, cells, t_end = float(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
over = sys.argv[5:]
rho, g, H0 = 1000.0, 9.81, 0.1
L = asp * H0
tau = B * rho * g * H0**2 / L
mu = math.sqrt(rho**2 * g * H0**3)  # Galileo number 1
xinf = (L + rho*g*H0**2/(6*tau)) if B >= 1/3 else (9*rho*g*H0**2*L**2/(8*tau))**(1/3)
h = H0 / cells
dom_x = math.ceil(1.4 * xinf / h) * h
raw = {"domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [dom_x, math.ceil(1.5*H0/h)*h], "cell_size_m": h},
 "boundary": {"x_lo": "symmetry", "x_hi": "slip", "y_lo": "noslip", "y_hi": "slip"},
 "time": {"t_end_s": t_end, "n_frames": 20},
 "material": {"model": "bingham", "density_kg_m3": rho, "bulk_modulus_pa": 50*rho*g*H0, "viscosity_pa_s": mu,
              "yield_stress_pa": tau, "papanastasiou_m_s": 1e4},
 "gravity": {"g_m_s2": g}, "bodies": [{"lo_m": [0.0, 0.0], "hi_m": [L, H0]}]}
for o in over:
    k, v = o.split("=", 1); sec, name = k.split(".", 1)
    try: v = json.loads(v)
    except Exception: pass
    raw.setdefault(sec, {})[name] = v
cfg = m.validate(raw)
s = m.build(cfg)
sc = s.scene
adv = m.make_advance(sc)
st = s.state
t0 = time.time(); c0 = time.process_time()
fronts = []
gauge = RunoutGauge.of(sc, s.info)
for f in range(sc.n_frames):
    st = adv(st, s.params)
    x = np.asarray(st.x); a = np.asarray(st.active, bool)
    fronts.append(gauge.front(x, np.asarray(st.vol0), a))
wall = time.time() - t0; cpu = time.process_time() - c0
v = np.asarray(st.v)[a]
from mpmjax.studies.converge import deposit_packing, occupied_area  # packing: Sigma J V0 per bin area in the interior

xa, Ja, V0a = x[a], np.asarray(st.J)[a], np.asarray(st.vol0)[a]
packing = deposit_packing(xa, Ja, V0a, h)
# the area under the free surface (each column of width h: its top particle + half a spacing) over Sigma J V0; the
# measure's own bias is not removed here (1.0 % high at 16 cells over H0: deposit_shape.py)
area_ratio = occupied_area(xa, h, h / cfg["numerics.ppc"]) / float(np.sum(Ja * V0a))
# the lubrication solution at the frames' times (mpmjax.studies.lubrication, measured as the headline front): the
# reference for a slump that has not come to rest, which x_inf is not
from mpmjax.studies.lubrication import headline_front, slump_profiles

lx, lh, _ = slump_profiles(L, H0, tau, mu, [(k + 1) * t_end / sc.n_frames for k in range(sc.n_frames)], density_kg_m3=rho, g_m_s2=g)
lub = [headline_front(lx, hk) for hk in lh]
print(json.dumps(dict(B=B, asp=asp, cells=cells, over=over, xinf=xinf, front=fronts[-1], err_pct=100*(fronts[-1]-xinf)/xinf,
      lubrication_fronts=[round(f_, 4) for f_ in lub], err_vs_lubrication_pct=100*(fronts[-1]-lub[-1])/lub[-1],
      fronts=[round(f_,4) for f_ in fronts], packing=packing, area_ratio=area_ratio, vmax=float(np.abs(v).max()), dt=sc.dt, steps=sc.n_steps, wall=wall, cpu=cpu,
      J=[float(np.asarray(st.J)[a].min()), float(np.asarray(st.J)[a].max())], lost=int(st.n_lost))))
if os.environ.get("MPMJAX_SLUMP_DUMP"):
    np.savez(os.environ["MPMJAX_SLUMP_DUMP"], x=xa, vol=V0a, dev=np.asarray(st.tau)[a], h=h, tau=tau, rho=rho, g=g, xinf=xinf)
