"""``numerics.wall_yield`` (``mpmjax._wall_yield``): the wall row's effective yield stress is exactly the
inverse of a Bingham flow rule averaged over a row with a linear stress, and the key is refused where it
cannot apply.  The physics (a layer near its yield limit on a no-slip incline) is tested in
tests/test_boundary_slopes.py."""

import numpy as np
import pytest

from mpmjax import SceneError, validate
from mpmjax._wall_yield import effective_yield_stress


@pytest.mark.parametrize("rate_factor", [0.0, 0.05, 0.3, 0.9, 1.0, 3.0])
def test_the_effective_yield_stress_inverts_the_row_averaged_bingham_law(rate_factor):
    """Row of height h, linear shear stress tau(y) = tau_bar + (h/2 - y) 2 Delta / h, Bingham rate
    (tau - tau_y)/mu where tau > tau_y.  Given the row's mean rate gdot, tau_bar = tau_y_eff + mu gdot
    must be the mean stress whose profile averages to gdot: checked by integrating the profile on 200 001
    points (midpoint error ~1e-10 of the rate).  rate_factor: mu gdot / Delta (at 1 the whole row has
    just yielded; above, the law is unchanged; at 0 the row holds up to tau_y - Delta)."""
    tau_y, mu, delta = 100.0, 20.0, 30.0
    gdot = rate_factor * delta / mu
    tau_bar = float(effective_yield_stress(tau_y, mu * gdot, delta)) + mu * gdot
    if rate_factor == 0.0:
        assert tau_bar == pytest.approx(tau_y - delta, rel=1e-12)
        return
    y = (np.arange(200_001) + 0.5) / 200_001  # y / h
    tau = tau_bar + (0.5 - y) * 2.0 * delta
    mean_rate = float(np.mean(np.maximum(tau - tau_y, 0.0) / mu))
    assert mean_rate == pytest.approx(gdot, rel=1e-6)
    if rate_factor >= 1.0:
        assert tau_bar == pytest.approx(tau_y + mu * gdot, rel=1e-12)


def test_no_drop_leaves_the_yield_stress():
    assert float(effective_yield_stress(50.0, 0.0, 0.0)) == 50.0
    assert float(effective_yield_stress(50.0, 7.0, 0.0)) == 50.0
    assert float(effective_yield_stress(5.0, 0.0, 30.0)) == 0.0  # never below zero


def _raw(**numerics):
    return {
        "domain": {"lo_m": [0.0, 0.0], "hi_m": [0.4, 0.2], "cell_size_m": 0.02},
        "time": {"t_end_s": 0.1},
        "material": {"model": "bingham", "density_kg_m3": 1000.0, "bulk_modulus_pa": 2e4,
                     "viscosity_pa_s": 1.0, "yield_stress_pa": 10.0},
        "bodies": [{"lo_m": [0.0, 0.0], "hi_m": [0.1, 0.1]}],
        "numerics": numerics,
    }


def test_the_default_falls_back_to_cell_where_wall_does_not_apply():
    """The default is "wall"; a scene with a B-spline shape, the thesis's shear measure or the depth-averaged
    formulation gets "cell" without being refused (only a "wall" the scene sets itself is refused there)."""
    assert validate(_raw())["numerics.wall_yield"] == "wall"
    assert validate(_raw(shape="linear"))["numerics.wall_yield"] == "wall"
    assert validate(_raw(shape="quadratic_bm"))["numerics.wall_yield"] == "cell"
    thesis = _raw()
    thesis["material"]["shear_measure"] = "thesis"
    assert validate(thesis)["numerics.wall_yield"] == "cell"
    shallow = _raw()
    shallow["model"] = {"formulation": "depth-averaged"}
    assert validate(shallow)["numerics.wall_yield"] == "cell"


def test_the_key_is_refused_where_it_cannot_apply():
    validate(_raw(wall_yield="wall"))
    with pytest.raises(SceneError, match="numerics.wall_yield"):
        validate(_raw(wall_yield="bed"))
    with pytest.raises(SceneError, match="numerics.shape = 'quadratic_bm'"):
        validate(_raw(wall_yield="wall", shape="quadratic_bm"))
    validate(_raw(wall_yield="wall", shape="linear"))
    thesis = _raw(wall_yield="wall")
    thesis["material"]["shear_measure"] = "thesis"
    with pytest.raises(SceneError, match="material.shear_measure"):
        validate(thesis)
    shallow = _raw(wall_yield="wall")
    shallow["model"] = {"formulation": "depth-averaged"}
    with pytest.raises(SceneError, match="numerics.wall_yield = 'wall' is invalid with model.formulation"):
        validate(shallow)


def test_gradients_are_finite_where_every_square_root_sits_at_zero():
    """The effective yield stress takes square roots of traced stresses, guarded at 0.  At the start
    of a run every particle's stress and rate are 0 (so the rows' tractions, the drop and tau_pl are
    0): the derivative of two steps' velocities with respect to tau_y, in reverse mode, must be finite.
    (Against finite differences through a whole run: the plug speed of the layer of
    tests/test_boundary_slopes.py at 5 cells, 0.2 s, float64: reverse -9.71508e-5, forward the same to
    1e-15, central difference -9.71322e-5 (m/s)/Pa: 2e-4 apart, its truncation; docs/wall-yield.md.)"""
    import jax
    import jax.numpy as jnp

    from mpmjax import build
    from mpmjax._step import make_step
    from mpmjax.studies.validate import incline_config

    for tp, d in ((0.0, 0.0), (0.0, 30.0), (30.0, 0.0), (30.0, 30.0)):
        g = jax.grad(lambda a, b, c: effective_yield_stress(a, b, c), argnums=(0, 1, 2))(50.0, tp, d)
        assert all(np.isfinite(float(x)) for x in g), (tp, d, g)
    base = {"numerics.dtype": "float64", "numerics.wall_yield": "wall"}
    s = build(incline_config(5, 1.1, 0.05, base))
    step = make_step(s.scene)

    def moved(tau_y):
        p = s.params._replace(material=s.params.material._replace(tau_y=tau_y))
        return jnp.sum(step(step(s.state, p), p).v)

    grad = jax.jit(jax.grad(moved))(s.params.material.tau_y)
    assert np.isfinite(float(grad))
