"""Pressure on the grid: the fractional-step projection of ``numerics.pressure = "incompressible"``.

The particles then carry no pressure (their stress is the deviatoric tau alone; kappa is not
used) and each step solves for one pressure per grid cell against the nodal velocities (a Q1-P0
pair: bilinear/trilinear velocity, cell-constant pressure):

1. predictor: v* = v + dt (f_tau/m + g) on the nodes, with the walls' conditions (``_step``);
2. pressure: find p on the fluid cells such that v = v* + dt m^-1 S B^T p satisfies
   B v = r V_c (phi_c - 1)^+ / dt, i.e.  (A + eps D) p = (r V_c (phi_c - 1)^+ / dt - B v*) / dt
   (with ``void_closure = "velocity"`` the deep cells' error both ways: step 4),
   A = B m^-1 S B^T, D its diagonal, eps = ``REGULARISATION``, r the correction rate (below);
3. corrector: v = v* + dt m^-1 S B^T p, then the walls' conditions again, then G2P (``_step``);
4. voids (``numerics.void_closure = "position"``; off by default): the interior's voids are closed by
   moving the particles, not their velocity: a second
   solve with the same A for a displacement d = m^-1 S B^T q with B d = r V_c (phi_c - 1) on the
   deep cells packed below 1 - ``PACKING_DEAD_BAND`` (0 on the other fluid cells), added to the
   particles' positions after G2P (``_step``).  Deep: every cell of the 3^d block around it holds fluid
   all round (phi_c reads the corner nodes, whose mass comes from that block, so only there is it the
   material's packing and not the free surface's).  No velocity is added, so no kinetic energy;
   the dead band leaves the packing's own fluctuation alone: without it the corrections never stop
   and a deposit at its yield limit (a slump at x_inf, whose bed shear is the yield stress everywhere)
   creeps on (+16 % at 60 s).  Even with it, that slump creeps at 32 cells over H0 (+16 % at 60 s,
   against -0.9 % with the closure off) and the lab runout stops converging in h
   (docs/incompressible.md), hence off by default.
   ``numerics.void_closure = "velocity"`` closes the voids in the pressure solve itself (no second
   solve): on the deep cells the packing error e = phi_c - 1 is corrected both ways beyond
   ``PACKING_DEAD_BAND`` (so B v = r V_c e / dt there, an overpacked deep cell corrected from 1.01
   instead of 1.00), and only the overpacking elsewhere.  Correcting only the overpacking is a
   ratchet: with no correction at all the lab deposit packs at 1.265, with the overpacking corrected
   at 0.856, with both at 0.942.

Here B v is the cell's volume rate, the integral over the cell of div v with the bilinear
(trilinear) interpolant of the nodal velocities: B_ci = int_c grad N_i dV = (h/2)^(d-1) s, s the
corner's sign vector; B^T p is the nodal force of the cell pressures.  S = P P^T with P the walls'
linear conditions (noslip and the pipe's driven nodes: 0; slip, symmetry, Navier slip, slip and
Coulomb terrain: remove the normal component), so A is symmetric positive semi-definite and the
correction obeys the walls (a slip wall's separation is applied after it; Coulomb friction before
it, resisting the last step's pressure push as well: ``make_projection``'s ``contact``).

Why Q1-P0: one pressure per cell against 2^d velocity nodes is one constraint per cell, a count
that does not lock (the particles' J is a constraint per particle, ppc^d of them per cell: it
locks as kappa grows, docs/incompressible.md).  Its spurious pressure mode
(the checkerboard) has B^T p = 0 in the interior, so it moves nothing, and the free-surface cells
(p = 0) pin it.

Fluid cells: phi_c, the cell's packing (the nodal masses of its corners over rho h^d, each node
divided by the packing a filled domain gives it, ``_boundary.node_fill``), at least
``FLUID_FRACTION``; every other cell, and every cell whose centre lies outside the domain box,
behind a plane or below the terrain, has p = 0 (the free surface, and the walls' ghost cells,
which couple to nothing the walls leave free).  (phi_c - 1)^+ is the volume correction: a cell packed
denser than its material is pushed back apart, at the rate r = dt / sqrt(h/|g|) (the free-fall time
across a cell; ``VOLUME_RELAXATION`` scales it), not in one step: the packing fluctuates by a few
per cent as particles cross cells, and a one-step correction turns that into velocity noise (h/dt
times the fluctuation) that fluidises a thixotropic deposit.  By default under-filled cells are not
pulled together by the velocity: closing them that way in every cell surrounded by fluid, with no
dead band, kept yield-stress slumps creeping past x_inf (+21 % and +41 %).  Left open, though, the
particles spread (the lab deposit's interior packed at 0.85 at h = 1 cm, 0.89 at 0.5 cm): step 4's
closures close them (``velocity``: the deep cells only, beyond a 1 % dead band).

Near walls and the free surface.  Two places where the pressure's force and the particles' mass
disagree, both fixed here (issue 31; measured in docs/incompressible.md):

* Mass.  B^T p integrates over the valid cells with the bilinear functions, so a filled domain's
  hydrostatic pressure gives node i the weight of rho h^d q1_i (q1: the node's share of the valid
  cells, 1/2 on a box wall, 1 inside); the node's mass comes from the MPM kernel, rho h^d fill_i
  (``_boundary.node_fill``: 47/48 on the quadratic B-spline's second node from a wall, more than 1/2
  on a boundary-modified spline's wall node).  Where they differ, hydrostatic pressure is no
  equilibrium.  The solve's m^-1 uses the lumped mass below times q1 / fill_l, fill_l the filled
  domain's lumped fill: 1 for GIMP and the plain B-splines, whose ghost nodes' fill lumped onto their
  mirror images makes up q1 exactly (47/48 + 1/48), not for the boundary-modified splines.
* Nodes beyond the fluid cells.  A particle of a fluid cell also reaches nodes that are no corner of
  a fluid cell: behind a box wall (the plain kernels' ghost nodes) and above the free surface (its
  kernel's tail).  The pressure's force does not reach them, so they kept v* (for gravity, free fall)
  and every particle near a wall or the surface took a share of it: a column at rest between slip
  walls crept at 3e-4 m/s (quadratic_bm), and a 2D dam break and its extrusion between symmetry faces
  differed by 3.8 mm.  The velocity change is carried out from the corner nodes ``EXTEND_LAYERS``
  ring (each node the mean of its face neighbours that have it), as free-surface fluid solvers extend
  the projected velocity into the air, and a node behind a box wall takes its mirror image's (a static
  gather; the walls' linear conditions then remove the normal component there).  The mass of those
  nodes moves with the nodes it takes its velocity from (``lumped_mass``: E^T m, E the extension), so
  the correction adds only the pressure's own momentum (before: a block sliding on a slip floor gained
  2.3e-3 of its momentum in 0.2 s).  Measured: one ring
  and the mirror match two rings of face means on the column (6.8e-6 m/s) and halve the extrusion's
  difference (0.013 against 0.059 mm); a ring costs about 0.4 ms of the lab's 3 ms step.

eps D pins the pressure's level in a region with no free surface (a full closed box), where A alone
is singular; there the system's mean is removed too, since a closed box's
volume can be kept but not corrected.

The solve: conjugate gradients (``jax.scipy.sparse.linalg.cg``, a ``lax.custom_linear_solve``:
differentiable by implicit differentiation, forward and reverse mode, and vmappable), Jacobi
preconditioned, matrix free on the whole grid (cells that are not fluid are masked; in 2D A is applied
as its 9-point stencil, formed once a step, in 3D as div(S(grad q)): ``OPERATOR``), started
from the last step's pressure (``State.p``) or, where that is zero, the hydrostatic pressure of
the fluid above the cell; the transposed solve of reverse mode starts from zero (its own
``lax.custom_linear_solve`` around ``cg``: ``cg`` alone would start it from that warm start too).

A finite-kappa (weakly compressible) form with the EOS pressure kappa (phi_c - 1) was tried and
dropped: phi measured on the grid fluctuates by 0.1-1 % as particles move, and times a stiff kappa
that is a pressure noise of the order of the hydrostatic pressure (docs/validation.md).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ._boundary import node_fill
from ._scene import Scene, box_wall_nodes

MODES = ("explicit", "incompressible")

# a cell is fluid (an unknown of the solve) at packing phi_c >= this; below it, p = 0
FLUID_FRACTION = 0.5
# relative residual of the pressure solve by precision.  float32: 1e-4 (was 1e-5) saves 11 % of the lab's loop
# CPU (about 10.5 instead of 15 CG iterations a step) and moves no validate case by more than 0.05 points but
# the two B = 0.5 blocks, which end near their yield limit (about half a point each); 1e-3 saved 25 % but let
# deposits at their yield limit creep (the B = 0.05 slump's largest speed at 60 s 1.5 mm/s instead of 0.18)
# and moved the B = 0.5, L = H0 block 3.7 points (docs/incompressible.md, "The solve's tolerance")
CG_RTOL = {"float32": 1e-4, "float64": 1e-11}
CG_MAXITER = 2000
# the volume error is corrected at this many times the rate 1/sqrt(h/|g|) (see project)
VOLUME_RELAXATION = 1.0
# numerics.void_closure = "position": the voids of the deep cells are closed by moving the particles, not
# their velocity, at this many times the rate 1/sqrt(h/|g|) (see project)
POSITION_RELAXATION = 1.0
# both void closures leave a deep cell's packing error within this alone (the grid packing fluctuates by about
# a per cent as particles cross cells): ``position`` closes voids deeper than it, ``velocity`` corrects the error
# beyond it, both ways
PACKING_DEAD_BAND = 0.01
# the position closure runs every this many steps
POSITION_EVERY = 4
# the pressure's velocity change is carried this many rings of nodes out from the fluid cells' corners: the
# nodes a particle of a fluid cell reaches (one ring for GIMP and the quadratic and cubic B-splines)
EXTEND_LAYERS = 1
# how the solve applies A: "stencil" (2D): its 3^d coefficients per cell formed once a step, then one fused pass
# per product, in difference form so that float32 keeps the products' accuracy (``stencil`` in make_projection;
# lab grid: about 24 us less per CG iteration, the lab's loop -9 % CPU and -14 % wall against the products,
# alternating); "products" (3D):
# div(S(grad q)) from the nodal weights, which reads 3 arrays instead of 27 (the 27-point stencil was 4 % slower
# on field-dambreak-3d's 507 x 57 x 11 grid: a product there is bound by memory, not by the passes)
OPERATOR = {2: "stencil", 3: "products"}
# A's diagonal is raised by this fraction: a region with no free surface (a full closed box) has pressure
# fixed only up to a constant, and the volume error can make its system inconsistent
REGULARISATION = 1e-4


def _shifter(periodic, lead: int = 0):
    """``shift(a, s, axis)``: a[i - s] along grid ``axis`` (s = +-1) of an array with ``lead`` axes before
    the grid's (a stack of fields).  A periodic axis wraps (roll); any other
    axis fills with zero, which equals the wrap there: the wrapped-in entries are the last cell (never
    fluid, so its pressure is zero) or the first ghost node (no mass).  Padding fuses with its
    neighbours where a roll's concatenation does not (XLA:CPU, lab grid: the product A p 38 -> 23 us)."""

    def shift(a, s, axis):
        if periodic[axis]:
            return jnp.roll(a, s, axis=axis + lead)
        cfg = [(0, 0, 0)] * a.ndim
        cfg[axis + lead] = (s, -s, 0)
        return jax.lax.pad(a, jnp.zeros((), a.dtype), cfg)

    return shift


def deep_cells(fluid, valid: np.ndarray, periodic):
    """The deep fluid cells: every cell of the 3^d block around them is a fluid cell whose neighbours all
    hold fluid (or lies outside the domain: ``valid`` False).  phi_c reads the corner nodes, whose mass
    comes from that block: only there is it the material's packing and not the free surface's."""
    shift, dim = _shifter(periodic), fluid.ndim
    closed = fluid
    for a in range(dim):
        for sh in (-1, 1):
            closed = closed & (shift(fluid, sh, a) | ~jnp.asarray(np.roll(valid, sh, axis=a)))
    full = closed | ~jnp.asarray(valid)
    deep = closed
    for off in np.ndindex(*(3,) * dim):
        t = full
        for a in range(dim):
            if off[a] != 1:
                t = shift(t, off[a] - 1, a)
        deep = deep & t
    return deep


def cell_valid(scene: Scene) -> np.ndarray:
    """Static bool array of ``grid_shape``: cells that may hold fluid.  Cell k spans nodes
    k .. k + 1 on every axis; on a non-periodic axis the last index (which would wrap) is never
    valid, nor is a cell whose centre is outside the box, behind a plane wall or below terrain."""
    shape = scene.grid_shape
    axes = [scene.grid_origin[d] + scene.h * (np.arange(shape[d]) + 0.5) for d in range(scene.dim)]
    xc = np.stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")], axis=-1)
    ok = np.ones(len(xc), bool)
    for d in range(scene.dim):
        if not scene.periodic[d]:
            ok &= (xc[:, d] > scene.lo[d]) & (xc[:, d] < scene.hi[d])
    for wall in scene.walls:
        nrm = np.asarray(wall.normal, float)
        ok &= (xc - np.asarray(wall.point)) @ (nrm / np.linalg.norm(nrm)) > 0.0
    if scene.terrain is not None:
        ok &= xc[:, -1] > scene.terrain.height(xc[:, :-1])
    return ok.reshape(shape)


def condition_matrix(scene: Scene, linear_conditions) -> tuple[np.ndarray, bool]:
    """Static per-node Q = P P^T (N, dim, dim) of the walls' linear conditions, and whether every
    Q is diagonal (box walls only: then the solve scales each component instead of a matrix product)."""
    n, dim = scene.n_nodes, scene.dim
    with jax.ensure_compile_time_eval():
        cols = [np.asarray(linear_conditions(jnp.broadcast_to(jnp.eye(dim)[a], (n, dim)))) for a in range(dim)]
    Pm = np.stack(cols, axis=-1)  # P[:, :, a] = P e_a
    Q = np.einsum("nij,nkj->nik", Pm, Pm)
    diagonal = bool(np.all(np.abs(Q - np.einsum("nii->ni", Q)[:, :, None] * np.eye(dim)[None]) < 1e-12))
    return Q, diagonal


def make_projection(
    scene: Scene,
    linear_conditions,
    fill: np.ndarray,
    maxiter: int = CG_MAXITER,
    operator: str | None = None,
):
    """``project(v_star, mass, inv_m, has, params, p_prev=None, t=0.0, contact=None) -> (v, p, d, (A, b))``:
    the pressure step of the module docstring on the whole grid (flat node arrays (N,), (N, dim); p per
    cell, ``grid_shape``; d the position closure's displacement or None; A and b the solved system, for
    diagnostics).  ``p_prev``: the last step's pressure, the solve's start where it is not zero.

    ``contact(v_star, push) -> v_star``: the walls' conditions of a caller with Coulomb terrain, applied to
    v* before the solve; push = dt m^-1 B^T p_prev, the last step's pressure's velocity change, unprojected,
    which the friction resists as well (``_boundary.terrain_velocity``), as the explicit step's friction
    resists the particles' pressure of the step's start.

    ``linear_conditions(v) -> P v``: the walls' conditions, linear (``_step._linear_conditions``);
    ``fill``: the static ``_boundary.node_fill`` (N,).  ``operator``: how A is applied (``OPERATOR``, by
    dimension, when None); both forms are the same matrix (tests/test_pressure.py).
    """
    dim, h, shape = scene.dim, scene.h, tuple(scene.grid_shape)
    valid = cell_valid(scene)
    coef = (0.5 * h) ** (dim - 1)
    vol_c = h**dim
    rtol = CG_RTOL[scene.dtype]
    signs = [np.array(s) for s in np.ndindex(*(2,) * dim)]  # corners of a cell, as node offsets
    Q, diagonal = condition_matrix(scene, linear_conditions)
    _roll = _shifter(scene.periodic)
    Qg = Q.reshape(shape + (dim, dim))
    operator = OPERATOR[dim] if operator is None else operator
    if operator not in ("stencil", "products"):
        raise ValueError(f"operator {operator!r}; allowed: 'stencil', 'products'")

    def div(vs):
        """B v: nodal velocity components (dim arrays of grid_shape) -> cell volume rates."""
        out = 0.0
        for a in range(dim):
            t = _roll(vs[a], -1, a) - vs[a]
            for b in range(dim):
                if b != a:
                    t = t + _roll(t, -1, b)
            out = out + t
        return coef * out

    def grad(q):
        """B^T q: cell values (grid_shape) -> nodal force components (dim arrays)."""
        cols = []
        for a in range(dim):
            t = q
            for b in range(dim):
                if b != a:
                    t = t + _roll(t, 1, b)
            cols.append(coef * (_roll(t, 1, a) - t))
        return cols

    def at(t, o):
        """A grid field read at index + o (o in {-1, 0, 1}^dim): a cell field at the neighbour cell c + o,
        or a nodal field at cell c's corner node c + o (o in {0, 1}^dim), or a cell field at node i's
        cell i + o (o in {-1, 0}^dim)."""
        for a in range(dim):
            if o[a]:
                t = _roll(t, -int(o[a]), a)
        return t

    def corner_sum(g):
        """Sum over a cell's 2^d corner nodes of a nodal scalar (grid_shape)."""
        return sum(at(g, c) for c in signs)

    fill_c = _np_corner_sum(np.asarray(fill, float).reshape(shape), signs)  # static
    # the pressure's nodal force integrates over the valid cells with the bilinear functions, the node's mass
    # comes from the MPM kernel: the solve uses the lumped mass times q1 / fill_l (below; module docstring, "Near
    # walls and the free surface")
    q1 = sum(np.roll(valid.astype(float), tuple(int(x) for x in sg), axis=tuple(range(dim))) for sg in signs)
    q1 = q1 / len(signs)
    # behind a box wall, a node takes its mirror image's value (static): (the wall node) + (the wall node - node)
    wlo, whi = box_wall_nodes(scene)
    idx = np.indices(shape)
    for a in range(dim):
        if np.isfinite(wlo[a]):
            idx[a] = np.where(idx[a] < wlo[a], 2 * int(wlo[a]) - idx[a], idx[a])
        if np.isfinite(whi[a]):
            idx[a] = np.where(idx[a] > whi[a], 2 * int(whi[a]) - idx[a], idx[a])
        idx[a] = np.clip(idx[a], 0, shape[a] - 1)
    mirror = np.ravel_multi_index(tuple(idx), shape).reshape(-1)
    mirror = None if np.array_equal(mirror, np.arange(mirror.size)) else mirror
    # a cell whose every corner node the walls' conditions hold (Q = 0: no-slip nodes, a pipe's prescribed
    # velocity) has A's row and column zero: the pressure cannot move it.  As an unknown with a right-hand side (its
    # packing's excess, say) it breaks CG down: r there never falls and M r = 0, so r.z = 0 and the next step is
    # 0 / 0 (flume-deposition with the grid pressure: every particle NaN at t = 312.5 s, the pipe's cell against
    # the no-slip bed).  Such cells are no unknowns; for the free surface and the deep cells they count as walls
    q_zero = np.all(Q.reshape(shape + (dim * dim,)) == 0.0, axis=-1).astype(float)
    solved = valid & (_np_corner_sum(q_zero, signs) < len(signs))  # static
    # the nodes behind a box wall move with their mirror images, so their mass is lumped onto them (the extension's
    # transpose, below): a filled domain's lumped fill, set against q1.  For a symmetric kernel (GIMP, the quadratic
    # and cubic B-splines) the mirror lumping makes it q1 exactly (the quadratic B-spline's 47/48 + 1/48 = 1); the
    # boundary-modified splines put more than 1/2 on the wall node and none behind it, and keep a ratio
    fill_l = np.asarray(fill, float)
    if mirror is not None:
        fill_l = np.zeros_like(fill_l)
        np.add.at(fill_l, mirror, node_fill(scene, ghosts=True))
    fill_l = fill_l.reshape(shape)
    mass_ratio = np.where(q1 > 0.0, fill_l / np.where(q1 > 0.0, q1, 1.0), 1.0)
    # the lattice's row sums (``node_fill(ghosts=True)``) are exact to about 1e-7, not to round-off
    mass_ratio = np.where(np.abs(mass_ratio - 1.0) < 1e-6, 1.0, mass_ratio)
    ratio_is_one = bool(np.all(mass_ratio == 1.0))

    def corner_nodes(fluid):
        """The nodes that are a corner of a fluid cell (the nodes the pressure's force reaches)."""
        out = jnp.zeros_like(fluid)
        for sgn in signs:
            out = out | at(fluid, -sgn)
        return out

    _roll_lead = _shifter(scene.periodic, lead=1)  # a stack of grid fields

    def stencil(W, fluid, reg):
        """A as a 3^d-point stencil in difference form: (A q)_c = sum_{o != 0} C_o[c] (q[c + o] - q[c])
        + (r_c + reg_c) q[c].  A_{c,c+o} = C_o sums over the nodes i = c + s = c + o + s' the two cells
        share coef^2 (2s - 1)^T W_i (2s' - 1), zero unless both cells are fluid; r_c = sum_o A_{c,c+o}, the
        row sum, is formed as coef^2 sum_s (2s - 1)^T W_{c+s} n_{c+s} with n_i the sum of the corner signs
        of node i over its fluid cells: a whole number, zero in the interior, so r_c is exactly zero there
        (a row of plain coefficients cancels to zero only up to the rounding of its largest term, and in
        float32 that error grew with the depth of the fluid: 3x the products form's on a 20-cell layer at
        hydrostatic pressure).  ``reg``: the regularisation on the diagonal.  Returns ({o: C_o}, r + reg),
        both zero on the cells that are not fluid."""
        C = {}
        for s1 in signs:
            for s2 in signs:
                o = tuple(int(x) for x in s1 - s2)
                if not any(o):
                    continue
                g1, g2 = 2.0 * s1 - 1.0, 2.0 * s2 - 1.0
                if diagonal:
                    w = sum(float(g1[a] * g2[a]) * W[a] for a in range(dim))
                else:
                    w = sum(float(g1[a] * g2[b]) * W[a][b] for a in range(dim) for b in range(dim))
                C[o] = C.get(o, 0.0) + coef**2 * at(w, s1)
        dtp = (W[0] if diagonal else W[0][0]).dtype
        n = [sum(float(2 * s2[a] - 1) * at(fluid, -s2).astype(dtp) for s2 in signs) for a in range(dim)]
        if diagonal:
            wn = [W[a] * n[a] for a in range(dim)]
        else:
            wn = [sum(W[a][b] * n[b] for b in range(dim)) for a in range(dim)]
        r = coef**2 * sum(float(2 * s1[a] - 1) * at(wn[a], s1) for s1 in signs for a in range(dim))
        return {o: jnp.where(fluid & at(fluid, o), c, 0.0) for o, c in C.items()}, jnp.where(fluid, r + reg, 0.0)

    def rings(inside, dtp):
        """The extension's ``EXTEND_LAYERS`` rings out from the ``inside`` nodes: per ring (the nodes inside so
        far, the ring's new nodes, each node's count of inside face neighbours).  Formed once a step, for
        ``extend`` and its transpose ``lumped_mass``."""
        out = []
        for _ in range(EXTEND_LAYERS):
            cnt = sum(_roll(inside.astype(dtp), sh_, a) for a in range(dim) for sh_ in (-1, 1))
            new = ~inside & (cnt > 0.0)
            out.append((inside, new, jnp.where(new, cnt, 1.0)))
            inside = inside | new
        return out

    def extend(comps, ring_list, dtp):
        """Nodal components (dim arrays of grid_shape) -> (N, dim), carried from the inside nodes to the
        nodes next to them (``rings``: each new node takes the mean of its inside face neighbours), then to
        the nodes behind box walls from their mirror images (a static gather).  The components travel as one
        stacked array, one shift per neighbour."""
        for inside, new, cnt in ring_list:
            stacked = jnp.stack([inside.astype(dtp) * c for c in comps])
            acc = sum(_roll_lead(stacked, sh_, a) for a in range(dim) for sh_ in (-1, 1))
            comps = [jnp.where(new, acc[k] / cnt, c) for k, c in enumerate(comps)]
        out = jnp.stack([c.reshape(-1) for c in comps], axis=-1)
        return out if mirror is None else out[mirror]

    def lumped_mass(mass, ring_list):
        """E^T m, E the extension (``extend``, linear in the velocity): each node's mass plus the shares of the
        nodes that take their velocity change from it.  The pressure's force F moves that mass as one, so the
        momentum it adds is sum_i M_i dv_i = sum_i F_i, the force's own (the walls' reaction, nothing where there
        is no wall): with the particles' mass m alone, the extension added sum_j m_j (E dv)_j on top (a block
        sliding on a slip floor gained 0.07 % of its momentum every 0.05 s).  E = (mirror) (rings), so E^T
        lumps the nodes behind box walls onto their mirror images first (a scatter-add by the static map), then
        each ring's new node onto its inside face neighbours, 1/cnt each, the last ring first.  The static
        map stays a numpy array: a jax array made here would be a captured constant, which kept jax.jit of a
        run off its fast path (tests/test_engine.py::test_second_call_does_not_recompile)."""
        m = mass if mirror is None else jnp.zeros_like(mass).at[mirror].add(mass)
        m = m.reshape(shape)
        for inside, new, cnt in reversed(ring_list):
            share = jnp.where(new, m / cnt, 0.0)
            acc = sum(_roll(share, sh_, a) for a in range(dim) for sh_ in (-1, 1))
            m = jnp.where(inside, m + acc, jnp.where(new, 0.0, m))
        return m

    def project(v_star, mass, inv_m, has, params, p_prev=None, t=0.0, contact=None):
        dtp = v_star.dtype
        mat = params.material
        rho = mat.rho
        # packing per cell and the fluid cells
        phi = corner_sum(mass.reshape(shape)) / (rho * vol_c * jnp.asarray(np.maximum(fill_c, 1e-12), dtp))
        fluid = jnp.asarray(solved) & (phi >= FLUID_FRACTION)
        inside = corner_nodes(fluid)
        ring_list = rings(inside, dtp)
        # the mass the pressure moves: the node's own and that of the nodes it carries its velocity change to
        m_l = lumped_mass(jnp.where(has, mass, 0.0), ring_list)
        m_g = jnp.where(inside & (m_l > 0.0), 1.0 / jnp.where(m_l > 0.0, m_l, 1.0), inv_m.reshape(shape))
        if not ratio_is_one:
            m_g = m_g * jnp.asarray(mass_ratio, dtp)
        # S = m^-1 P P^T per node: per component (box walls) or a dim x dim product
        if diagonal:
            W = [m_g * jnp.asarray(Qg[..., a, a], dtp) for a in range(dim)]

            def S(fs):
                return [W[a] * fs[a] for a in range(dim)]
        else:
            W = [[m_g * jnp.asarray(Qg[..., a, b], dtp) for b in range(dim)] for a in range(dim)]

            def S(fs):
                return [sum(W[a][b] * fs[b] for b in range(dim)) for a in range(dim)]

        if contact is not None:
            # Coulomb contact: the friction resists the last step's pressure push as well, and acts before this
            # step's solve, so that the solved field keeps every cell's volume with the friction in it
            last = jnp.zeros(shape, dtp) if p_prev is None else jnp.where(fluid, p_prev, 0.0)
            push = extend([m_g * c for c in grad(last)], ring_list, dtp)
            v_star = contact(v_star, scene.dt * push)
        vs = [v_star[:, a].reshape(shape) for a in range(dim)]
        # the volume error: overpacking, corrected over the free-fall time across a cell, sqrt(h/|g|), not in
        # one step (the packing fluctuates by a few per cent as particles cross cells; a one-step correction
        # turns that into velocity noise, h/dt times the fluctuation)
        g_mag = jnp.sqrt(jnp.sum(params.gravity * params.gravity))
        rate = jnp.minimum(1.0, VOLUME_RELAXATION * scene.dt * jnp.sqrt(g_mag / h))
        excess = jnp.maximum(phi - 1.0, 0.0)
        if scene.void_closure == "velocity":
            # the deep cells' packing error both ways, outside a dead band (the packing's own fluctuation):
            # correcting only the overpacking is a ratchet that leaves the particles spread (step 4)
            err = phi - 1.0
            err = jnp.sign(err) * jnp.maximum(jnp.abs(err) - PACKING_DEAD_BAND, 0.0)
            excess = jnp.where(deep_cells(fluid, solved, scene.periodic), err, excess)
        excess = rate * excess
        b = jnp.where(fluid, (vol_c * excess / scene.dt - div(vs)) / scene.dt, 0.0)
        # no free surface anywhere (a full closed box): the volume can only be kept, not corrected, so the
        # system's mean is removed (with eps D, the pressure's level is then about zero on average)
        surface = jnp.zeros_like(fluid)
        for a in range(dim):
            for sh in (-1, 1):
                surface = surface | (fluid & ~_roll(fluid, sh, a) & jnp.asarray(np.roll(solved, sh, axis=a)))
        n_fluid = jnp.maximum(jnp.sum(fluid), 1)
        b = jnp.where(jnp.any(surface), b, jnp.where(fluid, b - jnp.sum(b) / n_fluid, 0.0))
        # Jacobi: diag(A)_c = sum over corners i of coef^2 s^T W_i s
        if diagonal:
            diag = coef**2 * corner_sum(sum(W))
        else:
            diag = 0.0
            for sgn in signs:
                sg = 2.0 * sgn - 1.0
                term = sum(float(sg[a] * sg[b]) * W[a][b] for a in range(dim) for b in range(dim))
                diag = diag + coef**2 * at(term, sgn)
        shift = REGULARISATION * diag
        diag = diag + shift
        # a fluid cell whose corner nodes move no mass (the held ones are out of ``solved``; here: nodes with Q != 0
        # but no mass, as float32 drops a near-empty node) has a zero row too: no right-hand side there either, or
        # CG breaks down as above
        b = jnp.where(diag > 0.0, b, 0.0)
        if operator == "stencil":
            C, r_diag = stencil(W, fluid, shift)

            def A(q):
                return sum(c * (at(q, o) - q) for o, c in C.items()) + r_diag * q

        else:

            def A(q):
                q = jnp.where(fluid, q, 0.0)
                return jnp.where(fluid, div(S(grad(q))) + shift * q, 0.0)

        inv_diag = jnp.where(fluid & (diag > 0.0), 1.0 / jnp.where(diag > 0.0, diag, 1.0), 0.0)
        # start: the last step's pressure, else hydrostatic (the fluid above along the last axis)
        col = jnp.where(fluid, phi, 0.0)
        above = jnp.flip(jnp.cumsum(jnp.flip(col, dim - 1), axis=dim - 1), dim - 1) - 0.5 * col
        p0 = jnp.where(fluid, rho * jnp.maximum(-params.gravity[-1], 0.0) * h * above, 0.0)
        if p_prev is not None:
            p0 = jnp.where(fluid & (p_prev != 0.0), p_prev, p0)
        p0 = jax.lax.stop_gradient(p0)

        def solve(rhs, x0):
            def cg(x_start):
                def run(matvec, b):
                    return jax.scipy.sparse.linalg.cg(
                        matvec, b, x0=x_start, tol=rtol, atol=0.0, maxiter=maxiter, M=lambda r: inv_diag * r
                    )[0]

                return run

            # the forward solve starts from the warm start x0; the transposed one (reverse mode) from zero.
            # jax's cg hands its x0 to the transposed solve too, where it has the scale of the pressure, not
            # of its cotangent: the float32 reverse-mode derivative then drowned in the residual left over
            # from it (dambreak-lab, h = 2 cm, 10 steps, d(centroid)/d mu0: -8.35e-7 or +4.67e-6 by XLA's
            # flags, against -9.276e-7 by forward mode and finite differences; now -9.276e-7)
            return jax.lax.custom_linear_solve(A, rhs, cg(x0), transpose_solve=cg(None), symmetric=True)

        if scene.void_closure != "position":
            p, q = solve(b, p0), None
        else:
            b_x = jnp.where(
                deep_cells(fluid, solved, scene.periodic) & (phi < 1.0 - PACKING_DEAD_BAND), (phi - 1.0) * vol_c, 0.0
            )
            b_x = jnp.minimum(1.0, POSITION_RELAXATION * POSITION_EVERY * scene.dt * jnp.sqrt(g_mag / h)) * b_x
            b_x = jnp.where(diag > 0.0, b_x, 0.0)
            p = solve(b, p0)
            if POSITION_EVERY == 1:
                q = solve(b_x, jnp.zeros_like(b_x))
            else:
                # every POSITION_EVERY-th step only, by that many steps' worth (a displacement, not a
                # velocity: applying it less often changes no rate); under vmap both branches run
                due = jnp.round(t / scene.dt).astype(jnp.int32) % POSITION_EVERY == 0
                q = jax.lax.cond(due, lambda r: solve(r, jnp.zeros_like(r)), jnp.zeros_like, b_x)
        p = jnp.where(fluid, p, 0.0)
        dv = extend(S(grad(p)), ring_list, dtp)
        # a mirror image's normal component is no wall's; with contact, neither is a ring node's (the mean of its
        # neighbours' corrections) at or below the terrain, which the friction after the solve would resist again
        if mirror is not None or contact is not None:
            dv = linear_conditions(dv)
        v = v_star + scene.dt * dv
        v = jnp.where(has[:, None], v, 0.0)
        if q is None:
            return v, p, None, (A, b)
        # the walls' conditions on the displacement too (a mirror image behind a no-slip wall is no displacement)
        d = linear_conditions(extend(S(grad(jnp.where(fluid, q, 0.0))), ring_list, dtp))
        return v, p, jnp.where(has[:, None], d, 0.0), (A, b)

    return project


def _np_corner_sum(g: np.ndarray, signs) -> np.ndarray:
    out = np.zeros_like(g, dtype=float)
    for s in signs:
        t = g
        for a in range(g.ndim):
            if s[a]:
                t = np.roll(t, -1, axis=a)
        out = out + t
    return out
