"""A law defined in this file alone runs everywhere (issue 16, "a law in one file").

``AgingNewtonian``: a Newtonian fluid whose viscosity grows as it ages,

    mu = min(mu0 (1 + lam), mu_max),   dlam/dt = 1 / t_age,   lam(0) = lambda0,

with one new parameter, the aging time ``t_age`` [s] (scene key ``material.aging_time_s``),
and mu0, lambda0, mu_max, rho and kappa shared with the built-in laws.  Its exact update over
a step is lam + dt / t_age (the rate does not depend on lam or the shear).  Registered with
``mpmjax.register_law``, it goes through the scene schema and validation, ``build``,
``simulate``, ``sweep``, the 0-D rheometer and a one-parameter ``calibration.fit``; nothing
else in the code base names it.  The fixture removes it again, so the other tests see the
built-in laws only.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mpmjax
from calibration.data import Profile
from calibration.experiments import ProfileExperiment
from calibration.fit import fit
from calibration.params import DEFAULT_BOUNDS, UNITS, ParameterSet
from calibration.sweep import sweep
from mpmjax import rheometer

P = mpmjax.material_parameters()
AGING_TIME = mpmjax.Param(
    "t_age", "material.aging_time_s", "s", "Aging time t_age (aging Newtonian test law).", 1.0, lo=0.0,
    lo_open=True, bounds=(1e-3, 1e3),
)  # fmt: skip


class AgingParams(NamedTuple):
    rho: jnp.ndarray
    kappa: jnp.ndarray
    mu0: jnp.ndarray
    t_age: jnp.ndarray
    lambda0: jnp.ndarray
    mu_max: jnp.ndarray


@dataclasses.dataclass(frozen=True)
class AgingNewtonian(mpmjax.Law):
    name: ClassVar[str] = "aging_newtonian"
    params_type: ClassVar[type] = AgingParams
    params: ClassVar[tuple] = (P["rho"], P["kappa"], P["mu0"], AGING_TIME, P["lambda0"], P["mu_max"])
    internals: ClassVar[tuple] = (mpmjax.Internal("lam", "lambda", "-", "age", "lambda0"),)
    max_viscosity_params: ClassVar[tuple] = ("mu_max",)

    def rate(self, params, shear, internal):
        return {"lam": jnp.zeros_like(internal["lam"]) + 1.0 / params.t_age}

    def update_internal(self, params, shear, internal, dt):
        return {"lam": internal["lam"] + dt / params.t_age}

    def mu(self, params, shear, internal):
        return jnp.minimum(params.mu0 * (1.0 + internal["lam"]), params.mu_max)

    def max_viscosity(self, params):
        return params.mu_max


MU0, LAMBDA0, T_AGE = 20.0, 0.0, 0.1  # Pa s, -, s
SCENE = f"""
name = "aging-block"
[domain]
dim = 2
lo_m = [0.0, 0.0]
hi_m = [0.6, 0.2]
cell_size_m = 0.02
[numerics]
dtype = "float64"
[time]
t_end_s = 0.3
n_frames = 3
[material]
model = "aging_newtonian"
density_kg_m3 = 1000.0
bulk_modulus_pa = 10000.0
mu0_pa_s = {MU0}
lambda0 = {LAMBDA0}
aging_time_s = {T_AGE}
[[bodies]]
type = "box"
lo_m = [0.0, 0.0]
hi_m = [0.1, 0.1]
"""


@pytest.fixture(scope="module")
def law():
    jax.config.update("jax_enable_x64", True)
    mpmjax.register_law(AgingNewtonian)
    yield AgingNewtonian
    mpmjax.unregister_law("aging_newtonian")
    assert "material.aging_time_s" not in mpmjax.SCHEMA


@pytest.fixture(scope="module")
def scene_file(law, tmp_path_factory):
    path = tmp_path_factory.mktemp("aging") / "aging.toml"
    path.write_text(SCENE)
    return str(path)


def test_schema_and_validation_read_the_declaration(law, scene_file):
    spec = mpmjax.SCHEMA["material.aging_time_s"]
    assert (spec.unit, spec.default, spec.lo, spec.lo_open) == ("s", 1.0, 0.0, True)
    assert "aging_newtonian" in mpmjax.SCHEMA["material.model"].choices
    with pytest.raises(mpmjax.SceneError, match=r"material\.aging_time_s = -1\.0 is invalid.*> 0"):
        mpmjax.load_scene(scene_file, ["material.aging_time_s=-1.0"])
    # calibration reads the same declaration
    assert DEFAULT_BOUNDS["t_age"] == (1e-3, 1e3) and UNITS["t_age"] == "s"


def test_build_and_simulate_age_every_particle_exactly(law, scene_file):
    s = mpmjax.build(mpmjax.load_scene(scene_file))
    assert type(s.params.material) is AgingParams and float(s.params.material.t_age) == T_AGE
    final, frames = mpmjax.run(s.scene, s.state, s.params)
    t_end = float(final.t)
    # lam + dt / t_age summed over the steps: lambda0 + t / t_age to float64 rounding
    np.testing.assert_allclose(np.asarray(final.internal["lam"]), LAMBDA0 + t_end / T_AGE, rtol=1e-9)
    np.testing.assert_allclose(np.asarray(final.mu), MU0 * (1.0 + LAMBDA0 + t_end / T_AGE), rtol=1e-9)
    assert int(final.n_lost) == 0 and bool(np.all(final.active))


def test_sweep_faster_aging_stops_the_block_shorter(law, scene_file):
    res = sweep(scene_file, {"t_age": [0.02, 0.1, 1.0]}, progress=False)
    r = np.asarray(res["final_runout_m"])
    far = np.asarray(res["final_runout_farthest_particle_m"])
    # viscosity at 0.3 s: 20 (1 + 15) = 320, 80 and 26 Pa s; the viscous time rho H^2 / mu of the
    # 0.1 m block (0.03-0.4 s) spans the run, so the runout must grow with t_age, and strictly:
    # the farthest particle by 0.05 m, far above the particle spacing of 0.01 m;
    # the headline free-surface front by 3 spacings (measured 0.048 m: the front of a thin,
    # tapered tongue sits behind its farthest particles)
    assert r[0] < r[1] < r[2], r
    assert far[0] < far[1] < far[2] and far[2] - far[0] > 0.05, far
    assert r[2] - r[0] > 0.03, r


def test_rheometer_integrates_the_declared_rate(law):
    p = AgingParams(*(jnp.asarray(v, jnp.float64) for v in (1000.0, 1e4, MU0, T_AGE, LAMBDA0, 5000.0)))
    t = np.linspace(0.0, 0.5, 11)
    res = rheometer.constant_shear(p, 2.0, t)
    # exact: lam = lambda0 + t / t_age, mu = mu0 (1 + lam) (cap 5000 Pa s not reached), tau = mu gdot
    np.testing.assert_allclose(np.asarray(res.mu_pa_s), MU0 * (1.0 + LAMBDA0 + t / T_AGE), rtol=1e-8)
    np.testing.assert_allclose(np.asarray(res.tau_pa), 2.0 * np.asarray(res.mu_pa_s), rtol=1e-12)


def test_one_parameter_calibration_recovers_t_age(law, scene_file):
    """Twin at the fit's own resolution (no discretisation bias) and without noise: the data
    are the model at t_age = 0.1 s; the fit starts at 0.2 s.

    The fit stops once the loss is below atol = 1e-10 (an exact synthetic fit: the loss at the
    truth is round-off, ~1e-20), instead of idling at the round-off floor until rtol = 1e-10 has
    held for 3 iterations, each a line search of up to 16 evaluations.  The loss is quadratic in
    the relative error d of t_age near the truth, L ~ c d^2 with c of the order of the start's
    loss (10-100, at d = 1), so L < 1e-10 means |d| ~ 1e-6, a hundred times inside the asserted
    1e-4."""
    truth = mpmjax.build(mpmjax.load_scene(scene_file))
    _, frames = mpmjax.run(truth.scene, truth.state, truth.params)
    x = np.linspace(0.0, 0.4, 41)
    profiles = []
    for k in range(truth.scene.n_frames):
        h = mpmjax.height_profile(frames.x[k], truth.state.vol0, frames.active[k], jnp.asarray(x), bandwidth=0.02)
        profiles.append(Profile(x, np.asarray(h), float(frames.t[k])))
    exp = ProfileExperiment(truth, profiles, sigma_m=1e-3)
    ps = ParameterSet.from_names(["t_age"], truth.params.material, init={"t_age": 0.2})
    r = fit([exp], ps, max_iter=30, rtol=1e-10, atol=1e-10, patience=3, progress=False)
    # noise-free data at the model's own resolution: the minimum is the truth; the loss from
    # the start is O(10-100) per station, so the fit's stopping rule (rtol 1e-10 or a loss of
    # 0) leaves t_age within 1e-4 relative
    assert r.loss_final < 1e-6 * r.loss_initial, (r.loss_initial, r.loss_final)
    assert abs(r.params["t_age"] / T_AGE - 1.0) < 1e-4, r.params
