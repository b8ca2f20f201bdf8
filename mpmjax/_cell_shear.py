"""The particles of a cell sheared in series across the bed (``numerics.cell_shear = "series"``).

With the linear and GIMP shapes the grid gives every particle of a cell the cell's one velocity
gradient, so each shears at the same rate and the cell's stress is the mean of theirs: particles in
parallel.  Where the material shears in layers over a bed, the particles stacked across the bed are in
series instead: the shear stress is continuous from one to the next, each shears at its own rate, and
the cell's velocity difference is the sum.  That matters for a law whose particles differ at one rate
(Coussot: the structure lambda is each particle's history).  A thixotropic layer near its flow curve's
minimum stress shears in a band at the bed whose edge is a jump of two orders in viscosity (lambda 0.4
below it, 7 above, the lab material), and with one rate per cell that edge can only sit on a cell
boundary: the band is a whole number of cells, and a 5 cm layer's mean speed is -15.5 / +12.6 % off its
one-dimensional solution at 5 / 10 cells across it (docs/coussot-film.md).

``series``: in each cell, the shear stress across the bed's axis a is taken as linear,
tau(y) = tau_bar + (y - y_c) G_c, with the gradient G_c measured from the stress itself (the mean bed-normal
traction |tau . e_a| of the cells above and below, centred; one-sided in the first and last cells; an
empty neighbour a free surface, traction 0).  Particle p's shear rate across the bed is then
max(tau(y_p), 0) / mu_p, mu_p the law's viscosity at its own state, with tau_bar such that the cell's
volume-weighted mean of those rates is the grid's (the kinematics unchanged):

    tau_bar = (sum V g - G_c sum V (y - y_c) / mu) / sum V / mu,

g the particles' rates from the grid.  The particle's shear components across the bed (d'_ab, d'_ba,
b != a) are scaled to its own rate; its structure advances with it and its stress relaxes to it, so
the cell's stress is the series (harmonic) mean.  The stress gradient seeds the band: the lower
particles of the band's edge cell shear faster and break down, the upper ones rebuild and jam.  In a
cell whose particles share one state and no stress gradient it changes nothing.

Where: laws with internal variables (Coussot), the linear or GIMP shape, the standard shear measure, the
full formulation, and a no-slip box face on the last axis (the bed, as ``_pressure``'s vertical); a
no-op elsewhere.  Bingham's bed is ``_wall_yield``'s.  Cost: one scatter of 4 + (dim - 1) values per
particle into the cells and a gather back.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ._constitutive import _safe_sqrt, shear_rate
from ._scene import Scene
from ._wall_yield import _walls, cell_grid, cells_of
from ._wall_yield import applies as _one_rate_per_cell

MODES = ("uniform", "series")


def applies(shape: str, shear_measure: str, formulation: str) -> bool:
    """Whether ``series`` can act: one strain rate per cell (the linear and GIMP shapes), a rate in 1/s
    and the full formulation, as ``numerics.wall_yield = "wall"``."""
    return _one_rate_per_cell(shape, shear_measure, formulation)


def bed_axis(scene: Scene) -> int | None:
    """The last axis where a no-slip box face lies across it (the bed), else None."""
    a = scene.dim - 1
    return a if any(w[0] == a for w in _walls(scene)) else None


def make_cell_shear(scene: Scene, axis: str | None = None):
    """``series(state, material, shear, dprime, dd) -> (shear, dprime, dd)`` with the cells' particles in series across
    the bed (module docstring), or None where the setting, the law or the walls leave nothing to do.
    ``axis``: the device mesh axis when the particles are split over devices (the cells' sums are added
    across it)."""
    law = scene.rheology
    a = bed_axis(scene)
    if scene.cell_shear != "series" or not law.internals or a is None:
        return None
    if not applies(scene.shape, scene.shear_measure, scene.formulation):
        return None
    dim, h = scene.dim, scene.h
    origin, n_cells = cell_grid(scene)
    n_all = int(np.prod(n_cells))
    strides = np.array([int(np.prod(n_cells[b + 1 :])) for b in range(dim)], np.int32)
    t_axes = [b for b in range(dim) if b != a]
    across = np.zeros((dim, dim))  # the shear components across the bed: d'_ab and d'_ba, b != a
    for b in t_axes:
        across[a, b] = across[b, a] = 1.0
    # the rows of cells inside the no-slip faces across the bed's axis (the grid extends behind a box wall)
    idx = np.indices(tuple(n_cells))[a]
    first = np.zeros(tuple(n_cells), bool)
    last = np.zeros(tuple(n_cells), bool)
    for ax, point, sign in _walls(scene):
        if ax == a:
            k = int(round((point - scene.grid_origin[a]) / h))
            if sign > 0:
                first |= idx == k
            else:
                last |= idx == k - 1

    def series(state, mat, shear, dprime, dd):
        dtp = state.x.dtype
        x = state.x
        vol = state.vol0 * state.J * state.active.astype(dtp)
        cell = cells_of(x, origin, n_cells, h)
        cid = jnp.sum(cell * jnp.asarray(strides)[None, :], axis=1)
        y = x[:, a] - (jnp.asarray(origin[a], dtp) + (cell[:, a].astype(dtp) + 0.5) * h)  # height over the centre
        g = 2.0 * _safe_sqrt(sum(dprime[:, b, a] * dprime[:, b, a] for b in t_axes))  # the rate across the bed
        mu = law.mu(mat, shear, state.internal)
        inv = vol / mu
        traction = [vol * state.tau[:, b, a] for b in t_axes]
        chans = jnp.stack([vol, vol * g, inv, inv * y, *traction], axis=1)
        sums = jnp.zeros((n_all, chans.shape[1]), dtp).at[cid].add(chans)
        if axis is not None:
            sums = jax.lax.psum(sums, axis)
        v = sums[:, 0]
        mean = sums[:, 4:] / jnp.where(v > 0.0, v, 1.0)[:, None]
        m = _safe_sqrt(jnp.sum(mean * mean, axis=1)).reshape(tuple(n_cells))
        # d|tau|/dy [Pa/m], centred; a row on a no-slip face (first: the face below it, last: above) takes the
        # gradient between its two neighbours inward (behind the wall the cells are empty, not a free surface)
        up, dn = jnp.roll(m, -1, axis=a), jnp.roll(m, 1, axis=a)
        grad = (up - dn) / (2.0 * h)
        grad = jnp.where(jnp.asarray(first), (jnp.roll(m, -2, axis=a) - up) / h, grad)
        grad = jnp.where(jnp.asarray(last), (dn - jnp.roll(m, 2, axis=a)) / h, grad).reshape(-1)
        s = sums[cid]
        G = grad[cid]
        tau_bar = (s[:, 1] - G * s[:, 3]) / jnp.where(s[:, 2] > 0.0, s[:, 2], 1.0)
        rate = jnp.maximum(tau_bar + G * y, 0.0) / mu
        ok = g > 0.0
        k = jnp.where(ok, rate / jnp.where(ok, g, 1.0), 1.0)
        dd = dd + (k * k - 1.0) * 0.5 * g * g  # the two components across the bed: 2 d'_ba^2 summed over b = g^2 / 2
        factor = 1.0 + (k - 1.0)[:, None, None] * jnp.asarray(across, dtp)[None]
        return shear_rate(dd, scene.shear_measure), dprime * factor, dd

    return series
