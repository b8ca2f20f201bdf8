"""Engine verification, the shape functions and stencils (``mpmjax/_shapes.py``,
``mpmjax/_transfer._Stencil``): strict broadcasting and dtype, partition of unity and linear
completeness, gradients against finite differences, GIMP's per-node regimes, the tensor-product
stencil identities in 2D and 3D, and the compiled stencil on knife edges.  The rest of the engine's
verification (conservation, exact solutions, 2D/3D agreement, jit/vmap) is ``test_engine.py``;
the same conventions hold (float64, tolerances stated next to each assertion).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import ROUNDOFF, SHAPES, TEST_XLA_FLAGS

import mpmjax as m
from mpmjax import _shapes
from mpmjax._transfer import _Stencil

jax.config.update("jax_enable_x64", True)


# ======================================================================================
# Shape functions (mpmjax/_shapes.py)
# ======================================================================================

LP = 0.25  # GIMP half-width in cells for ppc = 2 (Scene.lp_cells = 0.5 / ppc)


def _kinks(kind):
    """Distances (cells) from a node where the 1-D weight is not smooth."""
    return {"linear": [0.0, 1.0], "gimp": [LP, 1 - LP, 1 + LP], "quadratic": [0.5, 1.5], "cubic": [0.0, 1.0, 2.0]}[kind]


def _sample_xi(kind, n=400, seed=0):
    """Coordinates in cell units, away (1e-3 cells) from the kinks so that a central
    finite difference of step 1e-6 cells never straddles one."""
    xi = np.random.default_rng(seed).uniform(3.0, 9.0, n)
    frac = xi - np.floor(xi)
    d = np.min([np.minimum(np.abs(frac - k % 1.0), 1 - np.abs(frac - k % 1.0)) for k in _kinks(kind)], axis=0)
    return jnp.asarray(xi[d > 1e-3], jnp.float64)


@pytest.mark.parametrize("kind", SHAPES)
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_shape_functions_strict_broadcasting_and_dtype(kind, dtype):
    """Shape functions evaluate under jax_numpy_rank_promotion = "raise" and keep the
    input dtype (float32 scenes stay float32 with x64 on).

    Regression test for a bug found while writing this file: _gimp and _cubic added a
    (..., 1) array to jnp.arange(k * 1.0) of shape (k,), which the strict harness
    rejects (so GIMP/cubic scenes could not run under it) and which, with x64 on, is
    float64 and silently promoted float32 weights.  Weights must sum to 1 (round-off
    of the dtype: 1e-6 in float32, 1e-12 in float64).
    """
    xi = jnp.full((3, 2), 2.3, dtype)
    with jax.numpy_rank_promotion("raise"):
        base, w, dw = _shapes.weights_1d(kind, xi, 0.1, LP)
    assert w.dtype == dtype and dw.dtype == dtype
    assert w.shape == (3, 2, _shapes.STENCIL[kind]) and base.shape == (3, 2)
    np.testing.assert_allclose(np.asarray(w, np.float64).sum(-1), 1.0, atol=1e-6 if dtype == jnp.float32 else ROUNDOFF)


@pytest.mark.parametrize("kind", SHAPES)
def test_shape_partition_of_unity_and_linear_completeness(kind):
    """sum_i w_i = 1, sum_i w_i x_i = x_p, sum_i dw_i = 0, sum_i dw_i x_i = 1 (1-D, h = 0.03 m).

    These are exact polynomial identities of all four kernels; float64 evaluation with
    O(1) terms leaves ~1e-15, so 1e-12 (absolute, in cells or in 1/h units) is round-off.
    """
    h = 0.03
    xi = _sample_xi(kind)
    base, w, dw = _shapes.weights_1d(kind, xi, h, LP)
    k = _shapes.STENCIL[kind]
    nodes = np.asarray(base)[:, None] + np.arange(k)[None, :]  # cell units
    w, dw = np.asarray(w), np.asarray(dw) * h  # dw per cell
    np.testing.assert_allclose(w.sum(1), 1.0, rtol=0, atol=ROUNDOFF)
    np.testing.assert_allclose((w * nodes).sum(1), np.asarray(xi), rtol=0, atol=ROUNDOFF * 10)
    np.testing.assert_allclose(dw.sum(1), 0.0, rtol=0, atol=ROUNDOFF)
    np.testing.assert_allclose((dw * nodes).sum(1), 1.0, rtol=0, atol=ROUNDOFF * 10)
    assert np.all(w >= -1e-15), "weights must be non-negative"


@pytest.mark.parametrize("kind", SHAPES)
def test_shape_gradient_matches_finite_difference(kind):
    """dw/dx equals the central difference of w (step 1e-6 h) on the same absolute nodes.

    Truncation error of the central difference is e^2 |w'''| / 6 ~ 1e-12 / h and the
    cancellation error is eps / e ~ 2e-10 / h, so the tolerance is 1e-8 / h.
    """
    h = 0.05
    xi = _sample_xi(kind, seed=1)
    e = 1e-6
    base, w, dw = _shapes.weights_1d(kind, xi, h, LP)
    bp, wp, _ = _shapes.weights_1d(kind, xi + e, h, LP)
    bm, wm, _ = _shapes.weights_1d(kind, xi - e, h, LP)
    k = _shapes.STENCIL[kind]

    def on_nodes(b, ww):  # weights indexed by absolute node over a window [base-1, base+k]
        out = np.zeros((len(xi), k + 2))
        off = np.asarray(b) - np.asarray(base) + 1
        for j in range(k):
            np.add.at(out, (np.arange(len(xi)), off + j), np.asarray(ww)[:, j])
        return out

    fd = (on_nodes(bp, wp) - on_nodes(bm, wm)) / (2 * e * h)
    np.testing.assert_allclose(on_nodes(base, dw), fd, rtol=0, atol=1e-8 / h)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_gimp_per_node_regimes_equal_the_general_kernel(dtype):
    """``_shapes._gimp`` evaluates each stencil node with only the regimes it can be in (a speed
    measure, docs/performance.md "Stencil layout"); it must equal ``_gimp_kernel`` at the same node
    distances bit for bit, for ppc 1-4 (lp = 1/2 ... 1/8 cell), at random positions and on the
    lattice's knife edges (nodes, half-cells, sixths and quarters of a cell)."""
    rng = np.random.default_rng(5)
    edges = [np.arange(3, 40, step) for step in (0.5, 1 / 6, 0.25)]
    xi = np.concatenate([rng.uniform(3, 40, 20000)] + edges)
    xi = jnp.asarray(xi.astype(dtype))
    for lp in (0.5, 0.25, 1 / 6, 0.125):
        base, w, dw = _shapes._gimp(xi, lp)
        r = xi[:, None] - (base[:, None] + jnp.arange(3.0, dtype=xi.dtype)[None, :])
        w_ref, dw_ref = _shapes._gimp_kernel(r, lp)
        assert np.array_equal(np.asarray(w), np.asarray(w_ref)) and np.array_equal(np.asarray(dw), np.asarray(dw_ref))


@pytest.mark.parametrize("kind", SHAPES)
@pytest.mark.parametrize("dim", [2, 3])
def test_stencil_tensor_product_identities(kind, dim):
    """Multi-D stencil (tensor product, as used by P2G/G2P): sum w = 1, sum w r = 0,
    sum grad w = 0 and sum r (x) grad w = I, where r = x_node - x_p (the gradient of
    the linear field x is reproduced exactly).

    These identities are what make P2G conserve mass and momentum and make the internal
    force sum to zero; float64 round-off only (tolerances in m, or 1/m scaled by h).
    """
    h = 0.04
    scene = m.Scene(
        dim=dim,
        h=h,
        lo=(0.0,) * dim,
        hi=(0.4,) * dim,
        periodic=(False,) * dim,
        grid_origin=(-0.12,) * dim,
        grid_shape=(17,) * dim,
        walls=(),
        shape=kind,
        lp_cells=LP,
        transfer="apic",
        flip_blend=0.95,
        rheology=m.Newtonian(),
        shear_measure="standard",
        viscous_update="maxwell",
        maxwell_G=1.0,
        dt=1e-3,
        steps_per_frame=1,
        n_frames=1,
        n_particles=50,
    )
    x = jnp.asarray(np.random.default_rng(2).uniform(0.05, 0.35, (50, dim)), jnp.float64)
    idx, w, dw, r = jax.jit(lambda x: (lambda st: (st.idx, st.w, st.dw, st.r))(_Stencil(scene, x)))(x)
    w, dw, r = np.asarray(w), np.asarray(dw), np.asarray(r)
    np.testing.assert_allclose(w.sum(1), 1.0, rtol=0, atol=ROUNDOFF)
    np.testing.assert_allclose((w[..., None] * r).sum(1), 0.0, rtol=0, atol=ROUNDOFF * h)
    np.testing.assert_allclose(dw.sum(1) * h, 0.0, rtol=0, atol=ROUNDOFF)
    np.testing.assert_allclose(
        np.einsum("nsi,nsj->nij", r, dw), np.broadcast_to(np.eye(dim), (50, dim, dim)), rtol=0, atol=ROUNDOFF * 10
    )
    # the flat node index must point at the node whose offset r describes
    xn = scene.node_positions()[np.asarray(idx)]
    np.testing.assert_allclose(xn - np.asarray(x)[:, None, :], r, rtol=0, atol=ROUNDOFF * h)


_KNIFE_EDGE = """
import json, jax, jax.numpy as jnp, numpy as np, mpmjax as m
from mpmjax._transfer import _Stencil, first_plane
jax.config.update("jax_enable_x64", True)
rng = np.random.default_rng(3)
out = {}
for dim in (2, 3):
    for dts in ("float32", "float64"):
        dt = np.dtype(dts)
        h, shape = (0.013, (160, 40)) if dim == 2 else (0.029, (60, 40, 30))
        origin = tuple(-0.037 * (a + 1) for a in range(dim))
        n = 6000
        # on a node or half-way between two (the knife edges of both stencil families), nudged by -3..3 ulps
        k = np.stack([rng.integers(8, shape[a] - 8, n) for a in range(dim)], 1)
        x = (np.asarray(origin) + (k + 0.5 * rng.integers(0, 2, (n, dim))) * h).astype(dt)
        nud = rng.integers(-3, 4, (n, dim))
        for _ in range(3):
            up, down = np.nextafter(x, dt.type(np.inf)), np.nextafter(x, dt.type(-np.inf))
            x = np.where(nud > 0, up, np.where(nud < 0, down, x))
            nud = nud - np.sign(nud)
        for kind in ("linear", "gimp", "quadratic", "cubic", "quadratic_bm", "cubic_bm"):
            scene = m.Scene(dim=dim, h=h, lo=tuple(o + 2 * h for o in origin),
                            hi=tuple(origin[a] + (shape[a] - 3) * h for a in range(dim)), periodic=(False,) * dim,
                            grid_origin=origin, grid_shape=shape, walls=(), shape=kind, lp_cells=1 / 6,
                            transfer="apic", flip_blend=0.95, rheology=m.Newtonian(), shear_measure="standard",
                            viscous_update="maxwell", maxwell_G=1.0, dt=1e-3, steps_per_frame=1, n_frames=1,
                            n_particles=n)
            f = jax.jit(lambda x: (lambda st: (st.idx, st.w, first_plane(scene, x)))(_Stencil(scene, x)))
            idx, w, plane = (np.asarray(a) for a in f(jnp.asarray(x)))
            rep = np.einsum("ns,nsd->nd", w.astype(np.float64), scene.node_positions()[idx])
            slipped = int(np.sum(np.abs(rep - x.astype(np.float64)).max(1) > h / 10))
            planes = int(np.sum(idx[:, 0] // int(np.prod(shape[1:])) != plane))
            out[f"{dim}D {dts} {kind}"] = [slipped, planes]
print(json.dumps(out))
"""


@pytest.mark.parametrize("emitters", ["harness", "library default"])
def test_compiled_stencil_is_consistent_on_knife_edges(emitters):
    """A particle exactly on a node, or half-way between two (every third particle of a ppc-3 lattice
    along each axis), sits on a knife edge of its stencil's first node: either choice is a valid
    stencil, but the node indices and the weights must make the same one.  Compiled, XLA:CPU once
    made them from two roundings of xi (floor(xi - 1/2), contracted into a fused multiply-add in one
    fusion and not in another): the GIMP and quadratic kinds put particles' weights one cell off, in
    float32 and float64 (``_shapes._half_base``).  Checked on 6000 particles per case placed on those
    edges and nudged by up to 3 ulps, 2D and 3D, float32 and float64, every kind, compiled with the
    harness's XLA flags and the library's defaults (this harness uses the older ones,
    conftest.py, hence the subprocesses): linear reproduction on the nodes the indices name,
    sum_i w_ip x_i = x_p, must hold to far better than the h a one-cell slip breaks it by (count of
    particles off by more than h/10: 0; the previous code: 6-64 per case for the 3-node kinds),
    and the slab decomposition's ``first_plane`` must name the stencil's first plane."""
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    if emitters == "library default":
        env["XLA_FLAGS"] = " ".join(f for f in env.get("XLA_FLAGS", "").split() if f not in TEST_XLA_FLAGS)
    p = subprocess.run([sys.executable, "-c", _KNIFE_EDGE], capture_output=True, text=True, env=env, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    res = json.loads(p.stdout.strip().splitlines()[-1])
    assert len(res) == 24 and all(v == [0, 0] for v in res.values()), res
