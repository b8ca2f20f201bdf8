"""The particles of a cell sheared in series across the bed (``numerics.cell_shear = "series"``).

With the linear and GIMP shapes the grid gives every particle of a cell the cell's one velocity
gradient, so each shears at the same rate and the cell's stress is the mean of theirs: particles in
parallel.  Where the material shears in layers over a bed, the particles stacked across the bed are in
series instead: the shear stress is continuous from one to the next, each shears at its own rate, and
the cell's velocity difference is the sum.  That matters for a law whose particles differ at one rate
(Coussot: the structure lambda is each particle's history).  A thixotropic layer near its flow curve's
minimum stress shears in a band at the bed whose edge is a jump of two orders in viscosity (lambda 0.4
below it, 7 above, the lab material), and with one rate per cell that edge can only sit on a cell
boundary: the band is a whole number of cells, and a 5 cm layer's mean speed is -15.5 / +12.5 % off its
one-dimensional solution at 5 / 10 cells across it (docs/coussot-film.md).

``series``: in each cell, each shear component across the bed's axis a (tau_ba, b != a, signed) is taken
as linear across the cell, tau(y) = tau_bar + (y - y_c) G_c, with the gradient G_c measured from the stress
itself: the cells' mean tractions tau_ba, centred between the neighbours above and below that hold
material, one-sided toward the one there is (a free surface; a no-slip face, behind which the grid's
cells hold nothing), zero in a cell with neither.  Particle p's rate across the bed is then
(tau_bar + (y_p - y_c) G_c) / mu_p, mu_p the law's viscosity at its own state, with tau_bar such that the
cell's volume-weighted mean of those rates is the grid's (the kinematics unchanged):

    tau_bar = (sum V g - G_c sum V (y - y_c) / mu) / sum V / mu,

g = 2 d'_ba the particles' rates from the grid.  The particle's d'_ab and d'_ba are set to its own rate
(the spin, and the other components, stay the grid's); its structure advances with it and its stress
relaxes to it, so the cell's stress across the bed is the series (harmonic) mean.  The stress gradient
seeds the band: the lower particles of the band's edge cell shear faster and break down, the upper ones
rebuild and jam.  In a cell whose particles share one state and see no stress gradient it changes
nothing.  The band's edge is then resolved to a particle layer (h / ppc) instead of a cell.

Where: laws with internal variables (Coussot), the linear or GIMP shape, the standard shear measure, the
full formulation, and a no-slip box face on the last axis (the bed, as ``_pressure``'s vertical); a
no-op elsewhere.  Bingham's bed is ``_wall_yield``'s.  Cost: one scatter of 4 + (dim - 1) values per
particle into the cells and a gather back.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ._constitutive import shear_rate
from ._scene import Scene
from ._wall_yield import _walls, applies, cell_grid, cells_of

MODES = ("uniform", "series")


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
    # the ends of the grid along the bed's axis: no neighbour beyond them (the roll would wrap)
    idx = np.indices(tuple(n_cells))[a]
    top_end, bottom_end = idx == n_cells[a] - 1, idx == 0
    n_t = len(t_axes)

    def series(state, mat, shear, dprime, dd):
        dtp = state.x.dtype
        x = state.x
        vol = state.vol0 * state.J * state.active.astype(dtp)
        cell = cells_of(x, origin, n_cells, h)
        cid = jnp.sum(cell * jnp.asarray(strides)[None, :], axis=1)
        y = x[:, a] - (jnp.asarray(origin[a], dtp) + (cell[:, a].astype(dtp) + 0.5) * h)  # height over the centre
        mu = law.mu(mat, shear, state.internal)  # Coussot's does not depend on the rate
        inv = vol / mu
        # per tangential axis b, signed: the rate across the bed 2 d'_ba from the grid, and the traction tau_ba
        g = [2.0 * dprime[:, b, a] for b in t_axes]
        chans = [vol, inv, inv * y] + [vol * gb for gb in g] + [vol * state.tau[:, b, a] for b in t_axes]
        sums = jnp.zeros((n_all, len(chans)), dtp).at[cid].add(jnp.stack(chans, axis=1))
        if axis is not None:
            sums = jax.lax.psum(sums, axis)
        v = sums[:, 0]
        has = (v > 0.0).reshape(tuple(n_cells))
        has_up = jnp.roll(has, -1, axis=a) & jnp.asarray(~top_end)
        has_dn = jnp.roll(has, 1, axis=a) & jnp.asarray(~bottom_end)
        s = sums[cid]
        dd_new = dd
        dprime_new = dprime
        for k, b in enumerate(t_axes):
            mean = (sums[:, 3 + n_t + k] / jnp.where(v > 0.0, v, 1.0)).reshape(tuple(n_cells))
            up, dn = jnp.roll(mean, -1, axis=a), jnp.roll(mean, 1, axis=a)
            # d tau_ba / dy [Pa/m]: centred between two neighbours with material, else one-sided toward the one
            # there is (a free surface, or a no-slip face: the cells behind a box wall hold nothing), else 0
            grad = jnp.where(
                has_up & has_dn,
                (up - dn) / (2.0 * h),
                jnp.where(has_up, (up - mean) / h, jnp.where(has_dn, (mean - dn) / h, 0.0)),
            ).reshape(-1)[cid]
            tau_bar = (s[:, 3 + k] - grad * s[:, 2]) / jnp.where(s[:, 1] > 0.0, s[:, 1], 1.0)
            rate = (tau_bar + grad * y) / mu
            half = 0.5 * rate
            dd_new = dd_new + 2.0 * (half * half - dprime[:, b, a] * dprime[:, b, a])
            dprime_new = dprime_new.at[:, b, a].set(half).at[:, a, b].set(half)
        return shear_rate(dd_new, scene.shear_measure), dprime_new, dd_new

    return series
