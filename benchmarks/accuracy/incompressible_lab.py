"""The lab dam break (dambreak-lab, 15 s) with --set style overrides: runout (free-surface front),
dt, steps, compile and loop wall/CPU time and the deposit packing, as one JSON line (docs/validation.md, "Incompressible limit").

    .venv/bin/python benchmarks/accuracy/incompressible_lab.py      # the scene as shipped: the grid pressure since 2026-12-06
    .venv/bin/python benchmarks/accuracy/incompressible_lab.py numerics.pressure=explicit material.bulk_modulus_pa=150000
"""
import json
import sys
import time

import numpy as np, jax
import mpmjax as m
args = sys.argv[1:]
cfg = m.load_scene("dambreak-lab", args)
setup = m.build(cfg)
sc, params, st, info = setup.scene, setup.params, setup.state, setup.info
adv = m.make_advance(sc)
t0=time.time(); c0=time.process_time()
st = adv(st, params); jax.block_until_ready(st.x)
tc=time.time()-t0
t1=time.time(); c1=time.process_time()
for f in range(sc.n_frames-1):
    st = adv(st, params)
jax.block_until_ready(st.x)
wall=time.time()-t1; cpu=time.process_time()-c1
x = np.asarray(st.x)[np.asarray(st.active)]
r = float(m.free_surface_front(st.x, st.vol0, st.active, bandwidth=sc.h, x_lo=sc.lo[0], x_hi=sc.hi[0])) - info["runout_origin_m"]
from mpmjax.studies.converge import deposit_packing  # Sigma J V0 per bin area in the deposit's interior (1: no voids)

act = np.asarray(st.active)
pack = deposit_packing(np.asarray(st.x)[act], np.asarray(st.J)[act], np.asarray(st.vol0)[act], sc.h)
print(json.dumps(dict(args=args, dt=sc.dt, steps=sc.n_steps, compile=tc, loop_wall=wall, loop_cpu=cpu, far=float(x[:,0].max()), J=[float(np.asarray(st.J).min()), float(np.asarray(st.J).max())], lost=int(st.n_lost), runout=str(r), packing=pack)))
