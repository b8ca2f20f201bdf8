"""Savage & Hutter's earth-pressure coefficient of a depth-averaged granular column (``model.internal_friction_deg``,
``mpmjax._earth_pressure``; docs/earth-pressure.md), in float64.  The dam break it must follow (Mangeney et al.
2000, active everywhere) is ``tests/test_depth_averaged_bed.py``'s, run with and without it.

* The coefficients against their closed forms, to round-off: Rankine's (1 -/+ sin phi) / (1 +/- sin phi) on a
  frictionless bed, and (1 + sin^2 phi) / cos^2 phi for both where the bed's friction angle equals phi.
* A parabolic cap released on a Coulomb incline against Savage & Hutter's (1989) similarity solution: its
  half-length with k = 1 and with the active k (35 degrees), its centroid; within 1 % of the spread.  And on the
  map (a 2-D plan) a paraboloid cap on a frictionless plane against its circular similarity solution.
* Which coefficient a column takes: a wedge of the material (its depth rising linearly along x) given a uniform
  velocity gradient, extending or contracting, accelerates in its interior over one step at k times the
  hydrostatic column's (k_act extending, k_pass contracting; Rankine's 1/3 and 3 at phi = 30 degrees), to 1e-9
  (exact in the quadratic B-splines' interior: measured 7e-15, and the hydrostatic one is g dH/dx as exactly).
* The derivative of the spreading wedge's speed after 40 steps with respect to the bed's friction, which k
  depends on, in forward mode against a central difference (1e-6 relative).
* The bed friction's declared range and calibration's search range end at tan(phi) in such a scene.
* The time step takes Rankine's passive coefficient in the wave speed: sqrt(3) times shorter at 30 degrees.
* The scene refuses it in the full model, without a Coulomb bed, below the bed's friction angle and above 60
  degrees, naming the key and the allowed range.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mpmjax import _earth_pressure
from mpmjax._build import build
from mpmjax._schema import SceneError, validate
from mpmjax._simulate import simulate
from mpmjax._step import make_step

G = 9.81


@pytest.mark.parametrize("phi", [20.0, 30.0, 45.0])
def test_the_coefficients_are_rankines_on_a_smooth_bed_and_meet_at_the_bed_friction_angle(phi):
    s = math.sin(math.radians(phi))
    k_act, k_pass = (float(k) for k in _earth_pressure.coefficients(phi, 0.0))
    assert k_act == pytest.approx((1 - s) / (1 + s), rel=1e-12)
    assert k_pass == pytest.approx((1 + s) / (1 - s), rel=1e-12) == _earth_pressure.largest(phi)
    both = (1 + s * s) / (1 - s * s)
    for k in _earth_pressure.coefficients(phi, math.tan(math.radians(phi))):
        assert float(k) == pytest.approx(both, rel=1e-7)  # the root's argument is 0 up to rounding of tan
    k_act, k_pass = (float(k) for k in _earth_pressure.coefficients(phi, 0.5 * math.tan(math.radians(phi))))
    assert (1 - s) / (1 + s) < k_act < both < k_pass < (1 + s) / (1 - s)


def _cap_length(t, l0, area, kgc):
    """Savage & Hutter's (1989) parabolic cap h = H (1 - (x/L)^2) spreading from rest: L'' = 3/2 k g cos A / L^2
    (the momentum balance of the similarity form, u = x L'/L; A its area), so ½ L'^2 = 3/2 k g cos A (1/L0 - 1/L)
    and, with L = L0 cosh^2 s, t = L0^(3/2) (s + sinh s cosh s) / sqrt(3 k g cos A): L at ``t`` by bisection."""
    lo, hi = 0.0, 10.0
    for _ in range(200):
        s = 0.5 * (lo + hi)
        if l0**1.5 * (s + math.sinh(s) * math.cosh(s)) / math.sqrt(3.0 * kgc * area) > t:
            hi = s
        else:
            lo = s
    return l0 * math.cosh(0.5 * (lo + hi)) ** 2


@pytest.mark.parametrize("phi", [None, 35.0], ids=["hydrostatic", "granular-35deg"])
def test_a_parabolic_cap_spreads_down_an_incline_as_savage_and_hutters_similarity_solution(phi):
    """A parabolic cap 0.05 m high and 1 m long, released from rest on a 30-degree Coulomb plane (mu = 0.3),
    spreads as the similarity solution while it slides: its centroid at m t^2 / 2, m = g (sin - mu cos), and its
    half-length L(t) (``_cap_length``; from the columns' second moment, L^2 = 5 var(x) for a parabola) with the
    active k, the cap extending everywhere.  The rear moves down the plane throughout (m > L''(0)), so the
    friction is uniform.  h = 1 cm, 8 columns a cell, 0.5 s.  Measured: L within 0.03 % (k = 1) and 0.09 %
    (phi = 35 degrees, k_act = 0.4358) of the spread L - L0, the centroid within 0.4 mm of its 0.29 m.  Bounds:
    1 % of the spread, 0.5 % of the travel."""
    theta, mu, h0, l0, xc, t_end = math.radians(30.0), 0.3, 0.05, 0.5, 1.0, 0.5
    raw = {
        "model": {"formulation": "depth-averaged"},
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [4.0, 0.2], "cell_size_m": 0.01},
        "boundary": {"x_lo": "slip", "x_hi": "open"},
        "numerics": {"shape": "quadratic", "ppc": 8, "dtype": "float64", "split_levels": 0},
        "gravity": {"slope_deg": 30.0},
        "material": {"model": "newtonian", "viscosity_pa_s": 1e-12, "density_kg_m3": 1000.0, "bulk_modulus_pa": 1e5},
        "terrain": {"type": "coulomb", "heights_m": [0.0, 0.0], "origin_m": [0.0], "spacing_m": 4.0, "friction": mu},
        "time": {"t_end_s": t_end, "n_frames": 5},
        "bodies": [{"type": "box", "lo_m": [xc - l0, 0.0], "hi_m": [xc + l0, h0]}],
    }
    if phi is not None:
        raw["model"]["internal_friction_deg"] = phi
    s = build(validate(raw))
    x0 = np.asarray(s.state.x[:, 0])
    vol = np.asarray(s.state.vol0) * 1.5 * (1.0 - ((x0 - xc) / l0) ** 2)  # the cap's area is the box's
    fin, _ = jax.jit(simulate, static_argnums=0)(s.scene, s.state._replace(vol0=jnp.asarray(vol)), s.params)
    assert np.all(np.asarray(fin.active))

    def centroid_and_length(x):
        c = np.sum(vol * x) / vol.sum()
        return c, math.sqrt(5.0 * np.sum(vol * (x - c) ** 2) / vol.sum())

    c0, length0 = centroid_and_length(x0)
    c1, length1 = centroid_and_length(np.asarray(fin.x[:, 0]))
    k = 1.0 if phi is None else float(_earth_pressure.coefficients(phi, mu)[0])
    exact = _cap_length(t_end, length0, vol.sum(), k * G * math.cos(theta))
    assert abs(length1 - exact) < 0.01 * (exact - length0)
    travel = 0.5 * G * (math.sin(theta) - mu * math.cos(theta)) * t_end**2
    assert abs(c1 - c0 - travel) < 0.005 * travel


@pytest.mark.parametrize("phi", [None, 35.0], ids=["hydrostatic", "granular-35deg"])
def test_a_paraboloid_cap_spreads_on_the_map_as_its_similarity_solution(phi):
    """The map (domain.dim = 3): a paraboloid cap h = H (1 - r^2/a^2), a0 = 0.3 m, H0 = 0.03 m, released from rest
    on a frictionless 30-degree plane (a coulomb terrain of friction 0: Rankine's k_act = 0.2710 at 35 degrees).
    With one k in every direction (this model's, isotropic in the plan) it stays a circular cap:
    a'' = 4 k g cos V / (pi a^3), so a(t)^2 = a0^2 + (4 k g cos V / pi) t^2 / a0^2, its centroid sliding at
    g sin t^2 / 2; the radius from the columns' second moments (a^2 = 6 var, along and across the slope).  h = 2 cm,
    4 x 4 columns a cell (11 304 inside the cap), 0.5 s.  Measured: a within 0.61 % (k = 1) and 0.58 % (35 deg)
    of the spread along and across, the centroid within 1.8 and 1.6 mm of 0.613 m.  Bounds: 2 % of the spread,
    0.5 % of the travel.  (On a bed with friction the lateral friction, along the velocity, breaks the similarity.)"""
    theta, a0, h0, xc, t_end = math.radians(30.0), 0.3, 0.03, 0.5, 0.5
    raw = {
        "model": {"formulation": "depth-averaged"},
        "domain": {"dim": 3, "lo_m": [0.0, -0.7, 0.0], "hi_m": [2.5, 0.7, 0.3], "cell_size_m": 0.02},
        "boundary": {"x_lo": "slip", "x_hi": "open", "y_lo": "slip", "y_hi": "slip"},
        "numerics": {"shape": "quadratic", "ppc": 4, "dtype": "float64", "split_levels": 0},
        "gravity": {"slope_deg": 30.0},
        "material": {"model": "newtonian", "viscosity_pa_s": 1e-12, "density_kg_m3": 1000.0, "bulk_modulus_pa": 1e5},
        "terrain": {"type": "coulomb", "heights_m": [[0.0, 0.0], [0.0, 0.0]], "origin_m": [0.0, -0.7],
                    "spacing_m": 2.5, "friction": 0.0},
        "time": {"t_end_s": t_end, "n_frames": 5},
        "bodies": [{"type": "box", "lo_m": [xc - a0, -a0, 0.0], "hi_m": [xc + a0, a0, h0]}],
    }
    if phi is not None:
        raw["model"]["internal_friction_deg"] = phi
    s = build(validate(raw))
    x0 = np.asarray(s.state.x)
    r2 = ((x0[:, 0] - xc) ** 2 + x0[:, 1] ** 2) / a0**2
    vol = np.asarray(s.state.vol0) * np.maximum(1.0 - r2, 0.0)
    start = s.state._replace(vol0=jnp.asarray(vol), active=s.state.active & jnp.asarray(r2 < 1.0))
    fin, _ = jax.jit(simulate, static_argnums=0)(s.scene, start, s.params)
    vol = vol * np.asarray(fin.active)

    def centroid_and_radii(x):
        c = np.sum(vol[:, None] * x[:, :2], axis=0) / vol.sum()
        return c, np.sqrt(6.0 * np.sum(vol[:, None] * (x[:, :2] - c) ** 2, axis=0) / vol.sum())

    c0, radii0 = centroid_and_radii(x0)
    c1, radii1 = centroid_and_radii(np.asarray(fin.x))
    k = 1.0 if phi is None else float(_earth_pressure.coefficients(phi, 0.0)[0])
    start_r = math.sqrt(radii0[0] * radii0[1])
    exact = math.sqrt(start_r**2 + 4 * k * G * math.cos(theta) * vol.sum() / math.pi * t_end**2 / start_r**2)
    assert np.all(np.abs(radii1 - exact) < 0.02 * (exact - start_r))
    travel = 0.5 * G * math.sin(theta) * t_end**2
    assert abs(c1[0] - c0[0] - travel) < 0.005 * travel and abs(c1[1] - c0[1]) < 1e-9


SLOPE = 0.05  # the wedge's depth gradient dH/dx: 0.1 m -> 0.15 m over 1 m


def _wedge_raw(phi, friction):
    raw = {
        "model": {"formulation": "depth-averaged"},
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [3.0, 0.5], "cell_size_m": 0.01},
        "boundary": {"x_lo": "slip", "x_hi": "slip"},
        "numerics": {"shape": "quadratic", "ppc": 8, "dtype": "float64", "split_levels": 0},
        "material": {"model": "newtonian", "viscosity_pa_s": 1e-12, "density_kg_m3": 1000.0, "bulk_modulus_pa": 1e5},
        "terrain": {"type": "coulomb", "heights_m": [0.0, 0.0], "origin_m": [0.0], "spacing_m": 3.0,
                    "friction": friction},
        "time": {"t_end_s": 1.0, "n_frames": 1},
        "bodies": [{"type": "box", "lo_m": [1.0, 0.0], "hi_m": [2.0, 0.1]}],
    }
    if phi is not None:
        raw["model"]["internal_friction_deg"] = phi
    return raw


def _wedge(phi, friction=0.0):
    """A 1 m block 0.1 m deep on a flat Coulomb bed whose columns' volumes rise linearly along x (depth slope
    SLOPE), 8 columns a cell, h = 1 cm."""
    s = build(validate(_wedge_raw(phi, friction)))
    x = s.state.x[:, 0]
    return s, s.state._replace(vol0=s.state.vol0 * (1.0 + SLOPE / 0.1 * (x - 1.0)))


def _interior_acceleration(phi, gamma):
    """The wedge with velocity gamma (x - 1.5 m) (its APIC matrix gamma: divergence gamma [1/s]) after one step:
    the mean acceleration [m/s^2] of the columns 0.3 m or more inside its ends."""
    s, st = _wedge(phi)
    x = st.x[:, 0]
    v = st.v.at[:, 0].set(gamma * (x - 1.5))
    st = st._replace(v=v, C=st.C.at[:, 0, 0].set(gamma))
    new = jax.jit(make_step(s.scene))(st, s.params)
    inner = np.asarray((x > 1.3) & (x < 1.7))
    return float(np.mean(np.asarray(new.v[:, 0] - v[:, 0])[inner])) / s.scene.dt


@pytest.mark.parametrize("gamma, branch", [(1e-4, 0), (-1e-4, 1)], ids=["extending-active", "contracting-passive"])
def test_a_column_takes_the_active_coefficient_where_it_extends_and_the_passive_where_it_is_compressed(gamma, branch):
    fluid = _interior_acceleration(None, gamma)
    assert fluid == pytest.approx(-G * SLOPE, rel=1e-9)  # the hydrostatic column: g dH/dx (measured 7e-15)
    k = float(_earth_pressure.coefficients(30.0, 0.0)[branch])  # Rankine's 1/3 and 3
    assert _interior_acceleration(30.0, gamma) == pytest.approx(k * fluid, rel=1e-9)  # measured 4e-16


def test_the_speed_has_the_derivative_of_its_finite_difference_through_the_coefficient():
    """The wedge spreading at 0.2 (x - 1.5 m) m/s on a bed of friction 0.1 (the friction decelerates it, the
    active pressure drives it): the mean speed of its columns between 1.55 and 1.75 m after 40 steps."""
    s, st = _wedge(35.0, friction=0.1)
    x = np.asarray(st.x[:, 0])
    st = st._replace(v=st.v.at[:, 0].set(0.2 * (st.x[:, 0] - 1.5)), C=st.C.at[:, 0, 0].set(0.2))
    step = make_step(s.scene)
    inner = jnp.asarray((x > 1.55) & (x < 1.75))

    def speed(friction):
        p = s.params._replace(basal=s.params.basal._replace(friction=friction))
        out = jax.lax.fori_loop(0, 40, lambda _, a: step(a, p), st)
        return jnp.sum(jnp.where(inner, out.v[:, 0], 0.0)) / jnp.sum(inner)

    mu = s.params.basal.friction
    _, jvp = jax.jit(lambda m: jax.jvp(speed, (m,), (jnp.ones_like(m),)))(mu)
    d = 1e-6
    f = jax.jit(speed)
    fd = (float(f(mu + d)) - float(f(mu - d))) / (2 * d)
    assert abs(float(jvp)) > 0.0 and float(jvp) == pytest.approx(fd, rel=1e-6)


def test_a_fit_or_a_sweep_keeps_the_bed_friction_at_or_below_tan_phi():
    """Savage & Hutter's k has an infinite derivative in the bed friction at delta = phi, and the scene refuses a
    rougher bed: the friction's declared range and calibration's default search range end at tan(phi) there."""
    import mpmjax

    s, _ = _wedge(30.0, friction=0.1)
    f = mpmjax.fit_parameters(s.params, validate(_wedge_raw(30.0, 0.1)))["friction"]
    assert f.hi == f.bounds[1] == pytest.approx(math.tan(math.radians(30.0)), rel=1e-15)
    assert mpmjax.fit_parameters(s.params)["friction"].bounds == (0.01, 1.5)  # without the scene: the default


def test_the_time_step_takes_rankines_passive_wave_speed():
    plain, _ = _wedge(None)
    granular, _ = _wedge(30.0)
    for key in ("wave_speed_m_s", "velocity_scale_m_s"):  # both sqrt(k g H): the bed is flat and the block at rest
        assert granular.info[key] / plain.info[key] == pytest.approx(math.sqrt(3.0), rel=1e-12)
    assert plain.info["dt_wave_s"] / granular.info["dt_wave_s"] == pytest.approx(math.sqrt(3.0), rel=1e-12)


@pytest.mark.parametrize(
    "change, match",
    [
        ({"model": {"internal_friction_deg": 30.0}}, r"model.internal_friction_deg = 30.0 is invalid with "
         r"model.formulation = 'full'"),
        ({"model": {"formulation": "depth-averaged", "internal_friction_deg": 30.0}, "terrain": {"type": "slip"}},
         r"model.internal_friction_deg = 30.0 is invalid with terrain.type = 'slip'.*allowed: terrain.type = "
         r"'coulomb' or 'voellmy'"),
        ({"model": {"formulation": "depth-averaged", "internal_friction_deg": 10.0}},
         r"model.internal_friction_deg = 10.0 is invalid with terrain.friction = 0.3 \(a bed friction angle of "
         r"16.6992 deg, above it\).*allowed range \[16.6992, 60\] deg, or terrain.friction <= tan\(phi\) = "
         r"0.176327"),
        ({"model": {"formulation": "depth-averaged", "internal_friction_deg": 30.0}, "terrain": {"friction": 0.5774}},
         r"model.internal_friction_deg = 30.0 is invalid with terrain.friction = 0.5774 \(a bed friction angle of "
         r"30.0021 deg"),
        ({"model": {"formulation": "depth-averaged", "internal_friction_deg": 50.0}, "terrain": {"friction": 2.0}},
         r"allowed: terrain.friction <= tan\(60 deg\) = 1.73205 \(the largest internal friction angle\)"),
        ({"model": {"formulation": "depth-averaged", "internal_friction_deg": 75.0}},
         r"model.internal_friction_deg = 75.0 .*60"),
    ],
    ids=["full-model", "no-coulomb-bed", "below-the-bed-friction", "just-below", "bed-above-60", "above-60"],
)
def test_the_scene_refuses_it_where_it_has_no_meaning(change, match):
    raw = {
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [3.0, 0.5], "cell_size_m": 0.05},
        "material": {"model": "newtonian", "viscosity_pa_s": 1.0, "density_kg_m3": 1000.0, "bulk_modulus_pa": 1e5},
        "terrain": {"type": "coulomb", "heights_m": [0.0, 0.0], "origin_m": [0.0], "spacing_m": 3.0, "friction": 0.3},
        "time": {"t_end_s": 1.0},
        "bodies": [{"lo_m": [0.0, 0.0], "hi_m": [1.0, 0.1]}],
    }
    for sec, keys in change.items():
        raw.setdefault(sec, {}).update(keys)
    with pytest.raises(SceneError, match=match):
        validate(raw)
