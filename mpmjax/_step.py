"""The MPM step: ``make_step(scene) -> step(state, params) -> state``.

One explicit step (update-stress-last); the modules named do the work, ``make_step``
composes them:

0. (pipe inflow only) pool particles whose layer time falls in this step are switched on
   (``_boundary.make_release``);
1. stress from the state: sigma = -p(J) I + tau, with the Tait EOS (thesis eq. 3.11;
   ``_constitutive.tait_pressure``);
2. P2G (``_transfer.make_p2g``): nodal mass, momentum (APIC affine or PIC/FLIP) and internal
   force f_i = -sum_p V_p sigma_p grad w_ip; one scatter-add with all channels stacked;
3. grid update (here): v = p/m + dt (f/m + g) on the nodes that hold mass
   (``EMPTY_NODE_FRACTION``), then the boundary conditions of ``_boundary``: walls as planes
   (``apply_wall``; a noslip box face with ``boundary.slip_length_m`` > 0: ``navier_slip``),
   terrain (``terrain_velocity``), the pipe inlet's driven nodes (``pipe_nodes``); periodic axes
   wrap the stencil index (``_transfer._Stencil``); with ``numerics.pressure = "incompressible"``
   the particles carry no pressure (step 1 is tau alone) and here the grid pressure is solved and
   the velocity corrected (``_pressure``), then the conditions applied again;
4. G2P (``_transfer.make_g2p``): velocity (APIC or FLIP/PIC blend), affine matrix, velocity
   gradient; then here the position, particles pushed back out of walls and terrain (never
   silently clamped elsewhere) and wrapped on periodic axes;
5. particle update (here, with ``_constitutive``): J <- J det(I + dt L), or with
   ``numerics.volume_averaging = "jbar"`` J <- J (1 + dbar) and L <- L-bar, dbar the volume
   increment averaged through the grid (``_transfer.volume_increment``, ``volume_average``;
   formulas and references in the ``_transfer`` docstring) (with
   ``numerics.grid_density_cap``, then capped by the grid-measured packing,
   ``_transfer.packing_fraction`` with ``_boundary.node_fill``); rheology (structure,
   viscosity: ``_rheology``); shear measures and deviatoric stress by the Maxwell exponential
   update or the explicit law (``_constitutive.shear_measures``, ``deviatoric_update``);
6. loss detection (here): particles whose stencil leaves the grid, or whose state is not
   finite, are deactivated and counted in ``n_lost``.

The same code runs in 2D (plane strain) and 3D.  A scene with ``model.formulation =
"depth-averaged"`` gets the shallow-flow step of ``_shallow`` instead.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from . import _shapes
from ._boundary import (
    _wall_masks,
    along,
    apply_wall,
    make_release,
    navier_slip,
    navier_slip_neighbours,
    node_fill,
    pipe_nodes,
    terrain_velocity,
)
from ._cell_shear import make_cell_shear
from ._constitutive import deviatoric_update, shear_measures, shear_rate
from ._fusion import VELOCITY_GRADIENT, boundary, derivative_boundary, saved
from ._pressure import make_projection
from ._scene import Params, Scene, State, next_time
from ._shallow import make_shallow_step
from ._shard import AXIS, Replicated, shard_particles
from ._slab import make_slab_advance
from ._wall_yield import make_wall_yield
from ._transfer import _wsum, make_g2p, make_p2g, packing_fraction, volume_average, volume_increment

# nodal mass below this fraction of a full cell's mass counts as an empty node (see step())
EMPTY_NODE_FRACTION = 1e-9


def _linear_conditions(walls, terrain, t_mask, t_nrm, pipe):
    """The walls' conditions as a linear projection P (the pressure solve's, ``_pressure``):
    noslip and the pipe's driven nodes v = 0; every other wall and terrain kind removes the
    normal component (a slip wall's separation and a Navier wall's slip are the step's own, applied
    after the solve; Coulomb friction too, before it: ``_pressure.make_projection``'s ``contact``).
    ``t_mask``, ``t_nrm``: the terrain's nodes and normals as ``make_step`` has them; ``pipe``: the
    pipe's driven nodes or None."""

    def P(v):
        for mask, nrm, wall in walls:
            v = apply_wall(v, nrm, "noslip" if wall.kind == "noslip" and wall.slip_length <= 0.0 else "symmetry", mask)
        if terrain is not None:
            if terrain.kind == "noslip":
                v = jnp.where(t_mask[:, None], 0.0, v)
            else:
                n = jnp.asarray(t_nrm, v.dtype)
                v = jnp.where(t_mask[:, None], v - jnp.sum(v * n, axis=1)[:, None] * n, v)
        if pipe is not None:
            v = jnp.where(pipe[:, None], 0.0, v)
        return v

    return P


def _push_out(x, v_p, walls, terrain):
    """Particle-level walls: a particle behind a wall plane or below the terrain is pushed back onto
    it and loses its inward normal velocity.  Column by column over the normal's nonzero components
    only: a box face touches one column, so the walls' updates do not chain through every column
    (XLA would recompute the chain in each fusion that reads it)."""
    dim = x.shape[1]
    xs, vs = [x[:, a] for a in range(dim)], [v_p[:, a] for a in range(dim)]
    for _, nrm, wall in walls:
        axes = np.flatnonzero(nrm)
        phi = sum((xs[a] - float(wall.point[a])) * float(nrm[a]) for a in axes)
        vn = sum(vs[a] * float(nrm[a]) for a in axes)
        behind = phi < 0.0
        inward = behind & (vn < 0.0)
        for a in axes:
            xs[a] = jnp.where(behind, xs[a] - phi * float(nrm[a]), xs[a])
            vs[a] = jnp.where(inward, vs[a] - vn * float(nrm[a]), vs[a])
    x, v_p = jnp.stack(xs, axis=1), jnp.stack(vs, axis=1)
    if terrain is not None:
        zb = terrain.height(x[:, :-1], jnp)
        below = x[:, -1] < zb
        x = x.at[:, -1].set(jnp.where(below, zb, x[:, -1]))
        n_p = terrain.normal(x[:, :-1], jnp)
        vn = jnp.sum(v_p * n_p, axis=1)
        v_p = jnp.where((below & (vn < 0.0))[:, None], v_p - vn[:, None] * n_p, v_p)
    return x, v_p


def make_step(scene: Scene, axis: str | None = None):
    """Build the pure step function ``step(state, params) -> state`` for ``scene``.

    With ``scene.devices`` > 1 the step runs sharded over particles on that many devices
    (``_shard``; with ``numerics.decomposition = "slab"``, ``_slab``).  ``axis``: the mesh axis
    name when this step is the per-device body of ``shard_map``: the grid sums and the lost count
    are then reduced across it.  The per-device body takes a third argument, ``grid``: the layout
    of the grid the device holds (default ``_shard.Replicated``; ``_slab.Slab`` for a slab of it),
    through which every grid sum, nodal index and static per-node array goes.
    """
    if scene.formulation == "depth-averaged":  # model.formulation: the shallow-flow step (_shallow)
        return make_shallow_step(scene)
    if scene.devices > 1 and axis is None:
        if scene.decomposition == "slab":
            return make_slab_advance(scene, make_step(scene, AXIS), 1)
        return shard_particles(make_step(scene, AXIS), scene.devices)
    dim, dt = scene.dim, scene.dt
    walls = _wall_masks(scene)
    # Navier slip (boundary.slip_length_m): per wall, the index of each wall node's first interior node
    slip_nb = {i: navier_slip_neighbours(scene, m, nrm) for i, (m, nrm, w) in enumerate(walls) if w.slip_length > 0.0}
    p2g = make_p2g(scene, axis)
    g2p = make_g2p(scene)
    rheo = scene.rheology
    lo = np.asarray(scene.lo)
    span = np.asarray(scene.hi) - lo
    sup = _shapes.SUPPORT[scene.shape]
    safe_lo = np.asarray(scene.grid_origin) + (sup + 1e-3) * scene.h
    safe_hi = np.asarray(scene.grid_origin) + (np.asarray(scene.grid_shape) - 1 - sup - 1e-3) * scene.h
    per = np.asarray(scene.periodic)
    release = make_release(scene)
    inf = scene.inflow
    pipe = pipe_nodes(scene) if inf is not None else None
    terrain = scene.terrain
    if terrain is not None:
        xn = scene.node_positions()
        t_mask = xn[:, -1] <= terrain.height(xn[:, :-1]) + 1e-6 * scene.h
        t_nrm = terrain.normal(xn[:, :-1])

    cap = scene.grid_density_cap
    jbar = scene.volume_averaging == "jbar"
    if scene.volume_averaging not in ("none", "jbar"):
        raise ValueError(f"volume_averaging {scene.volume_averaging!r}; allowed: 'none', 'jbar'")
    fill = node_fill(scene) if cap > 0.0 else None
    project = None
    coulomb = False
    if scene.pressure != "explicit":
        if jbar or cap > 0.0:
            raise ValueError(
                f"numerics.pressure = {scene.pressure!r} takes numerics.volume_averaging = 'none' and "
                "numerics.grid_density_cap = 0 (the grid pressure keeps the volume itself)"
            )
        if scene.decomposition == "slab" and scene.devices > 1:
            raise ValueError(
                f"numerics.pressure = {scene.pressure!r} is not available with numerics.decomposition = 'slab'"
            )
        t_args = (t_mask, t_nrm) if terrain is not None else (None, None)
        # Coulomb terrain: the friction resists the pressure's normal push too (without it the base resisted
        # only its own nodes' weight: a block on a 20-degree slope at friction 0.5 slid at 1.3 m/s^2), the last
        # step's, before this step's solve (``contact`` below)
        linear = _linear_conditions(walls, terrain, *t_args, pipe)
        coulomb = terrain is not None and terrain.kind == "coulomb"
        project = make_projection(scene, linear, node_fill(scene))

    wall_material = make_wall_yield(scene, axis)  # numerics.wall_yield = "wall", else None
    cell_series = make_cell_shear(scene, axis)  # numerics.cell_shear = "series", else None

    m_empty = EMPTY_NODE_FRACTION * scene.h**dim if np.dtype(scene.dtype) == np.float32 else 0.0

    whole = Replicated(scene.n_nodes, axis)

    def step(state: State, params: Params, grid=None) -> State:
        grid = whole if grid is None else grid
        dtp = state.x.dtype
        state = release(state, params)
        mass, mom, force, st = p2g(state, params, grid)
        # float32 only: a node holding less than EMPTY_NODE_FRACTION (1e-9) of a full cell's mass
        # counts as empty.  GIMP/B-spline tails give edge nodes masses down to ~1e-20 kg; there
        # d(1/m)/dm = -1/m^2 overflows float32 and the reverse pass turns inf * 0 into NaN.  Such
        # a node's velocity reaches a particle with a weight of the same 1e-9 order: dambreak-lab
        # and bingham-dambreak give bit-identical float32 positions after 2 s with floors 0,
        # 1e-12, 1e-9 and 1e-6.  The floor does drop the momentum of those nodes (5e-9 relative
        # on the frictionless-incline test), so float64, where 1/m^2 cannot overflow, keeps the
        # exact floor 0 and its exact conservation.
        has = mass > m_empty * params.material.rho
        inv_m = jnp.where(has, 1.0 / jnp.where(has, mass, 1.0), 0.0)
        v_old = mom * inv_m[:, None]
        g = jnp.asarray(params.gravity, dtp)[None, :]
        accel = g if force is None else force * inv_m[:, None] + g  # force None: numerics.force = "mls"
        v_new = jnp.where(has[:, None], v_old + dt * accel, 0.0)

        def conditions(v_new, push=None):
            for i, (mask, nrm, wall) in enumerate(walls):
                if i in slip_nb:  # the first interior nodes as the walls before this one left them
                    inner = grid.local(grid.nodes(slip_nb[i]))
                    v_wall = navier_slip(v_new, nrm, v_new[inner], wall.slip_length / scene.h)
                    v_new = jnp.where(grid.nodes(mask)[:, None], v_wall, v_new)
                else:
                    v_new = apply_wall(v_new, nrm, wall.kind, grid.nodes(mask))
            if terrain is not None:
                v_t = terrain_velocity(v_new, grid.nodes(t_nrm), terrain, push)
                v_new = jnp.where(grid.nodes(t_mask)[:, None], v_t, v_new)
            if pipe is not None:
                on = (state.t >= inf.t_start) & (state.t < inf.t_stop)
                v_pipe = jnp.where(on, inf.speed, 0.0) * jnp.asarray(inf.direction, dtp)
                v_new = jnp.where(grid.nodes(pipe)[:, None] & has[:, None], v_pipe[None, :], v_new)
            return v_new

        p_cell = d_node = None
        if project is None:
            v_new = conditions(v_new)
        else:
            # numerics.pressure = "incompressible": the pressure solved on the grid (_pressure).  On Coulomb
            # terrain the conditions are applied inside it, before the solve, with the last step's pressure
            # push in the friction: applied after the solve with this step's, the friction left the base cells
            # a volume rate that the next solve answered, and a stiff block (G = 100 kPa) sliding at friction
            # 0.2 on a 20-degree slope grew a shear oscillation on its base until every particle was lost at
            # 0.2 s (docs/incompressible-default.md, "The fourth trial")
            contact = conditions if coulomb else None
            v_new = v_new if coulomb else conditions(v_new)
            v_new, p_cell, d_node, _ = project(v_new, mass, inv_m, has, params, state.p[0], state.t, contact)
            v_new = conditions(v_new)

        # G2P: the nodal velocity is formed once, not inside the gather for every stencil node it
        # reaches; under differentiation the G2P's results too, so the transposed per-particle
        # update is formed once, not for every gathered stencil entry (_fusion); in reverse mode the
        # velocity gradient is kept, not recomputed (_fusion.saved, _simulate.make_chunk)
        v_new = boundary(v_new)
        v_pic, v_p, C, L = derivative_boundary(g2p(st, v_new, v_old, state.v))
        L = saved(L, VELOCITY_GRADIENT)
        x = state.x + dt * v_pic
        if d_node is not None:  # the incompressible step's void closure: a displacement only (_pressure)
            x = x + _wsum(st.w, st.gather(d_node))

        x, v_p = _push_out(x, v_p, walls, terrain)
        if per.any():
            lo_ = jnp.asarray(lo, dtp)[None, :]
            wrapped = lo_ + jnp.mod(x - lo_, jnp.asarray(span, dtp)[None, :])
            x = jnp.where(jnp.asarray(per)[None, :], wrapped, x)

        # particle update: volume, rheology, stress
        if jbar:
            # J-bar (numerics.volume_averaging): the step's volume increment averaged over the
            # particles around, through the grid; L becomes that of the assumed increment
            # s (I + dt L), s = ((1 + dbar)/(1 + delta))^(1/dim), so det(I + dt L) = 1 + dbar.
            delta = volume_increment(L, dt)
            mass_p = params.material.rho * state.vol0 * state.active
            dbar = volume_average(scene, st, mass_p, delta[:, None], inv_m, has, grid)[:, 0]
            pos = (delta > -1.0) & (dbar > -1.0)
            ln_s = jnp.where(pos, jnp.log1p(jnp.where(pos, dbar, 0.0)) - jnp.log1p(jnp.where(pos, delta, 0.0)), 0.0)
            s_1 = jnp.expm1(ln_s / dim)[:, None, None]  # s - 1, accurate for s near 1
            L = L + s_1 * L + (s_1 / dt) * jnp.eye(dim, dtype=dtp)[None]
            J = state.J + state.J * dbar
        elif p_cell is not None:
            J = jnp.ones_like(state.J)  # numerics.pressure = "incompressible" (_pressure)
        else:
            J = state.J * jnp.linalg.det(jnp.eye(dim, dtype=dtp)[None] + dt * L)
        if fill is not None:
            # grid volume check (numerics.grid_density_cap): the reference volume packed around the
            # particle, measured on the grid (phi = nodal mass / (rho h^d), divided by the packing a
            # full domain would give there, so walls do not count as gaps).  A particle whose J says
            # it is less dense than that by more than the cap gets J = (1 + cap) / phi, so its
            # pressure sees gaps closed between particles that no velocity gradient registered.
            phi_p = packing_fraction(scene, mass, st, params.material.rho, grid.nodes(fill, dtp))
            J = jnp.minimum(J, (1.0 + cap) / jnp.maximum(phi_p, 1e-6))
        dprime, dd = shear_measures(L, dim)
        # under differentiation: the rheology's inputs and results formed once (_fusion)
        J, L, dprime, dd = derivative_boundary((J, L, dprime, dd))
        shear = shear_rate(dd, scene.shear_measure)
        gate = state.gate
        if scene.gate is not None:
            # only active particles pass the gate: an inactive one (a parked pool particle, a lost one)
            # keeps its state untouched, so a run that steps only a prefix of the buffer holding every
            # active particle (``_simulate.make_prefix_advance``) carries the rest exactly as this step would
            beyond = along(x - jnp.asarray(scene.gate.point, dtp)[None, :], scene.gate.normal) > 0.0
            gate = gate | (state.active & beyond)
        # numerics.wall_yield = "wall": the wall row's yield stress as if tested at the wall (_wall_yield)
        material = params.material if wall_material is None else wall_material(state, params.material, shear)
        if cell_series is not None:
            # numerics.cell_shear = "series": the cell's particles sheared in series across the bed (_cell_shear)
            shear, dprime, dd = cell_series(state, material, shear, dprime, dd)
        mu, internal = rheo.viscosity(material, shear, state.internal, dt, gate)
        tau = deviatoric_update(
            state.tau, L, dprime, mu, scene.maxwell_G, dt, scene.viscous_update, scene.maxwell_rotation
        )
        mu, internal, tau = derivative_boundary((mu, internal, tau))

        # loss detection: stencil outside the grid, or a non-finite state
        inside = jnp.all(per[None, :] | ((x >= safe_lo[None, :]) & (x <= safe_hi[None, :])), axis=1)
        finite = jnp.all(jnp.isfinite(x), axis=1) & jnp.all(jnp.isfinite(v_p), axis=1) & jnp.isfinite(J) & (J > 0)
        ok = inside & finite
        lost_now = state.active & ~ok
        n_lost_now = grid.total(jnp.sum(lost_now).astype(jnp.int32))
        active = state.active & ok

        def keep(new, old):
            a = active.reshape(active.shape + (1,) * (new.ndim - 1))
            return jnp.where(a, new, old)

        return State(
            x=keep(x, state.x),
            v=keep(v_p, jnp.zeros_like(state.v)),
            C=keep(C, jnp.zeros_like(state.C)),
            tau=keep(tau, jnp.zeros_like(state.tau)),
            J=keep(J, state.J),
            vol0=state.vol0,
            mu=keep(mu, state.mu),
            internal={k: keep(internal[k], state.internal[k]) for k in internal},
            active=active,
            gate=gate,
            t=next_time(state.t, dt),
            n_lost=state.n_lost + n_lost_now,
            p=None if p_cell is None else p_cell[None],
        )

    return step
