"""Boundary-modified B-splines (``numerics.shape = quadratic_bm / cubic_bm``, issue 14 item 2).

The 1-D weights are checked directly (partition of unity and linear reproduction inside the
domain, interpolation at the wall, no weight on ghost nodes, gradient = derivative), then the
tensor-product stencil in 2D and 3D (the identities P2G/G2P rely on, APIC exact for affine
fields at the walls), the wall-corrected packing (``node_fill``), and jit/grad/vmap through
a short run.  The flow checks (plane Poiseuille, a settling column, the Bingham plug) are in
tests/test_engine.py and tests/test_rheology_mpm.py next to those of the other shapes.
All float64 unless a dtype is named; tolerances are round-off (see ROUNDOFF).
"""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mpmjax as m
from mpmjax import _shapes
from mpmjax._boundary import node_fill
from mpmjax._scene import WALL_KINDS, box_wall_nodes, ghost_cells
from mpmjax._transfer import _Stencil, make_g2p, make_p2g, packing_fraction

jax.config.update("jax_enable_x64", True)

BM = ("quadratic_bm", "cubic_bm")
ROUNDOFF = 1e-12  # float64, O(1) terms
W_LO, W_HI = 3.0, 13.0  # wall node indices (cells) of a 10-cell domain


def _weights(kind, xi, lo=W_LO, hi=W_HI, h=1.0):
    base, w, dw, mod = _shapes.boundary_modified_1d(kind, jnp.asarray(xi), h, lo, hi)
    k = _shapes.STENCIL[kind]
    nodes = np.asarray(base)[:, None] + np.arange(k)[None, :]
    return nodes, np.asarray(w, np.float64), np.asarray(dw, np.float64), np.asarray(mod)


def _inside(n=2000, seed=0):
    """Random positions across the whole domain, half of them within 2 cells of a wall, plus
    both walls exactly."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(W_LO, W_HI, n // 2)
    b = np.concatenate([rng.uniform(W_LO, W_LO + 2, n // 4), rng.uniform(W_HI - 2, W_HI, n // 4)])
    return np.concatenate([[W_LO, W_HI], a, b])


@pytest.mark.parametrize("kind", BM)
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_weights_partition_of_unity_interpolation_and_no_ghost_weight(kind, dtype):
    """Inside [wall_lo, wall_hi]: sum w = 1, sum w x_i = x, sum dw = 0, sum dw x_i = 1 (the
    modified functions reproduce linear fields), w >= 0; a particle on a wall has weight 1 on
    the wall node and 0 elsewhere; ghost nodes (beyond a wall) never get weight; 1-D weights keep
    the dtype and evaluate under strict rank promotion.  Tolerances: round-off of the dtype
    (1e-12 in float64, 1e-5 in float32 on coordinates ~10 cells)."""
    tol = ROUNDOFF * 10 if dtype == jnp.float64 else 1e-5
    xi = jnp.asarray(_inside(), dtype)
    with jax.numpy_rank_promotion("raise"):
        base, w, dw, mod = _shapes.boundary_modified_1d(kind, xi, 1.0, W_LO, W_HI)
    assert w.dtype == dtype and dw.dtype == dtype
    k = _shapes.STENCIL[kind]
    nodes = np.asarray(base)[:, None] + np.arange(k)[None, :]
    w, dw, x = np.asarray(w, np.float64), np.asarray(dw, np.float64), np.asarray(xi, np.float64)
    np.testing.assert_allclose(w.sum(1), 1.0, rtol=0, atol=tol)
    np.testing.assert_allclose((w * nodes).sum(1), x, rtol=0, atol=tol * 10)
    np.testing.assert_allclose(dw.sum(1), 0.0, rtol=0, atol=tol)
    np.testing.assert_allclose((dw * nodes).sum(1), 1.0, rtol=0, atol=tol * 10)
    assert np.all(w >= -tol)
    ghost = (nodes < W_LO) | (nodes > W_HI)
    assert np.all(w[ghost] == 0.0) and np.all(dw[ghost] == 0.0)
    # interpolation at the walls: entries 0 and 1 are exactly on the walls
    for j, wall in ((0, W_LO), (1, W_HI)):
        np.testing.assert_allclose(w[j], np.where(nodes[j] == wall, 1.0, 0.0), rtol=0, atol=tol)
    # the modification reaches half a cell (quadratic) or one cell (cubic) from each wall
    reach = {"quadratic_bm": 0.5, "cubic_bm": 1.0}[kind]
    near = np.minimum(x - W_LO, W_HI - x) < reach - 1e-6
    far = np.minimum(x - W_LO, W_HI - x) > reach + 1e-6
    assert np.all(mod[near]) and not np.any(mod[far])


@pytest.mark.parametrize("kind", BM)
def test_weights_equal_plain_bspline_away_from_walls_and_without_walls(kind):
    """Farther than the modified layer from the walls, and everywhere on an axis without walls
    (-inf, +inf: periodic or open), the weights are those of the plain B-spline (round-off)."""
    plain = _shapes.BOUNDARY_MODIFIED[kind]
    xi = np.random.default_rng(1).uniform(W_LO + 1.01, W_HI - 1.01, 500)
    for lo, hi in ((W_LO, W_HI), (-np.inf, np.inf)):
        nodes, w, dw, _ = _weights(kind, xi, lo, hi)
        b0, w0, dw0 = _shapes.weights_1d(plain, jnp.asarray(xi), 1.0)
        np.testing.assert_array_equal(nodes[:, 0], np.asarray(b0))
        np.testing.assert_allclose(w, np.asarray(w0), rtol=0, atol=ROUNDOFF)
        np.testing.assert_allclose(dw, np.asarray(dw0), rtol=0, atol=ROUNDOFF)


def test_quadratic_bm_closed_form_at_the_wall():
    """Quadratic, distance x (cells) from a lower wall W: N'_W = 1 - x, N'_{W+1} = x for
    x <= 1/2; at x = 3/4 the plain values 9/32, 22/32, 1/32; the same mirrored at the upper wall."""
    x = np.array([0.0, 0.1, 0.3, 0.5, 0.75])
    nodes, w, _, _ = _weights("quadratic_bm", W_LO + x)
    for j, xj in enumerate(x):
        on = {int(n): float(v) for n, v in zip(nodes[j], w[j]) if v != 0.0}
        exp = {3: 1 - xj, 4: xj} if xj <= 0.5 else {3: 9 / 32, 4: 22 / 32, 5: 1 / 32}
        exp = {n: v for n, v in exp.items() if v != 0.0}
        assert on.keys() == exp.keys() and np.allclose(list(on.values()), list(exp.values()), atol=ROUNDOFF), (xj, on)
    nodes_hi, w_hi, _, _ = _weights("quadratic_bm", W_HI - x)
    np.testing.assert_allclose(np.sort(w_hi, 1), np.sort(w, 1), atol=ROUNDOFF)


@pytest.mark.parametrize("kind", BM)
def test_weight_gradient_matches_finite_difference(kind):
    """dw/dx equals the central difference of w (step 1e-6 cells) on absolute nodes, near the
    walls included; points within 1e-3 cells of a kink (half-integers for the quadratic,
    integers for the cubic, relative to the nodes) are left out.  Tolerance as in
    tests/test_engine.py: 1e-8 / h."""
    h, e = 0.05, 1e-6
    xi = _inside(seed=2)
    frac = xi - np.floor(xi)
    kink = 0.5 if kind == "quadratic_bm" else 0.0
    d = np.minimum(np.abs(frac - kink), 1 - np.abs(frac - kink))
    xi = xi[(d > 1e-3) & (xi > W_LO + 1e-3) & (xi < W_HI - 1e-3)]
    nodes, _, dw, _ = _weights(kind, xi, h=h)
    n_p, wp = _weights(kind, xi + e, h=h)[:2]
    n_m, wm = _weights(kind, xi - e, h=h)[:2]
    k = nodes.shape[1]

    def on_nodes(nn, ww):
        out = np.zeros((len(xi), k + 2))
        np.add.at(out, (np.arange(len(xi))[:, None], nn - nodes[:, :1] + 1), ww)
        return out

    fd = (on_nodes(n_p, wp) - on_nodes(n_m, wm)) / (2 * e * h)
    np.testing.assert_allclose(on_nodes(nodes, dw), fd, rtol=0, atol=1e-8 / h)


# ======================================================================================
# Stencil (tensor product) with box walls, APIC, packing
# ======================================================================================


def _scene(kind, dim, faces=None, h=0.04):
    """A 0.4 m box (10 cells per axis) with walls on every face unless ``faces`` says otherwise
    (kind per face, 'xyz'[a] + '_lo'/'_hi')."""
    faces = faces or {}
    ng = ghost_cells(kind)
    walls = []
    for a in range(dim):
        for side, sgn in (("lo", 1.0), ("hi", -1.0)):
            kd = faces.get(f"{'xyz'[a]}_{side}", "slip")
            if kd in WALL_KINDS:
                nrm = [0.0] * dim
                nrm[a] = sgn
                pt = [0.0] * dim
                pt[a] = 0.0 if side == "lo" else 0.4
                walls.append(m.Wall(tuple(pt), tuple(nrm), kd))
    return m.Scene(
        dim=dim, h=h, lo=(0.0,) * dim, hi=(0.4,) * dim, periodic=(False,) * dim,
        grid_origin=(-ng * h,) * dim, grid_shape=(10 + 2 * ng + 1,) * dim, walls=tuple(walls),
        shape=kind, lp_cells=0.25, transfer="apic", flip_blend=0.95, rheology=m.Newtonian(),
        shear_measure="standard", viscous_update="maxwell", maxwell_G=1.0, dt=1e-3,
        steps_per_frame=1, n_frames=1, n_particles=60,
    )  # fmt: skip


def _near_wall_points(dim, n=60, seed=3):
    """Particles in the box, one in three within a cell of a face, one on a face exactly."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.0, 0.4, (n, dim))
    for i in range(0, n, 3):
        a = rng.integers(dim)
        x[i, a] = rng.choice([rng.uniform(0, 0.04), rng.uniform(0.36, 0.4)])
    x[0, 0] = 0.0
    x[1, -1] = 0.4
    return jnp.asarray(x)


@pytest.mark.parametrize("kind", BM)
@pytest.mark.parametrize("dim", [2, 3])
def test_stencil_identities_and_zero_ghost_weight(kind, dim):
    """sum w = 1, sum w r = 0, sum grad w = 0, sum r (x) grad w = I at particles next to the walls
    (so P2G conserves mass and momentum and the internal forces sum to zero), and every stencil
    node with non-zero weight lies inside the box (walls included); ghost nodes hold no mass."""
    scene = _scene(kind, dim)
    x = _near_wall_points(dim)
    st = jax.jit(lambda x: (lambda s: (s.idx, s.w, s.dw, s.r))(_Stencil(scene, x)))(x)
    idx, w, dw, r = (np.asarray(a) for a in st)
    h = scene.h
    np.testing.assert_allclose(w.sum(1), 1.0, rtol=0, atol=ROUNDOFF)
    np.testing.assert_allclose((w[..., None] * r).sum(1), 0.0, rtol=0, atol=ROUNDOFF * h)
    np.testing.assert_allclose(dw.sum(1) * h, 0.0, rtol=0, atol=ROUNDOFF)
    np.testing.assert_allclose(np.einsum("nsi,nsj->nij", r, dw), np.broadcast_to(np.eye(dim), (len(x), dim, dim)),
                               rtol=0, atol=ROUNDOFF * 10)  # fmt: skip
    xn = scene.node_positions()[idx]
    np.testing.assert_allclose(xn - np.asarray(x)[:, None, :], r, rtol=0, atol=ROUNDOFF * h)
    outside = np.any((xn < -1e-9) | (xn > 0.4 + 1e-9), axis=-1)
    assert outside.any()  # the stencils do reach the ghost layer ...
    assert np.all(w[outside] == 0.0) and np.all(dw[outside] == 0.0)  # ... with weight 0


@pytest.mark.parametrize("kind", BM)
@pytest.mark.parametrize("dim", [2, 3])
def test_apic_exact_for_affine_velocity_at_the_walls(kind, dim):
    """G2P of an affine nodal velocity v_i = a + A x_i gives v_p = a + A x_p and C = L = A at
    every particle, walls included (the near-wall columns of C switch from B D^-1 to L,
    ``_transfer.make_g2p``); tolerance 1e-11 of |A| (round-off)."""
    scene = _scene(kind, dim)
    x = _near_wall_points(dim, seed=4)
    rng = np.random.default_rng(5)
    a, A = rng.normal(size=dim), rng.normal(size=(dim, dim))
    xn = scene.node_positions()
    v_nodes = jnp.asarray(a[None, :] + xn @ A.T)
    st = _Stencil(scene, x)
    v_pic, v_p, C, L = make_g2p(scene)(st, v_nodes, v_nodes, jnp.zeros_like(x))
    np.testing.assert_allclose(np.asarray(v_pic), a[None, :] + np.asarray(x) @ A.T, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(C), np.broadcast_to(A, C.shape), rtol=0, atol=1e-11)
    np.testing.assert_allclose(np.asarray(L), np.broadcast_to(A, L.shape), rtol=0, atol=1e-11)
    assert np.asarray(st.modified).any()


def test_box_wall_nodes_only_box_faces():
    """Walls on the box faces are found (node index of the face); open faces and extra planes
    (even axis-aligned ones inside the box) are not modified."""
    scene = _scene("quadratic_bm", 2, faces={"x_hi": "open"})
    scene = scene.replace(walls=scene.walls + (m.Wall((0.2, 0.0), (1.0, 0.0), "noslip"),))
    lo, hi = box_wall_nodes(scene)
    ng = ghost_cells("quadratic_bm")
    assert list(lo) == [ng, ng] and hi[0] == np.inf and hi[1] == ng + 10


def _box_setup(shape, ppc, dim, faces):
    raw = {
        "domain": {"dim": dim, "lo_m": [0.0] * dim, "hi_m": [0.4] * (dim - 1) + [0.2], "cell_size_m": 0.05},
        "boundary": faces,
        "numerics": {"shape": shape, "ppc": ppc, "dtype": "float64"},
        "time": {"t_end_s": 0.01, "n_frames": 1},
        "material": {"model": "newtonian", "density_kg_m3": 1500.0, "bulk_modulus_pa": 1e5, "viscosity_pa_s": 1.0},
        "gravity": {"g_m_s2": 9.81},
        "bodies": [{"lo_m": [0.0] * dim, "hi_m": [0.4] * (dim - 1) + [0.2]}],
    }
    return m.build(m.validate(raw))


@pytest.mark.parametrize(
    "shape,ppc,dim,faces",
    [
        ("quadratic_bm", 2, 2, {"x_lo": "slip", "x_hi": "noslip", "y_lo": "noslip", "y_hi": "symmetry"}),
        ("quadratic_bm", 3, 2, {"x_lo": "slip", "x_hi": "slip", "y_lo": "noslip", "y_hi": "slip"}),
        ("cubic_bm", 2, 2, {"x_lo": "slip", "x_hi": "slip", "y_lo": "noslip", "y_hi": "slip"}),
        ("quadratic_bm", 2, 3, {f"{a}_{s}": "slip" for a in "xyz" for s in ("lo", "hi")}),
    ],
)
def test_filled_box_measures_phi_one_everywhere(shape, ppc, dim, faces):
    """As tests/test_grid_volume.py for the plain shapes: a box filled at the seeding lattice
    measures packing phi = 1 at every particle, walls included (``node_fill`` counts the
    modified functions exactly)."""
    setup = _box_setup(shape, ppc, dim, faces)
    sc = setup.scene
    mass, _, _, st = make_p2g(sc)(setup.state, setup.params)
    phi = np.asarray(packing_fraction(sc, mass, st, setup.params.material.rho, node_fill(sc)))
    assert phi.min() == pytest.approx(1.0, abs=1e-9) and phi.max() == pytest.approx(1.0, abs=1e-9)


def test_filled_box_with_an_open_face():
    """An open face is no wall: the fill runs on past it (1 in the interior near it) and the box
    packing still measures 1 at every particle farther than 3 cells below the open top (the reach
    of a particle's stencil plus that of its nodes: nearer, the missing material above counts)."""
    setup = _box_setup("quadratic_bm", 2, 2, {"x_lo": "slip", "x_hi": "slip", "y_lo": "noslip", "y_hi": "open"})
    sc = setup.scene
    mass, _, _, st = make_p2g(sc)(setup.state, setup.params)
    phi = np.asarray(packing_fraction(sc, mass, st, setup.params.material.rho, node_fill(sc)))
    y = np.asarray(setup.state.x[:, 1])
    inner = y < 0.2 - 3 * sc.h
    assert inner.sum() >= 16 and np.allclose(phi[inner], 1.0, atol=1e-9)


# ======================================================================================
# jit / grad / vmap through a short run
# ======================================================================================


def _small(shape, mu):
    return m.validate(
        {
            "domain": {"lo_m": [0, 0], "hi_m": [0.2, 0.1], "cell_size_m": 0.02},
            "boundary": {"x_lo": "slip", "x_hi": "slip", "y_lo": "noslip", "y_hi": "slip"},
            "numerics": {"shape": shape, "dtype": "float64"},
            "time": {"t_end_s": 0.03, "n_frames": 1},
            "material": {"model": "newtonian", "density_kg_m3": 1000.0, "bulk_modulus_pa": 15000.0,
                         "viscosity_pa_s": mu},
            "gravity": {"g_m_s2": 9.81},
            "bodies": [{"lo_m": [0.0, 0.0], "hi_m": [0.06, 0.06]}],
        }
    )  # fmt: skip


@pytest.mark.parametrize("kind", ["quadratic_bm"])  # cubic_bm runs the same fold (_shapes._boundary_modified)
def test_grad_and_vmap_through_a_run(kind):
    """d(mean x)/d(mu) by reverse mode equals a central finite difference (rtol 1e-5: the FD
    step 1e-4 relative leaves ~1e-8 truncation, float64), and vmap over two viscosities equals
    two runs (rtol 1e-10, reduction order only)."""
    s = m.build(_small(kind, 1.0))

    def final_x(mu):
        return m.simulate(s.scene, s.state, s.params._replace(material=s.params.material._replace(mu=mu)))[0].x

    run = jax.jit(final_x)
    mu0 = jnp.asarray(1.0, jnp.float64)
    g = float(jax.jit(jax.grad(lambda mu: jnp.mean(final_x(mu)[:, 0])))(mu0))
    e = 1e-4
    fd = (float(jnp.mean(run(mu0 + e)[:, 0])) - float(jnp.mean(run(mu0 - e)[:, 0]))) / (2 * e)
    assert np.isfinite(g) and g != 0.0
    np.testing.assert_allclose(g, fd, rtol=1e-5)
    mus = jnp.asarray([0.5, 4.0], jnp.float64)
    xb = jax.jit(jax.vmap(final_x))(mus)
    for i in range(2):
        np.testing.assert_allclose(np.asarray(xb[i]), np.asarray(run(mus[i])), rtol=1e-10)
