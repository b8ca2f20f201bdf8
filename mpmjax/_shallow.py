"""The depth-averaged (shallow-flow) MPM step, ``model.formulation = "depth-averaged"``:
``make_shallow_step(scene) -> step(state, params) -> state`` (``_step.make_step`` hands such a
scene here), and what ``_build`` needs to set one up (``columns``, ``time_step_limits``).

Particles are columns of material (Abe & Konagai 2016): plan position X (the first k = dim - 1
axes of ``state.x``), depth-averaged plan velocity u (``state.v[:, :k]``), volume V (``state.vol0``,
never changed: the mass rho V is carried, so it is conserved to round-off) and the law's internal
variables.  The grid is the scene's plan-view grid (the first k axes of its nodes: cell size h,
ghost layers and box faces as in the full step).  One step:

1. depth on the nodes: H_i = sum_p w_ip V_p / h^k [m], the vertical flow depth, >= 0 by
   construction (no negative depth, wet/dry fronts need no special case); mirrored across box walls
   (the material's image behind a slip wall), so a layer at rest against a wall stays level;
2. the driving forces: the hydrostatic pressure in the weak form of MPM, the nodal force
   f_i = sum_p (V_p / H_p) (rho g_n c_p^2 H_p^2 / 2) grad w_ip (the depth-integrated pressure
   rho g H^2 / 2 times the column's plan area V / H, H_p = sum_i w_ip H_i), which sums to zero over
   the nodes for every particle (momentum conserved, no self-force on a lone particle), and the
   body force of the bed's slope and the along-bed gravity at the particles,
   a_p = g_t - g_n c_p^2 grad z_b(X_p).  g_t: the plan components of the scene's gravity
   (``gravity.slope_deg`` tilts the bed: Savage & Hutter's bed-fitted frame on a plane), g_n: its
   vertical component; c^2 = 1 / (1 + |grad z_b|^2) = cos^2 of the terrain's slope: the bed-normal
   gravity g_n cos(theta) acting on the bed-normal depth H cos(theta) (so a block on a frictionless
   DEM plane slides with the exact g sin(theta) along it).  Integrated by parts, the two are
   -rho g_n c^2 H grad(z_b + H): a lake at rest has no net force up to the quadrature.  On a curved
   bed (``model.bed_curvature = "centrifugal"``, the default) g_n is the column's effective vertical
   gravity g_v = max(g_n + u.K.u, 0), K = grad grad z_b (the gradient of the nodes' slopes at the
   particle): the vertical acceleration of a column that follows the bed, as Savage-Hutter type
   models on curved beds carry it (a point mass on a frictionless bed z_b then moves as a bead on a
   wire; tests/test_depth_averaged_bed.py).  It enters the slope force, the pressure and the
   Coulomb part's normal stress (step 4).  With ``model.internal_friction_deg`` (a granular column on a
   Coulomb bed) the pressure is Savage & Hutter's k times the hydrostatic one, k active or passive by the
   sign of the column's velocity divergence tr(C_p) (``_earth_pressure``);
3. P2G (APIC): nodal mass, momentum sum_p w_ip m_p (u_p + C_p (x_i - X_p) + dt a_p) and the
   internal variables (mass-weighted); u* = momentum / mass;
4. basal shear on the nodes (``_basal``): tau_b = tau_0 + c U at the node's bed speed U and
   bed-normal depth h_n = H cos(theta), applied as |u| <- max(|u*| - dt tau_0 / (rho H), 0) /
   (1 + dt c' / (rho H)): the yield (and Coulomb) part tau_0 capped so that it can stop a node but
   never reverse it (a layer stays at rest while rho g_n H |grad(z_b + H)| c^2 <= tau_0 / ...,
   exactly: h = tau_y / (rho g sin(theta)) on an incline), the viscous part implicit (stable for
   any viscosity and depth); c' = c U / |u| turns the bed speed into the plan speed; with
   ``terrain.type = "voellmy"`` the Coulomb part mu sigma_n is in tau_0 and Voellmy's drag
   rho |g| U^2 / xi in c (c += rho |g| U / xi at the node's bed speed); then the box walls (slip,
   symmetry: no normal velocity; noslip: none);
5. G2P (APIC): u_p, C_p; X_p += dt u_p; particles behind a box wall are put back on it;
6. the law's internal variables advanced at the basal shear rate 3 U_p / h_n,p of the particle
   (``Law.viscosity``: for Coussot the exact exponential lambda update); ``state.mu``: the law's
   viscosity there.  With ``numerics.depth_layers`` = K > 1 the internal variables are (n, K), one
   value per layer across the depth, each advanced at its layer's own rate, and the nodes' closure
   takes the columns' mass-weighted fluidity F (scattered in step 3 instead of the variables) rather
   than the law at their mean (``_basal``, "layered"); ``state.mu`` is then 1 / (3 F), the Newtonian
   viscosity of the step's basal shear (the layers' viscosities before their update);
7. for the outputs, the stored vertical coordinate is the column's mid-depth z_b(X) + H(X) / 2
   and the vertical velocity u . grad z_b (the bed-following velocity), so result files, plan-view
   maps and hazard maps read a depth-averaged state as they read a 3-D one; J stays 1 and the
   deviatoric stress 0.

8. with ``numerics.split_levels`` > 0, columns sparser than the grid (H_p h^k < V_p: neighbours more
   than a cell away) are split into 2^k columns (``_split``), so that the grid resolves a thin tip.

Not here (docs/depth-averaged.md, "Missing"): the
earth-pressure coefficient of granular Savage-Hutter flows (the pressure is hydrostatic, K = 1),
extra planes, periodic faces, pipe inflow, the aging gate and device sharding.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import _basal, _earth_pressure, _shapes, _split
from ._scene import Params, Scene, State, box_wall_nodes, next_time

# nodal mass below this fraction of a full cell's mass (float32 only) counts as empty (as _step)
EMPTY_NODE_FRACTION = 1e-9
# shape functions whose APIC inertia is D = factor h^2 (the B-splines); with the others (linear,
# GIMP) the affine matrix is the velocity gradient, as in the full step
_APIC_D = _shapes.APIC_D_FACTOR


def plan_dims(scene: Scene) -> int:
    return scene.dim - 1


def _plan_grid(scene: Scene):
    k = plan_dims(scene)
    return np.asarray(scene.grid_origin[:k], float), tuple(int(n) for n in scene.grid_shape[:k])


def plan_nodes(scene: Scene) -> np.ndarray:
    """Plan positions (n_plan_nodes, k) [m] of the plan grid's nodes, C order."""
    origin, shape = _plan_grid(scene)
    axes = [origin[a] + scene.h * np.arange(shape[a]) for a in range(len(shape))]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=-1)


def bed(scene: Scene):
    """Bed elevation z_b [m] and its gradient (n, k) on the plan nodes (numpy): the terrain, or the
    domain floor (flat) without one."""
    xy = plan_nodes(scene)
    if scene.terrain is None:
        return np.full(len(xy), float(scene.lo[-1])), np.zeros_like(xy)
    n = scene.terrain.normal(xy)
    return scene.terrain.height(xy), -n[:, :-1] / n[:, -1:]


def bed_at(scene: Scene, xy, xp=np):
    """z_b [m] at plan positions ``xy`` (n, k)."""
    if scene.terrain is None:
        return xp.full(xy.shape[:1], float(scene.lo[-1]), dtype=xy.dtype)
    return scene.terrain.height(xy, xp)


def _mirror(scene: Scene):
    """Per plan axis, the box faces that are walls as (axis, wall node index): the depth is folded
    across them (step 1)."""
    lo, hi = box_wall_nodes(scene)
    out = []
    for a in range(plan_dims(scene)):
        for w in (lo[a], hi[a]):
            if np.isfinite(w):
                out.append((a, int(w)))
    return out


def _fold(V, shape, faces):
    """V (flat over the plan nodes) plus its mirror image across each wall face in ``faces``."""
    V = V.reshape(shape)
    for a, w in faces:
        n = shape[a]
        r = 2 * w - np.arange(n)
        ok = (r >= 0) & (r < n)
        img = jnp.take(V, np.clip(r, 0, n - 1), axis=a)
        m = ok.reshape([-1 if b == a else 1 for b in range(len(shape))])
        V = V + jnp.where(m, img, 0.0)
    return V.reshape(-1)


class _Stencil:
    """Plan-view stencil of every particle: flat node indices (n, S^k), weights (n, S^k), weight
    gradients (n, S^k, k) [1/m] and node offsets x_i - X_p (n, S^k, k) [m]."""

    def __init__(self, scene: Scene, xp):
        origin, shape = _plan_grid(scene)
        k = len(shape)
        S = _shapes.STENCIL[scene.shape]
        dt = xp.dtype
        xi = (xp - jnp.asarray(origin, dt)[None, :]) / scene.h
        base, w, dw = _shapes.weights_1d(scene.shape, xi, scene.h, scene.lp_cells)  # (n, k), (n, k, S)
        ar = jnp.arange(S, dtype=jnp.int32)
        idx = [jnp.clip(base[:, a, None] + ar[None, :], 0, shape[a] - 1) for a in range(k)]  # (n, S) per axis
        off = [(jnp.asarray(origin[a], dt) + idx[a].astype(dt) * scene.h) - xp[:, a, None] for a in range(k)]
        if k == 1:
            self.idx = idx[0]
            self.w = w[:, 0]
            self.dw = dw[:, 0][..., None]
            self.off = off[0][..., None]
        else:
            n = xp.shape[0]
            self.idx = (idx[0][:, :, None] * shape[1] + idx[1][:, None, :]).reshape(n, S * S)
            w0, w1, d0, d1 = w[:, 0, :, None], w[:, 1, None, :], dw[:, 0, :, None], dw[:, 1, None, :]
            self.w = (w0 * w1).reshape(n, S * S)
            self.dw = jnp.stack([(d0 * w1).reshape(n, S * S), (w0 * d1).reshape(n, S * S)], axis=-1)
            o0 = jnp.broadcast_to(off[0][:, :, None], (n, S, S)).reshape(n, S * S)
            o1 = jnp.broadcast_to(off[1][:, None, :], (n, S, S)).reshape(n, S * S)
            self.off = jnp.stack([o0, o1], axis=-1)

    def scatter(self, vals, n_nodes: int):
        """sum_p w_ip vals_p onto the nodes: vals (n, c) -> (n_nodes, c)."""
        contrib = self.w[:, :, None] * vals[:, None, :]
        out = jnp.zeros((n_nodes, vals.shape[1]), vals.dtype)
        return out.at[self.idx.reshape(-1)].add(contrib.reshape(-1, vals.shape[1]))

    def gather(self, a):
        """Nodal values a (n_nodes, ...) at the stencil: (n, S^k, ...)."""
        return a[self.idx]


def _safe_norm(u, axis=-1):
    """|u| with a finite derivative at u = 0 (0 there)."""
    q = jnp.sum(u * u, axis=axis)
    pos = q > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, q, 1.0)), 0.0)


def _basal_params(params: Params):
    """``params.basal``, which a depth-averaged scene on a coulomb or voellmy terrain needs (``make_params``)."""
    if params.basal is None:
        raise ValueError(
            "params.basal is None, but the scene's terrain is coulomb or voellmy: build the parameters with "
            "mpmjax.make_params (or set Params.basal = mpmjax.Basal(friction, turbulence))"
        )
    return params.basal


def make_shallow_step(scene: Scene):
    """The pure step ``step(state, params) -> state`` of a depth-averaged scene (module docstring)."""
    k = plan_dims(scene)
    dt, h = scene.dt, scene.h
    origin, shape = _plan_grid(scene)
    n_nodes = int(np.prod(shape))
    law = scene.rheology
    zb_np, grad_np = bed(scene)
    faces = _mirror(scene)
    terrain = scene.terrain
    kind = terrain.kind if terrain is not None else "none"
    # the Coulomb part and Voellmy's drag: static switches here, their coefficients traced (params.basal)
    frictional = kind in ("coulomb", "voellmy")
    voellmy = kind == "voellmy"
    # the bed's curvature term (step 2): only where the bed can be curved
    curved = scene.bed_curvature == "centrifugal" and terrain is not None
    # box walls on the plan axes: (axis, side, kind, node mask behind or on the wall)
    xn = plan_nodes(scene)
    walls = []
    for wall in scene.walls:
        nrm = np.asarray(wall.normal, float)
        a = int(np.argmax(np.abs(nrm)))
        if a >= k:
            continue
        mask = (xn[:, a] - wall.point[a]) * nrm[a] <= 1e-9 * h
        walls.append((a, float(wall.point[a]), float(nrm[a]), wall.kind, mask))
    sup = _shapes.SUPPORT[scene.shape]
    safe_lo = origin + (sup + 1e-3) * h
    safe_hi = origin + (np.asarray(shape) - 1 - sup - 1e-3) * h
    d_factor = _APIC_D.get(scene.shape)
    m_empty = EMPTY_NODE_FRACTION * h**k if np.dtype(scene.dtype) == np.float32 else 0.0
    names = law.internal_fields
    layered = scene.depth_layers > 1  # the internal variables in layers across the depth (``_basal.layered``)
    phi = scene.internal_friction_deg  # a granular column's earth pressure (``_earth_pressure``); None: k = 1
    # column splitting (``_split``): the children stay inside the box's walls and the grid's safe region
    split_lo, split_hi = safe_lo.copy(), safe_hi.copy()
    for ax, point, nrm, _, _ in walls:
        if nrm > 0:
            split_lo[ax] = max(split_lo[ax], point)
        else:
            split_hi[ax] = min(split_hi[ax], point)

    def step(state: State, params: Params) -> State:
        dtp = state.x.dtype
        mat = params.material
        rho = mat.rho
        zb = jnp.asarray(zb_np, dtp)
        gzb = jnp.asarray(grad_np, dtp)
        g_t = params.gravity[:k]
        g_n = -params.gravity[-1]
        X = state.x[:, :k]
        u = state.v[:, :k]
        C = state.C[:, :k, :k]
        act = state.active.astype(dtp)
        V = state.vol0 * act
        st = _Stencil(scene, X)

        # 1. depth on the nodes (volume / plan cell area), mirrored across walls
        Vn = st.scatter(V[:, None], n_nodes)[:, 0]
        H = _fold(Vn, shape, faces) / h**k

        # 2. driving forces: hydrostatic pressure in the weak form, the bed's slope and g_t at the particles
        grad_zb = jnp.sum(st.gather(zb)[..., None] * st.dw, axis=1)  # (n, k)
        c2 = 1.0 / (1.0 + jnp.sum(grad_zb * grad_zb, axis=1))
        H_p = jnp.sum(st.w * st.gather(H), axis=1)
        if curved:
            # the vertical acceleration of a column following the bed, u.K.u (K = grad grad z_b, the gradient of the
            # nodes' slopes), adds to the vertical gravity: g_v = g_n + u.K.u, never below zero (a column leaving a
            # convex bed presses on it with nothing)
            K = jnp.einsum("pna,pnb->pab", st.gather(gzb), st.dw)
            g_v = jnp.maximum(g_n + jnp.einsum("pa,pab,pb->p", u, 0.5 * (K + jnp.swapaxes(K, 1, 2)), u), 0.0)
        else:
            g_v = jnp.broadcast_to(g_n, c2.shape)
        a = g_t[None, :] - (g_v * c2)[:, None] * grad_zb
        m = rho * V
        push = 0.5 * g_v * c2 * m * H_p  # rho g_v c^2 V H / 2: the column's depth-integrated pressure x area
        if phi is not None:  # Savage & Hutter: k_act where the column extends (div u = tr C >= 0), k_pass else
            div_u = jnp.trace(C, axis1=1, axis2=2)
            k_p = _earth_pressure.per_column(phi, _basal_params(params).friction, div_u)
            grad_H = jnp.sum(st.gather(H)[..., None] * st.dw, axis=1)  # (n, k)
            a = a - ((k_p - 1.0) * g_v * c2)[:, None] * grad_H

        # 3. P2G: mass, momentum with the driving impulse, internal variables
        affine = jnp.einsum("pab,pnb->pna", C, st.off)  # C (x_i - X_p): (n, S^k, k)
        contrib = m[:, None, None] * st.w[..., None] * (u[:, None, :] + affine + dt * a[:, None, :])
        contrib = contrib + dt * push[:, None, None] * st.dw
        mom = jnp.zeros((n_nodes, k), dtp).at[st.idx.reshape(-1)].add(contrib.reshape(-1, k))
        if layered:  # the columns' fluidity F (``_basal.layered``) at their last speed, not the layers themselves
            U_last = _safe_norm(jnp.stack([_safe_norm(u), jnp.sum(u * grad_zb, axis=1)], axis=1))
            mu_k, F_p = _basal.layered(law, mat, U_last, jnp.maximum(H_p, 1e-12) * jnp.sqrt(c2), state.internal)
            chans = [m[:, None], (m * F_p)[:, None]]
        else:
            chans = [m[:, None]] + [(m * state.internal[nm])[:, None] for nm in names]
        normal_g = curved and frictional  # the nodes' bed-normal gravity from the particles' (Coulomb part)
        if normal_g:
            chans.append((m * g_v)[:, None])
        grid = st.scatter(jnp.concatenate(chans, axis=1), n_nodes)
        mass = grid[:, 0]
        has = mass > m_empty * rho
        inv_m = jnp.where(has, 1.0 / jnp.where(has, mass, 1.0), 0.0)
        u_star = mom * inv_m[:, None]
        if layered:  # a node without mass has no fluidity: 1 keeps c finite (its velocity is zeroed below)
            internal_n, fluidity_n = None, jnp.where(has, grid[:, 1] * inv_m, 1.0)
        else:
            internal_n, fluidity_n = {nm: grid[:, 1 + i] * inv_m for i, nm in enumerate(names)}, None
        g_vn = grid[:, -1] * inv_m if normal_g else g_n

        # 4. basal shear on the nodes: capped yield part, implicit viscous part
        speed = _safe_norm(u_star)
        slope_u = jnp.sum(u_star * gzb, axis=1)
        bed_speed = _safe_norm(jnp.concatenate([u_star, slope_u[:, None]], axis=1))  # finite derivative at rest
        cos_n = 1.0 / jnp.sqrt(1.0 + jnp.sum(gzb * gzb, axis=1))
        H_safe = jnp.where(has, jnp.maximum(H, 1e-12), 1.0)
        h_n = H_safe * cos_n
        sigma_n = rho * g_vn * cos_n * h_n  # bed-normal stress of the column [Pa] (Coulomb part)
        basal = _basal_params(params) if frictional else None
        mu_c = None if basal is None else basal.friction
        tau_0, c_bed, _ = _basal.closure(law, mat, bed_speed, h_n, internal_n, sigma_n, mu_c, fluidity_n)
        if voellmy:  # Voellmy's drag rho g U^2 / xi = c U, c = rho g U / xi (implicit like the rest)
            c_bed = c_bed + rho * jnp.sqrt(jnp.sum(params.gravity * params.gravity)) * bed_speed / basal.turbulence
        c_plan = c_bed * jnp.where(speed > 0, bed_speed / jnp.where(speed > 0, speed, 1.0), 1.0)
        inv_rh = 1.0 / (rho * H_safe)
        reduced = jnp.maximum(speed - dt * tau_0 * inv_rh, 0.0) / (1.0 + dt * c_plan * inv_rh)
        scale = jnp.where(speed > 0, reduced / jnp.where(speed > 0, speed, 1.0), 0.0)
        v_n = jnp.where(has[:, None], u_star * scale[:, None], 0.0)
        for ax, _, _, kind, mask in walls:
            if kind == "noslip":
                v_n = jnp.where(mask[:, None], 0.0, v_n)
            else:
                v_n = v_n.at[:, ax].set(jnp.where(mask, 0.0, v_n[:, ax]))

        # 5. G2P (APIC) and the move
        vg = st.gather(v_n)  # (n, S^k, k)
        u_new = jnp.sum(st.w[..., None] * vg, axis=1)
        if d_factor is not None:
            C_new = jnp.einsum("pn,pna,pnb->pab", st.w, vg, st.off) / (d_factor * h * h)
        else:
            C_new = jnp.einsum("pna,pnb->pab", vg, st.dw)
        X_new = X + dt * u_new
        for ax, point, nrm, _, _ in walls:
            behind = (X_new[:, ax] - point) * nrm < 0.0
            X_new = X_new.at[:, ax].set(jnp.where(behind, point, X_new[:, ax]))
            inward = behind & (u_new[:, ax] * nrm < 0.0)
            u_new = u_new.at[:, ax].set(jnp.where(inward, 0.0, u_new[:, ax]))

        # 6. the law's internal variables at the particle's basal shear rate
        cos_p = jnp.sqrt(c2)
        hn_p = jnp.maximum(H_p, 1e-12) * cos_p
        sp = _safe_norm(u_new)
        su = jnp.sum(u_new * grad_zb, axis=1)
        U_p = _safe_norm(jnp.stack([sp, su], axis=1))
        if layered:  # every layer at its own rate under the step's basal shear (``_basal.layer_rates``)
            rate = _basal.layer_rates(U_p, hn_p, mu_k, F_p)
            _, internal = law.viscosity(mat, rate, state.internal, dt, state.gate[:, None])
            _, _, mu = _basal.closure(law, mat, U_p, hn_p, None, fluidity=F_p)  # Newtonian mu of the step's shear
        else:
            rate = _basal.shear_rate(U_p, hn_p)
            _, internal = law.viscosity(mat, rate, state.internal, dt, state.gate)
            _, _, mu = _basal.closure(law, mat, U_p, hn_p, internal)

        # 7. the stored 3-D position and velocity; losses
        inside = jnp.all((X_new >= safe_lo[None, :]) & (X_new <= safe_hi[None, :]), axis=1)
        finite = jnp.all(jnp.isfinite(X_new), axis=1) & jnp.all(jnp.isfinite(u_new), axis=1)
        ok = inside & finite
        lost_now = state.active & ~ok
        active = state.active & ok
        Xs = jnp.clip(X_new, jnp.asarray(safe_lo, dtp)[None, :], jnp.asarray(safe_hi, dtp)[None, :])
        z = bed_at(scene, Xs, jnp) + 0.5 * H_p
        w_up = jnp.sum(u_new * grad_zb, axis=1)
        x3 = jnp.concatenate([X_new, z[:, None]], axis=1)
        v3 = jnp.concatenate([u_new, w_up[:, None]], axis=1)
        C3 = jnp.zeros_like(state.C).at[:, :k, :k].set(C_new)

        def keep(new, old):
            a_ = active.reshape(active.shape + (1,) * (new.ndim - 1))
            return jnp.where(a_, new, old)

        new = State(
            x=keep(x3, state.x),
            v=keep(v3, jnp.zeros_like(state.v)),
            C=keep(C3, jnp.zeros_like(state.C)),
            tau=state.tau,
            J=state.J,
            vol0=state.vol0,
            mu=keep(mu, state.mu),
            internal={nm: keep(internal[nm], state.internal[nm]) for nm in internal},
            active=active,
            gate=state.gate,
            t=next_time(state.t, dt),
            n_lost=state.n_lost + jnp.sum(lost_now).astype(jnp.int32),
            p=state.p,
        )
        if scene.split_levels > 0:
            new = _split.split(new, H_p, k=k, h=h, v_min=scene.split_min_volume, lo=split_lo, hi=split_hi)
        return new

    return step


# --------------------------------------------------------------------------------------------
# set-up (``_build``)
# --------------------------------------------------------------------------------------------


def columns(x: np.ndarray, vol0: np.ndarray, v: np.ndarray):
    """The seeded particles (n, dim) of bodies and release gathered into columns: one particle per
    distinct plan position, holding the column's volume, its volume-weighted mean velocity and
    mean elevation.  Returns (x, vol0, v) of the columns."""
    if not len(x):
        return x, vol0, v
    k = x.shape[1] - 1
    keys, inv = np.unique(x[:, :k], axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    vol = np.bincount(inv, weights=vol0, minlength=len(keys))
    out_x = np.zeros((len(keys), x.shape[1]))
    out_v = np.zeros((len(keys), x.shape[1]))
    out_x[:, :k] = keys
    out_x[:, k] = np.bincount(inv, weights=vol0 * x[:, k], minlength=len(keys)) / vol
    for a in range(x.shape[1]):
        out_v[:, a] = np.bincount(inv, weights=vol0 * v[:, a], minlength=len(keys)) / vol
    return out_x, vol, out_v


def max_depth(cfg: dict, x: np.ndarray, vol0: np.ndarray) -> float:
    """The largest flow depth [m] of the columns binned on cells of h (the depth the grid sees)."""
    k = cfg["domain.dim"] - 1
    h = cfg["domain.cell_size_m"]
    lo = np.asarray(cfg["domain.lo_m"][:k], float)
    idx = np.floor((x[:, :k] - lo) / h).astype(np.int64)
    key = idx[:, 0] if k == 1 else idx[:, 0] * (1 << 31) + idx[:, 1]
    _, inv = np.unique(key, return_inverse=True)
    return float(np.bincount(inv.reshape(-1), weights=vol0).max() / h**k) if len(x) else 0.0


def time_step_limits(cfg: dict, params: Params, x: np.ndarray, vol0: np.ndarray, v: np.ndarray, fall, rheology) -> dict:
    """The time step of a depth-averaged run [s], chosen before the scan, and its inputs:
    dt = cfl h / (c + U), c = sqrt(g_n H_max) the gravity-wave speed of the deepest column binned
    on the cells, U = the velocity scale (``numerics.velocity_scale_m_s``, or
    sqrt(4 g_n H_max + 2 g dZ) + the largest initial speed: the Ritter front speed 2 sqrt(g H) of the
    deepest column plus the speed of a fall dZ = ``fall`` [m], the drop from the highest bed point
    under the material to the lowest the material can reach); with ``model.internal_friction_deg`` g_n times the
    largest earth-pressure coefficient (``_earth_pressure.largest``).  The basal friction is implicit: no
    viscous limit (``dt_viscous_s`` = inf)."""
    g = np.asarray(params.gravity, float)
    g_n = float(-g[-1])
    gm = float(np.linalg.norm(g))
    phi = cfg["model.internal_friction_deg"]
    if phi is not None:  # a granular column's pressure, and so its wave speed, is at most Rankine's passive k times
        g_n *= _earth_pressure.largest(phi)
    h = float(cfg["domain.cell_size_m"])
    H = max_depth(cfg, x, vol0)
    c = math.sqrt(max(g_n, 0.0) * H)
    vscale = float(cfg["numerics.velocity_scale_m_s"])
    if vscale == 0.0:
        v0 = float(np.max(np.linalg.norm(v, axis=1), initial=0.0))
        vscale = math.sqrt(4.0 * max(g_n, 0.0) * H + 2.0 * gm * max(fall, 0.0)) + v0
    with np.errstate(all="ignore"):
        dt = float(np.float64(cfg["numerics.cfl"]) * h / (np.float64(c) + np.float64(vscale)))
    return {
        "dt_wave_s": dt,
        "dt_viscous_s": math.inf,
        "dt_limit_s": dt,
        "wave_speed_m_s": c,
        "velocity_scale_m_s": vscale,
        "maxwell_G_pa": 0.0,
        "mu_max_pa_s": float(rheology.max_viscosity(params.material)),
        "max_depth_m": H,
    }


def cell_depth_speed(scene: Scene, state: State, lo, shape, speed: bool = True):
    """Flow depth [m] and depth-averaged speed [m/s] on the cells [lo + i h, lo + (i + 1) h) of the
    plan (``shape`` cells per axis; flat, C order), from the step's own nodal fields: the depth H of
    ``plan_depth`` and the momentum sum_p w_ip V_p v_p on the plan nodes, each cell taking the mean of
    its 2^k corner nodes (speed: |mean momentum| / mean volume, all components of v; None without
    ``speed``).  The depth-averaged run's hazard maps and deposit thickness (``_hazard``,
    ``_metrics.RunoutGauge``): binned by particle position instead, the cells of field-breach-da's
    deposit scatter by 37-39 % (rms) about this depth, and its thickest cell read 12.5 or 15.5 m by
    float32 rounding alone where this reads 7.66 m both times (docs/depth-averaged.md)."""
    origin, gshape = _plan_grid(scene)
    k = len(gshape)
    st = _Stencil(scene, state.x[:, :k])
    V = state.vol0 * state.active.astype(state.x.dtype)
    n_nodes = int(np.prod(gshape))
    # one scatter for the volume and, with ``speed``, the momentum (XLA:CPU runs each scatter serially)
    sums = st.scatter(V[:, None] if not speed else jnp.concatenate([V[:, None], V[:, None] * state.v], axis=1), n_nodes)
    Vn = sums[:, 0]
    H = (_fold(Vn, gshape, _mirror(scene)) / scene.h**k).reshape(gshape)
    g = [int(round((lo[a] - origin[a]) / scene.h)) for a in range(k)]

    def corners(a):
        """Mean over each cell's 2^k corner nodes of the nodal field ``a``."""
        out = 0.0
        for c in np.ndindex(*(2,) * k):
            out = out + a[tuple(slice(g[i] + c[i], g[i] + c[i] + shape[i]) for i in range(k))]
        return out / 2**k

    depth = corners(H).reshape(-1)
    if not speed:
        return depth, None
    mom = corners(sums[:, 1:].reshape(gshape + (state.v.shape[1],)))
    vol = corners(Vn.reshape(gshape)).reshape(-1)
    m = mom.reshape(-1, state.v.shape[1])
    return depth, jnp.sqrt(jnp.sum(m * m, axis=1)) / jnp.where(vol > 0, vol, 1.0)


class _Fields(NamedTuple):
    """The particle fields ``cell_depth_speed`` reads."""

    x: jnp.ndarray
    vol0: jnp.ndarray
    active: jnp.ndarray
    v: jnp.ndarray | None


@functools.partial(jax.jit, static_argnums=0)
def _cell_depth(scene: Scene, x, vol0, active):
    k = plan_dims(scene)
    shape = tuple(int(round((scene.hi[a] - scene.lo[a]) / scene.h)) for a in range(k))
    st = _Fields(x=x, vol0=vol0, active=active, v=None)  # only the fields cell_depth_speed reads
    return cell_depth_speed(scene, st, tuple(scene.lo[:k]), shape, speed=False)[0].reshape(shape)


def cell_depth_map(scene: Scene, x, vol0, active) -> np.ndarray:
    """The depth [m] on every cell of the domain's plan, (n_x[, n_y]) (``cell_depth_speed``), from
    plan positions ``x`` (n, >= k), rest volumes and the active mask (numpy or jax)."""
    dt = np.dtype(scene.dtype)
    n = np.shape(active)[0]
    vol = jnp.broadcast_to(jnp.asarray(vol0, dt), (n,))
    return np.asarray(_cell_depth(scene, jnp.asarray(x, dt), vol, jnp.asarray(active, bool)), float)


def column_depth(scene: Scene, state: State):
    """Each column's depth H_p [m] as the step computes it from ``state`` (the nodal depth of ``plan_depth`` at the
    column): for the end-of-run check of column splitting (``mpmjax._driver.summary``)."""
    H, _ = plan_depth(scene, state)
    st = _Stencil(scene, state.x[:, : plan_dims(scene)])
    return jnp.sum(st.w * st.gather(H), axis=1)


def plan_depth(scene: Scene, state: State):
    """The flow depth H [m] on the plan nodes as the step sees it (step 1), and the nodes' plan
    positions (n_nodes, k) [m]: for validation and outputs."""
    origin, shape = _plan_grid(scene)
    st = _Stencil(scene, state.x[:, : plan_dims(scene)])
    V = state.vol0 * state.active.astype(state.x.dtype)
    Vn = st.scatter(V[:, None], int(np.prod(shape)))[:, 0]
    return _fold(Vn, shape, _mirror(scene)) / scene.h ** plan_dims(scene), plan_nodes(scene)
