"""The grid pressure's bed-row voids against the packing at which a cell joins the solve (issue 31's "no voids";
docs/voids.md, "Why: the bed row forms part-filled, and nothing refills it").

A cell is an unknown of the pressure solve once its packing reaches ``_pressure.FLUID_FRACTION`` (0.5); from then on
the solve keeps its volume, and with ``numerics.void_closure = "off"`` nothing refills it.  This runs ``dambreak-lab``
(with --set style overrides) at the thresholds given and prints one JSON line each: the runout (free-surface front),
and per cell row above the bed, averaged over the columns whose surface lies at least two cells above the row, the
packing twice: the particles' volume in the cell over h^2 (``row_packing.py``'s measure) and the grid's, the GIMP
nodal mass summed over the cell's corners over a full lattice's (the solve's phi; GIMP and 2D only).

    .venv/bin/python benchmarks/accuracy/fluid_threshold.py 0.5 0.7 0.9
    .venv/bin/python benchmarks/accuracy/fluid_threshold.py 0.9 -- domain.cell_size_m=0.005
"""
import json
import sys
import time

import jax
import numpy as np

import mpmjax as m
import mpmjax._pressure as pressure


def gimp(xp, xi, h, lp):
    """GIMP weight of nodes at xi for particles at xp (half-width lp)."""
    d = np.abs(xp - xi)
    w = np.zeros_like(d)
    a = d < lp
    w[a] = 1 - (d[a] ** 2 + lp**2) / (2 * h * lp)
    b = (d >= lp) & (d < h - lp)
    w[b] = 1 - d[b] / h
    c = (d >= h - lp) & (d < h + lp)
    w[c] = (h + lp - d[c]) ** 2 / (4 * h * lp)
    return w


def cell_mass(x, vol, h, shape, lp):
    """Each cell's corner sum of the GIMP nodal volume (2D, origin at 0)."""
    nx, ny = shape
    M = np.zeros((nx + 1, ny + 1))
    i0, j0 = np.floor(x[:, 0] / h).astype(int), np.floor(x[:, 1] / h).astype(int)
    for di in (-1, 0, 1, 2):
        ii = i0 + di
        wx = gimp(x[:, 0], ii * h, h, lp)
        for dj in (-1, 0, 1, 2):
            jj = j0 + dj
            wy = gimp(x[:, 1], jj * h, h, lp)
            ok = (ii >= 0) & (ii <= nx) & (jj >= 0) & (jj <= ny)
            np.add.at(M, (ii[ok], jj[ok]), (vol * wx * wy)[ok])
    return M[:-1, :-1] + M[1:, :-1] + M[:-1, 1:] + M[1:, 1:]


def row_packing(x, vol, h, shape, ppc, n_rows=3):
    s = h / ppc
    g = [(np.arange(n * ppc) + 0.5) * s for n in shape]
    full = np.stack([a.ravel() for a in np.meshgrid(*g, indexing="ij")], 1)
    grid = cell_mass(x, vol, h, shape, s / 2) / cell_mass(full, np.full(len(full), s * s), h, shape, s / 2)
    ix, iy = np.floor(x[:, 0] / h).astype(int), np.floor(x[:, 1] / h).astype(int)
    parts = np.zeros(shape)
    np.add.at(parts, (ix, iy), vol)
    parts /= h * h
    top = np.zeros(shape[0])
    np.maximum.at(top, ix, x[:, 1] + 0.5 * s)
    out = []
    for j in range(n_rows):
        cols = np.nonzero(top > (j + 2) * h)[0]
        if cols.size:
            out.append(dict(row=j, particles=round(float(parts[cols, j].mean()), 3), grid=round(float(grid[cols, j].mean()), 3), columns=int(cols.size)))
    return out


argv = sys.argv[1:]
split = argv.index("--") if "--" in argv else len(argv)
thresholds, overrides = [float(a) for a in argv[:split]], argv[split + 1 :]
for ff in thresholds:
    pressure.FLUID_FRACTION = ff  # read when the step is traced
    cfg = m.load_scene("dambreak-lab", overrides)
    setup = m.build(cfg)
    sc, params, st, info = setup.scene, setup.params, setup.state, setup.info
    assert sc.dim == 2 and cfg["numerics.shape"] == "gimp" and not np.any(sc.lo), "2D GIMP, origin at 0"
    adv = m.make_advance(sc)
    c0 = time.process_time()
    for _ in range(sc.n_frames):
        st = adv(st, params)
    jax.block_until_ready(st.x)
    act = np.asarray(st.active)
    r = float(m.free_surface_front(st.x, st.vol0, st.active, bandwidth=sc.h, x_lo=sc.lo[0], x_hi=sc.hi[0]))
    x, vol = np.asarray(st.x, float)[act], (np.asarray(st.vol0) * np.asarray(st.J))[act].astype(float)
    shape = tuple(int(round((b - a) / sc.h)) for a, b in zip(sc.lo, sc.hi))  # cells of the domain
    rows = row_packing(x, vol, sc.h, shape, cfg["numerics.ppc"])
    print(json.dumps(dict(fluid_fraction=ff, overrides=overrides, t_s=float(st.t), runout_m=round(r - info["runout_origin_m"], 4), rows=rows, cpu_s=round(time.process_time() - c0, 1))), flush=True)
