"""The automatic time step's velocity bound (``mpmjax.time_step_limits``).

With ``numerics.velocity_scale_m_s = 0`` the wave-speed limit uses |v| <= sqrt(2 g H) + max
|v0|, H the fall height along gravity from the top of the material to the lowest point it can
reach.  A frictionless fall converts at most that potential energy into speed (walls do no
work, viscosity dissipates), so the bound must hold for every particle at every step.
"""

from __future__ import annotations

import copy
import math
import tomllib
from importlib import resources

import jax.numpy as jnp
import numpy as np
import pytest

from mpmjax import build, validate
from mpmjax._simulate import run

G = 9.81


def _lab(**changes):
    raw = tomllib.loads(resources.files("mpmjax.scenes").joinpath("dambreak-lab.toml").read_text())
    raw = copy.deepcopy(raw)
    for key, val in changes.items():
        sec, k = key.split(".")
        if sec == "bodies":
            raw["bodies"][0][k] = val
        else:
            raw.setdefault(sec, {})[k] = val
    return raw


def _scale(raw):
    setup = build(validate(raw))
    return setup, setup.info["velocity_scale_m_s"]


def test_block_on_the_floor_uses_its_own_height():
    # dambreak-lab: a 0.2 m block on the floor -> H = 0.2 m exactly (unchanged by the fall fix)
    _, v = _scale(_lab())
    assert v == pytest.approx(math.sqrt(2 * G * 0.2), rel=1e-12)


def test_raised_block_counts_its_drop():
    # the same block with its base 1 m above the floor: H = 1.2 m (the old bound used 0.2 m)
    _, v = _scale(_lab(**{"bodies.lo_m": [0.0, 1.0], "bodies.hi_m": [0.2, 1.2], "domain.hi_m": [2.0, 1.5]}))
    assert v == pytest.approx(math.sqrt(2 * G * 1.2), rel=1e-12)


def test_tilted_gravity_counts_the_drop_along_the_slope():
    # gravity tilted by theta towards +x: the lowest point of the box is its far bottom corner
    theta = 10.0
    raw = _lab(**{"gravity.slope_deg": theta})
    setup, v = _scale(raw)
    th = math.radians(theta)
    up = np.array([-math.sin(th), math.cos(th)])
    x = np.asarray(setup.state.x, float)
    lo, hi = raw["domain"]["lo_m"], raw["domain"]["hi_m"]
    corners = np.array([[a, b] for a in (lo[0], hi[0]) for b in (lo[1], hi[1])])
    sp = raw["domain"]["cell_size_m"] / raw["numerics"]["ppc"]
    H = float(np.max(x @ up) - np.min(corners @ up)) + sp / 2
    assert v == pytest.approx(math.sqrt(2 * G * H), rel=1e-6)
    assert H > 0.2 + (hi[0] - lo[0]) * math.sin(th) * 0.9  # the slope's drop is included


def test_terrain_limits_the_fall_to_its_lowest_sample():
    # a terrain whose lowest sample is 0.3 m above the domain floor: the material cannot fall below it
    raw = _lab(
        **{
            "bodies.lo_m": [0.0, 0.5],
            "bodies.hi_m": [0.2, 0.7],
            "domain.hi_m": [2.0, 1.0],
            "terrain.type": "slip",
            "terrain.heights_m": [0.5, 0.4, 0.3],
            "terrain.spacing_m": 1.0,
        }
    )
    _, v = _scale(raw)
    assert v == pytest.approx(math.sqrt(2 * G * (0.7 - 0.3)), rel=1e-9)


def test_a_dropped_block_stays_within_the_cfl_limit():
    """A 0.1 m block dropped from 0.4 m onto a no-slip floor (coarse, 0.45 s; it lands at
    ~0.29 s).  The per-particle speed bound is a heuristic: on impact a splash can carry a few
    particles faster than sqrt(2 g H) (measured: 4.4 m/s against the 3.1 m/s bound), as only
    the total kinetic energy is bounded by the potential energy released.  What the time step
    must guarantee is stability: the measured CFL number dt (c + max|v|) / h stays below 1
    (measured 0.44; the old bound, the block's own height, gave 0.55 here and let the 1 m drop
    of ``mpmjax stress`` blow up), the total
    kinetic energy stays below the energy released (+1 % for transfer errors), and nothing is
    lost."""
    raw = _lab(
        **{
            "bodies.lo_m": [0.0, 0.4],
            "bodies.hi_m": [0.1, 0.5],
            "domain.hi_m": [1.0, 0.6],
            "domain.cell_size_m": 0.02,
            "time.t_end_s": 0.45,
            "time.n_frames": 45,
        }
    )
    setup, bound = _scale(raw)
    assert bound == pytest.approx(math.sqrt(2 * G * 0.5), rel=1e-9)
    final, frames = run(setup.scene, setup.state, setup.params)
    assert int(final.n_lost) == 0
    assert bool(jnp.all(jnp.isfinite(final.x)))
    v = np.asarray(frames.v, float)
    active = np.asarray(frames.active)
    speed = np.where(active, np.linalg.norm(v, axis=-1), 0.0)
    # it did fall: the fastest particle reached most of the free-fall impact speed sqrt(2 g 0.4)
    assert speed.max() > 0.8 * math.sqrt(2 * G * 0.4), speed.max()
    lim = setup.info
    cfl = setup.scene.dt * (lim["wave_speed_m_s"] + speed.max()) / setup.scene.h
    assert cfl < 1.0, cfl
    mass = np.asarray(setup.params.material.rho * setup.state.vol0, float)
    ke = 0.5 * np.sum(mass * np.where(active, np.sum(v * v, axis=-1), 0.0), axis=1)
    released = G * np.sum(mass * (np.asarray(setup.state.x)[:, 1] - np.asarray(frames.x)[..., 1]), axis=1)
    assert np.all(ke <= released + 0.01 * released.max()), float(np.max(ke - released) / released.max())


def test_the_clock_is_the_step_count_times_dt():
    """Time is (step count) x dt, not a running float32 sum of dt (``_scene.next_time``).

    At dt = 1/540 s, 270 float32 additions of dt reach 0.5 s off by 15 ulp (8.9e-7 s,
    measured; more than the 1e-6 relative tolerance of the plotting tests), and the drift
    grows with the step count; the step-count clock lands within one ulp.  A short coarse lab
    run with that dt must then report frame k at k x 54 x float32(dt) to float32 rounding."""
    from mpmjax._scene import next_time

    dt32 = np.float32(1.0 / 540.0)
    t_sum = np.float32(0.0)
    t_clock = jnp.float32(0.0)
    for _ in range(270):
        t_sum = np.float32(t_sum + dt32)
        t_clock = next_time(t_clock, dt32)
    ulp = float(np.spacing(np.float32(0.5)))
    assert abs(float(t_clock) - 0.5) <= ulp
    assert abs(float(t_sum) - 0.5) > 10 * ulp  # what the running sum did (15 ulp)

    raw = _lab(
        **{
            "domain.cell_size_m": 0.04,
            "numerics.dt_s": 1.0 / 540.0,
            "time.t_end_s": 0.5,
            "time.n_frames": 5,
        }
    )
    setup = build(validate(raw))
    _, frames = run(setup.scene, setup.state, setup.params)
    t = np.asarray(frames.t, np.float64)
    k = np.arange(1, 6)  # the frames are the ends of the five frames of 54 steps
    np.testing.assert_allclose(t, k * 54 * np.float64(dt32), rtol=2e-7)
