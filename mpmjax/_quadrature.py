"""The stress's smooth part integrated on the grid: ``numerics.stress_quadrature = "corrected"``.

MPM integrates the internal force f_i = -int sigma grad N_i dV at the particles: -sum_p V_p sigma_p
grad w_ip.  That sum is exact for a uniform stress only while the particles tile the cells evenly; once
shear has disordered them, a stress that is uniform along the flow gives a nodal force anyway, of the
order of the stress times the disorder.  In a layer sheared over its bed the stress (the bed shear
rho g sin(theta) H, hundreds of pascals) is large against the forces that keep the particles in order,
and that force moves the particles further from order: the layer leaves its steady film after a bed
shear strain of about 25-35 with the grid pressure (whose J = 1 resists no sub-cell crowding), 50-70 with
the particles' pressure (docs/incompressible-default.md, "Long shear").  Subtracting the film's exact base
stress from the particles and integrating it exactly removes the growth; this module does that with the
stress the particles themselves carry:

1. tau_i = sum_p m_p w_ip sigma_p / m_i, the stress on the nodes (mass weighted: constants exactly);
2. the particles' sum carries only sigma_p - tau_h(x_p), tau_h = sum_i w_ip tau_i, on the particles of
   the material's cells (below);
3. the smooth part's force is integrated exactly over those cells: -int_c tau_h grad N_i dV with the
   bilinear (trilinear) tau_h and hat functions N_i, by 2-point Gauss rules per axis (exact here), a
   fixed 2^d x 2^d x d table of coefficients per cell.

So f_i = -sum_p V_p (sigma_p - tau_h(x_p)) grad w_ip - int tau_h grad N_i: equal to the particles' sum
where they tile the cells evenly (GIMP's particle domains then tile the cells, and the two smooth terms
cancel), and where they do not, the smooth part's quadrature error is gone and only the remainder's is left.

The material's cells: the grid pressure's deep cells (``_pressure.deep_cells``: packing phi_c >=
``_pressure.FLUID_FRACTION`` in every cell of the 3^d block around), so the region ends a cell inside the
free surface, where the material does not fill the cell and its exact integral would not be the material's.
The boundary is not where the deviatoric stress vanishes (a block at rest carries tau_xx = p at its sides),
so the region must stay inside the material: with the fluid cells themselves (phi_c >= 0.5) a viscous block
held by Coulomb friction crept 6 times faster (15.6 against 2.6 mm/s, tests/test_pressure.py), and with a
threshold inside the material (0.9: the region's edge then runs through a deposit packed at 0.86, cells
toggling in and out) the lab dam break blew up.  Voids inside the region count as material: a deep cell
packed at 0.86 carries the smooth stress of a full cell, which slows yield-limit slumps (B0.05-a1 -10.0 %
against -3.7 %); weighting the cells by their packing halves that but loses the film again, the packing
being itself a sum over the particles.  Hence experimental and not the default (the validation suite:
docs/incompressible-default.md).

Either pressure: with the particles' (Tait) pressure the smooth part includes it, and a film that the
particles' quadrature lets drift to -13.6 % by 24 s holds -0.25 % throughout.

Hat functions: GIMP and the linear kernel only (their particle sums integrate against the hats); the
B-splines would need the integral against the splines (``numerics.stress_quadrature`` refuses them).
The cost is a second scatter (mass and the stress's d(d+1)/2 components), one gather of tau_h, the deep
cells and the cell integrals: the lab dam break's step 1.78 -> 2.83 ms of CPU.
"""

from __future__ import annotations

import itertools

import jax.numpy as jnp
import numpy as np

from ._boundary import node_fill
from ._pressure import FLUID_FRACTION, _np_corner_sum, cell_valid, deep_cells
from ._scene import Scene

MODES = ("particles", "corrected")
# the kernels whose particle sums integrate against the hat functions
SHAPES = ("gimp", "linear")


def _coefficients(dim: int, h: float) -> np.ndarray:
    """K[c, c2, b] = int_cell N_c2 dN_c/dx_b dV over one cell (c, c2 corner numbers of ``itertools.product``
    order, b an axis), by 2-point Gauss per axis: exact for these polynomials."""
    corners = list(itertools.product((0, 1), repeat=dim))
    g = (0.5 - 0.5 / np.sqrt(3.0), 0.5 + 0.5 / np.sqrt(3.0))
    K = np.zeros((len(corners), len(corners), dim))
    w = h**dim / 2**dim
    for pt in itertools.product(g, repeat=dim):
        n1 = [[pt[a] if c[a] else 1.0 - pt[a] for a in range(dim)] for c in corners]
        N = [float(np.prod(v)) for v in n1]
        for ci, c in enumerate(corners):
            for b in range(dim):
                d = [n1[ci][a] for a in range(dim)]
                d[b] = (1.0 if c[b] else -1.0) / h
                dN = float(np.prod(d))
                for c2 in range(len(corners)):
                    K[ci, c2, b] += w * N[c2] * dN
    return K


def make_correction(scene: Scene):
    """Returns ``correct(sigma, mass_w, st, x, rho, sums) -> (sigma', f_smooth)``: ``sigma`` (n, d, d) the
    particles' stress, ``mass_w`` (n, S) m_p w_ip, ``st`` their stencil, ``x`` (n, d) their positions,
    ``sums(vals (n, S, C)) -> (N, C)`` the grid sums; ``sigma'`` the stress the particles' force sum takes
    and ``f_smooth`` (N, d) the exact force of the smooth part, to add to that sum (module docstring)."""
    dim, h, shape = scene.dim, scene.h, tuple(scene.grid_shape)
    corners = list(itertools.product((0, 1), repeat=dim))
    comps = [(a, b) for a in range(dim) for b in range(a, dim)]
    index = {}
    for k, (a, b) in enumerate(comps):
        index[(a, b)] = index[(b, a)] = k
    K = _coefficients(dim, h)
    fill = np.maximum(node_fill(scene).reshape(shape), 0.0)
    fill_c = _np_corner_sum(fill, corners)  # the packing's denominator, as the grid pressure's
    # the cells that may hold material: inside the box, in front of the planes, above the terrain
    valid = cell_valid(scene)
    origin = np.asarray(scene.grid_origin)

    def at(t, o):
        for a in range(dim):
            if o[a]:
                t = jnp.roll(t, -int(o[a]), axis=a)
        return t

    def correct(sigma, mass_w, st, x, rho, sums):
        dtp = sigma.dtype
        tc = jnp.stack([sigma[:, a, b] for a, b in comps], axis=-1)  # (n, C)
        g = sums(jnp.concatenate([mass_w[..., None], mass_w[..., None] * tc[:, None, :]], axis=-1))
        m = g[:, 0]
        tau = jnp.where(m[:, None] > 0.0, g[:, 1:] / jnp.where(m > 0.0, m, 1.0)[:, None], 0.0)
        # the material's cells: the grid pressure's packing and fluid fraction
        mg = m.reshape(shape)
        phi = sum(at(mg, c) for c in corners) / (rho * h**dim * jnp.asarray(np.maximum(fill_c, 1e-12), dtp))
        cells = deep_cells((phi >= FLUID_FRACTION) & jnp.asarray(valid), valid, scene.periodic)
        # the particles of those cells carry sigma - tau_h
        cell = jnp.floor((x - jnp.asarray(origin, dtp)[None, :]) / h).astype(jnp.int32)
        cell = tuple(jnp.mod(cell[:, a], shape[a]) for a in range(dim))
        inside = cells[cell]
        tau_p = jnp.sum(st.w[..., None] * st.gather(tau), axis=1)  # (n, C)
        tau_p = jnp.where(inside[:, None], tau_p, 0.0)
        smooth = jnp.stack([jnp.stack([tau_p[:, index[(a, b)]] for b in range(dim)], -1) for a in range(dim)], -2)
        # the smooth part's force, cell by cell, onto the corner nodes
        T = tau.reshape(shape + (len(comps),))
        Tc = [at(T, c) for c in corners]
        f = jnp.zeros(shape + (dim,), dtp)
        for ci, c in enumerate(corners):
            fc = []
            for a in range(dim):
                acc = 0.0
                for c2 in range(len(corners)):
                    for b in range(dim):
                        k = float(K[ci, c2, b])
                        if k != 0.0:
                            acc = acc + k * Tc[c2][..., index[(a, b)]]
                fc.append(-jnp.where(cells, acc, 0.0))
            fc = jnp.stack(fc, axis=-1)
            for a in range(dim):
                if c[a]:
                    fc = jnp.roll(fc, 1, axis=a)
            f = f + fc
        return sigma - smooth, f.reshape(-1, dim)

    return correct

