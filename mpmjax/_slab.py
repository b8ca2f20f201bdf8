"""One simulation across devices by slabs: particles and grid both split along x, halos exchanged.

``numerics.decomposition = "slab"`` with ``numerics.devices = N > 1`` (``mpmjax run --devices N``):
the grid's node planes along x (axis 0) are cut into N slabs, one per device, and each particle
lives on the device whose slab holds the first node plane of its stencil
(``_transfer.first_plane``).  A device holds a window of the grid from its slab's first plane:
room for its slab's planes plus a halo of ``STENCIL - 1`` planes beyond its right edge (its
particles' stencils reach that far).  Per step (``Slab``, the grid layout the step
reads the grid through, ``_step.make_step``'s ``grid``):

1. P2G into the device's window;
2. the halo planes' partial sums sent to the right neighbour, which adds them to its first planes
   (``ppermute``), and those planes' whole sums sent back into the halo (``ppermute``), so every
   node a device's particles reach holds the whole sum; the same for J-bar's second grid sum;
3. the grid update, the G2P and the particle update on the device, as on one device (static
   per-node arrays, such as wall masks, terrain normals and the wall packing, are cut to the window);
4. migration (``_migrate``, run at the start of the next step, on the stored state): the particles
   whose first plane left the slab (at most one slab per step: the CFL limit keeps a step under one
   cell, and a slab is at least two planes wide) are packed into a buffer of ``SEND`` x the slots
   (``_rows``: one ``ppermute`` per direction) and sent to that neighbour, which puts them into free
   slots.

What crosses devices per step: 2 x ``STENCIL - 1`` node planes per grid sum and the migration
buffers, where the replicated layout (``_shard``) all-reduces the whole grid; 5 collectives per
step (7 with J-bar) against 2 (3): the lost count's sum over devices is the step's own.

Layout and balance.  Each device has ``capacity`` particle slots, ``numerics.slab_capacity``
(``scene.slab_capacity``) times an even share;
an empty slot is an inactive particle (no mass, so it adds exact zeros to the grid).  Every
``REBALANCE_STEPS`` steps (and at the start of every call) the particles are gathered into the
State's own order and dealt out again (``_distribute``, ``_collect``): the slab edges are re-chosen
so that each slab holds about as many active particles as the others,
and each particle's place in the State is kept by its index (``ids``), so frames, calibration and
``--resume`` see the same State as on one device.  Results equal one device's to float rounding:
the grid sums add the same terms in another order (tests/test_parallel_slab.py).

Limits, checked when the scene is built (``check``): no periodic x axis (the halo ring is not
built), no Navier slip on a wall whose normal is along x (its nodes read a neighbour plane that
may sit on another device), and at least ``W_MIN`` planes per device.  A device whose slots run
out (more particles crowd into its slab between rebalancings than its slots hold), or a
migration buffer that overflows, drops the particles that do not fit: they are counted in
``n_lost`` and keep their state from the last rebalancing, inactive, so the run reports them
(``mpmjax run``'s health check stops it, its hint naming ``numerics.slab_capacity``) rather
than carrying them on silently (a particle that jumps more than one slab in a step is
made inactive and counted too).  Pipe inflow is refused for every multi-device run (``_schema``).

Memory: a slab may be as wide as the grid less the other slabs' fewest planes (where the material
sits in a narrow band of x the slabs beyond it take the empty rest), so a device's window is
``nx - (N - 1) W_MIN + STENCIL - 1`` planes: about the whole grid.  Slabs replace the all-reduce of
the whole grid by halo exchange; they do not cut the grid memory per device.  A window bounded
below the grid would need slab edges that respect it, and then a dense band of material falls
on few devices and overflows their slots (measured with windows of 2 nx / N planes: dambreak-lab
on 3 and 4 devices lost a third of its particles at the default slots).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import PartitionSpec

from . import _shapes
from ._scene import Scene, State
from ._schema import SceneError
from ._shard import AXIS, particle_mesh
from ._transfer import first_plane

# the fewest planes a slab may have: two, so that a particle moving less than a cell per step
# crosses at most one slab edge, and no fewer than the halo, which must lie on one neighbour
W_MIN = 2
# particles that may cross one slab edge in one direction in one step, relative to a device's slots
# (at least SEND_MIN): a step moves particles less than a cell, so those crossing come from the one
# plane next to the edge
SEND, SEND_MIN = 0.25, 64
# steps between rebalancings (slab edges re-chosen, particles dealt out again)
REBALANCE_STEPS = 32


class Geometry(NamedTuple):
    """Static sizes of the decomposition: devices, node planes along x ``nx``, nodes per plane
    ``sx``, halo planes, the fewest and most planes a slab may own, the planes of a device's
    window (``w_max + halo``), the particle slots per device and the rows of a migration buffer."""

    n_dev: int
    nx: int
    sx: int
    halo: int
    w_min: int
    w_max: int
    planes: int
    capacity: int
    send: int


def geometry(scene: Scene, n_particles: int) -> Geometry:
    n_dev, nx = scene.devices, scene.grid_shape[0]
    sx = int(np.prod(scene.grid_shape[1:]))
    halo = _shapes.STENCIL[scene.shape] - 1
    w_min = max(W_MIN, halo)
    # a slab may be as wide as the others' fewest planes leave it: the edges balance particles, and
    # where the material sits in a narrow band of x the slabs beyond it must take the empty rest
    w_max = nx - (n_dev - 1) * w_min
    cap = min(n_particles, math.ceil(scene.slab_capacity * n_particles / n_dev))
    send = min(cap, max(SEND_MIN, math.ceil(SEND * cap)))
    return Geometry(n_dev, nx, sx, halo, w_min, w_max, w_max + halo, cap, send)


def check(scene: Scene) -> None:
    """Raise ``SceneError`` where the slab decomposition cannot run this scene (module docstring)."""
    if scene.devices < 2 or scene.decomposition != "slab":
        return
    if scene.periodic[0]:
        raise SceneError(
            "numerics.decomposition = 'slab' is invalid with a periodic x axis (the slabs' halo ring is not built); "
            "allowed: 'replicated'"
        )
    for w in scene.walls:
        nrm = np.asarray(w.normal, float)
        if w.slip_length > 0.0 and abs(nrm[0]) > 1e-12:
            raise SceneError(
                f"numerics.decomposition = 'slab' is invalid with a Navier slip wall facing along x (slip length "
                f"{w.slip_length} m, normal {tuple(w.normal)}): its nodes read the plane next to them, which may "
                "sit on another device; allowed: 'replicated', or slip_length_m = 0 on the x walls"
            )
    need = scene.devices * max(W_MIN, _shapes.STENCIL[scene.shape] - 1)
    if scene.grid_shape[0] < need:
        raise SceneError(
            f"numerics.devices = {scene.devices} is invalid with numerics.decomposition = 'slab' on a grid of "
            f"{scene.grid_shape[0]} node planes along x: each device needs at least "
            f"{need // scene.devices}; allowed range: 1 .. {scene.grid_shape[0] // (need // scene.devices)}"
        )


class Slab:
    """The grid layout of one device's slab (``_shard.Replicated`` has the same methods).

    ``lo``, ``hi``: the device's owned node planes [lo, hi) (traced: they move at every
    rebalancing).  The device holds ``geo.planes`` planes from ``lo`` on; planes [hi - lo,
    hi - lo + halo) of it are the right neighbour's first planes (the halo)."""

    def __init__(self, geo: Geometry, lo, hi):
        self.geo, self.lo, self.width = geo, lo, hi - lo
        self.n_nodes = geo.planes * geo.sx
        n = geo.n_dev
        self._right = [(d, d + 1) for d in range(n - 1)]
        self._left = [(d + 1, d) for d in range(n - 1)]

    def local(self, idx):
        return idx - self.lo * self.geo.sx

    def nodes(self, a, dtype=None):
        """The window's rows of a static per-node array (``scene.n_nodes`` rows, flat C order)."""
        g = self.geo
        a = np.asarray(a)
        rows = a.reshape((g.nx, g.sx) + a.shape[1:])
        rows = np.concatenate([rows, np.zeros((g.planes,) + rows.shape[1:], a.dtype)])  # no clamped slices
        win = jax.lax.dynamic_slice_in_dim(jnp.asarray(rows, dtype), self.lo, g.planes, axis=0)
        return win.reshape((self.n_nodes,) + a.shape[1:])

    def reduce(self, grid):
        """Partial grid sums -> whole sums on every plane a particle of this device reaches."""
        g, h = self.geo, self.geo.halo
        w = grid.reshape((g.planes, g.sx) + grid.shape[1:])
        halo = jax.lax.dynamic_slice_in_dim(w, self.width, h, axis=0)
        w = w.at[:h].add(jax.lax.ppermute(halo, AXIS, self._right))
        back = jax.lax.ppermute(w[:h], AXIS, self._left)
        w = jax.lax.dynamic_update_slice_in_dim(w, back, self.width, axis=0)
        return w.reshape(grid.shape)

    def total(self, x):
        return jax.lax.psum(x, AXIS)


def _particles(state: State):
    """The per-particle part of the State (time and lost count left out)."""
    return state._replace(t=None, n_lost=None)


def _edges(geo: Geometry, planes, weight):
    """Slab edges b_0 = 0 < b_1 < ... < b_N = nx (int32, (N + 1,)): slab d owns planes [b_d, b_d+1),
    each about an even share of ``weight`` (per particle, 0 or 1), within [w_min, w_max] planes."""
    n, nx = geo.n_dev, geo.nx
    cum = jnp.cumsum(jnp.zeros(nx, jnp.int32).at[planes].add(weight))
    total = cum[-1]
    b = [jnp.int32(0)]
    for d in range(1, n):
        share = (total // n) * d + ((total % n) * d) // n  # total * d // n without int32 overflow
        target = jnp.searchsorted(cum, share, side="left").astype(jnp.int32) + 1
        lo = jnp.maximum(b[-1] + geo.w_min, nx - (n - d) * geo.w_max)
        hi = jnp.minimum(b[-1] + geo.w_max, nx - (n - d) * geo.w_min)
        b.append(jnp.clip(target, lo, hi))
    b.append(jnp.int32(nx))
    return jnp.stack(b)


def _distribute(scene: Scene, geo: Geometry, state: State):
    """State (State order) -> (slab State of N x capacity slots, ids (N x capacity,), bounds (N, 2))."""
    n = state.x.shape[0]
    C, N = geo.capacity, geo.n_dev
    planes = first_plane(scene, state.x)
    b = _edges(geo, planes, state.active.astype(jnp.int32))  # balance the particles that move
    dev = jnp.sum(planes[:, None] >= b[None, 1:N], axis=1).astype(jnp.int32)
    # by device, and within a device the active particles first: an inactive one (lost) gets a slot
    # only where one is left
    order = jnp.lexsort((~state.active, dev))
    dev_s = dev[order]
    start = jnp.searchsorted(dev_s, jnp.arange(N, dtype=jnp.int32), side="left")
    rank = jnp.arange(n, dtype=jnp.int32) - start[dev_s]
    slot = jnp.where(rank < C, dev_s * C + rank, N * C)  # N * C: no slot left (dropped, counted in _collect)

    def deal(a):
        empty = jnp.broadcast_to(a[:1], (N * C,) + a.shape[1:])  # empty slots copy a real particle: finite
        return empty.at[slot].set(a[order], mode="drop")

    slabs = jax.tree_util.tree_map(deal, _particles(state))
    slabs = slabs._replace(active=jnp.zeros(N * C, bool).at[slot].set(state.active[order], mode="drop"))
    ids = jnp.full(N * C, -1, jnp.int32).at[slot].set(order.astype(jnp.int32), mode="drop")
    return slabs._replace(t=state.t, n_lost=state.n_lost), ids, jnp.stack([b[:-1], b[1:]], axis=1)


def _collect(state0: State, slabs: State, ids):
    """Back to the State's order: each particle from its slot; one that has none (dropped for
    want of slots) keeps its ``state0`` entry, inactive, and counts as lost if it was active."""
    n = state0.x.shape[0]
    tgt = jnp.where(ids >= 0, ids, n)
    out = jax.tree_util.tree_map(lambda a0, a: a0.at[tgt].set(a, mode="drop"), _particles(state0), _particles(slabs))
    present = jnp.zeros(n, bool).at[tgt].set(True, mode="drop")
    dropped = jnp.sum(state0.active & ~present).astype(jnp.int32)
    return out._replace(active=out.active & present, t=slabs.t, n_lost=slabs.n_lost + dropped)


def _nth_true(mask, size: int):
    """Indices of the first ``size`` True entries of ``mask`` in order, ``len(mask)`` past the last one.
    A binary search per entry in the running count: gathers only (XLA:CPU runs a scatter, which
    ``jnp.nonzero`` uses, one element at a time)."""
    count = jnp.cumsum(mask.astype(jnp.int32))
    return jnp.searchsorted(count, jnp.arange(1, size + 1, dtype=jnp.int32), side="left").astype(jnp.int32)


def _rows(tree, n_ids: int):
    """The leaves of a per-particle pytree (leading axis n) as few arrays: the floats (n, K) in
    their own dtype, and the integers and flags (n, L) (bools widened), so that a migration sends
    one or two buffers, not one per leaf: each collective costs a rendezvous of the devices
    (measured on XLA:CPU: 50-130 us).  The floats stay floats, so derivatives pass (a bitcast has
    none).  Where the float dtype holds every integer exactly (ids below ``n_ids`` and node planes
    under 2^24 in float32, 2^53 in float64) the integers ride in the float buffer: one buffer."""
    fl, il = [], []
    for a in jax.tree_util.tree_leaves(tree):
        a2 = a.reshape(a.shape[0], -1)
        (fl if jnp.issubdtype(a.dtype, jnp.floating) else il).append(a2)
    dt = fl[0].dtype
    if max(n_ids, 2**16) < 2 ** (jnp.finfo(dt).nmant + 1):
        return (jnp.concatenate(fl + [a.astype(dt) for a in il], axis=1),)
    return jnp.concatenate(fl, axis=1), jnp.concatenate([a.astype(jnp.int32) for a in il], axis=1)


def _unrows(bufs, like):
    """Inverse of ``_rows``: its buffers (m rows each) back into a pytree shaped as ``like``."""
    leaves, tdef = jax.tree_util.tree_flatten(like)
    width = [int(np.prod(a.shape[1:], dtype=int)) for a in leaves]
    is_float = [bool(jnp.issubdtype(a.dtype, jnp.floating)) for a in leaves]
    kf = sum(w for w, f in zip(width, is_float) if f)
    cols = {True: bufs[0][:, :kf], False: bufs[1] if len(bufs) > 1 else jnp.round(bufs[0][:, kf:]).astype(jnp.int32)}
    at = {True: 0, False: 0}
    out = []
    for a, w, f in zip(leaves, width, is_float):
        out.append(cols[f][:, at[f] : at[f] + w].reshape((-1,) + a.shape[1:]).astype(a.dtype))
        at[f] += w
    return jax.tree_util.tree_unflatten(tdef, out)


def _migrate(scene: Scene, geo: Geometry, state: State, ids, lo, hi):
    """Send the active particles whose first plane left [lo, hi) to the neighbour slab; put the
    ones received into free slots.  Inside ``shard_map``: arrays are this device's slots.

    Each direction sends a buffer of ``geo.send`` rows: the leavers gathered to its front, the
    rest marked empty.  A leaver that does not fit (more than ``send`` particles crossing one
    slab edge in one step) or that finds no free slot on the other side is dropped: it leaves
    no id behind, and ``_collect`` counts it as lost.  All moves are gathers."""
    C, N, M = geo.capacity, geo.n_dev, geo.send
    planes = first_plane(scene, state.x)
    left = state.active & (planes < lo)
    right = state.active & (planes >= hi)
    parts = (_particles(state), ids, planes)

    rows = _rows((parts, jnp.ones(C, bool)), N * C)

    def pack(mask):
        sel = _nth_true(mask, M)
        keep = (sel < C)[:, None]
        return tuple(jnp.where(keep, jnp.take(r, jnp.minimum(sel, C - 1), axis=0), 0) for r in rows)

    from_right = jax.lax.ppermute(pack(left), AXIS, [(d + 1, d) for d in range(N - 1)])
    from_left = jax.lax.ppermute(pack(right), AXIS, [(d, d + 1) for d in range(N - 1)])
    both = [jnp.concatenate([a, b]) for a, b in zip(from_right, from_left)]
    (p_in, ids_in, planes_in), inc = _unrows(both, (parts, jnp.ones(C, bool)))
    gone = left | right
    ids = jnp.where(gone, -1, ids)
    free = ids < 0
    # slot j, the r-th free slot, takes the r-th valid incoming row
    r = jnp.cumsum(free.astype(jnp.int32)) - 1
    src = _nth_true(inc, 2 * M)  # 2M: no such row
    take = free & (r < 2 * M)
    row = jnp.where(take, src[jnp.clip(r, 0, 2 * M - 1)], 2 * M)
    take = row < 2 * M
    row = jnp.minimum(row, 2 * M - 1)
    stray = (planes_in < lo) | (planes_in >= hi)  # moved more than one slab in a step
    p_in = p_in._replace(active=p_in.active & ~stray)

    def place(a, b):
        t = take.reshape(take.shape + (1,) * (a.ndim - 1))
        return jnp.where(t, jnp.take(b, row, axis=0), a)

    parts = jax.tree_util.tree_map(place, _particles(state)._replace(active=state.active & ~gone), p_in)
    ids = place(ids, ids_in)
    # strays on this device (made inactive, keep their slot): summed over devices once per block
    strays = jnp.sum(take & jnp.take(stray, row)).astype(jnp.int32)
    return parts._replace(t=state.t, n_lost=state.n_lost), ids, strays


def make_slab_advance(scene: Scene, local_step, n_steps: int, observe=None):
    """``advance(state, params) -> state``: ``n_steps`` steps of ``local_step`` (the step built with
    ``axis=AXIS``, taking a ``grid`` layout) on slabs, rebalanced every ``REBALANCE_STEPS``.

    ``observe(carry, state) -> carry``: called after every step on each device with the device's
    particles (its slots; empty ones inactive) and a carry replicated over devices, which it must
    keep replicated (reduce its particle sums with ``psum`` over ``AXIS``; the hazard maps,
    ``_hazard``).  With it, ``advance(state, params, carry) -> (state, carry)``."""
    mesh = particle_mesh(scene.devices)

    def block(state, params, length, obs):
        geo = geometry(scene, state.x.shape[0])
        slabs, ids, bounds = _distribute(scene, geo, state)

        def body(s, ids, bounds, params, obs):
            lo, hi = bounds[0, 0], bounds[0, 1]
            grid = Slab(geo, lo, hi)

            def one(carry, _):
                s, ids, strays, obs = carry
                # migrate first, then step: the planes that place a particle and the stencil the step
                # builds are then both read from the stored carry, never from two fusions' roundings
                # of a freshly computed x (docs/performance.md, "Stencil layout"); at a block's start
                # every particle is already in its slab
                s, ids, n = _migrate(scene, geo, s, ids, lo, hi)
                s = local_step(s, params, grid)
                if observe is not None:
                    obs = observe(obs, s)
                return (s, ids, strays + n, obs), None

            zero = ids[0] * 0  # an int32 zero that varies over devices, as the per-device count it starts
            s, ids, strays, obs = jax.lax.scan(one, (s, ids, zero, obs), None, length=length)[0]
            return s._replace(n_lost=s.n_lost + jax.lax.psum(strays, AXIS)), ids, obs

        spec = jax.tree_util.tree_map(lambda a: PartitionSpec(AXIS) if jnp.ndim(a) else PartitionSpec(), slabs)
        pspec = jax.tree_util.tree_map(lambda _: PartitionSpec(), params)
        ospec = jax.tree_util.tree_map(lambda _: PartitionSpec(), obs)
        sharded = jax.shard_map(
            body,
            mesh=mesh,
            in_specs=(spec, PartitionSpec(AXIS), PartitionSpec(AXIS), pspec, ospec),
            out_specs=(spec, PartitionSpec(AXIS), ospec),
        )
        out, ids, obs = sharded(slabs, ids, bounds, params, obs)
        return _collect(state, out, ids), obs

    q, r = divmod(n_steps, REBALANCE_STEPS)

    def advance(state, params, obs=()):
        if q:
            (state, obs), _ = jax.lax.scan(
                lambda c, _: (block(c[0], params, REBALANCE_STEPS, c[1]), None), (state, obs), None, length=q
            )
        if r:
            state, obs = block(state, params, r, obs)
        return state if observe is None else (state, obs)

    return advance
