"""Where the no-slip bed samples the yield criterion (issue 31, item 2): a Bingham layer on an incline
near its yield limit, against the exact film flow and against the cell-centred prediction.

The validation suite's layer (``mpmjax.studies.validate.incline_config``, ``incline_plug_speed``):
an infinite layer (periodic along the slope, 4 cells long), depth H = 0.1 m, slope 30 degrees,
rho = 1000 kg/m^3, plastic viscosity 20 Pa s (Papanastasiou m = 1000 s), no-slip bed, free surface.
The bed stress is tau_b = rho g H sin(theta); tau_y = tau_b / r for r = tau_b / tau_y.  Exact steady
plug speed (the layer's momentum balance): u = rho g sin(theta) (H - h_p)^2 / (2 mu), h_p = tau_y / (rho g
sin(theta)), so the sheared layer is delta = H (1 - 1/r) thick.

The cell-centred prediction is what a grid whose strain rate is one value per cell gives at steady
state: each cell row k yields at its centre z_k = (k + 1/2) h, gamma_k = max(0, rho g sin(theta)
(H - z_k) - tau_y) / mu, and u = sum_k h gamma_k (exact where the sheared layer spans whole cells,
zero where delta < h/2: the yield criterion sampled h/2 above the bed).

One JSON line per run: r, cells across H, pressure, exact and cell-centred plug speeds, the measured
one (the mean speed of the top fifth of the particles over the last 0.3 s of 1 s), its error against
each, steps and CPU.

    .venv/bin/python benchmarks/accuracy/incline_yield.py            # both pressures, r 1.05-1.5, 5/10/20 cells
    .venv/bin/python benchmarks/accuracy/incline_yield.py incompressible 1.1 10
    .venv/bin/python benchmarks/accuracy/incline_yield.py incompressible 1.1 10 maxwell_shear_modulus_pa=2e5
    .venv/bin/python benchmarks/accuracy/incline_yield.py explicit 1.1 5 maxwell_shear_modulus_pa=2e5 wall_yield=wall

The rows with "numerics.wall_yield": "wall" in incline_yield.jsonl are docs/wall-yield.md's table (explicit
at cfl 0.4 and 0.2, and the grid pressure).
"""

import json
import sys
import time

import numpy as np

from mpmjax import build
from mpmjax._simulate import run
from mpmjax.studies.validate import (
    INCLINE_H as H,
    INCLINE_MU as MU,
    INCLINE_SLOPE as SLOPE,
    RHO,
    G,
    incline_config,
    incline_plug_speed,
    incline_top,
)

T_END, T_AVG = 1.0, 0.3
S = float(np.sin(np.radians(SLOPE)))


def cell_centred_speed(r: float, cells: int) -> float:
    h = H / cells
    tau_y = RHO * G * H * S / r
    z = (np.arange(cells) + 0.5) * h
    gamma = np.maximum(0.0, RHO * G * S * (H - z) - tau_y) / MU
    return float(np.sum(h * gamma))


def measure(r: float, cells: int, pressure: str, numerics: dict | None = None) -> dict:
    h = H / cells
    base = {"numerics.dtype": "float64", "numerics.pressure": pressure}
    base.update({f"numerics.{k}": v for k, v in (numerics or {}).items()})
    s = build(incline_config(cells, r, T_END, base))
    c0 = time.process_time()
    final, frames = run(s.scene, s.state, s.params)
    cpu = time.process_time() - c0
    keep = int(round(T_AVG / T_END * s.scene.n_frames))
    u = float(np.asarray(frames.v)[-keep:, :, 0][:, incline_top(s)].mean())
    ex, cc = incline_plug_speed(r), cell_centred_speed(r, cells)
    return {
        "r": r,
        "cells": cells,
        "pressure": pressure,
        **{f"numerics.{k}": v for k, v in (numerics or {}).items()},
        "delta_over_h": round(H * (1 - 1 / r) / h, 3),
        "u_exact": ex,
        "u_cell_centred": cc,
        "u": u,
        "err_exact_pct": round(100 * (u - ex) / ex, 2),
        "err_cell_centred_pct": round(100 * (u - cc) / cc, 2) if cc > 0 else None,
        "steps": s.scene.n_steps,
        "cpu_s": round(cpu, 1),
    }


if __name__ == "__main__":
    pressures = [sys.argv[1]] if len(sys.argv) > 1 else ["explicit", "incompressible"]
    ratios = [float(sys.argv[2])] if len(sys.argv) > 2 else [1.05, 1.1, 1.2, 1.5]
    cells = [int(sys.argv[3])] if len(sys.argv) > 3 else [5, 10, 20]
    def value(v: str):
        try:
            return float(v)
        except ValueError:
            return v  # a choice, e.g. wall_yield=wall

    extra = {k: value(v) for k, v in (a.split("=", 1) for a in sys.argv[4:])}  # <numerics key>=<value>
    for p in pressures:
        for r in ratios:
            for c in cells:
                print(json.dumps(measure(r, c, p, extra)), flush=True)
