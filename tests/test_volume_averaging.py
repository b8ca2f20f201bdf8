"""``numerics.volume_averaging = "jbar"``: J-bar (F-bar) volume averaging against volumetric
locking (issue 14; Zhao, Jiang & Choo 2023; formulas in the ``mpmjax._transfer`` docstring).

* The projection returns a uniform volume increment exactly, at walls and ghost nodes, on
  periodic axes, for every shape function, in 2D and 3D, and ignores inactive particles.
* ``volume_increment`` is det(I + dt L) - 1 without the rounding of forming det near 1.
* Stiff column (the locking of the issue): a 0.1 m water column (rho = 1000, mu = 1e-3 Pa s,
  GIMP, ppc 2, h = 0.0125 m, float32) released at kappa = 2.25e5 Pa and at 2.2e8 Pa.  The stiff
  case needs dt = 7.0e-6 s (c = 716 m/s); both run at that dt, so that the comparison sees the
  pressure's locking only: the transfers lose momentum at a rate that grows as dt shrinks (the
  soft column run at the stiff dt is 17 % behind the soft column run at its own dt 2.0e-4 s at
  t = 0.12 s; docs/validation.md, "Volumetric locking").  Measured (front in m from the left
  wall at t* = 0.15 s, where the soft front has moved one column width): soft 0.2129 (off) /
  0.2110 (on); stiff 0.1980 off (-7.0 %, locked) and 0.2142 on (+1.5 %).  ~40 s of CPU.
* Deposit (dambreak-lab, coarse and short): the bottom row keeps J within 0.9-1.1 with jbar.
* The pipe inflow's parked pool particles (zero mass) keep their J = 1.
* jax.grad of a final-state scalar with respect to kappa and mu0 matches a central finite
  difference (float64), and vmap over two kappas equals the two separate runs.

Every case sets ``numerics.pressure = "explicit"``: J-bar is a device of the particles' pressure
(the grid pressure refuses it).
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import COUSSOT_BASE

import mpmjax as m
from mpmjax._transfer import make_p2g, volume_average, volume_increment


def _box(shape, dim, periodic=False):
    faces = {f"{a}_{s}": "slip" for a in "xyz"[:dim] for s in ("lo", "hi")}
    if periodic:
        faces.update(x_lo="periodic", x_hi="periodic")
    raw = {
        "domain": {"dim": dim, "lo_m": [0.0] * dim, "hi_m": [0.4] * (dim - 1) + [0.2], "cell_size_m": 0.05},
        "boundary": faces,
        "numerics": {"shape": shape, "ppc": 2, "dtype": "float64", "volume_averaging": "jbar", "pressure": "explicit"},
        "time": {"t_end_s": 0.01, "n_frames": 1},
        "material": {"model": "newtonian", "density_kg_m3": 1500.0, "bulk_modulus_pa": 1e5, "viscosity_pa_s": 1.0},
        "bodies": [{"lo_m": [0.0] * dim, "hi_m": [0.4] * (dim - 1) + [0.2]}],
    }
    return m.build(m.validate(raw))


@pytest.mark.parametrize(
    "shape,dim,periodic",
    [("gimp", 2, False), ("linear", 2, False), ("quadratic", 2, False), ("cubic", 2, True), ("gimp", 3, False)],
)
def test_uniform_increment_is_returned_exactly(shape, dim, periodic):
    s = _box(shape, dim, periodic)
    n = s.scene.n_particles
    active = jnp.asarray(np.arange(n) % 7 != 3)  # a few inactive particles: zero mass, must not count
    state = s.state._replace(active=active)
    mass, _, _, st = make_p2g(s.scene)(state, s.params)
    has = mass > 0.0
    inv_m = jnp.where(has, 1.0 / jnp.where(has, mass, 1.0), 0.0)
    mass_p = s.params.material.rho * state.vol0 * active
    delta = jnp.where(active, 3e-3, 0.5)  # the inactive particles' value is garbage
    dbar = np.asarray(volume_average(s.scene, st, mass_p, delta[:, None], inv_m, has)[:, 0])
    np.testing.assert_allclose(dbar[np.asarray(active)], 3e-3, rtol=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_volume_increment_is_det_minus_one(dim):
    L = jnp.asarray(np.random.default_rng(0).normal(size=(50, dim, dim)))
    for dt in (1e-1, 1e-3):
        exact = jnp.linalg.det(jnp.eye(dim)[None] + dt * L) - 1.0
        np.testing.assert_allclose(np.asarray(volume_increment(L, dt)), np.asarray(exact), rtol=1e-10, atol=1e-15)
    # float32: an increment of 1e-9 survives (det(I + A) would round it to 0 or 1.2e-7)
    A = jnp.zeros((1, dim, dim), jnp.float32).at[0, 0, 0].set(1e-9)
    assert float(volume_increment(A, 1.0)[0]) == pytest.approx(1e-9, rel=1e-6)


# ------------------------------------------------------------------- stiff column

COLUMN_A = 0.1  # column width = height [m]
T_COLUMN = 0.15


def _column(kappa, va, dt=0.0):
    """The column's setup; dt = 0: the scene's own stable step."""
    raw = {
        "name": "stiff-column",
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [0.4, 0.2], "cell_size_m": 0.0125},
        "boundary": {"x_lo": "slip", "x_hi": "slip", "y_lo": "slip", "y_hi": "slip"},
        "numerics": {"shape": "gimp", "ppc": 2, "volume_averaging": va, "dt_s": dt, "pressure": "explicit"},
        "time": {"t_end_s": T_COLUMN, "n_frames": 15},
        "material": {"model": "newtonian", "density_kg_m3": 1000.0, "bulk_modulus_pa": kappa, "viscosity_pa_s": 1e-3},
        "bodies": [{"lo_m": [0.0, 0.0], "hi_m": [COLUMN_A, COLUMN_A]}],
    }
    return m.build(m.validate(raw))


def _front(s):
    """Front position [m] (from the left wall) at each of the 15 frames."""
    _, fr = m.run(s.scene, s.state, s.params)
    return np.asarray(m.runout(fr.x, fr.active, 0, 0.0, s.info["particle_spacing_m"]))


def test_stiff_column_flows_like_the_soft_one_with_jbar():
    stiff_dt = _column(2.2e8, "none").scene.dt  # 7.0e-6 s, the wave-speed limit at kappa = 2.2e8 Pa
    fronts = {(k, va): _front(_column(k, va, stiff_dt)) for k in (2.25e5, 2.2e8) for va in ("none", "jbar")}
    soft = fronts[(2.25e5, "jbar")]
    i = int(np.argmax(soft >= 2 * COLUMN_A))  # first frame where the soft front has moved one width
    assert soft[i] >= 2 * COLUMN_A
    gap = {va: fronts[(2.2e8, va)][i] / fronts[(2.25e5, va)][i] - 1.0 for va in ("none", "jbar")}
    print(f"t* = {(i + 1) * T_COLUMN / 15:.3f} s; fronts", {k: round(float(v[i]), 4) for k, v in fronts.items()}, gap)
    assert abs(gap["jbar"]) < 0.05
    assert gap["none"] < -0.05  # without it the stiff column locks (the defect)


# ------------------------------------------------------------------- inflow pool


def test_parked_inflow_particles_keep_their_state():
    cfg = m.load_scene(
        "flume-deposition", ["time.t_end_s=1.0", "time.n_frames=1", "numerics.volume_averaging=jbar", "numerics.pressure=explicit"]
    )
    s = m.build(cfg)
    fin, _ = m.run(s.scene, s.state, s.params)
    act = np.asarray(fin.active)
    J = np.asarray(fin.J)
    assert act.sum() > 0 and (~act).sum() > 0 and int(fin.n_lost) == 0
    assert np.all(J[~act] == 1.0)  # still parked: zero mass, untouched
    assert np.all(np.isfinite(J)) and np.all(np.isfinite(np.asarray(fin.x)))


# ------------------------------------------------------------------- gradients and vmap


@functools.cache
def _small():
    raw = {
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [0.6, 0.3], "cell_size_m": 0.03},
        "numerics": {"dtype": "float64", "shape": "gimp", "ppc": 2, "volume_averaging": "jbar", "pressure": "explicit"},
        "time": {"t_end_s": 0.06, "n_frames": 2},
        "material": dict(COUSSOT_BASE),
        "bodies": [{"lo_m": [0.0, 0.0], "hi_m": [0.2, 0.15]}],
    }
    return m.build(m.validate(raw))


def _loss(mat):
    s = _small()
    fin, _ = m.simulate(s.scene, s.state, s.params._replace(material=mat))
    return jnp.sum(fin.x[:, 0] ** 2) + jnp.sum(fin.J)


def test_gradient_matches_finite_difference():
    """d loss / d kappa and d mu0 by jax.grad against a central difference (step 1e-5 relative;
    tests/test_gradients.py explains the choice): relative error < 1e-4."""
    s = _small()
    mat = s.params.material
    g = jax.jit(jax.grad(_loss))(mat)
    f = jax.jit(_loss)
    for name in ("kappa", "mu0"):
        th = float(getattr(mat, name))
        d = 1e-5 * th
        fd = (f(mat._replace(**{name: jnp.asarray(th + d)})) - f(mat._replace(**{name: jnp.asarray(th - d)}))) / (2 * d)
        ad = float(getattr(g, name))
        print(name, "AD", ad, "FD", float(fd), "rel err", abs(float(fd) - ad) / abs(ad))
        assert np.isfinite(ad) and abs(float(fd) - ad) < 1e-4 * abs(ad)


def test_vmap_over_kappa_equals_separate_runs(allclose):
    s = _small()
    kap = jnp.asarray([15000.0, 60000.0])
    pb = jax.tree.map(lambda a: jnp.broadcast_to(a, (2,) + jnp.shape(a)), s.params)
    pb = pb._replace(material=pb.material._replace(kappa=kap))
    batched = jax.jit(jax.vmap(lambda p: m.simulate(s.scene, s.state, p)))(pb)
    runs = [m.run(s.scene, s.state, s.params._replace(material=s.params.material._replace(kappa=k))) for k in kap]
    single = jax.tree.map(lambda *a: jnp.stack(a), *runs)
    assert allclose(batched, single, rtol=1e-10, atol=1e-13)
    assert np.max(np.abs(np.asarray(batched[0].J[0] - batched[0].J[1]))) > 1e-4  # kappa matters


# ------------------------------------------------------------------- deposit


def test_deposit_bottom_row_volume_ratio():
    """dambreak-lab, coarse and short (h = 0.02 m, 3 s; the docs figure is the full 15 s at
    h = 0.01 m): the bottom row of particles (y < one particle spacing) keeps J within 0.9-1.1
    with jbar; without it J there spans 0.81-1.38 (measured).  Above the bottom row (y > h) jbar
    gives 0.942-1.046 (1-99 %: 0.954-1.027) against 0.896-1.137 without: the issue's 0.97-1.03
    there is not met (docs/validation.md)."""
    out = {}
    for va in ("none", "jbar"):
        cfg = m.load_scene(
            "dambreak-lab",
            ["time.t_end_s=3.0", "time.n_frames=1", "domain.cell_size_m=0.02", f"numerics.volume_averaging={va}", "numerics.ppc=2", "numerics.pressure=explicit"],
        )
        s = m.build(cfg)
        fin, _ = m.run(s.scene, s.state, s.params)
        x, J, a = np.asarray(fin.x), np.asarray(fin.J), np.asarray(fin.active)
        bot = a & (x[:, 1] < s.info["particle_spacing_m"])
        out[va] = (J[bot].min(), J[bot].max())
    print(out)
    assert 0.9 <= out["jbar"][0] and out["jbar"][1] <= 1.1
    assert out["none"][0] < 0.9 or out["none"][1] > 1.1
