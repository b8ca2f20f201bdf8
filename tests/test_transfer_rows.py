"""Row windows (``_transfer._Stencil.rows``): on the CPU the transfers gather and scatter a row of
k nodes along the last axis per index instead of one node.  The padded lines and their fold must
give exactly what the flat node indices give: clipped at the grid's faces, wrapped on a periodic
last axis, for every shape kind in 2D and 3D, in the whole step and in its derivative.

Tolerance 1e-12 relative (float64): the row scatter adds a node's contributions in the same
particle order as the flat one, except that those folded back from the padding come last, so
only the order of a few additions differs.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_fusion import RAW, _value_grad_jvp

from calibration.fit import forward_jacobian

import mpmjax as m
from mpmjax import _shapes, _transfer
from mpmjax._transfer import _Stencil

REL = 1e-12


def _scene(dim, kind, periodic_last):
    h, n = 0.04, 9
    return m.Scene(
        dim=dim, h=h, lo=(0.0,) * dim, hi=(n * h,) * dim, periodic=(False,) * (dim - 1) + (periodic_last,),
        grid_origin=(0.0,) * dim, grid_shape=(n,) * dim, walls=(), shape=kind, lp_cells=0.5, transfer="apic",
        flip_blend=0.95, rheology=m.Newtonian(), shear_measure="standard", viscous_update="maxwell", maxwell_G=1.0,
        dt=1e-3, steps_per_frame=1, n_frames=1, n_particles=200,
    )


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("kind", sorted(_shapes.STENCIL))
@pytest.mark.parametrize("periodic_last", [False, True])
def test_row_gather_and_scatter_equal_the_flat_ones(dim, kind, periodic_last):
    """Particles over the whole grid and beyond its faces (so stencils are clipped or wrapped)."""
    if periodic_last and kind in _shapes.BOUNDARY_MODIFIED:
        pytest.skip("boundary-modified weights need walls, not a periodic axis")
    sc = _scene(dim, kind, periodic_last)
    rng = np.random.default_rng(dim * 7 + len(kind))
    x = jnp.asarray(rng.uniform(-0.1, 0.46, (200, dim)))
    a = jnp.asarray(rng.standard_normal((sc.n_nodes, dim)))
    vals = jnp.asarray(rng.standard_normal((200, _shapes.STENCIL[kind] ** dim, 3)))

    def both(rows):
        st = _Stencil(sc, x, rows=rows).localise(_transfer.Replicated(sc.n_nodes))
        return st.gather(a), st.scatter(vals, sc.n_nodes)

    g_rows, s_rows = jax.jit(lambda: both(True))()
    g_flat, s_flat = jax.jit(lambda: both(False))()
    np.testing.assert_array_equal(np.asarray(g_rows), np.asarray(g_flat))  # a gather copies values
    scale = float(jnp.max(jnp.abs(s_flat)))
    assert scale > 0.0
    np.testing.assert_allclose(np.asarray(s_rows), np.asarray(s_flat), rtol=0, atol=REL * scale)


@pytest.mark.parametrize("numerics", [{}, {"volume_averaging": "jbar", "grid_density_cap": 0.05}])
def test_the_step_and_its_derivatives_are_those_of_the_flat_transfers(monkeypatch, numerics):
    """The coarse lab dam break of test_fusion (51 steps, float64): final mean x, its reverse and
    forward derivative w.r.t. mu0, with rows (the CPU default) and flat; with J-bar and the grid volume
    check too (their own scatter and gathers)."""
    raw = dict(RAW, numerics=dict(RAW["numerics"], **numerics))
    setup = m.build(m.validate(raw))
    assert _Stencil(setup.scene, setup.state.x).rows  # the CPU default
    rows = _value_grad_jvp(setup)
    monkeypatch.setattr(_transfer, "on_cpu", lambda: False)
    assert not _Stencil(setup.scene, setup.state.x).rows
    flat = _value_grad_jvp(setup)
    assert rows[1] != 0.0
    for a, b in zip(rows, flat):
        assert abs(a - b) <= REL * abs(b), (rows, flat)


def test_flat_transfers_is_a_trace_time_switch():
    """Inside ``mpmjax.flat_transfers()`` (forward-mode Jacobians) stencils are flat, outside the CPU's
    rows again; the forward-mode gradient of the calibration (``forward_jacobian``) equals reverse mode's
    to 1e-9 relative, the bound test_fusion sets for the two modes in float64 (they round in different
    orders through 51 steps)."""
    setup = m.build(m.validate(RAW))
    with m.flat_transfers():
        assert not _Stencil(setup.scene, setup.state.x).rows
    assert _Stencil(setup.scene, setup.state.x).rows

    def f(z):
        p = setup.params._replace(material=setup.params.material._replace(mu0=z[0], lambda0=z[1]))
        s = m.simulate(setup.scene, setup.state, p)[0]
        return jnp.sum(s.x[:, 0] * s.active) / jnp.sum(s.active)

    z = jnp.asarray([setup.params.material.mu0, setup.params.material.lambda0])
    v_f, g_f = jax.jit(forward_jacobian(f))(z)
    v_r, g_r = jax.jit(jax.value_and_grad(f))(z)
    assert abs(float(v_f - v_r)) <= REL * abs(float(v_r))
    np.testing.assert_allclose(np.asarray(g_f), np.asarray(g_r), rtol=1e-9, atol=0)
