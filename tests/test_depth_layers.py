"""Layers across a column's depth (``numerics.depth_layers``, ``mpmjax._basal.layered``): the depth-averaged
step's Coussot column carries its structure in K layers, each sheared at its own rate under the shallow
layer's linear stress (docs/depth-layers.md).  Float64 (tests/conftest.py).

* the layered fluidity F = sum_k w_k / mu_k against its closed forms: a uniform column is the Newtonian
  closure (F = 1 / (3 mu), each layer at the parabolic profile's rate 3 U / h (1 - zeta)), and a column whose
  bed layers are broken under a structured plug has F = (1 - (1 - e)^3) / (3 mu_band) + (1 - e)^3 / (3 mu_plug)
  (the series integral with the edge e on a layer edge): to round-off;
* a 5 cm layer of the lab material released from rest on an incline at twice its flow curve's minimum stress,
  in the depth-averaged step with 32 layers, against the same layer solved across its depth
  (``mpmjax.studies.film``): the mean speed at 6 s within 5 % (measured +0.4 %; one value per column, the
  default, runs it 1.75x too fast: benchmarks/accuracy/coussot_layers.py);
* the derivative of that speed with respect to mu0 through the layered step (forward mode) against a central
  difference of 1e-6 mu0 (1e-6 relative; measured 3e-8: the speed is far from linear in mu0, so the
  difference converges only below 1e-5 mu0);
* float32 reverse mode through the layers equals forward mode and is finite (a node without mass has no
  fluidity);
* the result file holds the depth mean and the layers; the full model refuses layers (naming the key) and ignores
  the default;
* ``mpmjax validate``'s ``coussot-film-da`` at its full size passes with the default layers at both stresses, and
  with one value per column misses by more than 50 % (measured -0.02 / -3.2 % against +75 / +348 %).
"""

from __future__ import annotations

import math

import h5py
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mpmjax
from mpmjax import _basal, rheometer
from mpmjax._build import build
from mpmjax._io import FrameWriter
from mpmjax._rheology import MODELS
from mpmjax._schema import SceneError, validate
from mpmjax._simulate import simulate
from mpmjax.studies import film
from mpmjax.studies.validate import FILM_H, LAB_COUSSOT

G = 9.81
LAW = MODELS["coussot"]()


def _params():
    m = LAB_COUSSOT
    return rheometer.make_params(rho=m["density_kg_m3"], mu0=m["mu0_pa_s"], alpha=m["alpha"], T=m["T_s"], n=m["n"],
                                 mu_max=m["mu_max_pa_s"], lambda0=m["lambda0"])


def test_a_uniform_column_is_the_newtonian_closure():
    p = _params()
    K, U, h = 16, jnp.asarray([0.2]), jnp.asarray([0.05])
    lam = jnp.full((1, K), 0.7)
    mu_k, F = _basal.layered(LAW, p, U, h, {"lam": lam})
    rates = _basal.layer_rates(U, h, mu_k, F)
    mu = float(LAW.mu(p, jnp.zeros(1), {"lam": jnp.asarray([0.7])})[0])
    assert float(F[0]) == pytest.approx(1.0 / (3.0 * mu), rel=1e-12)
    _, s, _ = _basal.layer_weights(K)
    np.testing.assert_allclose(np.asarray(rates[0]), 3.0 * 0.2 / 0.05 * s, rtol=1e-12)
    # the closure through the fluidity: c = 3 mu / h, the one-value closure's at this lambda
    _, c, _ = _basal.closure(LAW, p, U, h, None, fluidity=F)
    _, c1, _ = _basal.closure(LAW, p, U, h, {"lam": jnp.asarray([0.7])})
    assert float(c[0]) == pytest.approx(float(c1[0]), rel=1e-12)


def test_a_band_under_a_plug_is_the_series_integral():
    p = _params()
    K = 16
    e = _basal.layer_edges(K)
    j = 5  # the band: the bottom five layers
    lam = jnp.where(jnp.arange(K) < j, 0.3, 9.0)[None, :]
    _, F = _basal.layered(LAW, p, jnp.asarray([0.1]), jnp.asarray([0.05]), {"lam": lam})
    mu_b, mu_p = (float(LAW.mu(p, jnp.zeros(1), {"lam": jnp.asarray([v])})[0]) for v in (0.3, 9.0))
    exact = (1.0 - (1.0 - e[j]) ** 3) / (3.0 * mu_b) + (1.0 - e[j]) ** 3 / (3.0 * mu_p)
    assert float(F[0]) == pytest.approx(exact, rel=1e-12)


R = 2.0  # bed stress / tau_c
T_END = 6.0


def _layer(layers, mu0=None):
    """The lab material FILM_H deep from rest on a 16 m incline at R tau_c (benchmarks/accuracy/coussot_layers.py)."""
    p = _params()
    tau_c = float(rheometer.critical_point(p)[1])
    theta = math.degrees(math.asin(R * tau_c / (float(p.rho) * G * FILM_H)))
    mat = dict(LAB_COUSSOT, bulk_modulus_pa=1e5)
    if mu0 is not None:
        mat["mu0_pa_s"] = mu0
    raw = {
        "model": {"formulation": "depth-averaged"},
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [16.0, 0.2], "cell_size_m": 0.05},
        "boundary": {"x_lo": "slip", "x_hi": "open"},
        "numerics": {"shape": "quadratic", "ppc": 4, "dtype": "float64", "depth_layers": layers, "split_levels": 0},
        "gravity": {"g_m_s2": G, "slope_deg": theta},
        "material": mat,
        "time": {"t_end_s": T_END, "n_frames": 1},
        "bodies": [{"type": "box", "lo_m": [0.0, 0.0], "hi_m": [16.0, FILM_H]}],
    }
    return build(validate(raw)), theta


def _middle_speed(s):
    x0 = np.asarray(s.state.x[:, 0])
    mid = jnp.asarray((x0 > 16.0 / 3) & (x0 < 32.0 / 3))

    def speed(params):
        fin, _ = simulate(s.scene, s.state, params)
        return jnp.sum(jnp.where(mid, jnp.abs(fin.v[:, 0]), 0.0)) / jnp.sum(mid)

    return speed


@pytest.fixture(scope="module")
def layered_lab():
    return _layer(32)


def test_a_layered_column_follows_the_film_from_rest(layered_lab):
    s, theta = layered_lab
    U = float(jax.jit(_middle_speed(s))(s.params))
    y, u, _, _ = film.film_profiles(_params(), FILM_H, theta, np.asarray([T_END]), g_m_s2=G)
    assert U == pytest.approx(float(film.mean_speed(y, u)[-1]), rel=0.05)


def test_the_layered_speed_has_the_derivative_of_its_finite_difference(layered_lab):
    s, _ = layered_lab
    speed = jax.jit(_middle_speed(s))
    mat = s.params.material
    d = 1e-6 * float(mat.mu0)  # the speed is far from linear in mu0 (a band at its edge): 1e-3 reads 4 % off

    def at(mu0):
        return s.params._replace(material=mat._replace(mu0=jnp.asarray(mu0, mat.mu0.dtype)))

    zero = jax.tree_util.tree_map(jnp.zeros_like, s.params)
    tangent = zero._replace(material=zero.material._replace(mu0=jnp.ones_like(mat.mu0)))
    _, jvp = jax.jvp(speed, (s.params,), (tangent,))
    fd = (float(speed(at(float(mat.mu0) + d))) - float(speed(at(float(mat.mu0) - d)))) / (2 * d)
    assert float(jvp) == pytest.approx(fd, rel=1e-6)  # measured 3e-8


def test_float32_reverse_mode_through_layers_is_finite_and_equals_forward_mode():
    """The lab dam break as columns with 8 layers, float32 under the suite's 64-bit mode (the layers' weights take
    the state's dtype), 0.2 s: d(front speed sum)/d mu0 by reverse mode equals forward mode (1e-3: float32) and is
    finite (a node the stencil reaches without mass has no fluidity; its c must not be 1/0 in reverse mode)."""
    s = mpmjax.build(mpmjax.load_scene("dambreak-lab", [
        "model.formulation=depth-averaged", "numerics.depth_layers=8", "numerics.dtype=float32",
        "domain.cell_size_m=0.02", "time.t_end_s=0.2", "time.n_frames=1"]))
    assert s.state.internal["lam"].dtype == jnp.float32

    def f(mu0):
        p = s.params._replace(material=s.params.material._replace(mu0=mu0))
        fin, _ = simulate(s.scene, s.state, p)
        return jnp.sum(jnp.abs(fin.v[:, 0]) * fin.active)

    mu0 = s.params.material.mu0
    rev = float(jax.jit(jax.grad(f))(mu0))
    fwd = float(jax.jit(lambda m: jax.jvp(f, (m,), (jnp.ones_like(m),))[1])(mu0))
    assert math.isfinite(rev) and rev < 0.0  # a more viscous material moves slower
    assert rev == pytest.approx(fwd, rel=1e-3)


def test_the_result_file_holds_the_mean_and_the_layers(tmp_path, layered_lab):
    s, _ = layered_lab
    lam = jnp.broadcast_to(jnp.asarray(_basal.layer_edges(32)[1:]), s.state.internal["lam"].shape)
    state = s.state._replace(internal={"lam": lam})
    with FrameWriter(tmp_path / "result.h5", s, "test") as w:
        w.append(state)
    with h5py.File(tmp_path / "result.h5") as f:
        layers = f["frames"]["lambda_layers"][0]
        mean = f["frames"]["lambda"][0]
    np.testing.assert_array_equal(layers, np.asarray(lam))
    e = _basal.layer_edges(32)
    np.testing.assert_allclose(mean, np.sum(np.diff(e) * e[1:]), rtol=1e-12)


def test_the_full_model_refuses_layers():
    raw = {
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [1.0, 0.5], "cell_size_m": 0.05},
        "material": LAB_COUSSOT,
        "numerics": {"depth_layers": 8},
        "time": {"t_end_s": 1.0},
        "bodies": [{"lo_m": [0.0, 0.0], "hi_m": [0.2, 0.2]}],
    }
    with pytest.raises(SceneError, match="numerics.depth_layers = 8 is invalid with model.formulation = 'full'"):
        validate(raw)
    del raw["numerics"]
    assert validate(raw)["numerics.depth_layers"] == 1  # the depth-averaged default is not the full model's


def test_the_validate_case_passes_with_the_default_layers_and_fails_with_one(tmp_path):
    """The suite's depth-averaged Coussot case at its full size (6 s, two runs of 1280 columns: seconds): the
    default's 16 layers within its 5 % at 2 and 1.5 tau_c; one value per column fails it by far (+75 / +348 %
    measured), so the case is what chose the default."""
    from mpmjax.studies.validate import run_validate

    doc = run_validate(["coussot-film-da"], size="full", out=tmp_path / "k16", log=lambda m: None)
    rec = doc["cases"]["coussot-film-da"]
    assert rec["pass"] and [r["depth_layers"] for r in rec["runs"]] == [16, 16]
    assert [c["name"] for c in rec["checks"]] == ["mean speed vs the 1D film at 2 tau_c",
                                                  "mean speed vs the 1D film at 1.5 tau_c"]
    one = run_validate(["coussot-film-da"], size="full", out=tmp_path / "k1", base={"numerics.depth_layers": 1},
                       log=lambda m: None)["cases"]["coussot-film-da"]
    assert one["pass"] is False and all(c["error"] > 0.5 for c in one["checks"])
