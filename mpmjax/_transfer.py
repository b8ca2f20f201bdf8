"""Particle-grid transfers: the stencil, P2G and the G2P gather.

* ``_Stencil``: per particle, the flat indices of the nodes its shape function reaches
  (tensor product of the 1-D kernels of ``_shapes``; periodic axes wrap the index, other
  axes clip it to the grid), their weights w_ip, weight gradients grad w_ip [1/m] and the
  node-minus-particle offsets r_ip [m].
* P2G (``make_p2g``): nodal mass, momentum (APIC affine or PIC/FLIP) and internal force
  f_i = -sum_p V_p sigma_p grad w_ip, with sigma = -p(J) I + tau (``_constitutive``) and
  V_p = V0 J; one scatter-add with all channels stacked.
* G2P (``make_g2p``): particle velocity (APIC or FLIP/PIC blend), affine matrix C and
  velocity gradient L from the nodal velocities.
* ``packing_fraction``: the grid-measured packing at each particle (the grid volume check,
  ``numerics.grid_density_cap``), with the wall correction ``_boundary.node_fill``.
* ``volume_increment`` and ``volume_average``: the J-bar (assumed-deformation-gradient)
  volume averaging of ``numerics.volume_averaging = "jbar"`` (Zhao, Jiang & Choo 2023), below.

J-bar volume averaging (``numerics.volume_averaging = "jbar"``)
----------------------------------------------------------------
Pressure from each particle's own J = det F locks a nearly incompressible material: with
ppc^dim particles per cell each holding its volume, the few nodal velocities per cell cannot
satisfy every particle's constraint, and the flow stiffens (Coombs et al. 2018; Zhao, Jiang &
Choo 2023, "Circumventing volumetric locking in explicit material point methods: a simple,
efficient, and general approach", IJNME).  The F-bar remedy replaces each particle's volume
change over the step by its average over the particles around it, through the same transfers:

1. the particle's volume increment over the step, delta_p = det(I + dt L_p) - 1 [-]
   (``volume_increment``: expanded as tr A + minors + det A with A = dt L, so a tiny
   increment is not lost to the rounding of det(I + A) near 1);
2. a mass-weighted nodal average (P2G with the stencil of the step, one scalar channel):
   delta_i = sum_p w_ip m_p delta_p / m_i, with m_i = sum_p w_ip m_p the nodal mass [kg; 2D kg/m]
   (empty nodes, and in float32 nodes below the step's empty-node floor, carry 0);
3. back to the particle, normalised by the weight of the nodes that hold mass:
   dbar_p = sum_i w_ip delta_i / sum_{i: m_i > 0} w_ip;
4. J_p <- J_p (1 + dbar_p), and the velocity gradient the stress update reads becomes that of
   the assumed increment F-bar = s (I + dt L), s = ((1 + dbar_p)/(1 + delta_p))^(1/dim):
   L-bar = s L + (s - 1)/dt I, so det(I + dt L-bar) = 1 + dbar_p; its deviator in 3D is s d',
   in 2D plane strain the out-of-plane part d'_zz = -tr(d-bar)/3 sees the averaged dilatation.

The average is over reference volume (m_p = rho V0_p, rho uniform), of the increment, not of J
itself: J keeps its history and a uniform field is returned unchanged (a filled box, walls
and ghost nodes included, gives back exactly each particle's delta since step 3 divides by the
weights actually used); a field linear in space is reproduced away from free surfaces.
Inactive particles (parked inflow pool, lost) have zero mass: they add nothing, and the step
keeps their J.  Periodic axes need nothing: the stencil's indices already wrap.

Nodes are numbered flat in C order over ``scene.grid_shape``; node i sits at
``grid_origin + index * h``.  Per-particle arrays have the leading axis n, stencil arrays
(n, S) with S = k^dim stencil nodes.  Inactive particles carry zero mass and volume.
Units SI; in 2D masses are per metre of depth (kg/m).
"""

from __future__ import annotations

import contextlib
import contextvars
import itertools

import jax
import jax.numpy as jnp
import numpy as np

from . import _shapes
from ._constitutive import tait_pressure
from ._fusion import GRID_SUMS, boundary, derivative_boundary, on_cpu, saved
from ._quadrature import make_correction
from ._scene import Params, Scene, State, box_wall_nodes
from ._shard import Replicated


# Small fixed-size contractions written as broadcast-multiply-sum: XLA:CPU lowers batched
# einsum/matmul over tiny (dim x dim) matrices to slow per-batch dot calls, while these fuse
# into the surrounding elementwise loops (measured: the P2G went from 629 to ~250 us per
# step on the default scene).  The matrix product ``_mm`` is in ``_constitutive``.
def _bmv(A, r):
    """(n, i, j) x (n, s, j) -> (n, s, i)."""
    d = A.shape[-1]
    return jnp.stack([sum(A[:, i, j][:, None] * r[:, :, j] for j in range(d)) for i in range(A.shape[1])], axis=-1)


def _wsum(w, v):
    """(n, s) x (n, s, i) -> (n, i)."""
    return jnp.stack([jnp.sum(w * v[:, :, i], axis=1) for i in range(v.shape[-1])], axis=-1)


def _outer_sum(a, b):
    """(n, s, i) x (n, s, j) -> (n, i, j)."""
    rows = [
        jnp.stack([jnp.sum(a[:, :, i] * b[:, :, j], axis=1) for j in range(b.shape[-1])], axis=-1)
        for i in range(a.shape[-1])
    ]
    return jnp.stack(rows, axis=1)


_FLAT = contextvars.ContextVar("mpmjax_flat_transfers", default=False)


@contextlib.contextmanager
def flat_transfers():
    """Steps traced inside this context scatter and gather by flat node indices, not by rows
    (``_Stencil``).  For ``vmap`` over tangents of one run (forward-mode Jacobians,
    ``calibration.fit.forward_jacobian``): there the indices are not batched, so the batch becomes part
    of each row's window, strided across the grid, and the row transfers cost more than the flat
    ones (the calibration twin's forward-mode gradient: 1.13x the time; docs/performance.md, "Row
    windows and saved residuals").  A trace-time choice, like the backend's: values are the same."""
    token = _FLAT.set(True)
    try:
        yield
    finally:
        _FLAT.reset(token)


class _Stencil:
    """Per-particle stencil data: node indices, weights, gradients and offsets.

    ``idx`` (n, S): flat global node indices (C order over the k^dim block of each particle).
    ``rows``: whether the transfers (``gather``, ``scatter``) read and write the grid by rows: the
    stencil is k^(dim-1) rows of k consecutive nodes along the last axis, and XLA:CPU scatters and
    gathers a whole row per index: its scatter alone is about 3x faster than with one node per index
    (docs/performance.md, "Row windows and saved residuals").  The grid is then seen with P = k - 1
    extra nodes at both ends of each line along the last axis; a row starting there is folded back
    onto the nodes the flat indices name (clipped, or wrapped on a periodic axis), so both layouts
    give the same sums.  Default: on the CPU only (the
    GPU path is the flat one, unmeasured with rows), and not inside ``flat_transfers()``.
    ``localise`` makes the indices those of a device's grid (``_shard.Replicated``, ``_slab.Slab``)
    before the transfers use them.
    """

    def __init__(self, scene: Scene, x, rows: bool | None = None):
        dim, h = scene.dim, scene.h
        xi = (x - jnp.asarray(scene.grid_origin, x.dtype)[None, :]) / h
        if scene.shape in _shapes.BOUNDARY_MODIFIED:
            wlo, whi = box_wall_nodes(scene)
            base, w1, dw1, mod = _shapes.boundary_modified_1d(scene.shape, xi, h, wlo[None, :], whi[None, :])
            # (n, dim): on which axes the particle sits close enough to a wall for its weights to be modified
            self.modified = mod
        else:
            base, w1, dw1 = _shapes.weights_1d(scene.shape, xi, h, scene.lp_cells)
            self.modified = None
        k = _shapes.STENCIL[scene.shape]
        n = x.shape[0]
        S = k**dim
        strides = np.cumprod((list(scene.grid_shape[1:]) + [1])[::-1])[::-1]
        full = (n,) + (k,) * dim

        def spread(a, d):
            """(n, k) per-axis values -> (n, S): stencil node s (C order over the k^dim block) takes
            the value of its index along axis d.  A broadcast, not a gather: XLA:CPU fuses it into
            its consumers, recomputing the values there."""
            return jnp.broadcast_to(a.reshape((n,) + tuple(k if e == d else 1 for e in range(dim))), full).reshape(n, S)

        offs = np.array(list(itertools.product(range(k), repeat=dim)), dtype=np.int32)  # (S, dim)
        gather = scene.shape in _shapes.PIECEWISE

        def weight(a, d):
            """``spread`` for 1-D weights; for the piecewise kinds a gather, which makes XLA compute
            them once instead of once per stencil node (docs/performance.md, "Stencil layout")."""
            return jnp.take(a, offs[:, d], axis=1) if gather else spread(a, d)

        idx = 0
        line = 0
        w = 1.0
        r = []
        for d in range(dim):
            node = base[:, d][:, None] + jnp.arange(k, dtype=jnp.int32)[None, :]  # (n, k)
            # node minus particle position, unwrapped [m]
            r.append(spread(node.astype(x.dtype) * h - (xi[:, d] * h)[:, None], d))
            if scene.periodic[d]:
                node = jnp.mod(node, scene.grid_shape[d])
            else:
                node = jnp.clip(node, 0, scene.grid_shape[d] - 1)
            idx = idx + spread(node * int(strides[d]), d)
            if d < dim - 1:  # the row's line: its flat index at last-axis index 0, (n, k^(dim-1))
                line = line + spread(node * int(strides[d]), d)[:, ::k]
        wd = [weight(w1[:, d, :], d) for d in range(dim)]
        for d in range(dim):
            w = w * wd[d]
        grads = []
        for d in range(dim):
            g = weight(dw1[:, d, :], d)
            for e in range(dim):
                if e != d:
                    g = g * wd[e]
            grads.append(g)
        self.idx = idx  # (n, S)
        self.w = w  # (n, S)
        self.dw = jnp.stack(grads, axis=-1)  # (n, S, dim)
        self.r = jnp.stack(r, axis=-1)  # (n, S, dim)
        self.S, self.k = S, k
        # rows: where the last axis's nodes base .. base + k - 1 sit in a line padded by P = k - 1 nodes at
        # both ends (a start in [0, n_last + P - 1]), and which line node p of the padded line stands for
        n_last, P = scene.grid_shape[-1], k - 1
        last = base[:, -1]
        if scene.periodic[-1]:
            last = jnp.mod(last, n_last)
            self._fold = np.mod(np.arange(n_last + 2 * P) - P, n_last)
        else:  # every node below 0 (above n_last - 1) clips to 0 (n_last - 1), as the flat indices do
            last = jnp.clip(last, -P, n_last - 1)
            self._fold = np.clip(np.arange(n_last + 2 * P) - P, 0, n_last - 1)
        small = scene.n_nodes // n_last * (n_last + 2 * P) < 2**31  # int32 indices of the padded grid's nodes
        self.rows = bool(on_cpu() and dim > 1 and small and not _FLAT.get()) if rows is None else rows
        self._line, self._start, self._n_last = line, (last + P)[:, None], n_last
        if self.rows:  # (n, k^(dim-1)): each row's first node in the padded grid, whole grid
            self._rows = self._padded(line // n_last)

    def _padded(self, lines):
        return lines * (self._n_last + 2 * (self.k - 1)) + self._start

    def localise(self, grid):
        """The indices of the grid layout ``grid`` holds (``grid.local``), formed once: not inside the
        channels' fusion and the scatter that read them (``_fusion.boundary``)."""
        if self.rows:
            self.idx = None  # the global flat indices no longer name this device's nodes
            self._rows = boundary(self._padded(grid.local(self._line) // self._n_last))
        else:
            self.idx = boundary(grid.local(self.idx))
        return self

    def gather(self, a):
        """Per-node ``a`` (N, ...) -> (n, S, ...): each particle's stencil nodes."""
        if not self.rows:
            return a[self.idx]
        k, n_last, n = self.k, self._n_last, self._rows.shape[0]
        tail = a.shape[1:]
        lines = a.reshape((-1, n_last) + tail)
        P = k - 1
        ends = [lines[:, i : i + 1] for i in self._fold]  # what each padded position stands for
        padded = jnp.concatenate(ends[:P] + [lines] + ends[P + n_last :], axis=1).reshape((-1,) + tail)
        dn = jax.lax.GatherDimensionNumbers(
            offset_dims=tuple(range(2, 3 + len(tail))), collapsed_slice_dims=(), start_index_map=(0,)
        )
        mode = jax.lax.GatherScatterMode.PROMISE_IN_BOUNDS
        out = jax.lax.gather(padded, self._rows[..., None], dn, (k,) + tail, mode=mode)
        return out.reshape((n, self.S) + tail)

    def scatter(self, vals, n_nodes: int):
        """grid (n_nodes, C) with grid[node] += vals[p, s] over each particle's stencil nodes (``vals``
        (n, S, C); the reference is ``scatter_add``)."""
        if not self.rows:
            return scatter_add(self.idx, vals, n_nodes)
        k, n_last, C = self.k, self._n_last, vals.shape[-1]
        P = k - 1
        n_lines = n_nodes // n_last
        g = jnp.zeros((n_lines * (n_last + 2 * P), C), vals.dtype)
        # a (k, C) window per row.  A flat (k C) window scatters 2x faster alone, but under vmap XLA:CPU
        # then forms the channels in a layout that costs a batch of 16 more than it saves (docs/performance.md,
        # "Row windows and saved residuals")
        dn = jax.lax.ScatterDimensionNumbers(
            update_window_dims=(1, 2), inserted_window_dims=(), scatter_dims_to_operand_dims=(0,)
        )
        mode = jax.lax.GatherScatterMode.PROMISE_IN_BOUNDS
        g = jax.lax.scatter_add(g, self._rows.reshape(-1, 1), vals.reshape(-1, k, C), dn, mode=mode)
        g = g.reshape(n_lines, n_last + 2 * P, C)
        out = g[:, P : P + n_last]
        for i in list(range(P)) + list(range(P + n_last, n_last + 2 * P)):  # the padding folded back
            t = int(self._fold[i])
            out = out.at[:, t].add(g[:, i])
        return out.reshape(n_nodes, C)


def first_plane(scene: Scene, x):
    """The first node plane along x (axis 0) of each particle's stencil (int32, (n,)), as
    ``_Stencil`` numbers it: the x index of its first node (the slab decomposition, ``_slab``,
    keeps a particle on the device whose slab holds it).  Not for a periodic x axis."""
    xi = (x[:, :1] - jnp.asarray(scene.grid_origin[:1], x.dtype)[None, :]) / scene.h
    if scene.shape in _shapes.BOUNDARY_MODIFIED:
        wlo, whi = box_wall_nodes(scene)
        base = _shapes.boundary_modified_1d(scene.shape, xi, scene.h, wlo[None, :1], whi[None, :1])[0]
    else:
        base = _shapes.weights_1d(scene.shape, xi, scene.h, scene.lp_cells)[0]
    return jnp.clip(base[:, 0], 0, scene.grid_shape[0] - 1)


def scatter_add(idx, vals, n_nodes: int):
    """The reference scatter: grid (n_nodes, C) with grid[idx[p, s]] += vals[p, s] (XLA's scatter-add).

    ``idx`` (n, S) flat node indices, ``vals`` (n, S, C).  On the CPU XLA runs the updates one at a
    time on one core (docs/performance.md, "P2G alternatives"); on the CPU the transfers scatter by
    rows instead (``_Stencil``)."""
    C = vals.shape[-1]
    grid = jnp.zeros((n_nodes, C), vals.dtype)
    return grid.at[idx.reshape(-1)].add(vals.reshape(-1, C))


def make_p2g(scene: Scene, axis: str | None = None, flat=None):
    """Returns ``p2g(state, params, grid=None) -> (mass (N,), momentum (N, dim), force (N, dim), stencil)``;
    with ``scene.force == "mls"`` the force is None (the stress impulse is in the momentum).

    ``grid``: the layout of the grid this device holds (``_shard.Replicated``, ``_slab.Slab``); the
    stencil's indices are made local to it and the partial sums reduced by it, so N is its node
    count.  Default: the whole grid, reduced over ``axis`` when given (inside ``shard_map`` over
    particles, ``_shard``, each device's partial grid is summed by ``psum``).
    ``flat(idx, vals, n_nodes) -> grid``: a scatter-add by flat node indices in place of the stencil's
    own (``_Stencil.scatter``; the alternatives measured in docs/performance.md, "P2G alternatives").
    """
    dim = scene.dim
    apic = scene.transfer == "apic"
    # numerics.force = "mls" (MLS-MPM, Hu et al. 2018): the stress enters as the impulse
    # -dt V sigma D^-1 (x_i - x_p) w_ip in the affine momentum, not as a force channel through grad w
    mls = scene.force == "mls"
    if mls:
        inv_d = 1.0 / (_shapes.APIC_D_FACTOR[scene.shape] * scene.h**2)

    whole = Replicated(scene.n_nodes, axis)
    # numerics.stress_quadrature = "corrected": the stress's smooth part integrated on the grid (_quadrature)
    correct = make_correction(scene) if scene.stress_quadrature == "corrected" and not mls else None

    def p2g(state: State, params: Params, grid=None):
        grid = whole if grid is None else grid
        mat = params.material
        st = _Stencil(scene, state.x, rows=False if flat else None).localise(grid)
        # under differentiation the weights, their gradients and the offsets are formed once (_fusion)
        st.w, st.dw, st.r = derivative_boundary((st.w, st.dw, st.r))
        mass_p = mat.rho * state.vol0 * state.active
        vol = state.vol0 * state.J * state.active
        if scene.pressure == "explicit":
            p = tait_pressure(state.J, mat.kappa)
            sigma = state.tau - p[:, None, None] * jnp.eye(dim, dtype=state.x.dtype)[None]
        else:  # the pressure is solved on the grid (_pressure)
            sigma = state.tau
        mw = mass_p[:, None] * st.w  # (n, S)
        f_smooth = None
        if correct is not None:

            def sums(vals):
                out = st.scatter(vals, grid.n_nodes) if flat is None else flat(st.idx, vals, grid.n_nodes)
                return derivative_boundary(grid.reduce(out))

            sigma, f_smooth = correct(sigma, mw, st, state.x, mat.rho, sums)
        if apic:
            vel = state.v[:, None, :] + _bmv(state.C, st.r)
        else:
            vel = jnp.broadcast_to(state.v[:, None, :], st.r.shape)
        mom = mw[..., None] * vel
        if mls:
            impulse = (-scene.dt * inv_d) * vol[:, None, None] * sigma
            mom = mom + st.w[..., None] * _bmv(impulse, st.r)
            chans = jnp.concatenate([mw[..., None], mom], axis=-1)  # (n, S, 1+dim)
        else:
            force = -vol[:, None, None] * _bmv(sigma, st.dw)
            chans = jnp.concatenate([mw[..., None], mom, force], axis=-1)  # (n, S, 1+2dim)
        # under differentiation the grid sums are formed once, and so is their cotangent in the reverse
        # pass before the transposed scatter gathers it (_fusion); the channels are not: with the grid
        # sums saved (below) a boundary on them cost the gradient 5-7 % (docs/performance.md, "Row windows")
        g = st.scatter(chans, grid.n_nodes) if flat is None else flat(st.idx, chans, grid.n_nodes)
        # in reverse mode the grid sums are kept, not recomputed (_fusion.saved, _simulate.make_chunk)
        g = saved(derivative_boundary(grid.reduce(g)), GRID_SUMS)
        if f_smooth is not None:
            return g[:, 0], g[:, 1 : 1 + dim], g[:, 1 + dim :] + f_smooth, st
        return g[:, 0], g[:, 1 : 1 + dim], (None if mls else g[:, 1 + dim :]), st

    return p2g


def make_g2p(scene: Scene):
    """Returns ``g2p(st, v_new, v_old, v) -> (v_pic, v_p, C, L)``: the gather from the nodes.

    ``st`` the particles' ``_Stencil``, ``v_new`` / ``v_old`` the nodal velocities (N, dim)
    after / before the grid update, ``v`` the particle velocities (n, dim) of the state.
    v_pic = sum_i w_ip v_i (the velocity that moves the particle); L = sum_i v_i (x) grad w_ip
    (with ``scene.force == "mls"``: L = C, MLS-MPM's velocity gradient);
    APIC: v_p = v_pic, C = B D^-1 for B-splines (D = ``APIC_D_FACTOR`` h^2 I), C = L for linear
    and GIMP; FLIP: v_p = blend (v + sum_i w_ip (v_new - v_old)_i) + (1 - blend) v_pic, C = 0.

    Boundary-modified B-splines: APIC's inertia D_p = sum_i w_ip r_ip r_ip^T is diagonal
    (tensor product, linear reproduction) but is h^2/4 (h^2/3) only away from walls; on an
    axis d where the particle's weights are modified (``st.modified``) D_p,dd falls to 0 at the
    wall, where B D_p^-1 is 0/0.  There column d of C is that of the velocity gradient L:
    for ``quadratic_bm`` this is exactly B D_p^-1 (the modified weights are the linear hat
    there: w_i r_i = D_p,dd dw_i), so C is continuous; for ``cubic_bm`` both are exact for
    affine velocity fields and differ by O(h |grad^2 v|) across the first cell's edge.
    """
    d_apic = _shapes.APIC_D_FACTOR.get(scene.shape)
    mls = scene.force == "mls"

    def g2p(st: _Stencil, v_new, v_old, v):
        vi = st.gather(v_new)  # (n, S, dim)
        v_pic = _wsum(st.w, vi)
        L = None if mls else _outer_sum(vi, st.dw)
        if scene.transfer == "apic":
            v_p = v_pic
            if d_apic is not None:
                B = _outer_sum(st.w[:, :, None] * vi, st.r)
                C = B / (d_apic * scene.h**2)
                if mls:  # MLS: the affine matrix is the velocity gradient
                    L = C
                elif st.modified is not None:
                    C = jnp.where(st.modified[:, None, :], L, C)
            else:
                C = L
        else:
            dv = _wsum(st.w, vi - st.gather(v_old))
            v_p = scene.flip_blend * (v + dv) + (1.0 - scene.flip_blend) * v_pic
            C = jnp.zeros_like(L)
        return v_pic, v_p, C, L

    return g2p


def packing_fraction(scene: Scene, mass, st, rho, fill):
    """phi at each particle: the reference volume packed around it, measured on the grid.

    Nodal phi_i = m_i / (rho h^d) (with m = rho V0 per particle: reference volume per node
    volume), interpolated to the particle with its own weights and divided by the same
    interpolation of ``fill`` (``_boundary.node_fill``), so that a domain filled at the seeding
    lattice gives exactly 1 at every particle, walls included, and 1/J where it is uniformly strained.
    """
    dtp = mass.dtype
    phi_node = mass / (rho * scene.h**scene.dim)
    phi_p = jnp.sum(st.w * st.gather(phi_node), axis=1)
    fill_p = jnp.sum(st.w * st.gather(jnp.asarray(fill, dtp)), axis=1)
    return phi_p / jnp.maximum(fill_p, 1e-6)


def volume_increment(L, dt):
    """delta = det(I + dt L) - 1 [-] per particle, without forming det(I + A) near 1.

    With A = dt L: 2D tr A + det A; 3D tr A + (sum of the principal 2x2 minors) + det A.
    """
    A = dt * L
    dim = A.shape[-1]
    if dim == 2:
        return A[:, 0, 0] + A[:, 1, 1] + (A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0])
    tr = A[:, 0, 0] + A[:, 1, 1] + A[:, 2, 2]
    minors = sum(A[:, i, i] * A[:, j, j] - A[:, i, j] * A[:, j, i] for i, j in ((0, 1), (0, 2), (1, 2)))
    return tr + minors + jnp.linalg.det(A)


def volume_average(scene: Scene, st: _Stencil, mass_p, q, inv_m, has, grid=None):
    """The mass-weighted average through the grid of the particle fields ``q`` (n, k) (J-bar).

    ``st`` the stencil of the step's P2G, ``mass_p`` (n,) the particle masses (0 when inactive),
    ``inv_m`` (N,) 1/m_i on the nodes that hold mass and 0 elsewhere, ``has`` (N,) bool those
    nodes.  Nodal q_i = sum_p w_ip m_p q_p / m_i; at the particle
    sum_i w_ip q_i / sum_{i: has} w_ip (the module docstring).  A particle none of whose
    nodes holds mass keeps its own q.  ``grid``: the layout of ``make_p2g`` that made ``st``
    (default: the whole grid on one device); the nodal sums are reduced by it.
    """
    grid = Replicated(scene.n_nodes) if grid is None else grid
    num = grid.reduce(st.scatter((mass_p[:, None] * st.w)[:, :, None] * q[:, None, :], grid.n_nodes))
    q_node = num * inv_m[:, None]
    wsum = jnp.sum(st.w * st.gather(has).astype(q.dtype), axis=1)
    ok = wsum > 0.0
    qbar = _wsum(st.w, st.gather(q_node)) / jnp.where(ok, wsum, 1.0)[:, None]
    return jnp.where(ok[:, None], qbar, q)
