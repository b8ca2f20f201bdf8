"""Boundary conditions on the grid: walls, terrain, the pipe inlet, and the wall-corrected packing.

* walls (``_scene.Wall``): planes whose normal points into the fluid; a node with
  (x - point).normal <= 1e-6 h takes the wall's condition (``_wall_masks``, ``apply_wall``:
  ``noslip``, ``slip`` or ``symmetry``; a noslip box face with a slip length takes the Navier
  partial-slip law, ``navier_slip``).  The box faces of those kinds and the extra planes
  are walls; periodic faces wrap the stencil index instead (``_transfer._Stencil``) and open
  faces have no condition.
* terrain (``_scene.Terrain``): a height map z_b; nodes with z <= z_b take ``noslip``,
  ``slip`` or ``coulomb`` with the local normal (``terrain_velocity``).
* pipe inlet (``_scene.Inflow``): ``inflow_layout`` is the geometry of the pool (cross-section
  offsets, area, layer count and layer time; scene validation checks the pool's size with it and
  the build seeds it); ``make_release`` switches on the pool particles whose layer time falls in
  the step; ``pipe_nodes`` are the nodes driven at the pipe velocity.
* ``node_fill``: per node, the packing fraction a domain filled at the seeding lattice would
  measure, less than 1 where the kernel reaches through a wall (for the boundary-modified
  B-splines, near every box wall: their modified functions hold less lattice weight).  It is a property of the
  walls (and of the kernel), used by the grid volume check (``_transfer.packing_fraction``).

Node masks, normals and fills are static numpy arrays of length n_nodes computed once per
scene (``scene.node_positions()``); velocities are nodal (N, dim) arrays [m/s].  Lengths [m],
times [s]; the last axis is vertical.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from . import _shapes
from ._scene import Params, Scene, State, box_wall_nodes, next_time


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


def along(a, nrm):
    """a . nrm per row, for a (m, dim) array and a static (numpy) direction ``nrm``: the sum over
    its nonzero components only, so a box face's normal reads one column.  XLA:CPU runs ``a @ n``
    as a separate matrix-vector call that no elementwise loop fuses (12 such calls were 12 of the
    mpm88 step's 87 thunks); this sum fuses with its neighbours."""
    nrm = np.asarray(nrm, float)
    terms = [a[:, k] * float(nrm[k]) for k in np.flatnonzero(nrm)]
    return sum(terms[1:], terms[0]) if terms else jnp.zeros(a.shape[:1], a.dtype)


def apply_wall(v, nrm, kind, on):
    """Velocity after a wall condition on the nodes ``on`` ((N,) bool; the rest unchanged):
    ``noslip`` v=0; ``slip`` remove inward normal velocity; ``symmetry`` remove all normal
    velocity.  ``nrm`` (static) points into the fluid.  Column by column: ``slip`` and
    ``symmetry`` change only the columns of the normal's nonzero components, so a box face's
    update does not make every column depend on every other (XLA:CPU would recompute the walls'
    chain in each fusion that reads it)."""
    if kind == "noslip":
        return jnp.where(on[:, None], 0.0, v)
    if kind not in ("slip", "symmetry"):
        raise ValueError(kind)
    cols = [v[:, a] for a in range(v.shape[1])]
    vn = along(v, nrm)
    if kind == "slip":
        vn = jnp.minimum(vn, 0.0)
    for a in np.flatnonzero(nrm):
        cols[a] = jnp.where(on, cols[a] - vn * float(nrm[a]), cols[a])
    return jnp.stack(cols, axis=1)


def navier_slip_neighbours(scene: Scene, mask: np.ndarray, nrm) -> np.ndarray:
    """Static (n_nodes,) index: for each node in the wall mask, the node one cell inside the
    fluid along the wall's normal ``nrm`` (the first interior node on the same grid line; the
    wall's face is on a node plane); every other node maps to itself.  Box faces only (``nrm``
    along an axis)."""
    a = int(np.argmax(np.abs(nrm)))
    idx = np.arange(scene.n_nodes).reshape(scene.grid_shape)
    xn = scene.node_positions()
    phi = np.round(((xn[:, a] - xn[:, a].min()) / scene.h)).astype(int).reshape(scene.grid_shape)
    out = idx.copy()
    m = mask.reshape(scene.grid_shape)
    sign = 1 if nrm[a] > 0 else -1
    # the wall's node plane and the one inside it
    wall_plane = np.max(phi[m]) if sign > 0 else np.min(phi[m])
    inner = np.take(idx, [wall_plane + sign], axis=a)  # shape with axis a of length 1
    out = np.where(m, np.broadcast_to(inner, idx.shape), idx)
    return out.ravel()


def navier_slip(v, nrm, v_inner, b_over_h: float):
    """Wall-node velocity under the Navier partial-slip law u_t = b du_t/dn with the gradient
    over the first cell, (u_1 - u_t) / h: u_t = u_1 b / (b + h), u_1 the tangential velocity of
    the first interior node (``v_inner``), and no normal velocity (no penetration, no
    separation, as ``noslip``).  b = 0 is no slip; b -> inf free slip.  ``b_over_h`` = b / h."""
    n = jnp.asarray(nrm, v.dtype)[None, :]
    vt = v_inner - along(v_inner, nrm)[:, None] * n
    return (b_over_h / (1.0 + b_over_h)) * vt


def _friction_scale(vt, inward, friction):
    """Coulomb: the factor on the tangential velocity ``vt`` that reduces its speed by friction x the removed
    normal speed |``inward``|, at most to zero."""
    s2 = jnp.sum(vt * vt, axis=1)
    moving = s2 > 0.0
    # the square root of the masked value: sqrt's derivative at a node at rest would be inf, and 0 * inf = NaN
    # in reverse mode (a grid pressure's push reaches nodes with no mass, unmasked)
    speed = jnp.sqrt(jnp.where(moving, s2, 1.0))
    return jnp.where(moving, jnp.maximum(0.0, 1.0 - friction * (-inward) / speed), 0.0)


def terrain_velocity(v, nrm, terrain, push=None):
    """Nodal velocity after the terrain condition; ``nrm`` (N, dim) per-node unit normals.

    ``push`` (N, dim), Coulomb only: a velocity change the node gets after this condition from a force the
    terrain resists too (the grid pressure's, the last step's: ``_pressure.make_projection``'s ``contact``).
    The friction then acts on v + push, the velocity the node is about to have, normal and tangential, and
    the push's tangential part is taken off again (the caller adds this step's); the normal is v's less its
    inward part, as for slip."""
    if terrain.kind == "noslip":
        return jnp.zeros_like(v)
    n = jnp.asarray(nrm, v.dtype)
    vn = jnp.sum(v * n, axis=1)
    inward = jnp.minimum(vn, 0.0)
    v_s = v - inward[:, None] * n
    if terrain.kind == "slip":
        return v_s
    if push is not None:
        u = v + push
        un = jnp.sum(u * n, axis=1)
        ut = u - un[:, None] * n
        pt = push - jnp.sum(push * n, axis=1)[:, None] * n
        scale = _friction_scale(ut, jnp.minimum(un, 0.0), terrain.friction)
        return scale[:, None] * ut - pt + jnp.maximum(vn, 0.0)[:, None] * n
    # coulomb: tangential speed reduced by friction x |removed normal speed|, at most to zero
    vt = v_s - jnp.sum(v_s * n, axis=1)[:, None] * n
    scale = _friction_scale(vt, inward, terrain.friction)
    return v_s - (1.0 - scale)[:, None] * vt


def make_release(scene: Scene):
    """Returns ``release(state, params) -> state``: switches on the pipe-inflow layers due in
    this step (see ``_scene.Inflow``); the identity without an inflow.

    A pool particle is released in the step whose interval [t, t + dt) holds its layer
    time; the windows of consecutive steps tile the time axis (each ends where the next
    begins, at ``_scene.next_time``), so each layer is released exactly once (as long as
    t + dt > t in the state's precision: use float64 for runs whose t / dt exceeds ~1e6).
    Released particles start at rest in stress (J = 1,
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
        due = in_pool & ~state.active & (t_k >= state.t) & (t_k < next_time(state.t, dt))
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


def node_fill(scene: Scene, ghosts: bool = False) -> np.ndarray:
    """Per node, the packing fraction phi it would measure with the whole domain filled at the
    seeding lattice (spacing 2 lp_cells cells, half a spacing off each wall): 1 in the interior,
    less where the kernel reaches through a wall.  phi = (1 - sum over the lattice sites beyond
    each wall of N(site - node) * spacing), multiplied over the walls (exact for box walls on
    different axes).  Inclined planes count as planes, and so does the terrain, as its tangent plane
    under the node (its height and normal there), so that the cells a height map cuts read the
    packing of the material above it, not a low one.  With the boundary-modified B-splines the box
    walls are counted exactly instead (``_fill_box_walls``), the extra planes as above.
    ``ghosts=True``: the box walls counted exactly for every shape, so that a node behind a box wall
    gets the fill a filled domain gives it (the formula above holds in front of a wall only);
    ``_pressure`` lumps those nodes onto their mirror images.
    """
    xn = scene.node_positions()
    sp = 2.0 * scene.lp_cells
    reach = _shapes.SUPPORT[scene.shape] + 1.0
    s_k = (np.arange(int(np.ceil(reach / sp)) + 1) + 0.5) * sp  # sites beyond the wall, cells
    fill = np.ones(len(xn))
    walls = scene.walls
    if scene.shape in _shapes.BOUNDARY_MODIFIED or ghosts:
        fill, walls = _fill_box_walls(scene, xn, sp, reach), _other_walls(scene)
    def beyond(d):
        """The fill a plane at signed distance ``d`` [cells] (positive inside) leaves a node."""
        r = -s_k[None, :] - d[:, None]  # site minus node
        with jax.ensure_compile_time_eval():  # a constant, also when make_step runs under a trace
            missing = np.asarray(_shapes.kernel_1d(scene.shape, jnp.asarray(r), scene.lp_cells)).sum(axis=1) * sp
        return np.clip(1.0 - missing, 0.0, 1.0)

    for wall in walls:
        nrm = np.asarray(wall.normal, float)
        nrm = nrm / np.linalg.norm(nrm)
        fill = fill * beyond((xn - np.asarray(wall.point)) @ nrm / scene.h)
    if scene.terrain is not None:
        xy = xn[:, :-1]
        # the distance to the tangent plane at the node's own column: (z - z_b) n_z
        fill = fill * beyond((xn[:, -1] - scene.terrain.height(xy)) * scene.terrain.normal(xy)[:, -1] / scene.h)
    return fill


def _other_walls(scene: Scene):
    """The walls that are not box walls (``_scene.box_wall_nodes``): extra planes."""
    lo, hi = box_wall_nodes(scene)
    out = []
    for wall in scene.walls:
        nrm = np.asarray(wall.normal, float)
        a = int(np.argmax(np.abs(nrm)))
        if np.count_nonzero(nrm) == 1:
            node = round((wall.point[a] - scene.grid_origin[a]) / scene.h)
            if (nrm[a] > 0 and lo[a] == node) or (nrm[a] < 0 and hi[a] == node):
                continue
        out.append(wall)
    return out


def _fill_box_walls(scene: Scene, xn, sp, reach):
    """``node_fill`` of the box walls for the boundary-modified B-splines: per axis with a box
    wall, the 1-D sum over a row of seeding-lattice sites of the modified weights times the
    spacing (the row stops half a spacing inside a wall face and runs on past a face that is no
    wall), multiplied over the axes.  Exact for the box (tensor-product weights)."""
    wlo, whi = box_wall_nodes(scene)
    fill = np.ones(len(xn))
    extra = int(np.ceil(reach / sp)) + 1
    for a in range(scene.dim):
        if not (np.isfinite(wlo[a]) or np.isfinite(whi[a])):
            continue
        f_lo = (scene.lo[a] - scene.grid_origin[a]) / scene.h
        n = int(round((scene.hi[a] - scene.lo[a]) / scene.h / sp))
        j = np.arange(-(0 if np.isfinite(wlo[a]) else extra), n + (0 if np.isfinite(whi[a]) else extra))
        sites = f_lo + (j + 0.5) * sp
        with jax.ensure_compile_time_eval():  # a constant, also when make_step runs under a trace
            base, w, _ = _shapes.weights_1d(scene.shape, jnp.asarray(sites), 1.0, scene.lp_cells, wlo[a], whi[a])
            base, w = np.asarray(base), np.asarray(w)
        k = w.shape[1]
        row = np.zeros(scene.grid_shape[a])
        np.add.at(row, np.clip(base[:, None] + np.arange(k)[None, :], 0, scene.grid_shape[a] - 1), w * sp)
        idx = np.round((xn[:, a] - scene.grid_origin[a]) / scene.h).astype(int)
        fill = fill * np.clip(row[idx], 0.0, 1.0)
    return fill


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
