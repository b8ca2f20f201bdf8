"""Boundary conditions: slip walls are frictionless, no-slip walls are not, at any angle.

Exact statement used: the only external forces are gravity and the walls, and a slip
(frictionless) wall only removes normal velocity — on the grid nodes behind it and on particles
pushed back out of it — so the total momentum along the wall's tangent t evolves as
P_t(t) = P_t(0) + M (g . t) t exactly (round-off), however the body bounces or deforms.
"""

import math

import numpy as np
import pytest

import mpmjax as m

TH = math.radians(20.0)


def _incline(kind, t_end=0.3, pressure="explicit"):
    # plane y = 0.1 + x tan(th), normal into the fluid (-sin th, cos th); open box faces
    raw = {
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [1.0, 0.6], "cell_size_m": 0.02},
        "boundary": {
            "x_lo": "open",
            "x_hi": "open",
            "y_lo": "open",
            "y_hi": "open",
            "planes": [{"point_m": [0.0, 0.1], "normal": [-math.sin(TH), math.cos(TH)], "type": kind}],
        },
        # ppc 2 as measured (at the default 3 the block seeds closer to the open x_lo face and a few
        # particles leave through it)
        "numerics": {"dtype": "float64", "shape": "gimp", "ppc": 2, "pressure": pressure},
        "time": {"t_end_s": t_end, "n_frames": 6},
        "material": {"model": "newtonian", "density_kg_m3": 1000.0, "bulk_modulus_pa": 2e4, "viscosity_pa_s": 1.0},
        "gravity": {"g_m_s2": 9.81},
        "bodies": [{"lo_m": [0.5, 0.1 + 0.72 * math.tan(TH)], "hi_m": [0.7, 0.1 + 0.72 * math.tan(TH) + 0.1]}],
    }
    s = m.build(m.validate(raw))
    final, frames = m.run(s.scene, s.state, s.params)
    mass = np.asarray(s.state.vol0) * 1000.0
    t_hat = np.array([math.cos(TH), math.sin(TH)])
    n_hat = np.array([-math.sin(TH), math.cos(TH)])
    p_t = np.einsum("p,fpi,i->f", mass, np.asarray(frames.v), t_hat)
    times = (np.arange(6) + 1) * s.scene.steps_per_frame * s.scene.dt
    return s, final, frames, mass, p_t, times, n_hat


def test_slip_incline_is_frictionless():
    # The per-particle pressure, where the statement is exact.  With the grid pressure it is not, at a plane that
    # cuts the cells: the solve scales a node's mass by its kernel fill over its share of the cells whose centre
    # is in front of the plane (so that hydrostatic pressure is an equilibrium at walls; _pressure, "Near walls"),
    # and along a cut these differ node by node, so the pressure's impulse gets a tangential part: measured
    # -0.25 / -0.19 / +1.6 / +1.9 / +1.6 / +1.4 % of the exact tangential momentum per frame (h = 2 cm, the
    # block 5 cells thick); with that scale set to 1 the statement holds to round-off (checked 2026-12-08).
    # Along an axis-aligned slip floor the grid pressure is exact: test_slip_floor_keeps_horizontal_momentum.
    s, final, frames, mass, p_t, times, n_hat = _incline("slip")
    assert int(final.n_lost) == 0
    M = mass.sum()
    exact = -M * 9.81 * math.sin(TH) * times  # g . t = -g sin(th)
    np.testing.assert_allclose(p_t, exact, rtol=1e-10)
    # and the body really is on the plane by the end (it fell 2 cm onto it and slid):
    x = np.asarray(final.x)
    dist = (x - [0.0, 0.1]) @ n_hat
    assert dist.min() > -1e-9 and dist.min() < 0.02


def test_noslip_incline_holds_back():
    s, final, frames, mass, p_t, times, n_hat = _incline("noslip")
    exact = -mass.sum() * 9.81 * math.sin(TH) * times
    # after contact the no-slip wall takes tangential momentum out (grid contact starts up to
    # (1 + lp) h = 2.5 cm before the particles touch, the usual MPM early contact, so even the
    # first frame is slightly below free sliding).  A slip-like bug gives ratio 1 to 1e-10 (test
    # above); here the ratio must fall frame after frame and end well below 1 (measured 0.97,
    # 0.92, 0.81, 0.66, 0.53, 0.45; the bound 0.75 only needs the wall to act at all).
    ratio = p_t / exact
    print("no-slip / frictionless tangential momentum per frame:", np.round(ratio, 3))
    assert ratio[0] < 1.0 and np.all(np.diff(ratio) < 0) and ratio[-1] < 0.75


@pytest.mark.parametrize("kind, pressure", [("slip", "explicit"), ("symmetry", "explicit"), ("slip", "incompressible")])
def test_slip_floor_keeps_horizontal_momentum(kind, pressure):
    """A block sliding at 0.5 m/s on a slip floor keeps its horizontal momentum (rtol 1e-10: round-off
    over 0.2 s).  With the grid pressure too: its velocity change reaches the nodes beyond the fluid cells
    (``_pressure.extend``), and the mass of those nodes is moved with the nodes it comes from
    (``lumped_mass``); before that the block gained 2.3e-3 of its momentum over the 0.2 s."""
    raw = {
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [1.2, 0.3], "cell_size_m": 0.02},
        "boundary": {"x_lo": "open", "x_hi": "open", "y_lo": kind, "y_hi": "open"},
        "numerics": {"dtype": "float64", "pressure": pressure},
        "time": {"t_end_s": 0.2, "n_frames": 4},
        "material": {"model": "newtonian", "density_kg_m3": 1000.0, "bulk_modulus_pa": 2e4, "viscosity_pa_s": 1.0},
        "bodies": [{"lo_m": [0.3, 0.0], "hi_m": [0.5, 0.1], "velocity_m_s": [0.5, 0.0]}],
    }
    s = m.build(m.validate(raw))
    final, frames = m.run(s.scene, s.state, s.params)
    mass = np.asarray(s.state.vol0) * 1000.0
    px = np.einsum("p,fp->f", mass, np.asarray(frames.v)[..., 0])
    np.testing.assert_allclose(px, mass.sum() * 0.5, rtol=1e-10)
