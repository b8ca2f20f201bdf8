"""The MPM step: ``make_step(scene) -> step(state, params) -> state``.

One explicit step (update-stress-last):

1. stress from the state: sigma = -p(J) I + tau, with the Tait EOS (thesis eq. 3.11);
2. P2G: nodal mass, momentum (APIC affine or PIC/FLIP) and internal force
   f_i = -sum_p V_p sigma_p grad w_ip; one scatter-add with all channels stacked;
3. grid update with gravity and boundary conditions (walls as planes, periodic axes
   by index wrapping);
4. G2P: velocity (APIC or FLIP/PIC blend), affine matrix, velocity gradient,
   position; particles pushed back out of walls (never silently clamped elsewhere);
   particles whose stencil leaves the grid, or whose state is not finite, are
   deactivated and counted in ``n_lost``;
5. particle update: J <- J det(I + dt L) (with ``numerics.grid_density_cap``, then capped by the
   grid-measured packing, see ``node_fill``); rheology (structure, viscosity);
   deviatoric stress by the Maxwell exponential update or the explicit law.

0. (pipe inflow only) pool particles whose layer time falls in this step are switched on;
   in step 3 the grid nodes inside the pipe get the pipe velocity (``pipe_nodes``);

The same code runs in 2D (plane strain) and 3D.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from . import _shapes
from ._constitutive import deviatoric_update, shear_measures, shear_rate
from ._scene import Params, Scene, State
from ._transfer import make_g2p, make_p2g, packing_fraction


def _wall_masks(scene: Scene):
    """Static per-wall node masks (n_nodes,) and unit normals."""
    xn = scene.node_positions()
    out = []
    for wall in scene.walls:
        nrm = np.asarray(wall.normal, float)
        nrm = nrm / np.linalg.norm(nrm)
        phi = (xn - np.asarray(wall.point)) @ nrm
        out.append((phi <= 1e-6 * scene.h, nrm, wall))
    return out


def apply_wall(v, nrm, kind):
    """Velocity after a wall condition: ``noslip`` v=0; ``slip`` remove inward normal
    velocity; ``symmetry`` remove all normal velocity.  ``nrm`` points into the fluid."""
    n = jnp.asarray(nrm, v.dtype)
    vn = v @ n
    n = n[None, :]
    if kind == "noslip":
        return jnp.zeros_like(v)
    if kind == "slip":
        return v - jnp.minimum(vn, 0.0)[:, None] * n
    if kind == "symmetry":
        return v - vn[:, None] * n
    raise ValueError(kind)


def terrain_velocity(v, nrm, terrain):
    """Nodal velocity after the terrain condition; ``nrm`` (N, dim) per-node unit normals."""
    if terrain.kind == "noslip":
        return jnp.zeros_like(v)
    n = jnp.asarray(nrm, v.dtype)
    vn = jnp.sum(v * n, axis=1)
    inward = jnp.minimum(vn, 0.0)
    v_s = v - inward[:, None] * n
    if terrain.kind == "slip":
        return v_s
    # coulomb: tangential speed reduced by friction x |removed normal speed|, at most to zero
    vt = v_s - jnp.sum(v_s * n, axis=1)[:, None] * n
    speed = jnp.sqrt(jnp.sum(vt * vt, axis=1))
    moving = speed > 0.0
    scale = jnp.where(moving, jnp.maximum(0.0, 1.0 - terrain.friction * (-inward) / jnp.where(moving, speed, 1.0)), 0.0)
    return v_s - (1.0 - scale)[:, None] * vt


def make_release(scene: Scene):
    """Returns ``release(state, params) -> state``: switches on the pipe-inflow layers due in
    this step (see ``_scene.Inflow``); the identity without an inflow.

    A pool particle is released in the step whose interval [t, t + dt) holds its layer
    time; the windows of consecutive steps tile the time axis, so each layer is released
    exactly once (as long as t + dt > t in the state's precision: use float64 for runs
    whose t / dt exceeds ~1e6).  Released particles start at rest in stress (J = 1,
    tau = 0, C = 0) with the rheology's initial internal state and, with an aging gate,
    have not yet passed it (material in the pipe does not age).
    """
    inf = scene.inflow
    if inf is None:
        return lambda state, params: state
    dt = scene.dt
    n_per = inf.n_per_layer

    def release(state: State, params: Params) -> State:
        dtp = state.x.dtype
        n = state.x.shape[0]
        rel = jnp.arange(n, dtype=jnp.int32) - inf.first
        in_pool = rel >= 0
        rel = jnp.maximum(rel, 0)
        k, j = rel // n_per, rel % n_per
        t_k = inf.t_start + k.astype(dtp) * inf.layer_dt
        due = in_pool & ~state.active & (t_k >= state.t) & (t_k < state.t + dt)
        d = jnp.asarray(inf.direction, dtp)
        back = 0.5 * inf.thickness + inf.speed * (t_k - state.t)
        pos = jnp.asarray(inf.point, dtp)[None, :] + jnp.asarray(inf.offsets, dtp)[j] - back[:, None] * d[None, :]
        dd = due[:, None]
        dm = due[:, None, None]
        init = scene.rheology.init_internal(params.material, n)
        return state._replace(
            x=jnp.where(dd, pos, state.x),
            v=jnp.where(dd, inf.speed * d[None, :], state.v),
            C=jnp.where(dm, 0.0, state.C),
            tau=jnp.where(dm, 0.0, state.tau),
            J=jnp.where(due, 1.0, state.J),
            internal={key: jnp.where(due, jnp.asarray(init[key], dtp), a) for key, a in state.internal.items()},
            active=state.active | due,
            gate=state.gate & ~due if scene.gate is not None else state.gate,
        )

    return release


def pipe_nodes(scene: Scene) -> np.ndarray:
    """Grid nodes inside the pipe (bool, n_nodes): behind the exit plane by at most
    ``inflow.pipe_length`` and within the cross-section (half-width max(width/2, h/2), so a
    pipe narrower than a cell still holds one row of nodes).  While the inflow runs these
    nodes move at the pipe velocity (a velocity inlet that pushes the released layers out
    against the material ahead); before and after it they are held at rest (a closed pipe).
    """
    inf = scene.inflow
    xn = scene.node_positions() - np.asarray(inf.point)[None, :]
    d = np.asarray(inf.direction)
    along = xn @ d
    lateral = np.linalg.norm(xn - along[:, None] * d[None, :], axis=1)
    tol = 1e-9 * scene.h
    half = max(inf.half_width, 0.5 * scene.h)
    return (along <= tol) & (along >= -inf.pipe_length - tol) & (lateral <= half + tol)


def node_fill(scene: Scene) -> np.ndarray:
    """Per node, the packing fraction phi it would measure with the whole domain filled at the
    seeding lattice (spacing 2 lp_cells cells, half a spacing off each wall): 1 in the interior,
    less where the kernel reaches through a wall.  phi = (1 - sum over the lattice sites beyond
    each wall of N(site - node) * spacing), multiplied over the walls (exact for box walls on
    different axes; inclined planes and terrain are not counted, so there phi is low and the
    grid volume check does not act).
    """
    xn = scene.node_positions()
    sp = 2.0 * scene.lp_cells
    reach = _shapes.SUPPORT[scene.shape] + 1.0
    s_k = (np.arange(int(np.ceil(reach / sp)) + 1) + 0.5) * sp  # sites beyond the wall, cells
    fill = np.ones(len(xn))
    for wall in scene.walls:
        nrm = np.asarray(wall.normal, float)
        nrm = nrm / np.linalg.norm(nrm)
        d = (xn - np.asarray(wall.point)) @ nrm / scene.h  # cells, positive inside
        r = -s_k[None, :] - d[:, None]  # site minus node
        with jax.ensure_compile_time_eval():  # a constant, also when make_step runs under a trace
            missing = np.asarray(_shapes.kernel_1d(scene.shape, jnp.asarray(r), scene.lp_cells)).sum(axis=1) * sp
        fill = fill * np.clip(1.0 - missing, 0.0, 1.0)
    return fill


# nodal mass below this fraction of a full cell's mass counts as an empty node (see step())
EMPTY_NODE_FRACTION = 1e-9


def make_step(scene: Scene):
    """Build the pure step function ``step(state, params) -> state`` for ``scene``."""
    dim, dt = scene.dim, scene.dt
    walls = _wall_masks(scene)
    p2g = make_p2g(scene)
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
    fill = node_fill(scene) if cap > 0.0 else None

    m_empty = EMPTY_NODE_FRACTION * scene.h**dim if np.dtype(scene.dtype) == np.float32 else 0.0

    def step(state: State, params: Params) -> State:
        dtp = state.x.dtype
        state = release(state, params)
        mass, mom, force, st = p2g(state, params)
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
        v_new = jnp.where(has[:, None], v_old + dt * (force * inv_m[:, None] + g), 0.0)
        for mask, nrm, wall in walls:
            v_new = jnp.where(jnp.asarray(mask)[:, None], apply_wall(v_new, nrm, wall.kind), v_new)
        if terrain is not None:
            v_new = jnp.where(jnp.asarray(t_mask)[:, None], terrain_velocity(v_new, t_nrm, terrain), v_new)
        if pipe is not None:
            on = (state.t >= inf.t_start) & (state.t < inf.t_stop)
            v_pipe = jnp.where(on, inf.speed, 0.0) * jnp.asarray(inf.direction, dtp)
            v_new = jnp.where(jnp.asarray(pipe)[:, None] & has[:, None], v_pipe[None, :], v_new)

        # G2P
        v_pic, v_p, C, L = g2p(st, v_new, v_old, state.v)
        x = state.x + dt * v_pic

        # particle-level walls: push back out, remove inward normal velocity
        for _, nrm, wall in walls:
            n_ = jnp.asarray(nrm, dtp)
            phi = (x - jnp.asarray(wall.point, dtp)[None, :]) @ n_
            behind = phi < 0.0
            x = jnp.where(behind[:, None], x - phi[:, None] * n_[None, :], x)
            vn = v_p @ n_
            v_p = jnp.where((behind & (vn < 0.0))[:, None], v_p - vn[:, None] * n_[None, :], v_p)
        if terrain is not None:
            zb = terrain.height(x[:, :-1], jnp)
            below = x[:, -1] < zb
            x = x.at[:, -1].set(jnp.where(below, zb, x[:, -1]))
            n_p = terrain.normal(x[:, :-1], jnp)
            vn = jnp.sum(v_p * n_p, axis=1)
            v_p = jnp.where((below & (vn < 0.0))[:, None], v_p - vn[:, None] * n_p, v_p)
        if per.any():
            lo_ = jnp.asarray(lo, dtp)[None, :]
            wrapped = lo_ + jnp.mod(x - lo_, jnp.asarray(span, dtp)[None, :])
            x = jnp.where(jnp.asarray(per)[None, :], wrapped, x)

        # particle update: volume, rheology, stress
        J = state.J * jnp.linalg.det(jnp.eye(dim, dtype=dtp)[None] + dt * L)
        if fill is not None:
            # grid volume check (numerics.grid_density_cap): the reference volume packed around the
            # particle, measured on the grid (phi = nodal mass / (rho h^d), divided by the packing a
            # full domain would give there, so walls do not count as gaps).  A particle whose J says
            # it is less dense than that by more than the cap gets J = (1 + cap) / phi, so its
            # pressure sees gaps closed between particles that no velocity gradient registered.
            phi_p = packing_fraction(scene, mass, st, params.material.rho, fill)
            J = jnp.minimum(J, (1.0 + cap) / jnp.maximum(phi_p, 1e-6))
        dprime, dd = shear_measures(L, dim)
        shear = shear_rate(dd, scene.shear_measure)
        gate = state.gate
        if scene.gate is not None:
            gn = jnp.asarray(scene.gate.normal, dtp)
            # only active particles pass the gate: an inactive one (a parked pool particle, a lost one)
            # keeps its state untouched, so a run that steps only a prefix of the buffer holding every
            # active particle (``_simulate.make_prefix_advance``) carries the rest exactly as this step would
            gate = gate | (state.active & ((x - jnp.asarray(scene.gate.point, dtp)[None, :]) @ gn > 0.0))
        mu, internal = rheo.viscosity(params.material, shear, state.internal, dt, gate)
        tau = deviatoric_update(state.tau, L, dprime, mu, scene.maxwell_G, dt, scene.viscous_update)

        # loss detection: stencil outside the grid, or a non-finite state
        inside = jnp.all(per[None, :] | ((x >= safe_lo[None, :]) & (x <= safe_hi[None, :])), axis=1)
        finite = jnp.all(jnp.isfinite(x), axis=1) & jnp.all(jnp.isfinite(v_p), axis=1) & jnp.isfinite(J) & (J > 0)
        ok = inside & finite
        lost_now = state.active & ~ok
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
            t=state.t + dt,
            n_lost=state.n_lost + jnp.sum(lost_now).astype(jnp.int32),
        )

    return step
