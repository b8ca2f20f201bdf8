"""The final shape and stresses of an inertia-free slump against the Bingham static profile
H^2 = 2 tau_y (x_f - x)/(rho g) (docs/incompressible.md, "Voids through the solve").

    MPMJAX_SLUMP_DUMP=s16.npz .venv/bin/python benchmarks/accuracy/incompressible_slump.py 0.05 1 16 60 \
        numerics.pressure=incompressible numerics.void_closure=velocity
    .venv/bin/python benchmarks/accuracy/deposit_shape.py s16.npz

Prints, per file: the farthest particle, the apparent yield stress of the profile (H^2 fitted as
a (x_f - x) between 10 and 85 % of the front: rho g a / 2 over tau_y; 1 for the static shape), the
same fit of the exact static shape filled with particles at the run's spacing (the measure's own bias,
which the first figure carries too), and the mean deviatoric stresses over tau_y by height above the bed
and third of the deposit.

A column's surface is its top particle plus half the particle spacing (sqrt of a particle's area).
Before 2026-12-07 (stop 60) it was the top particle plus half a cell, which read the exact static shape
at 1.12 tau_y with 16 cells over H0 and 1.06 with 32 (ppc 3): the figures docs/incompressible.md
quoted from it then (1.30, 1.65, 1.28 tau_y) carry that bias.
"""
import sys

import numpy as np

from mpmjax.studies.converge import static_slump_lattice  # the static profile filled at the run's spacing


def fitted(x, h, s):
    """a of H^2 = a (x_f - x) over the columns of width h between 10 and 85 % of the farthest particle x_f;
    a column's surface: its top particle + s / 2."""
    col = np.floor(x[:, 0] / h).astype(int)
    top = np.array([x[col == c, 1].max() + 0.5 * s if np.any(col == c) else np.nan for c in range(col.max() + 1)])
    xc = (np.arange(top.size) + 0.5) * h
    xf = x[:, 0].max()
    sel = (xc > 0.1 * xf) & (xc < 0.85 * xf) & np.isfinite(top)
    H, X = top[sel], xc[sel]
    return np.sum(H**2 * (xf - X)) / np.sum((xf - X) ** 2)


for f in sys.argv[1:]:
    d = np.load(f)
    x, h = d["x"], float(d["h"])
    tau, rho, g = float(d["tau"]), float(d["rho"]), float(d["g"])
    s = float(np.sqrt(np.median(d["vol"])))  # particle spacing (2D: a particle's area is s^2)
    k = 2.0 * tau / (rho * g)
    xf = x[:, 0].max()
    a = fitted(x, h, s)
    a_exact = fitted(static_slump_lattice(xf, k, s), h, s)
    print(f"{f}: farthest particle {xf:.4f} m (x_inf {float(d['xinf']):.4f} m), apparent yield stress "
          f"{rho * g * a / 2 / tau:.2f} tau_y (the exact static shape to the same front, read the same way: "
          f"{a_exact / k:.3f} tau_y)")
    # incompressible_slump.py's area_ratio (each column of width h: its top particle + half a spacing, over the
    # particles' area) of the exact static shape of x_inf, filled at this spacing: the measure's own bias
    exact = static_slump_lattice(float(d["xinf"]), k, s)
    col = np.floor(exact[:, 0] / h).astype(int)
    top = np.zeros(col.max() + 1)
    np.maximum.at(top, col, exact[:, 1] + 0.5 * s)
    print(f"  area_ratio of the exact static shape of x_inf at this spacing: {np.sum(top) * h / (len(exact) * s * s):.4f}")
    if "dev" not in d:
        continue
    T = d["dev"]
    txz, txx, tzz = T[:, 0, 1], T[:, 0, 0], T[:, 1, 1]
    vm = np.sqrt(0.5 * (txx**2 + tzz**2 + 2 * txz**2))
    for lo, hi in ((0.0, 0.5), (0.5, 1.0), (1.0, 2.0), (2.0, 4.0)):
        for xa, xb in ((0.1, 0.4), (0.4, 0.7), (0.7, 0.9)):
            s = (x[:, 1] >= lo * h) & (x[:, 1] < hi * h) & (x[:, 0] > xa * xf) & (x[:, 0] < xb * xf)
            if s.any():
                print(f"  z in [{lo}, {hi}) h, x in [{xa}, {xb}] x_f: {s.sum():4d} particles, |txz| "
                      f"{abs(np.mean(txz[s])) / tau:.2f}, txx {np.mean(txx[s]) / tau:+.2f}, |tau| {np.mean(vm[s]) / tau:.2f} tau_y")
