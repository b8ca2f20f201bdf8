"""MPM validation of the rheology against exact solutions and the thesis's lab case.

References are ../shared/REFERENCE.md ("Exact solutions to test against", "Thesis
scenarios").  Every test runs a coarse grid so that this file stays well inside the CI
budget (about a minute on 2 CPU cores); the default-resolution versions are marked
``slow`` (``pytest -m slow``).

Numbers measured when these tests were written (float64 unless stated, 2 CPU cores):

* simple shear, Coussot BASE at gdot = 5 1/s: max |lam - exact| / exact = 6.0e-4 over
  1 s (interior particles; 4.7 % on the free-surface rows); grid rate within 2.2e-4 and
  the rate seen by the stress update (tau_xy / mu) within 3.3e-4 of gdot.
* Bingham plane Poiseuille, H = 0.1 m, y0 = H/2, linear shape functions, h = H/10:
  plug velocity +0.55 % (Papanastasiou) / +0.59 % (bi-viscosity), fitted plug half-width
  -0.3 %, sheared-zone curvature -G/mu to 7e-4.  With quadratic B-splines: plug velocity
  +12.7 %, y0 +5.5 %, curvature +19 % (see the xfail test); with the boundary-modified
  quadratic (quadratic_bm): +0.67 %, -0.40 %, -0.14 %.
* Bingham slump, tau_y = 82 Pa, h = 0.02 m: x_f = 0.589 m (mass-consistent 0.592 m), depth
  within 6.6 % of sqrt(k (x_f - x)) over the body, fitted tau_y = 85.6 Pa (+4.4 %).
* lab dam break BASE: runout 1.235 m (h = 0.02 m) and 1.268 m (h = 0.01 m) at 15 s;
  run 7c (alpha = 10): 1.374 m and 1.458 m; thesis-compatible options (gdot^2/8, Euler):
  1.182 m and 1.208 m; no lost particles.  Viscous-gravity-current band 0.37 .. 1.52 m.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mpmjax as m
from mpmjax._constitutive import shear_measures, shear_rate
from mpmjax._rheology import coussot_mu

# --------------------------------------------------------------------------------------
# Simple shear of Coussot material (REFERENCE.md "Coussot at constant shear rate")
# --------------------------------------------------------------------------------------

# thesis BASE (Table 8): mu0 = 4, n = 2.5, alpha = 1, T = 0.5, lambda0 = 1.5, rho = 1850, kappa = 15 kPa
BASE_MAT = {"model": "coussot", "density_kg_m3": 1850.0, "bulk_modulus_pa": 15000.0, "mu0_pa_s": 4.0,
            "alpha": 1.0, "T_s": 0.5, "n": 2.5, "lambda0": 1.5, "mu_max_pa_s": 5000.0}


def _simple_shear_run(gdot, t_end=1.0, h=0.02):
    """A 0.2 m x 0.2 m Coussot block, periodic in x, free (open) top and bottom, no gravity,
    sheared kinematically at the constant rate ``gdot``.

    The engine has no moving walls, and any dynamic set-up (a driven lid, a decaying initial
    profile) reaches a uniform rate only after a momentum-diffusion time rho H^2 / mu ~ 1 s,
    longer than the structure time 1/(alpha gdot) = 0.2 s we want to resolve.  So the rate is
    imposed: before every ``step`` the particle velocities are reset to v = (gdot (y - yc), 0)
    and the APIC affine matrices to C = [[0, gdot], [0, 0]].  The step then does everything
    else itself (P2G of that affine field, grid update with the stress forces, the grid
    velocity gradient L, the structure update, the Maxwell stress update), so the test checks
    that the MPM pipeline hands the rheology the right rate and integrates lam(t) exactly.
    """
    lo_y, hi_y = 0.1, 0.3
    yc = 0.5 * (lo_y + hi_y)
    cfg = m.validate({
        "domain": {"lo_m": [0.0, 0.0], "hi_m": [0.2, 0.4], "cell_size_m": h},
        "boundary": {"x_lo": "periodic", "x_hi": "periodic", "y_lo": "open", "y_hi": "open"},
        # the flow speed is bounded by gdot * (hi_y - lo_y)/2: that bounds dt's |v| term
        "numerics": {"velocity_scale_m_s": gdot * (hi_y - lo_y) / 2, "dtype": "float64"},
        "time": {"t_end_s": t_end, "n_frames": 20},
        "material": BASE_MAT,
        "gravity": {"g_m_s2": 0.0},
        "bodies": [{"lo_m": [0.0, lo_y], "hi_m": [0.2, hi_y]}],
    })
    s = m.build(cfg)
    sc = s.scene
    step = m.make_step(sc)

    def impose(st):
        v = jnp.stack([gdot * (st.x[:, 1] - yc), jnp.zeros_like(st.x[:, 1])], axis=1)
        return st._replace(v=v, C=jnp.zeros_like(st.C).at[:, 0, 1].set(gdot))

    def frame(st, _):
        st = jax.lax.scan(lambda c, _: (step(impose(c), s.params), None), st, None, length=sc.steps_per_frame)[0]
        # C after the step is the APIC B D^-1 of the grid velocity: the grid's own gradient.
        return st, (st.t, st.x[:, 1], st.internal["lam"], st.C, st.tau[:, 0, 1], st.mu)

    final, out = jax.jit(lambda st: jax.lax.scan(frame, st, None, length=sc.n_frames))(impose(s.state))
    return s, final, [np.asarray(a) for a in out], (lo_y, hi_y)


def test_simple_shear_coussot_structure_matches_exact():
    gdot, alpha, T, lam0 = 5.0, 1.0, 0.5, 1.5
    s, final, (t, y, lam, C, txy, mu), (lo_y, hi_y) = _simple_shear_run(gdot)
    h = s.scene.h
    assert int(final.n_lost) == 0
    # Interior particles: more than 2 cells (the quadratic stencil plus one) from the free
    # surfaces, where the unbalanced surface traction tau_xy accelerates the boundary nodes
    # within the step and so perturbs L of the particles that see those nodes.
    inner = (y[0] > lo_y + 2 * h) & (y[0] < hi_y - 2 * h)
    assert inner.sum() >= 0.3 * inner.size
    lam_ss = 1.0 / (alpha * T * gdot)
    exact = lam_ss + (lam0 - lam_ss) * np.exp(-alpha * gdot * t)  # REFERENCE.md
    err = np.abs(lam[:, inner] - exact[:, None]) / exact[:, None]
    # Brief: 2 %.  The exact update integrates lam exactly at a constant rate, so the only
    # error is the rate error of the MPM gradient (measured 6e-4 relative).
    assert err.max() < 0.02, err.max()
    # 20 frames over 5 relaxation times: lam went from 1.5 to within 1 % of lam_ss = 0.4
    assert abs(lam[-1, inner].mean() / lam_ss - 1) < 0.02
    # Rate seen by the grid: the standard measure of the APIC gradient C equals gdot.
    # 0.5 %: the within-step velocity change dt f/m of nodes near the free surface reaches the
    # outer interior particles at the 1e-4 level (measured 2.2e-4).
    _, dd = shear_measures(jnp.asarray(C[-1]), 2)
    g_grid = np.asarray(shear_rate(dd, "standard"))[inner]
    np.testing.assert_allclose(g_grid, gdot, rtol=5e-3)
    # Rate seen by the rheology: tau_xy = 2 mu d'_xy = mu gdot_L once the Maxwell lag mu/G
    # (~3e-4 s) is over; mu(t) varies on 1/(alpha gdot) = 0.2 s, so the lag error is ~1e-3.
    np.testing.assert_allclose(txy[-1, inner] / mu[-1, inner], gdot, rtol=5e-3)
    # and mu is the Coussot law of the integrated structure
    np.testing.assert_allclose(mu[-1, inner], np.asarray(coussot_mu(lam[-1, inner], 4.0, 2.5, 5000.0)), rtol=1e-12)


# --------------------------------------------------------------------------------------
# Bingham plane Poiseuille (REFERENCE.md "Bingham plane Poiseuille")
# --------------------------------------------------------------------------------------

POIS_H, POIS_RHO, POIS_G = 0.1, 1000.0, 9.81
POIS_MU = 25.0  # thesis Table 2 Newtonian Poiseuille viscosity
POIS_Y0 = POIS_H / 2  # tau_y = G y0 chosen so that the plug is half the channel


def _poiseuille(h, shape, variant, t_end=2.0, pressure="explicit"):
    """Channel -H < y < H, periodic in x (4 cells long), no-slip walls, driven by the body
    force G = rho g along +x (gravity set purely along x after build: slope_deg stops at 89).
    Steady by t_end: the slowest mode decays as exp(-t/tau), tau = rho (2H)^2/(pi^2 mu) = 0.16 s
    (Newtonian bound; the plug is faster), so 2 s is 12 tau."""
    G = POIS_RHO * POIS_G
    tau_y = G * POIS_Y0
    u_plug = G * (POIS_H - POIS_Y0) ** 2 / (2 * POIS_MU)
    mat = {"model": "bingham", "density_kg_m3": POIS_RHO, "bulk_modulus_pa": 15000.0,
           "viscosity_pa_s": POIS_MU, "yield_stress_pa": tau_y, "bingham_variant": variant}
    if variant == "papanastasiou":
        # m = 1000 s: the regularisation matters only for gdot < 5/m = 5e-3 1/s, i.e. within
        # 1e-5 m of the yield surface; the plug's creep rate tau/(tau_y m) <= 1e-3 1/s.
        mat["papanastasiou_m_s"] = 1000.0
    else:
        # alpha_b = 1000: plug shear rate <= tau_y/(alpha_b mu) = 0.02 1/s -> plug non-uniformity
        # <= 0.02 * y0 / 2 = 5e-4 m/s, 0.1 % of the plug velocity.
        mat["alpha_b"] = 1000.0
    cfg = m.validate({
        "domain": {"lo_m": [0.0, -POIS_H], "hi_m": [4 * h, POIS_H], "cell_size_m": h},
        "boundary": {"x_lo": "periodic", "x_hi": "periodic", "y_lo": "noslip", "y_hi": "noslip"},
        "numerics": {"shape": shape, "velocity_scale_m_s": 1.2 * u_plug, "dtype": "float64", "pressure": pressure},
        "time": {"t_end_s": t_end, "n_frames": 4},
        "material": mat,
        "gravity": {"g_m_s2": 0.0},
        "bodies": [{"lo_m": [0.0, -POIS_H], "hi_m": [4 * h, POIS_H]}],
    })
    s = m.build(cfg)
    params = s.params._replace(gravity=jnp.asarray([POIS_G, 0.0], s.params.gravity.dtype))
    final, frames = m.run(s.scene, s.state, params)
    y = np.asarray(final.x[:, 1])
    u = np.asarray(final.v[:, 0])
    rows = np.unique(np.round(y, 9))  # particles move only along x: rows stay rows
    u_row = np.array([u[np.abs(y - r) < 1e-9].mean() for r in rows])
    u_prev = np.asarray(frames.v[-2, :, 0]).max()
    return dict(final=final, rows=rows, u_row=u_row, u_plug=u_plug, G=G, u_prev=u_prev)


def _plug_measures(r):
    rows, u_row = r["rows"], r["u_row"]
    ay = np.abs(rows)
    u_plug_mpm = u_row[ay < POIS_Y0].mean()
    # Plug half-width from a fit of the sheared zone alone: u = a + b|y| + c y^2 there, and
    # the yield surface is where du/d|y| = 0, i.e. y0 = -b/(2c).  Rows within half a particle
    # spacing of the exact yield surface are left out (they straddle it).
    sheared = ay > POIS_Y0 + 0.25 * (rows[1] - rows[0])
    c2, c1, _ = np.polyfit(ay[sheared], u_row[sheared], 2)
    return u_plug_mpm, -c1 / (2 * c2), 2 * c2


@pytest.mark.parametrize("shape, variant", [
    ("linear", "papanastasiou"),
    ("linear", "biviscosity"),
    ("gimp", "papanastasiou"),
])
def test_bingham_poiseuille_plug(shape, variant):
    """Linear (hat) functions interpolate, so the no-slip condition set on the wall nodes holds
    exactly at the wall; uGIMP (the thesis's choice) is the hat smoothed over the particle's own
    width (h/4 here) and keeps that near-wall behaviour.
    Particles move only along x, parallel to the cell faces in y, so the usual cell-crossing
    noise of hat functions does not arise here."""
    h = POIS_H / 10
    r = _poiseuille(h, shape, variant)
    assert int(r["final"].n_lost) == 0
    u_plug_mpm, y0_fit, curv = _plug_measures(r)
    # steady: the last two frames (0.5 s apart, 3 decay times) agree to 1e-3
    assert abs(r["u_prev"] / r["u_row"].max() - 1) < 1e-3
    # Brief: 5 %.  Measured +0.6 % (plug velocity) and -0.3 % (y0): the O(h^2) error of the
    # discrete viscous operator plus the nodal plug edge; 5 % leaves room for dtype/seeding.
    assert abs(u_plug_mpm / r["u_plug"] - 1) < 0.05, (u_plug_mpm, r["u_plug"])
    assert abs(y0_fit / POIS_Y0 - 1) < 0.05, y0_fit
    # sheared zone: u'' = -G/mu exactly for Bingham (measured to 7e-4); 2 % allowed.
    assert abs(curv / (-r["G"] / POIS_MU) - 1) < 0.02, curv
    # plug is rigid: its velocity varies by < 1 % across |y| < y0 - h
    core = np.abs(r["rows"]) < POIS_Y0 - h
    assert np.ptp(r["u_row"][core]) < 0.01 * r["u_plug"]


def test_bingham_poiseuille_plug_incompressible():
    """The same channel with the grid pressure at its default Maxwell modulus G = max(rho v^2, 100 tau_y)
    (``_constitutive.MAXWELL_YIELD_FACTOR``).  With G = rho v^2 alone (v = 1.2 u_plug: G = 345 Pa, below
    tau_y = 490 Pa) every particle was lost.  Measured (GIMP, H/h = 10): plug +0.007 %, y0 -0.04 %,
    curvature -0.08 %, the last two frames 4e-6 apart (at the floor of 20 tau_y it had until 2026-12-06:
    +0.10 / +0.07 / +0.11 % and 1.1e-3, the softer G's shear waves decaying more slowly than the explicit
    run's, so 2e-3 here).  Asserted as for the explicit cases."""
    r = _poiseuille(POIS_H / 10, "gimp", "papanastasiou", pressure="incompressible")
    assert int(r["final"].n_lost) == 0
    u_plug_mpm, y0_fit, curv = _plug_measures(r)
    assert abs(r["u_prev"] / r["u_row"].max() - 1) < 2e-3
    assert abs(u_plug_mpm / r["u_plug"] - 1) < 0.05, (u_plug_mpm, r["u_plug"])
    assert abs(y0_fit / POIS_Y0 - 1) < 0.05, y0_fit
    assert abs(curv / (-r["G"] / POIS_MU) - 1) < 0.02, curv


@pytest.mark.xfail(strict=True, reason="quadratic B-splines are not interpolating: zeroing the wall and ghost "
                   "nodes leaves an O(h) error next to a no-slip wall (plug velocity +12.7 % at H/h = 10). "
                   "See the report; remove the marker when the wall treatment is fixed.")
def test_bingham_poiseuille_plug_quadratic():
    r = _poiseuille(POIS_H / 10, "quadratic", "papanastasiou")
    u_plug_mpm, y0_fit, _ = _plug_measures(r)
    assert abs(u_plug_mpm / r["u_plug"] - 1) < 0.05, (u_plug_mpm, r["u_plug"])
    assert abs(y0_fit / POIS_Y0 - 1) < 0.05, y0_fit


def test_bingham_poiseuille_plug_quadratic_bm():
    """The boundary-modified quadratic B-spline (``quadratic_bm``: interpolating at the wall, no
    ghost-node weight; mpmjax/_shapes.py) removes the wall defect of the plain quadratic above,
    whose xfail stays: ``quadratic`` keeps its behaviour.  Measured at H/h = 10: plug velocity
    +0.67 %, y0 -0.40 %, sheared-zone curvature -0.14 %.  Asserted: plug within 2 % (the issue's
    target), y0 within 5 % and curvature within 2 % as for the linear/GIMP cases."""
    r = _poiseuille(POIS_H / 10, "quadratic_bm", "papanastasiou")
    assert int(r["final"].n_lost) == 0
    u_plug_mpm, y0_fit, curv = _plug_measures(r)
    assert abs(r["u_prev"] / r["u_row"].max() - 1) < 1e-3
    assert abs(u_plug_mpm / r["u_plug"] - 1) < 0.02, (u_plug_mpm, r["u_plug"])
    assert abs(y0_fit / POIS_Y0 - 1) < 0.05, y0_fit
    assert abs(curv / (-r["G"] / POIS_MU) - 1) < 0.02, curv


# --------------------------------------------------------------------------------------
# Bingham slump on a horizontal plane (REFERENCE.md: Coussot, Proust & Ancey 1996)
# --------------------------------------------------------------------------------------

SLUMP_RHO, SLUMP_G = 1000.0, 9.81
SLUMP_TAU_Y = 82.0  # k = 2 tau_y/(rho g) = 1.67 cm: x_f ~ 0.6 m, h(0) ~ 0.10 m = 5 cells of 2 cm


def test_bingham_slump_final_profile():
    """A 0.2 m x 0.2 m Bingham block against a symmetry wall at x = 0 slumps on a no-slip
    base (the formula's basal stress = tau_y needs a no-slip base) until rest; the deposit
    must be the yield-limited profile h(x) = sqrt(k (x_f - x)), k = 2 tau_y/(rho g).

    Choices.  The formula is the inertia-free limit: too small a plastic viscosity and the
    collapse overshoots (mu = 2 Pa s: x_f = 0.685 m against 0.60 m from mass conservation,
    deposit 20 % too thin); too large and the approach to rest, which is algebraic for a
    Bingham slump, takes long (mu = 10-20 Pa s: still creeping after 8 s).  mu = 7 Pa s is at
    rest by 6 s.  Papanastasiou m = 1e4 s makes the rest viscosity tau_y m = 8e5 Pa s, so the
    sub-yield creep is ~1e-5 m/s; the Maxwell update keeps dt at the wave-speed limit anyway.
    h = 0.02 m with 4^2 particles per cell (1600 particles, ~13 s).
    """
    h, ppc, mu = 0.02, 4, 7.0
    cfg = m.validate({
        "domain": {"lo_m": [0.0, 0.0], "hi_m": [1.0, 0.24], "cell_size_m": h},
        "boundary": {"x_lo": "symmetry", "x_hi": "slip", "y_lo": "noslip", "y_hi": "slip"},
        # quadratic B-spline: measured max profile deviation 6.6 %.  With GIMP the last ~4 cells
        # before the front come out up to 26 % thicker (docs/validation.md), so this test pins
        # the shape function it validates.
        # The per-particle pressure (kappa below), as measured.  With the grid pressure the profile's largest
        # departure is +12.4 % (2026-12-08), at the last station before the front (elsewhere -7.8 to +8.4 %): the
        # validate suite's slumps measure the grid pressure against x_inf (docs/incompressible.md).
        "numerics": {"ppc": ppc, "shape": "quadratic", "pressure": "explicit"},
        "time": {"t_end_s": 6.0, "n_frames": 12},
        "material": {"model": "bingham", "density_kg_m3": SLUMP_RHO, "bulk_modulus_pa": 15000.0,
                     "viscosity_pa_s": mu, "yield_stress_pa": SLUMP_TAU_Y, "papanastasiou_m_s": 1e4},
        "gravity": {"g_m_s2": SLUMP_G},
        "bodies": [{"lo_m": [0.0, 0.0], "hi_m": [0.2, 0.2]}],
    })
    s = m.build(cfg)
    final, frames = m.run(s.scene, s.state, s.params)
    assert int(final.n_lost) == 0
    sp = s.info["particle_spacing_m"]
    ro = np.asarray(m.runout(frames.x, frames.active, 0, 0.0, sp))
    # at rest: the front moved < 0.5 % in the last second (measured 0.2 mm = 0.03 %)
    assert ro[-1] - ro[-3] < 0.005 * ro[-1], ro
    assert float(jnp.max(jnp.abs(final.v))) < 5e-3  # m/s; measured 2e-4 (elastic ringing)

    x = np.asarray(final.x[:, 0])
    area = np.asarray(final.vol0 * final.J)  # actual (weakly compressed) area per particle [m^2]
    x_f = ro[-1]
    k = 2 * SLUMP_TAU_Y / (SLUMP_RHO * SLUMP_G)
    # Mass conservation for the yield-limited profile: A = (2/3) sqrt(k) x_f^(3/2).  Measured
    # x_f = 0.589 m vs 0.592 m (-0.6 %); 5 % allows for the profile error below near the front.
    x_f_mass = (1.5 * area.sum() / math.sqrt(k)) ** (2 / 3)
    assert abs(x_f / x_f_mass - 1) < 0.05, (x_f, x_f_mass)

    # Depth profile: particle areas spread with a hat kernel one cell wide (smooths the
    # discreteness of ~3 particle columns per cell after the 3x stretching).
    def depth(xs):
        K = np.clip(1 - np.abs(xs[:, None] - x[None, :]) / h, 0, None) / h
        return K @ area

    # Stations from 0.05 m to x_f - 2h.  Left out:
    #  * x < 0.05 m (~h(0)/2): at the symmetry wall the deposit has dh/dx = 0, while the thin-
    #    layer formula has slope -k/(2 h(0)); the 2-D stress field differs from the lubrication
    #    one within about a deposit thickness of the wall, and the kernel is cut by the wall.
    #  * the last two cells: there h -> 0 with infinite slope, the thin-layer assumption fails
    #    (aspect h/(x_f - x) = sqrt(k/(x_f - x)) > 0.6) and the tip is thinner than 2 cells.
    xs = np.arange(0.05, x_f - 2 * h, h / 2)
    ratio = depth(xs) / np.sqrt(k * (x_f - xs))
    # Brief: 10 %.  Measured max |ratio - 1| = 6.6 %: +6 % mid-body, -6 % at 3/4 of the runout;
    # the residual is weak compressibility (J ~ 0.95 at the base) and the coarse grid.
    assert np.max(np.abs(ratio - 1)) < 0.10, np.round(ratio, 3)
    # Yield stress recovered from the deposit: least squares of h^2 = k (x_f - x) over the
    # stations (measured tau_y = 85.6 Pa, +4.4 %); 10 % like the profile.
    k_fit = np.sum(depth(xs) ** 2 * (x_f - xs)) / np.sum((x_f - xs) ** 2)
    assert abs(k_fit / k - 1) < 0.10, (k_fit, k)


# --------------------------------------------------------------------------------------
# Thesis lab dam break, BASE and run 7c (REFERENCE.md scenario 1)
# --------------------------------------------------------------------------------------

THESIS_RUNOUT_M = 1.1


def _huppert_front(mu, t, area=0.2 * 0.2, rho=1850.0, g=9.81):
    """Front of a 2-D viscous gravity current of constant area per unit width ``area``
    released against a wall (Huppert 1982): x_N = 1.411 (rho g A^3 t / (3 mu))^(1/5)."""
    return 1.411 * (rho * g * area**3 * t / (3 * mu)) ** 0.2


_DAMBREAK_CACHE = {}


def _dambreak(cell, alpha, extra=None):
    key = (cell, alpha, tuple(sorted((extra or {}).items())))
    if key not in _DAMBREAK_CACHE:
        # ppc 2: the runouts and J bounds below were measured there (at ppc 3, run 7c at h = 0.02 m
        # reaches J = 2.18 in the thin front: docs/validation.md, "Defaults")
        over = {"domain.cell_size_m": cell, "material.alpha": alpha, "numerics.ppc": 2, **(extra or {})}
        s = m.build(m.load_scene("dambreak-lab", over))
        final, frames = m.run(s.scene, s.state, s.params)
        ro = np.asarray(m.runout(frames.x, frames.active, s.info["runout_axis"], s.info["runout_origin_m"],
                                 s.info["particle_spacing_m"]))
        _DAMBREAK_CACHE[key] = (s, final, frames, ro)
    return _DAMBREAK_CACHE[key]


def _check_dambreak(cell, alpha, extra=None):
    s, final, frames, ro = _dambreak(cell, alpha, extra)
    assert s.scene.t_end == pytest.approx(15.0)
    # The Maxwell update runs at the wave-speed step, far above the explicit viscous limit
    # rho h^2/(2 d mu_max) that the thesis's update needed (why run 7c crashed there).
    assert s.info["dt_s"] > 50 * s.info["dt_viscous_s"]
    assert int(final.n_lost) == 0
    assert bool(jnp.all(final.active))
    for leaf in (final.x, final.v, final.J, final.tau, final.mu, final.internal["lam"]):
        assert bool(jnp.all(jnp.isfinite(leaf)))
    lam = np.asarray(frames.internal["lam"])
    # 0 <= lam <= lam0 + t/T: destructuration only removes structure, aging adds at most 1/T
    assert lam.min() >= 0.0 and lam.max() <= 1.5 + 15.0 / 0.5 + 1e-3
    assert float(jnp.max(frames.mu)) <= 5000.0 * (1 + 1e-6)
    J = np.asarray(final.J)
    y = np.asarray(final.x[:, 1])
    # Weakly compressible at rest: the deposit is < 0.06 m thick, so the base pressure
    # rho g h < 1.1 kPa and the Tait EOS gives 1 - J < C ln(1 + p/(C kappa)) = 0.05; a fluid at
    # rest under gravity is not in tension (J <= 1) up to particle-level pressure noise (a
    # pressure mode the grid does not see).  More than two cells above the base the noise
    # is bounded by 0.85 < J < 1.2, i.e. |p| < 3 kPa, below the initial base pressure
    # rho g H = 3.6 kPa.  Measured with quadratic B-splines: 0.92 .. 1.024 (h = 0.02 m),
    # 0.94 .. 1.045 (h = 0.01 m); with GIMP, the default: within 0.9 .. 1.06 at h = 0.02 m,
    # 0.927 .. 1.080 (BASE) and 0.910 .. 1.143 (run 7c) at h = 0.01 m.  The GIMP noise is an
    # open defect (docs/validation.md; a J-bar volume average is the usual remedy).
    # (At h = 0.02 m run 7c's deposit is thinner than two cells; then this part is empty.)
    above = y > 2 * s.scene.h
    if above.any():
        assert J[above].min() > 0.85 and J[above].max() < 1.2, (J[above].min(), J[above].max())
    # The two cells over the no-slip base are looser (measured 0.81 .. 1.18 with quadratic
    # B-splines; with GIMP, the default, 0.81 .. 1.46 for BASE and up to 1.62 for run 7c at
    # h = 0.02 m): particles of the bottom row sit on the wall nodes, where the zeroed wall
    # velocity squashes or stretches them.  Only check that nothing inverts (J > 0.7) or runs
    # away (J < 2) there; docs/validation.md records this artefact as an open defect.
    assert J.min() > 0.7 and J.max() < 2.0, (J.min(), J.max())
    # Physical band for the runout at 15 s: the Coussot viscosity lies between mu0 = 4 and
    # mu_max = 5000 Pa s, so the front lies between the viscous gravity currents (Huppert 1982)
    # of those two viscosities: 0.37 m and 1.52 m (5 % allowance on the upper bound for the
    # inertial start and the half-spacing in the runout definition).  Thesis: ~1.1 m.
    lo_b, hi_b = _huppert_front(5000.0, 15.0), _huppert_front(4.0, 15.0)
    assert lo_b == pytest.approx(0.365, abs=2e-3) and hi_b == pytest.approx(1.520, abs=2e-3)
    assert lo_b < ro[-1] < 1.05 * hi_b, ro[-1]
    # the current is close to rest: the front advanced < 3 % in the last 2.5 s (aged material
    # near mu_max still creeps; measured 0.1 % for BASE, 2 % for 7c at h = 0.01 m)
    n25 = int(round(2.5 / 15.0 * (len(ro))))
    assert ro[-1] - ro[-1 - n25] < 0.03 * ro[-1], (ro[-1 - n25], ro[-1])
    return ro[-1]


@pytest.mark.parametrize("alpha", [1.0, 10.0], ids=["BASE", "run7c"])
def test_dambreak_lab_stable_coarse(alpha):
    """Full 15 s at h = 0.02 m (CI).  Measured runout: BASE 1.235 m, 7c 1.374 m."""
    runout = _check_dambreak(0.02, alpha)
    if alpha == 1.0:
        # Thesis BASE ~1.1 m, insensitive to the grid.  We use the standard rate measure and
        # the Maxwell update (the thesis: gdot^2/8 and the explicit law), which destructures
        # faster for gdot > sqrt(8) 1/s, so runout is somewhat longer; 20 % bounds that
        # (measured +12 %; with the thesis measure +7 %, see the next test).
        assert abs(runout / THESIS_RUNOUT_M - 1) < 0.2, runout


def test_dambreak_run7c_runs_further_than_base():
    """alpha = 10 destructures 10x faster, so lam and mu stay lower and the current runs
    further (measured 1.374 m vs 1.235 m at h = 0.02 m)."""
    base = _dambreak(0.02, 1.0)[3][-1]
    fast = _dambreak(0.02, 10.0)[3][-1]
    assert fast > base + 0.05


def test_dambreak_thesis_measure_reproduces_thesis_runout():
    """Thesis compatibility options (shear measure gdot^2/8, explicit-Euler lam) at h = 0.02 m:
    runout 1.182 m vs the thesis's ~1.1 m.  10 %: the remaining differences are the Maxwell
    stress update, the quadratic B-spline (thesis: GIMP), and "about 1.1 m" itself."""
    runout = _check_dambreak(0.02, 1.0, {"material.shear_measure": "thesis", "material.lambda_integrator": "euler"})
    assert abs(runout / THESIS_RUNOUT_M - 1) < 0.1, runout


@pytest.mark.slow
@pytest.mark.parametrize("alpha", [1.0, 10.0], ids=["BASE", "run7c"])
def test_dambreak_lab_stable_default_resolution(alpha):
    """Default resolution h = 0.01 m (~40 s each).  Measured: BASE 1.268 m, 7c 1.458 m."""
    runout = _check_dambreak(0.01, alpha)
    if alpha == 1.0:
        assert abs(runout / THESIS_RUNOUT_M - 1) < 0.2, runout
