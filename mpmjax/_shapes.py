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
"""

from __future__ import annotations

import jax.numpy as jnp

STENCIL = {"linear": 2, "gimp": 3, "quadratic": 3, "cubic": 4}
# Half-width of the support in cells: how far a particle's influence reaches.
SUPPORT = {"linear": 1.0, "gimp": 1.5, "quadratic": 1.5, "cubic": 2.0}
# APIC inertia D = D_FACTOR * h^2 * I for B-splines (Jiang et al. 2015); for linear and
# GIMP, APIC's B D^-1 equals (linear) or is replaced by (GIMP) the velocity gradient.
APIC_D_FACTOR = {"quadratic": 0.25, "cubic": 1.0 / 3.0}


def _linear(xi):
    base = jnp.floor(xi)
    f = xi - base
    w = jnp.stack([1.0 - f, f], axis=-1)
    dw = jnp.stack([-jnp.ones_like(f), jnp.ones_like(f)], axis=-1)
    return base, w, dw


def _quadratic(xi):
    base = jnp.floor(xi - 0.5)
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


def _gimp_kernel(r, lp):
    """uGIMP weight and derivative for r = x_p - x_i in cell units, half-width lp (cells)."""
    a = jnp.abs(r)
    s = jnp.sign(r)
    w1 = 1.0 - (r * r + lp * lp) / (2.0 * lp)
    w2 = 1.0 - a
    w3 = (1.0 + lp - a) ** 2 / (4.0 * lp)
    w = jnp.where(a < lp, w1, jnp.where(a < 1.0 - lp, w2, jnp.where(a < 1.0 + lp, w3, 0.0)))
    d1 = -r / lp
    d2 = -s
    d3 = -s * (1.0 + lp - a) / (2.0 * lp)
    dw = jnp.where(a < lp, d1, jnp.where(a < 1.0 - lp, d2, jnp.where(a < 1.0 + lp, d3, 0.0)))
    return w, dw


def _gimp(xi, lp):
    base = jnp.floor(xi - 0.5)
    r = xi[..., None] - (base[..., None] + jnp.arange(3.0, dtype=xi.dtype).reshape((1,) * xi.ndim + (3,)))
    w, dw = _gimp_kernel(r, lp)
    return base, w, dw


def weights_1d(kind: str, xi, h: float, lp_cells: float = 0.25):
    """Stencil base index (int32), weights and x-derivatives for coordinates ``xi`` (cells).

    Args:
      kind: one of ``STENCIL``.
      xi: array of coordinates in cell units, any shape ``S``.
      h: cell size [m].
      lp_cells: GIMP particle half-width in cells (ignored by the other kinds).
    Returns:
      base: int32 array of shape ``S``; w, dw: arrays of shape ``S + (k,)``; dw in 1/m.
    """
    if kind == "linear":
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


def kernel_1d(kind: str, r, lp_cells: float = 0.25):
    """The 1-D weight N(r) of a node at signed distance r (cells) from a particle."""
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
