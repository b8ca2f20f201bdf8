"""Where a grid-pressure deposit's voids are: its packing row by row above the bed (issue 31's "no voids").

Each cell row's packing is the particles' volume (V0 J) in the cell over h^d, averaged over the columns whose
surface (top particle + half a particle spacing) lies at least two cells above the row, so that the free
surface's partly filled cells do not count.  1: no voids.

    .venv/bin/mpmjax run dambreak-lab --out runs/lab --quiet --no-animation
    .venv/bin/python benchmarks/accuracy/row_packing.py runs/lab/result.h5 0.01 [FRAME ...]
    .venv/bin/python benchmarks/accuracy/row_packing.py s16.npz           # incompressible_slump.py's MPMJAX_SLUMP_DUMP

2D results (x along the bed, y up); a result's frames by index (default: the last).  Prints one line per frame:
the rows' packing from the bed up, with the number of columns averaged, and the lowest particle's height over
the particle spacing s per 5-cell stretch of bed (0.5: a full lattice's bottom row, which sits at s/2).
"""
import sys

import h5py
import numpy as np


def rows(x, vol, h):
    """[(row, packing, columns)] from the bed up: x (n, 2) [m], vol (n,) [m^2], h [m]."""
    s = float(np.sqrt(np.median(vol)))
    ix = np.floor(x[:, 0] / h).astype(int)
    iy = np.floor(x[:, 1] / h).astype(int)
    packed = np.zeros((ix.max() + 1, iy.max() + 1))
    np.add.at(packed, (ix, iy), vol)
    packed /= h * h
    top = np.zeros(ix.max() + 1)
    np.maximum.at(top, ix, x[:, 1] + 0.5 * s)
    out = []
    for j in range(iy.max() + 1):
        cols = np.nonzero(top > (j + 2) * h)[0]
        if cols.size:
            out.append((j, float(packed[cols, j].mean()), int(cols.size)))
    return out


def lowest(x, vol, h):
    """The lowest particle's height over the particle spacing, per stretch of 5 h along the bed."""
    s = float(np.sqrt(np.median(vol)))
    ix = np.floor(x[:, 0] / (5.0 * h)).astype(int)
    low = np.full(ix.max() + 1, np.inf)
    np.minimum.at(low, ix, x[:, 1])
    return low / s


def show(label, x, vol, h):
    r = rows(x, vol, h)
    print(label + ": " + " ".join(f"row {j}: {p:.3f} ({n})" for j, p, n in r))
    print("  lowest particle / s per 5 h: " + " ".join(f"{v:.2f}" for v in lowest(x, vol, h)))


path = sys.argv[1]
if path.endswith(".npz"):
    d = np.load(path)
    show(path, d["x"], d["vol"], float(d["h"]))
else:
    h = float(sys.argv[2])
    with h5py.File(path, "r") as f:
        frames = [int(a) for a in sys.argv[3:]] or [-1]
        vol0 = f["particles/vol0_m3"][()]
        for k in frames:
            a = f["frames/active"][k].astype(bool)
            x, J = f["frames/x_m"][k], f["frames/J"][k]
            show(f"{path} t = {float(f['frames/t_s'][k]):.2f} s", x[a], (vol0 * J)[a], h)
