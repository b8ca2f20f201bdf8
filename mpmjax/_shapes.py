"""1-D shape functions; multi-D weights are their tensor products.

Each shape function maps a coordinate in cell units ``xi = (x - origin)/h`` to
``(base, w, dw)``: the index of the first node of the stencil, the weights of the
``k`` stencil nodes ``base .. base+k-1`` and their derivatives with respect to x
(so ``dw`` carries the 1/h factor).

* ``linear``: standard MPM hat functions, 2 nodes.
* ``gimp``: uniform GIMP (Bardenhagen & Kober 2004; thesis §2, Fig. 11) with particle
  half-width ``lp = h / (2 ppc)``, 3 nodes.
* ``quadratic``: quadratic B-spline, 3 nodes.
* ``cubic``: cubic B-spline, 4 nodes.
* ``quadratic_bm``, ``cubic_bm``: the same B-splines, boundary-modified at box walls (below).

Boundary-modified B-splines (``quadratic_bm``, ``cubic_bm``).  Plain B-splines are not
interpolating: next to a wall their support reaches the ghost nodes behind it, whose
velocities the wall condition zeroes, and momentum leaks there every step
(docs/validation.md).  The modified basis has no ghost node at all: the coefficient of the
one ghost node whose B-spline reaches into the domain (node W - 1 behind a wall node W) is
eliminated by linear extrapolation, c_{W-1} = 2 c_W - c_{W+1}, i.e.

    N'_W = N_W + 2 N_{W-1},   N'_{W+1} = N_{W+1} - N_{W-1},   N'_{W-1} = 0

(mirrored at an upper wall), every other function unchanged.  The modified functions are
C1 piecewise polynomials of the same degree, non-negative inside the domain, a partition of
unity there, reproduce linear fields (sum_i N'_i x_i = x, so APIC conserves momentum and
the velocity gradient of an affine field is exact at the wall), and interpolate at the wall
(N'_W(wall) = 1, every other function 0 there).  In cell units x = distance from the wall:

* quadratic, 0 <= x <= 1/2: N'_W = 1 - x, N'_{W+1} = x (the linear hat); x >= 1/2: plain;
* cubic, 0 <= x <= 1: N'_W = 1 - x + x^3/6, N'_{W+1} = 2/3 - (1 - x)^2 + (1 - x)^3/3; x >= 1: plain.

Only the first half-cell (quadratic) or cell (cubic) next to a wall is affected.  This is the
construction of the extended B-splines of Hoellig et al. (Yamaguchi, Moriguchi & Terada 2021
for MPM) with linear extrapolation; Steffen, Kirby & Berzins (2008) modify the same two
functions differently (N'_W = 1 - 4x^2/3 ... for the quadratic), which keeps the partition of
unity but not linear reproduction (sum_i N'_i x_i = x + O(x^2) near the wall): with APIC that
creates momentum at the wall, so it is not used here.  A quadratic extrapolation
(c_{W-1} = 3 c_W - 3 c_{W+1} + c_{W+2}) would reproduce quadratics but gives a negative,
non-interpolating N'_{W+1}(wall) = -1/4.

The weights need the wall node indices per axis (``wall_lo``, ``wall_hi``: node indices of
the box faces that are walls, -inf / +inf where there is none; ``_scene.box_wall_nodes``).
The stencil base is clamped so that a particle on (or rounded a hair behind) a wall still
has the wall node at the same stencil position; the ghost node stays in the stencil with
weight exactly 0.
"""

from __future__ import annotations

import jax.numpy as jnp

STENCIL = {"linear": 2, "gimp": 3, "quadratic": 3, "cubic": 4, "quadratic_bm": 3, "cubic_bm": 4}
# Half-width of the support in cells: how far a particle's influence reaches (away from
# walls; the boundary-modified kinds reach no further than the plain ones).
SUPPORT = {"linear": 1.0, "gimp": 1.5, "quadratic": 1.5, "cubic": 2.0, "quadratic_bm": 1.5, "cubic_bm": 2.0}
# APIC inertia D = D_FACTOR * h^2 * I for B-splines (Jiang et al. 2015); for linear and
# GIMP, APIC's B D^-1 equals (linear) or is replaced by (GIMP) the velocity gradient.  The
# boundary-modified kinds have this D away from walls only (``_transfer.make_g2p``).
APIC_D_FACTOR = {"quadratic": 0.25, "cubic": 1.0 / 3.0, "quadratic_bm": 0.25, "cubic_bm": 1.0 / 3.0}
# Kinds whose 1-D weights are costly piecewise functions (a chain of selects per node).  The stencil
# (``_transfer._Stencil``) gathers their per-node values, so XLA computes them once; the other kinds'
# values are broadcast, which XLA fuses and recomputes per stencil node, cheaper than the gather.  The
# measured choice per kind (GIMP broadcast with its per-node kernel, ``_gimp``): docs/performance.md,
# "Stencil layout".
PIECEWISE = frozenset({"cubic"})
# boundary-modified kind -> the plain B-spline it modifies
BOUNDARY_MODIFIED = {"quadratic_bm": "quadratic", "cubic_bm": "cubic"}


def _half_base(xi):
    """floor(xi - 1/2), the first node of a 3-node stencil centred on the nearest node, written as
    round(xi) - 1 (round half to even), which differs only exactly half-way between two nodes,
    where both stencils are valid (the far node's weight is 0).

    Not floor(xi - 0.5): xi is (x - origin) / h, which XLA computes as a product with 1/h, and
    XLA:CPU contracts a product followed by an add into one fused multiply-add wherever both sit in
    one fusion.  XLA also recomputes the stencil in each fusion that reads it, so the node indices
    and the weights (from xi - base) could see two roundings of xi - 0.5: a particle exactly
    half-way between nodes (every third particle of a ppc-3 lattice along each axis) then took one
    stencil's weights on the other's nodes, one cell off (119 of dambreak-lab's 3600 particles at
    t = 0, and particles that stay near the edge later; float64 too).  round(xi) has no add after
    the product to contract, so every fusion gets the same base.
    ``floor(xi)`` (linear, cubic) is safe as it stands."""
    return jnp.round(xi) - 1.0


def _linear(xi):
    base = jnp.floor(xi)
    f = xi - base
    w = jnp.stack([1.0 - f, f], axis=-1)
    dw = jnp.stack([-jnp.ones_like(f), jnp.ones_like(f)], axis=-1)
    return base, w, dw


def _quadratic(xi):
    base = _half_base(xi)
    f = xi - base  # in [0.5, 1.5)
    w = jnp.stack([0.5 * (1.5 - f) ** 2, 0.75 - (f - 1.0) ** 2, 0.5 * (f - 0.5) ** 2], axis=-1)
    dw = jnp.stack([f - 1.5, -2.0 * (f - 1.0), f - 0.5], axis=-1)
    return base, w, dw


def _cubic_kernel(r):
    """Cubic B-spline N(r) and N'(r) for signed distance r in cell units."""
    a = jnp.abs(r)
    s = jnp.sign(r)
    inner = 0.5 * a**3 - a**2 + 2.0 / 3.0
    outer = (2.0 - a) ** 3 / 6.0
    w = jnp.where(a < 1.0, inner, jnp.where(a < 2.0, outer, 0.0))
    d_inner = 1.5 * a**2 - 2.0 * a
    d_outer = -0.5 * (2.0 - a) ** 2
    dw = s * jnp.where(a < 1.0, d_inner, jnp.where(a < 2.0, d_outer, 0.0))
    return w, dw


def _cubic(xi):
    base = jnp.floor(xi) - 1.0
    r = xi[..., None] - (base[..., None] + jnp.arange(4.0, dtype=xi.dtype).reshape((1,) * xi.ndim + (4,)))
    w, dw = _cubic_kernel(r)
    return base, w, dw


def _cubic_poly(xi):
    """Cubic B-spline in polynomial form (base = floor(xi) - 1, t = xi - base - 1 in [0, 1)).

    The same values as ``_cubic`` inside [0, 1); written as polynomials in t so that a base
    clamped at a wall (t a hair outside [0, 1)) continues the same pieces."""
    base = jnp.floor(xi) - 1.0
    return base, _cubic_blend(xi - base - 1.0)


def _cubic_blend(t):
    u = 1.0 - t
    w = jnp.stack([u**3 / 6.0, 0.5 * t**3 - t**2 + 2.0 / 3.0, 0.5 * u**3 - u**2 + 2.0 / 3.0, t**3 / 6.0], axis=-1)
    dw = jnp.stack([-0.5 * u**2, 1.5 * t**2 - 2.0 * t, -1.5 * u**2 + 2.0 * u, 0.5 * t**2], axis=-1)
    return w, dw


def _boundary_modified(kind, xi, wall_lo, wall_hi):
    """(base, w, dw, modified) of ``quadratic_bm`` / ``cubic_bm`` (module docstring).

    wall_lo, wall_hi: wall node indices (cells), broadcastable to ``xi``; -inf / +inf for none.
    ``modified``: bool of the shape of ``xi``, whether a ghost weight was folded in.
    """
    k = STENCIL[kind]
    dt = xi.dtype
    lo = jnp.asarray(wall_lo, dt)
    hi = jnp.asarray(wall_hi, dt)
    if kind == "quadratic_bm":
        base = jnp.clip(_half_base(xi), lo - 1.0, hi - 1.0)
        f = xi - base
        w = jnp.stack([0.5 * (1.5 - f) ** 2, 0.75 - (f - 1.0) ** 2, 0.5 * (f - 0.5) ** 2], axis=-1)
        dw = jnp.stack([f - 1.5, -2.0 * (f - 1.0), f - 0.5], axis=-1)
    else:
        base = jnp.clip(jnp.floor(xi) - 1.0, lo - 1.0, hi - 2.0)
        w, dw = _cubic_blend(xi - base - 1.0)
    # the ghost node W - 1 sits at stencil position 0 exactly when base == W - 1 (and W + 1 at
    # position k - 1 when base == W + 2 - k): fold its weight into W and W + 1 (c_{W-1} = 2 c_W - c_{W+1})
    at_lo = base == lo - 1.0
    at_hi = base == hi + 2.0 - k

    def fold(a):
        cols = [a[..., j] for j in range(k)]
        g = jnp.where(at_lo, cols[0], 0.0)
        cols[0], cols[1], cols[2] = cols[0] - g, cols[1] + 2.0 * g, cols[2] - g
        g = jnp.where(at_hi, cols[k - 1], 0.0)
        cols[k - 1], cols[k - 2], cols[k - 3] = cols[k - 1] - g, cols[k - 2] + 2.0 * g, cols[k - 3] - g
        return jnp.stack(cols, axis=-1)

    return base, fold(w), fold(dw), at_lo | at_hi


def _gimp_kernel(r, lp):
    """uGIMP weight and derivative for r = x_p - x_i in cell units, half-width lp (cells)."""
    a = jnp.abs(r)
    w_in, d_in = _gimp_inner(r, lp)
    w_out, d_out = _gimp_outer(a, lp)
    return jnp.where(a < lp, w_in, w_out), jnp.where(a < lp, d_in, jnp.sign(r) * d_out)


def _gimp_inner(r, lp):
    """uGIMP weight and derivative at |r| < lp, where the particle covers the node."""
    return 1.0 - (r * r + lp * lp) / (2.0 * lp), -r / lp


def _gimp_outer(a, lp):
    """uGIMP weight and derivative (with respect to r, for r = a > 0; for r = -a it changes sign) at
    distance a >= lp, beyond the inner regime: the linear and the outer regime, then 0."""
    w = jnp.where(a < 1.0 - lp, 1.0 - a, jnp.where(a < 1.0 + lp, (1.0 + lp - a) ** 2 / (4.0 * lp), 0.0))
    d = jnp.where(a < 1.0 - lp, -1.0, jnp.where(a < 1.0 + lp, -(1.0 + lp - a) / (2.0 * lp), 0.0))
    return w, d


def _gimp(xi, lp):
    """``_gimp_kernel`` at the three stencil nodes, each with only the regimes it can be in: with
    f = xi - base in [1/2, 3/2], node 0 is at distance f, node 2 at 2 - f (both >= 1/2: linear or
    outer) and node 1 at |f - 1| <= 1/2 (inner or linear; lp = 1/(2 ppc) <= 1/2).  The same formulas
    as ``_gimp_kernel`` (equal to it bit for bit), about half its selects: cheap enough for the stencil
    to broadcast them, which XLA recomputes per stencil node, instead of gathering them
    (``PIECEWISE``, docs/performance.md, "Stencil layout")."""
    base = _half_base(xi)
    f = xi - base
    r1 = f - 1.0
    a1 = jnp.abs(r1)
    w_in, d_in = _gimp_inner(r1, lp)
    w1 = jnp.where(a1 < lp, w_in, 1.0 - a1)
    d1 = jnp.where(a1 < lp, d_in, -jnp.sign(r1))
    w0, d0 = _gimp_outer(f, lp)
    w2, d2 = _gimp_outer(2.0 - f, lp)
    return base, jnp.stack([w0, w1, w2], axis=-1), jnp.stack([d0, d1, -d2], axis=-1)


def weights_1d(kind: str, xi, h: float, lp_cells: float = 0.25, wall_lo=-jnp.inf, wall_hi=jnp.inf):
    """Stencil base index (int32), weights and x-derivatives for coordinates ``xi`` (cells).

    Args:
      kind: one of ``STENCIL``.
      xi: array of coordinates in cell units, any shape ``S``.
      h: cell size [m].
      lp_cells: GIMP particle half-width in cells (ignored by the other kinds).
      wall_lo, wall_hi: for the boundary-modified kinds, the node indices of the walls below
        and above (broadcastable to ``S``; -inf / +inf: none); ignored by the other kinds.
    Returns:
      base: int32 array of shape ``S``; w, dw: arrays of shape ``S + (k,)``; dw in 1/m.
    """
    if kind in BOUNDARY_MODIFIED:
        base, w, dw, _ = _boundary_modified(kind, xi, wall_lo, wall_hi)
    elif kind == "linear":
        base, w, dw = _linear(xi)
    elif kind == "quadratic":
        base, w, dw = _quadratic(xi)
    elif kind == "cubic":
        base, w, dw = _cubic(xi)
    elif kind == "gimp":
        base, w, dw = _gimp(xi, lp_cells)
    else:  # pragma: no cover - validated at scene load
        raise ValueError(f"unknown shape function {kind!r}; allowed: {sorted(STENCIL)}")
    return base.astype(jnp.int32), w, dw / h


def boundary_modified_1d(kind: str, xi, h: float, wall_lo, wall_hi):
    """``weights_1d`` of a boundary-modified kind, plus ``modified`` (bool, shape ``S``): the
    particle is close enough to a wall for a ghost weight to have been folded in (the first
    half-cell for ``quadratic_bm``, the first cell for ``cubic_bm``)."""
    base, w, dw, mod = _boundary_modified(kind, xi, wall_lo, wall_hi)
    return base.astype(jnp.int32), w, dw / h, mod


def kernel_1d(kind: str, r, lp_cells: float = 0.25):
    """The 1-D weight N(r) of a node at signed distance r (cells) from a particle (away from
    walls: the boundary-modified kinds give their plain B-spline)."""
    kind = BOUNDARY_MODIFIED.get(kind, kind)
    a = jnp.abs(r)
    if kind == "linear":
        return jnp.maximum(0.0, 1.0 - a)
    if kind == "quadratic":
        return jnp.where(a < 0.5, 0.75 - a * a, jnp.where(a < 1.5, 0.5 * (1.5 - a) ** 2, 0.0))
    if kind == "cubic":
        return _cubic_kernel(r)[0]
    if kind == "gimp":
        return _gimp_kernel(r, lp_cells)[0]
    raise ValueError(f"unknown shape function {kind!r}; allowed: {sorted(STENCIL)}")
