"""The yield criterion of the cell row on a no-slip wall, sampled at the wall (``numerics.wall_yield``).

With one strain rate per cell row, a no-slip bed's first row of particles shears as a whole, and its
stress is the row's mean: in equilibrium the bed stress less the weight of the half cell below the
row's centre.  So that row yields when the stress h/2 above the bed reaches tau_y, not the bed's: a
deposit stops where rho g (H - h/2) |grad H| = tau_y, a bed raised by h/2, first order in h
(docs/wall-yield.md).

``wall_yield = "wall"`` gives the wall row the flow rule integrated across the row instead.  The
shear stress falls linearly across the row, tau(y) = tau_bar + (h/2 - y) 2 Delta / h, its drop from
the wall to the row's centre Delta = (h/2) |d tau/dy| measured from the stress itself: half the
difference of the mean tangential tractions |tau . n| of the wall row and the row above it (the
row above empty: its traction taken as 0, a free surface), per cell column along the wall.  A
Bingham row's mean rate is then the mean of (tau(y) - tau_y)/mu where positive, whose inverse is

    tau_bar = tau_y + tau_pl(gdot) - (max(sqrt(Delta) - sqrt(tau_pl(gdot)), 0))^2,

tau_pl the law's stress without its yield stress at the row's rate gdot (mu gdot for Bingham): the
row holds (gdot = 0) up to tau_bar = tau_y - Delta, i.e. until the wall's stress reaches tau_y, and
rejoins the law where the whole row yields (tau_pl >= Delta), continuous in value and slope there.
So the particles of the wall row take the effective yield stress tau_y - (max(sqrt(Delta) -
sqrt(tau_pl), 0))^2 (>= 0) in the law's own viscosity (Papanastasiou, bi-viscosity, Herschel-Bulkley;
for Herschel-Bulkley the flowing branch is Bingham's form with tau_pl = K gdot^n, the arrest exact).
Every other particle, and a law without a yield stress, is unchanged.

Where: the scene's axis-aligned no-slip box faces (not Navier-slip faces, inclined planes or DEM
terrain), with the linear or GIMP shape and the standard shear measure (the scene validation falls back
to "cell" otherwise).  The default since 2026-12-05.  Cost: one scatter of the volume and the traction
into the two rows of each such wall.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ._constitutive import _safe_sqrt
from ._scene import Scene

# the shapes with one strain rate per cell row, which the row-averaged flow rule assumes (with the B-splines
# the rate varies inside the row: the near-yield incline read -59 / -38 % at 5 / 10 cells with quadratic_bm)
SHAPES = ("gimp", "linear")


def applies(shape: str, shear_measure: str, formulation: str) -> bool:
    """Whether ``wall_yield = "wall"`` can act: a shape of ``SHAPES``, the standard shear measure (a rate in
    1/s) and the full formulation (the depth-averaged one has no wall row).  Where it cannot, the scene
    validation falls back to "cell" (or refuses a "wall" the scene sets), and the step does nothing."""
    return shape in SHAPES and shear_measure == "standard" and formulation == "full"


def effective_yield_stress(tau_y, tau_pl, delta):
    """The wall row's yield stress [Pa]: tau_y - (max(sqrt(delta) - sqrt(tau_pl), 0))^2, at least 0.

    tau_y: the law's yield stress; tau_pl: the law's stress without it at the row's rate [Pa];
    delta: the drop of the shear stress from the wall to the row's centre [Pa].  With it the row's
    stress tau_y_eff + tau_pl is the mean over the row of a linear stress profile whose Bingham rate,
    averaged over the row, is the row's rate (module docstring); delta = 0 gives tau_y."""
    gap = jnp.maximum(_safe_sqrt(delta) - _safe_sqrt(tau_pl), 0.0)
    return jnp.maximum(tau_y - gap * gap, 0.0)


def _walls(scene: Scene):
    """The axis-aligned no-slip box faces: (axis, wall coordinate [m], inward sign)."""
    out = []
    for w in scene.walls:
        n = np.asarray(w.normal, float)
        if w.kind != "noslip" or w.slip_length > 0.0 or np.count_nonzero(n) != 1:
            continue
        a = int(np.flatnonzero(n)[0])
        if scene.periodic[a]:
            continue
        out.append((a, float(w.point[a]), float(np.sign(n[a]))))
    return out


def cell_grid(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(grid origin [m], cells per axis) of the scene's grid: a periodic axis has as many cells as nodes (the
    last cell wraps onto the first node), another one fewer."""
    return np.asarray(scene.grid_origin, float), np.asarray(scene.grid_shape) - (~np.asarray(scene.periodic)).astype(int)


def cells_of(x, origin: np.ndarray, n_cells: np.ndarray, h: float):
    """The cell index per axis (n, dim) of positions ``x`` [m], clipped to the grid."""
    cell = jnp.floor((x - jnp.asarray(origin, x.dtype)[None, :]) / h).astype(jnp.int32)
    return jnp.clip(cell, 0, jnp.asarray(n_cells - 1, jnp.int32)[None, :])


def make_wall_yield(scene: Scene, axis: str | None = None):
    """``material(state, material, shear) -> material`` with the wall row's effective yield stress (per
    particle) in place of the law's, or None where the scene's setting, law or walls leave nothing to do.
    ``axis``: the device mesh axis when the particles are split over devices (the rows' sums are added
    across it)."""
    law = scene.rheology
    walls = _walls(scene)
    if scene.wall_yield != "wall" or law.yield_stress_param is None or not walls:
        return None
    if not applies(scene.shape, scene.shear_measure, scene.formulation):
        return None
    dim, h = scene.dim, scene.h
    origin, n_cells = cell_grid(scene)
    name = law.yield_stress_param

    def material(state, mat, shear):
        dtp = state.x.dtype
        x = state.x
        vol = state.vol0 * state.active.astype(dtp)
        cell = cells_of(x, origin, n_cells, h)
        delta = jnp.zeros(x.shape[0], dtp)
        for a, point, sign in walls:
            t_axes = [b for b in range(dim) if b != a]
            n_t = int(np.prod(n_cells[t_axes]))
            tid = jnp.zeros(x.shape[0], jnp.int32)
            for b in t_axes:
                tid = tid * int(n_cells[b]) + cell[:, b]
            row = jnp.floor((x[:, a] - point) * sign / h)
            seg = jnp.where(row == 0, tid, jnp.where(row == 1, n_t + tid, 2 * n_t))
            traction = jnp.stack([state.tau[:, b, a] for b in t_axes], axis=1)
            chans = jnp.concatenate([vol[:, None], vol[:, None] * traction], axis=1)
            sums = jnp.zeros((2 * n_t + 1, chans.shape[1]), dtp).at[seg].add(chans)
            if axis is not None:
                sums = jax.lax.psum(sums, axis)
            v = sums[: 2 * n_t, 0]
            mean = sums[: 2 * n_t, 1:] / jnp.where(v > 0.0, v, 1.0)[:, None]
            mag = _safe_sqrt(jnp.sum(mean * mean, axis=1))
            drop = 0.5 * jnp.maximum(mag[:n_t] - mag[n_t:], 0.0)
            delta = jnp.where(row == 0, jnp.maximum(delta, drop[tid]), delta)
        plain = mat._replace(**{name: jnp.zeros_like(getattr(mat, name))})
        tau_pl = law.mu(plain, shear, state.internal) * shear
        return mat._replace(**{name: effective_yield_stress(getattr(mat, name), tau_pl, delta)})

    return material
