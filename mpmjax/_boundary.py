"""Boundaries: walls, terrain and the pipe inlet.

``inflow_layout``: the geometry of a pipe inlet's particle pool (cross-section offsets,
area, layer count and layer time), shared by scene validation (which checks the pool's
size) and the build (which seeds the pool).  Units: SI (m, s, m^2 or 2D m).
"""

from __future__ import annotations

import math

import numpy as np


def perp_basis(d: np.ndarray) -> list[np.ndarray]:
    """Unit vectors spanning the plane normal to the unit vector ``d``."""
    if d.size == 2:
        return [np.array([-d[1], d[0]])]
    a = np.eye(3)[int(np.argmin(np.abs(d)))]
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1)
    return [e1, np.cross(d, e1)]


def inflow_layout(cfg: dict, dim: int):
    """Cross-section offsets (n_per, dim) [m], area A [m^2; 2D: m], pool size, layer count and layer dt [s].

    The particle spacing is sp = h / ppc.  2D: n_per = round(width / sp) points evenly across the
    width.  3D: the points of a square lattice of spacing sp' = min(sp, diameter/2) (centred on
    the axis) inside the disc of the diameter (so at least 2 x 2 points); layers sp' thick.
    Layer time dt_l = sp' / u (2D: sp / u) rounded so that a whole number of layers spans
    [t_start, t_stop]; each layer carries Q dt_l.
    """
    sp = cfg["domain.cell_size_m"] / cfg["numerics.ppc"]
    d = np.asarray(cfg["inflow.direction"], float)
    d = d / np.linalg.norm(d)
    w = cfg["inflow.width_m"]
    basis = perp_basis(d)
    if dim == 2:
        m = max(1, int(round(w / sp)))
        offs = [((j + 0.5) * w / m - 0.5 * w) * basis[0] for j in range(m)]
        area = w
    else:
        # at least 2 x 2 points across: a single particle on the pipe axis sits on a plane of
        # symmetry in y and never spreads sideways (measured in field-pipe-3d at h = 0.5 m)
        sp = min(sp, 0.5 * w)
        area = math.pi * w * w / 4.0
        m = max(1, int(math.ceil(w / sp)))
        c = (np.arange(m) - 0.5 * (m - 1)) * sp
        offs = [a * basis[0] + b * basis[1] for a in c for b in c if a * a + b * b <= 0.25 * w * w]
        offs = offs or [0.0 * d]
    t0 = cfg["inflow.t_start_s"]
    t1 = cfg["time.t_end_s"] if math.isnan(cfg["inflow.t_stop_s"]) else cfg["inflow.t_stop_s"]
    u = cfg["inflow.flow_rate_m3_s"] / area
    with np.errstate(all="ignore"):
        n_layers = max(1, int(round(min((t1 - t0) * u / sp, 1e12))))
    return np.asarray(offs), area, float(n_layers) * len(offs), n_layers, (t1 - t0) / n_layers, u, d

