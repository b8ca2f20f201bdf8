"""The final shape and stresses of an inertia-free slump against the Bingham static profile
H^2 = 2 tau_y (x_f - x)/(rho g) (docs/incompressible.md, "Voids through the solve").

    MPMJAX_SLUMP_DUMP=s16.npz .venv/bin/python benchmarks/accuracy/incompressible_slump.py 0.05 1 16 60 \
        numerics.pressure=incompressible numerics.void_closure=velocity
    .venv/bin/python benchmarks/accuracy/deposit_shape.py s16.npz

Prints, per file: the farthest particle, the apparent yield stress of the profile (H^2 fitted as
a (x_f - x) between 10 and 85 % of the front: rho g a / 2 over tau_y; 1 for the static shape), and the
mean deviatoric stresses over tau_y by height above the bed and third of the deposit.
"""
import sys

import numpy as np

for f in sys.argv[1:]:
    d = np.load(f)
    x, h = d["x"], float(d["h"])
    tau, rho, g = float(d["tau"]), float(d["rho"]), float(d["g"])
    col = np.floor(x[:, 0] / h).astype(int)
    top = np.array([x[col == c, 1].max() + 0.5 * h if np.any(col == c) else np.nan for c in range(col.max() + 1)])
    xc = (np.arange(top.size) + 0.5) * h
    xf = x[:, 0].max()
    sel = (xc > 0.1 * xf) & (xc < 0.85 * xf) & np.isfinite(top)
    H, X = top[sel], xc[sel]
    a = np.sum(H**2 * (xf - X)) / np.sum((xf - X) ** 2)
    print(f"{f}: farthest particle {xf:.4f} m (x_inf {float(d['xinf']):.4f} m), apparent yield stress "
          f"{rho * g * a / 2 / tau:.2f} tau_y")
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
