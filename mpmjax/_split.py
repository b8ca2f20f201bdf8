"""Column splitting of the depth-averaged step (``numerics.split_levels`` > 0): columns that have
spread more than a cell apart are split into 2^k columns of equal volume, so that the grid can
resolve the thin tip of a flow and of its deposit (docs/depth-averaged.md, "Column splitting").

Why.  A column of volume V_p is spread over about one cell by the shape function, so the grid
resolves depths down to V_p / h^k.  Where the columns are more than a cell apart (a stretching
tip), the nodal depth is a row of bumps, one per column, whose pressure exceeds the yield friction
a node can hold: an arrested deposit's tip keeps creeping, and a dam break's tip holds too little
volume to reach the Ritter front (docs/depth-averaged.md, "Creep after arrest", "The Ritter tip").

The criterion.  A column is sparse where its depth H_p (the nodal depth at the column, which the
step computes anyway) is below V_p / h^k: with neighbours a distance s apart along a profile,
H_p ~ V_p / s, so this is s > h, whatever the column's volume.  A sparse column is split into
m = 2^k children of volume V_p / m at X_p + (+-d, ...), d = a quarter of its footprint's side
(V_p / H_p)^(1/k), at most h / 2: the centroids of the footprint's 2^k parts.  Each child has
the parent's velocity, affine matrix and internal variables, so mass, momentum and the volume
centroid are unchanged (kinetic energy too); the state's arrays keep their size: the children go
into spare slots reserved by ``_build`` (inactive, volume 0; a slot, once used, is never reused,
so a column that later leaves the domain is not mistaken for a free one).  No split where the
children would be smaller than ``v_min`` (the median seeded column over 2^(k levels)) or where
the spare slots have run out (``spare_slots`` tells the driver).

The decision is a step function of the state, so a split moves the outputs by a jump (the
children's depth is spread differently): a gradient is the derivative between splits, as for a
particle crossing a cell.  Pure, jit-compiled and vmappable (every array keeps its shape).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ._scene import State

# the children's offset, as a fraction of the footprint's side (the centroids of its halves)
OFFSET_FRACTION = 0.25
# and at most this many cells (a lone column's footprint is unbounded)
OFFSET_MAX_CELLS = 0.5


def spare_slots(state: State):
    """Slots still free for children: inactive with volume 0 (never used)."""
    return ~state.active & (state.vol0 == 0)


def sparse_columns(state: State, H_p, *, k: int, h: float, v_min: float):
    """The active columns a split would split (module docstring): depth on the grid H_p below V_p/h^k, and at least
    2^k times ``v_min``.  ``H_p``: each column's depth [m] as the step computes it."""
    return state.active & (jnp.maximum(H_p, 1e-30) * h**k < state.vol0) & (state.vol0 >= 2**k * v_min)


def split(state: State, H_p, *, k: int, h: float, v_min: float, lo, hi) -> State:
    """``state`` with its sparse columns split (module docstring).  ``H_p``: each column's depth
    [m] in the step that made ``state``; ``lo`` / ``hi``: (k,) plan bounds the children are kept
    within [m] (the box's walls and the grid's safe region)."""
    m = 2**k
    n = state.vol0.shape[0]
    dt = state.x.dtype
    V = state.vol0
    Hs = jnp.maximum(H_p, 1e-30)
    free = spare_slots(state)
    sparse = sparse_columns(state, H_p, k=k, h=h, v_min=v_min)
    rank = jnp.cumsum(sparse) - 1
    sparse = sparse & ((rank + 1) * (m - 1) <= jnp.sum(free))  # as many as the spare slots allow, in order
    rank = jnp.cumsum(sparse) - 1
    n_split = jnp.sum(sparse)
    parent_of = jnp.zeros((n,), jnp.int32).at[jnp.where(sparse, rank, n)].set(jnp.arange(n, dtype=jnp.int32), mode="drop")
    f = jnp.cumsum(free) - 1
    used = free & (f < n_split * (m - 1))
    par = parent_of[jnp.where(used, f // (m - 1), 0)]
    child = jnp.where(used, f % (m - 1) + 1, 0)  # 1 .. m-1; the parent stays as child 0

    # only active columns with volume: elsewhere (spare slots, columns gone through an open face) the quotient and
    # the root take 1, since their derivatives there are infinite (float32: 1 / 1e-30^2) and reverse mode would
    # multiply them by a zero cotangent into NaN
    ok = state.active & (V > 0)
    q = jnp.where(ok, V / jnp.where(ok, Hs, 1.0), 1.0)
    side = jnp.where(ok, q ** (1.0 / k), 0.0)
    lo_a = jnp.asarray(lo, dt)[None, :]
    hi_a = jnp.asarray(hi, dt)[None, :]
    X = state.x[:, :k]
    # the offset per axis, no further than the nearer bound allows, so the children stay symmetric about the
    # parent (the centroid kept) next to a wall too
    d = jnp.minimum(OFFSET_FRACTION * side, OFFSET_MAX_CELLS * h)[:, None]  # (n, 1)
    d = jnp.clip(jnp.minimum(d, jnp.minimum(X - lo_a, hi_a - X)), 0.0, None)  # (n, k)
    bits = jnp.asarray([[(c >> a) & 1 for a in range(k)] for c in range(m)], dt) * 2.0 - 1.0  # (m, k): -1 / +1

    X_par = jnp.where(sparse[:, None], X + bits[0][None, :] * d, X)
    X_child = X[par] + bits[child] * d[par]
    X_new = jnp.where(used[:, None], X_child, X_par)

    def take(a):
        """Children take their parent's value; every other slot keeps its own."""
        u = used.reshape(used.shape + (1,) * (a.ndim - 1))
        return jnp.where(u, a[par], a)

    vol = jnp.where(sparse, V / m, V)
    vol = jnp.where(used, V[par] / m, vol)
    return State(
        x=take(state.x).at[:, :k].set(X_new),
        v=take(state.v),
        C=take(state.C),
        tau=take(state.tau),
        J=take(state.J),
        vol0=vol,
        mu=take(state.mu),
        internal={nm: take(a) for nm, a in state.internal.items()},
        active=state.active | used,
        gate=take(state.gate),
        t=state.t,
        n_lost=state.n_lost,
        p=state.p,
    )


def min_volume(vol0: np.ndarray, k: int, levels: int) -> float:
    """The smallest column a split may leave: the median seeded column over 2^(k levels) (a column's volume:
    m^3 in a 3D scene, m^2 per metre in 2D)."""
    v = np.asarray(vol0, float)
    v = v[v > 0]
    return float(np.median(v)) / 2.0 ** (k * levels) if len(v) else 0.0
