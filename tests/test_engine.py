"""Engine verification (issue 2): conservation, exact solutions, 2D/3D agreement, jit/vmap (the shape
functions and stencils: ``test_engine_shapes.py``).

Every test asserts a physical number against an exact or closed-form value with a
tolerance whose origin is stated next to it.  All runs are float64
(``numerics.dtype = "float64"``) on coarse grids so the whole file runs in about a
minute on two CPU cores.

Exact solutions and thesis parameters are from ../shared/REFERENCE.md ("Exact
solutions to test against"; thesis Table 2 for plane Poiseuille).

Conventions used below: 2D is plane strain with masses per metre of depth; the last
axis is vertical; ``rel`` errors are stated against the scale named in each test.
"""

from __future__ import annotations

import functools
import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import ROUNDOFF, SHAPES

import mpmjax as m
from mpmjax._metrics import RunoutGauge

jax.config.update("jax_enable_x64", True)

G = 9.81  # m/s^2
RHO = 1000.0  # kg/m^3
KAPPA = 15000.0  # Pa, thesis lab value (REFERENCE.md "Pressure")


def _cfg(dim, lo, hi, h, faces, bodies, *, t_end, n_frames, mu=1.0, numerics=None, g=G, slope=0.0):
    """A validated float64 Newtonian scene dict (thesis lab kappa, water density)."""
    num = {"dtype": "float64", "shape": "quadratic"}
    num.update(numerics or {})
    return m.validate(
        {
            "domain": {"dim": dim, "lo_m": list(lo), "hi_m": list(hi), "cell_size_m": h},
            "boundary": faces,
            "numerics": num,
            "time": {"t_end_s": t_end, "n_frames": n_frames},
            "material": {"model": "newtonian", "density_kg_m3": RHO, "bulk_modulus_pa": KAPPA, "viscosity_pa_s": mu},
            "gravity": {"g_m_s2": g, "slope_deg": slope},
            "bodies": bodies,
        }
    )


def _open_faces(dim):
    return {f"boundary.{'xyz'[a]}_{s}": "open" for a in range(dim) for s in ("lo", "hi")}


def _nested(flat_faces):
    return {k.split(".")[1]: v for k, v in flat_faces.items()}


# ======================================================================================
# A short Newtonian dam break, shared by the mass and 2D/3D tests
# ======================================================================================

DB_H = 0.02  # m
DB_BLOCK = 0.1  # m, square column at the left wall
DB_T = 0.3  # s


@functools.cache
def _dambreak(dim, nz=2, shape="quadratic"):
    """Dam break of a 0.1 m x 0.1 m Newtonian column (mu = 1 Pa s) in a 0.4 m x 0.2 m box:
    slip side walls and lid, no-slip base.  In 3D the problem is extruded nz cells along
    y (the middle axis) between symmetry faces.  Returns (setup, final, frames)."""
    if dim == 2:
        lo, hi = [0.0, 0.0], [0.4, 0.2]
        faces = {"x_lo": "slip", "x_hi": "slip", "y_lo": "noslip", "y_hi": "slip"}
        body = {"lo_m": [0.0, 0.0], "hi_m": [DB_BLOCK, DB_BLOCK]}
    else:
        w = nz * DB_H
        lo, hi = [0.0, 0.0, 0.0], [0.4, w, 0.2]
        faces = {
            "x_lo": "slip",
            "x_hi": "slip",
            "y_lo": "symmetry",
            "y_hi": "symmetry",
            "z_lo": "noslip",
            "z_hi": "slip",
        }
        body = {"lo_m": [0.0, 0.0, 0.0], "hi_m": [DB_BLOCK, w, DB_BLOCK]}
    # the particles' pressure, pinned: test_2d_and_3d_extruded_dambreak_agree asserts round-off agreement (1e-9 m),
    # which the grid pressure's iterative solve (rtol 1e-11) cannot give; its own extrusion test is in
    # tests/test_pressure.py
    cfg = _cfg(
        dim, lo, hi, DB_H, faces, [body], t_end=DB_T, n_frames=6, mu=1.0,
        numerics={"shape": shape, "ppc": 2, "pressure": "explicit"},
    )
    s = m.build(cfg)
    final, frames = m.run(s.scene, s.state, s.params)
    return s, final, frames


def test_mass_conserved_by_p2g():
    """Grid mass from P2G equals sum_p rho vol0_p to round-off at every frame of a dam
    break (particles next to walls spread mass onto ghost nodes, which must be counted).

    Exact by partition of unity (sum_i w_ip = 1); float64 relative tolerance 1e-12.
    Checked for every shape function on the same particle positions (the quadratic
    grid's 3-cell ghost layer also holds the linear, GIMP and cubic stencils).
    """
    s, final, frames = _dambreak(2)
    assert int(final.n_lost) == 0
    m_particles = float(jnp.sum(s.params.material.rho * s.state.vol0))
    np.testing.assert_allclose(m_particles, RHO * DB_BLOCK * DB_BLOCK, rtol=ROUNDOFF)  # kg per m depth
    # the front must have moved, so the check covers particles near the walls and the base
    assert float(np.max(frames.x[-1][:, 0])) > DB_BLOCK + DB_H
    for kind in SHAPES:
        p2g = m.make_p2g(s.scene.replace(shape=kind))
        grid_mass = jax.jit(lambda st, prm, p2g=p2g: p2g(st, prm)[0])
        for k in range(frames.x.shape[0]):
            st = s.state._replace(x=frames.x[k], J=frames.J[k], active=frames.active[k])
            mass = grid_mass(st, s.params)
            assert abs(float(jnp.sum(mass)) - m_particles) <= ROUNDOFF * m_particles, (kind, k)


# ======================================================================================
# Momentum with no gravity and no walls
# ======================================================================================


@pytest.mark.parametrize("transfer", ["apic", "flip", "mls"])
def test_momentum_conserved_without_gravity_or_walls(transfer):
    """Total momentum sum_p m_p v_p is constant over 100 steps (g = 0, all faces open).

    A 0.2 m square block of Newtonian fluid (mu = 25 Pa s) sits in the middle of a
    0.6 m box with a non-uniform velocity: translation + rigid rotation + simple shear,
    so pressure and viscous forces are active.  Exact for APIC and FLIP/PIC: the grid
    forces sum to zero (sum_i grad w_ip = 0) and both transfers conserve sum m v.
    ``mls``: APIC with the quadratic B-spline and ``numerics.force = "mls"``, where the stress
    enters as the impulse -dt V sigma D^-1 (x_i - x_p) w_ip: exact too, since sum_i w_ip
    (x_i - x_p) = 0 for a B-spline (linear reproduction).
    Tolerance: 1e-12 of sum_p m_p |v_p| (round-off, see ROUNDOFF).
    """
    numerics = {"transfer": transfer, "velocity_scale_m_s": 1.0, "dt_s": 5e-4}
    if transfer == "mls":
        numerics.update(transfer="apic", shape="quadratic", force="mls")
    h = 0.03
    cfg = _cfg(
        2,
        [0, 0],
        [0.6, 0.6],
        h,
        _nested(_open_faces(2)),
        [{"lo_m": [0.2, 0.2], "hi_m": [0.4, 0.4]}],
        t_end=0.05,
        n_frames=10,
        mu=25.0,
        g=0.0,
        numerics=numerics,
    )
    s = m.build(cfg)
    assert s.scene.n_steps == 100
    x = np.asarray(s.state.x)
    r = x - 0.3
    v = np.array([0.2, -0.1]) + 2.0 * np.stack([-r[:, 1], r[:, 0]], 1) + np.stack([1.5 * r[:, 1], 0 * r[:, 0]], 1)
    state = s.state._replace(v=jnp.asarray(v))
    final, frames = m.run(s.scene, state, s.params)
    assert int(final.n_lost) == 0
    mass = np.asarray(s.params.material.rho * s.state.vol0)
    p0 = (mass[:, None] * v).sum(0)
    scale = float((mass * np.linalg.norm(v, axis=1)).sum())
    p_t = np.einsum("n,fnd->fd", mass, np.asarray(frames.v))
    drift = np.max(np.abs(p_t - p0)) / scale
    print(f"momentum drift ({transfer}) {drift:.2e} of sum m|v|")
    assert drift < ROUNDOFF, drift
    # the flow is non-trivial: the velocity field has changed by O(1) of itself
    dv = np.max(np.abs(np.asarray(final.v) - v)) / np.max(np.abs(v))
    assert dv > 0.05, dv


def test_mls_force_matches_the_gradient_force_on_the_water_dam_break():
    """``numerics.force = "mls"`` (experimental) against the default nodal force, quadratic
    B-spline, APIC, ``dambreak-water`` at h = 0.02 m to its 1.2 s: the fronts agree within 1.5 %.
    Why that bound: both are consistent discretisations of the same stress divergence, so at one
    h they differ by their O(h) errors, and the default's own front moves 0.8 % from h = 0.02 to
    0.01 m (0.4166 -> 0.4198 m, measured); 1.5 % is about twice that.  Measured: 0.4166 against
    0.4182 m (+0.4 %); at h = 0.01 m 0.4198 against 0.4171 m (-0.6 %).  No particle is lost and
    J stays within 2 % of 1 in both (the water is weakly compressible: measured 0.987-1.012 MLS).
    A scene the option cannot serve is refused naming the keys."""
    fronts = {}
    for force in ("gradient", "mls"):
        s = m.build(
            m.load_scene(
                "dambreak-water", ["numerics.shape=quadratic", f"numerics.force={force}", "domain.cell_size_m=0.02"]
            )
        )
        final, _ = m.run(s.scene, s.state, s.params)
        assert int(final.n_lost) == 0
        assert 0.97 < float(jnp.min(final.J)) and float(jnp.max(final.J)) < 1.03
        fronts[force] = RunoutGauge.of(s.scene, s.info).front(final.x, final.vol0, final.active)
    assert abs(fronts["mls"] / fronts["gradient"] - 1.0) < 0.015, fronts
    for bad in (
        ["numerics.shape=gimp"],
        ["numerics.shape=quadratic_bm"],
        ["numerics.transfer=flip", "numerics.shape=quadratic"],
    ):
        with pytest.raises(m.SceneError, match="numerics.force"):
            m.build(m.load_scene("dambreak-water", ["numerics.force=mls", *bad]))


# ======================================================================================
# Free fall
# ======================================================================================


def test_free_fall_matches_symplectic_euler():
    """A block in an open domain falls with a_y = -g.

    The step is symplectic Euler on the grid: v^{n+1} = v^n - g dt, x^{n+1} = x^n +
    dt v^{n+1} (a uniform velocity gives L = 0 exactly, so J = 1, p = 0, tau = 0 and no
    internal force), hence exactly
        y_c(t_n) = y_c(0) - g t_n^2 / 2 - g dt t_n / 2,   v_y(t_n) = -g t_n.
    Asserted to 1e-12 relative (round-off).  The continuous solution -g t^2/2 is
    therefore missed by exactly g dt t / 2, which is also asserted as a bound.
    """
    cfg = _cfg(
        2,
        [0, 0],
        [0.4, 0.6],
        0.02,
        _nested(_open_faces(2)),
        [{"lo_m": [0.15, 0.4], "hi_m": [0.25, 0.5]}],
        t_end=0.25,
        n_frames=10,
        mu=1.0,
        numerics={"velocity_scale_m_s": 2.5},
    )
    s = m.build(cfg)
    final, frames = m.run(s.scene, s.state, s.params)
    assert int(final.n_lost) == 0
    dt = s.scene.dt
    t = np.asarray(frames.t)
    yc0 = float(np.mean(s.state.x[:, 1]))
    yc = np.asarray(frames.x[:, :, 1]).mean(1)
    exact_discrete = yc0 - G * t**2 / 2 - G * dt * t / 2
    np.testing.assert_allclose(yc, exact_discrete, rtol=ROUNDOFF, atol=ROUNDOFF * yc0)
    np.testing.assert_allclose(
        np.asarray(frames.v[:, :, 1]), -G * t[:, None] * np.ones_like(frames.v[:, :, 1]), rtol=ROUNDOFF, atol=0
    )
    np.testing.assert_allclose(np.asarray(frames.v[:, :, 0]), 0.0, atol=ROUNDOFF)
    err_continuous = np.abs(yc - (yc0 - G * t**2 / 2))
    print(
        f"free fall: max |y_c - discrete exact| = {np.max(np.abs(yc - exact_discrete)):.2e} m; "
        f"vs -g t^2/2: {err_continuous[-1]:.4e} m = g dt t/2 = {G * dt * t[-1] / 2:.4e} m"
    )
    assert np.all(err_continuous <= G * dt * t / 2 * (1 + 1e-9) + 1e-15)
    # the block fell a meaningful distance (0.31 m = 15 cells)
    assert yc0 - yc[-1] > 0.3


# ======================================================================================
# Hydrostatic column
# ======================================================================================


@functools.cache
def _hydrostatic(shape="gimp", h=0.01, pressure=None):
    """0.1 m x 0.2 m Newtonian column (mu = 300 Pa s) in a box with slip side walls,
    no-slip base and slip lid (0.24 m), settled under gravity for 1.5 s."""
    cfg = _cfg(
        2,
        [0, 0],
        [0.1, 0.24],
        h,
        {"x_lo": "slip", "x_hi": "slip", "y_lo": "noslip", "y_hi": "slip"},
        [{"lo_m": [0.0, 0.0], "hi_m": [0.1, 0.2]}],
        t_end=1.5,
        n_frames=5,
        mu=300.0,
        numerics={"shape": shape} | ({"pressure": pressure} if pressure else {}),
    )
    s = m.build(cfg)
    final, frames = m.run(s.scene, s.state, s.params)
    return s, final, frames


def test_hydrostatic_column_pressure():
    """Settled column: particle pressure p = Tait(J) matches the hydrostatic weight.

    Metric: the weight of the material above a particle is Lagrangian-invariant, so the
    exact hydrostatic pressure is p = rho0 g (H0 - Y0), Y0 the particle's initial height
    and H0 = 0.2 m the initial column height.  (With kappa = 15 kPa the base compresses
    by 8 % (J = 0.92), so the Eulerian rho0 g (H - y) would be off by up to 8 % of
    rho0 g H0 from compressibility alone; the Lagrangian form has no such error.)
    Assert max |p - rho0 g (H0 - Y0)| <= 5 % of rho0 g H0 over all particles except the
    top two cells (p -> 0 there, and the free-surface particles carry the largest
    relative error).  Measured with GIMP (the thesis's shape function, Annex 2),
    h = 0.01 m: 3.5 %; the residual is the known particle-pair (odd-even) pressure
    oscillation of MPM, which the cell average removes: cell-averaged error <= 2 %
    (measured 0.9 %).  Settling: max |v| < 1e-4 m/s at 1.5 s (measured ~2e-7).
    """
    h = 0.01
    # the particles' pressure, Tait(J) (the grid pressure's column: tests/test_pressure.py)
    s, final, frames = _hydrostatic("gimp", h, pressure="explicit")
    assert int(final.n_lost) == 0
    vmax = float(np.max(np.abs(final.v)))
    assert vmax < 1e-4, vmax
    Y0 = np.asarray(s.state.x[:, 1])
    p = np.asarray(m.tait_pressure(final.J, s.params.material.kappa))
    p_exact = RHO * G * (0.2 - Y0)
    scale = RHO * G * 0.2
    sel = Y0 < 0.2 - 2 * h
    err = np.max(np.abs(p - p_exact)[sel]) / scale
    print(f"hydrostatic: max particle error {err:.3e} of rho g H0, vmax {vmax:.1e} m/s")
    assert err < 0.05, err
    # cell averages (the ppc = 2 particles of each cell row, paired by initial cell)
    cell = np.floor(Y0 / h + 1e-9).astype(int)
    errs = [abs(np.mean(p[cell == c]) - np.mean(p_exact[cell == c])) / scale for c in np.unique(cell[sel])]
    print(f"hydrostatic: max cell-averaged error {max(errs):.3e}")
    assert max(errs) < 0.02, max(errs)
    # the base pressure is really hydrostatic (not, e.g., an undamped oscillation around it)
    assert abs(np.mean(p[cell == 0]) / (RHO * G * (0.2 - h / 2)) - 1) < 0.02


# ======================================================================================
# Plane Poiseuille (thesis Table 2)
# ======================================================================================

POIS_MU, POIS_HALF = 25.0, 0.1  # Pa s, m (gap 0.2 m)
POIS_UMAX = RHO * G * POIS_HALF**2 / (2 * POIS_MU)  # 1.962 m/s


def _poiseuille(h, shape, t_end=2.0, nx=4, extra=None, boundary=None):
    """Plane Poiseuille of thesis Table 2: mu = 25 Pa s, kappa = 15 kPa, rho = 1000,
    gap 0.2 m between no-slip walls at y = 0 and y = 0.2, periodic in x (nx cells long,
    so no stencil wraps onto itself), gravity 9.81 along x, run 2 s.  The time step
    uses velocity_scale 2.5 m/s > u_max = 1.96 m/s; ``extra``: more numerics keys,
    ``boundary``: more boundary keys.  Returns (setup, final)."""
    L = nx * h
    faces = {"x_lo": "periodic", "x_hi": "periodic", "y_lo": "noslip", "y_hi": "noslip", **(boundary or {})}
    cfg = _cfg(
        2,
        [0.0, 0.0],
        [L, 0.2],
        h,
        faces,
        [{"lo_m": [0.0, 0.0], "hi_m": [L, 0.2]}],
        t_end=t_end,
        n_frames=4,
        mu=POIS_MU,
        numerics={"shape": shape, "velocity_scale_m_s": 2.5, **(extra or {})},
    )
    s = m.build(cfg)
    # gravity purely along x (slope_deg is capped at 89 degrees); params are traced
    params = s.params._replace(gravity=jnp.asarray([G, 0.0], jnp.float64))
    final, _ = m.run(s.scene, s.state, params)
    return s, final


def _poiseuille_error(final):
    """max_p |u_p - u(y_p)| / u_max with u(y) = G (H^2 - (y - 0.1)^2) / (2 mu), G = rho g,
    the exact profile between walls at y = 0 and 0.2, evaluated at the particle positions."""
    y = np.asarray(final.x[:, -1])
    u = np.asarray(final.v[:, 0])
    u_exact = RHO * G * (POIS_HALF**2 - (y - POIS_HALF) ** 2) / (2 * POIS_MU)
    return float(np.max(np.abs(u - u_exact)) / POIS_UMAX)


def test_poiseuille_converges_gimp():
    """Thesis Table 2 Poiseuille with GIMP (the thesis's shape function): steady profile
    within 1 % of u_max at h = 0.01 m, and second-order convergence.

    Steady state: the slowest mode decays as exp(-nu pi^2 t / (4 H^2)) = exp(-6.2 t), so
    at 2 s the transient is 4e-6 of u_max, far below the tolerances.
    Measured max error / u_max: 3.1e-2 (h = 0.04), 7.4e-3 (0.02), 1.8e-3 (0.01);
    observed order 2.07, 2.07.  Asserted: finest < 1 % (the issue's target) and each
    halving of h reduces the error by at least 2^1.5 (margin below order 2).
    """
    errs = []
    for h in (0.04, 0.02, 0.01):
        s, final = _poiseuille(h, "gimp")
        assert int(final.n_lost) == 0
        errs.append(_poiseuille_error(final))
    orders = [math.log2(a / b) for a, b in itertools.pairwise(errs)]
    print(f"Poiseuille GIMP errors/u_max {errs}, orders {orders}")
    assert errs[-1] < 0.01, errs
    assert all(o > 1.5 for o in orders), (errs, orders)


def test_poiseuille_navier_slip_gimp():
    """Poiseuille between walls with a Navier slip length b = 0.01 m (``boundary.slip_length_m``),
    GIMP at h = 0.02 m: the steady profile is the no-slip parabola lifted by the slip speed.

    The wall law takes du/dn over the first cell, (u_1 - u_w) / h; with the parabola's nodal
    values that gives the steady slip speed c_h = b G (H - h/2) / mu = 0.353 m/s (18 % of u_max),
    the continuous law's c = b G H / mu = 0.392 m/s less its first-order error b G h / (2 mu)
    (2 % of u_max at h = 0.02 m, halving with h).  Asserted: the particles' velocities within
    1.5 % of u_max of the discrete law's profile, and their mean lift over the no-slip parabola
    within 1 % of u_max of c_h (the no-slip GIMP profile is within 0.74 % of u_max at this h;
    measured: 0.97 % and 0.66 %), both far below the 18 % a no-slip wall would leave.  At
    1.5 s the slowest mode, exp(-nu pi^2 t / (4 (H + b)^2)), has decayed to 5e-4 of u_max.
    """
    h, b = 0.02, 0.01
    s, final = _poiseuille(h, "gimp", t_end=1.5, boundary={"slip_length_m": b})
    assert int(final.n_lost) == 0
    c_h = b * RHO * G * (POIS_HALF - h / 2) / POIS_MU
    y = np.asarray(final.x[:, -1])
    u = np.asarray(final.v[:, 0])
    u_noslip = RHO * G * (POIS_HALF**2 - (y - POIS_HALF) ** 2) / (2 * POIS_MU)
    err = float(np.max(np.abs(u - u_noslip - c_h)) / POIS_UMAX)
    lift = float(np.mean(u - u_noslip))
    print(f"Navier-slip Poiseuille: max error vs discrete law {err:.4f} u_max, lift {lift:.4f} m/s (c_h {c_h:.4f})")
    assert err < 0.015, err
    assert abs(lift - c_h) < 0.01 * POIS_UMAX, (lift, c_h)


def test_poiseuille_quadratic_bspline_documented_plateau():
    """Same problem with the default quadratic B-spline at h = 0.01 m.

    Measured max error / u_max: 2.9e-1 (h = 0.04), 2.2e-2 (0.02), 2.4e-2 (0.01),
    2.3e-2 (0.005): it does not reach 1 % and stops converging below h = 0.02.  The error
    is a uniform offset set in the first cell at each wall and depends on dt/h (at
    h = 0.02: -2 %, -9 %, -19 % for cfl 0.4, 0.2, 0.1), i.e. the B-spline support
    reaches the zero-velocity ghost nodes and the transfer removes momentum there every
    step.  Linear hats and GIMP do not show it (see test above).  This test guards the
    measured level (< 3 % of u_max) so that a regression, or a fix, is noticed.
    """
    s, final = _poiseuille(0.01, "quadratic")
    err = _poiseuille_error(final)
    print(f"Poiseuille quadratic h=0.01 error/u_max {err}")
    assert err < 0.03, err


def test_poiseuille_converges_quadratic_bm():
    """The same problem with the boundary-modified quadratic B-spline (``quadratic_bm``,
    mpmjax/_shapes.py): the wall defect of the plain quadratic is gone.

    Measured max error / u_max: 2.24e-1 (h = 0.04), 2.88e-2 (0.02), 2.76e-3 (0.01, H/h = 20
    for the 0.2 m gap); observed orders 2.96, 3.38.  Asserted: finest < 0.5 % (the issue's
    target) and order > 1.8 per halving.  Below h = 0.01 the default Maxwell stress update
    sets a floor: its corotational regularisation thins the shear stress by 1/(1 + (lambda
    gdot)^2), lambda = mu/G = 1.7e-3 s, which speeds the flow up by (lambda gdot_wall)^2 / 2 =
    2.1e-3 of u_max (gdot_wall = 39 1/s) whatever the shape function (h = 0.005: quadratic_bm
    2.2e-3, GIMP 1.6e-3); ``test_poiseuille_quadratic_bm_order_explicit`` removes it.
    """
    errs = []
    for h in (0.04, 0.02, 0.01):
        s, final = _poiseuille(h, "quadratic_bm")
        assert int(final.n_lost) == 0
        errs.append(_poiseuille_error(final))
    orders = [math.log2(a / b) for a, b in itertools.pairwise(errs)]
    print(f"Poiseuille quadratic_bm errors/u_max {errs}, orders {orders}")
    assert errs[-1] < 0.005, errs
    assert all(o > 1.8 for o in orders), (errs, orders)


@pytest.mark.slow
def test_poiseuille_quadratic_bm_order_explicit():
    """Asymptotic order of ``quadratic_bm`` with the explicit viscous update (sigma' = 2 mu d',
    no Maxwell regularisation; dt at the viscous limit): measured 3.25e-3 (h = 0.01) and
    8.15e-4 (h = 0.005), order 1.99 (GIMP: 1.88e-3, 4.73e-4, order 1.99).  About 40 s."""
    errs = []
    for h in (0.01, 0.005):
        s, final = _poiseuille(h, "quadratic_bm", extra={"viscous_update": "explicit"})
        assert int(final.n_lost) == 0
        errs.append(_poiseuille_error(final))
    order = math.log2(errs[0] / errs[1])
    print(f"Poiseuille quadratic_bm explicit errors/u_max {errs}, order {order}")
    assert errs[-1] < 0.002 and order > 1.8, (errs, order)


def test_quadratic_bm_column_between_slip_walls_settles():
    """A 0.1 m x 0.1 m Newtonian column (mu = 300 Pa s, kappa = 15 kPa) filling the width
    between slip walls, on a no-slip base under a slip lid (0.14 m), h = 0.02 m, 100 particles,
    released at rest (J = 1) so that it first compresses and rings, run 2 s.

    With ``quadratic_bm`` the maximum particle speed falls to 3e-11 m/s at 2 s (2.4e-9 at
    1 s), as with GIMP (2.6e-11 m/s); the plain quadratic creeps at 6e-4 m/s there.  Asserted:
    < 1e-6 m/s at 2 s (the issue's target), no lost particle, and the particles still fill
    the width (slip walls hold them without a gap: x within [0, 0.1]).
    """
    cfg = _cfg(
        2,
        [0, 0],
        [0.1, 0.14],
        0.02,
        {"x_lo": "slip", "x_hi": "slip", "y_lo": "noslip", "y_hi": "slip"},
        [{"lo_m": [0.0, 0.0], "hi_m": [0.1, 0.1]}],
        t_end=2.0,
        n_frames=4,
        mu=300.0,
        # the particles' pressure, pinned: the subject is the spline's wall rows under the explicit step (3e-11
        # m/s); the grid pressure's column is tests/test_pressure.py's (6.8e-6 m/s, a looser bound)
        numerics={"shape": "quadratic_bm", "pressure": "explicit"},
    )
    s = m.build(cfg)
    final, frames = m.run(s.scene, s.state, s.params)
    assert int(final.n_lost) == 0
    speed = np.sqrt(np.sum(np.asarray(frames.v) ** 2, axis=-1)).max(axis=-1)
    print(f"quadratic_bm column: max speed per frame {speed}")
    assert speed[-1] < 1e-6, speed
    x = np.asarray(final.x[:, 0])
    assert x.min() >= 0.0 and x.max() <= 0.1


# ======================================================================================
# 2D and 3D agree on an extruded problem
# ======================================================================================


def test_2d_and_3d_extruded_dambreak_agree():
    """The 2D dam break and the same problem extruded 2 cells in 3D between symmetry
    faces give the same runout and the same particle paths.

    With symmetry faces no node carries transverse velocity by symmetry, and because the
    weights are tensor products and the state does not vary along y, every node column
    has the 2D mass, momentum and force times a y-factor that cancels in v = p/m; the
    plane-strain stress (d'_zz included in 2D) equals the 3D stress.  So the runs agree
    to floating-point summation order: tolerance 1e-9 m on positions and runout,
    1e-9 m/s on velocities (about 1e-7 of h and of the 1 m/s front speed); measured
    ~1e-15.  The runout itself must have advanced by several cells.
    """
    s2, f2, fr2 = _dambreak(2)
    s3, f3, fr3 = _dambreak(3, nz=2)
    assert int(f2.n_lost) == 0 and int(f3.n_lost) == 0
    assert s2.scene.dt == s3.scene.dt and s2.scene.n_steps == s3.scene.n_steps
    ro2 = np.asarray(m.runout(fr2.x, fr2.active, 0, 0.0, s2.info["particle_spacing_m"]))
    ro3 = np.asarray(m.runout(fr3.x, fr3.active, 0, 0.0, s3.info["particle_spacing_m"]))
    print(f"2D/3D: runout {ro2[-1]:.4f} m, max |runout diff| {np.max(np.abs(ro3 - ro2)):.1e} m")
    np.testing.assert_allclose(ro3, ro2, rtol=0, atol=1e-9)
    assert ro2[-1] > DB_BLOCK + 5 * DB_H, ro2
    # particle-by-particle: seeding is meshgrid 'ij' over (x, y[, z]) so reshape and compare
    nb = round(DB_BLOCK / (DB_H / 2))  # particles per side (ppc = 2)
    nf = fr2.x.shape[0]
    x2 = np.asarray(fr2.x).reshape(nf, nb, nb, 2)
    v2 = np.asarray(fr2.v).reshape(nf, nb, nb, 2)
    x3 = np.asarray(fr3.x).reshape(nf, nb, 4, nb, 3)
    v3 = np.asarray(fr3.v).reshape(nf, nb, 4, nb, 3)
    np.testing.assert_allclose(x3[..., [0, 2]], np.broadcast_to(x2[:, :, None], x3[..., [0, 2]].shape), atol=1e-9)
    np.testing.assert_allclose(v3[..., [0, 2]], np.broadcast_to(v2[:, :, None], v3[..., [0, 2]].shape), atol=1e-9)
    np.testing.assert_allclose(v3[..., 1], 0.0, atol=1e-9)


# ======================================================================================
# Compilation and vmap
# ======================================================================================


def _small_cfg(mu):
    return _cfg(
        2,
        [0, 0],
        [0.2, 0.1],
        0.02,
        {"x_lo": "slip", "x_hi": "slip", "y_lo": "noslip", "y_hi": "slip"},
        [{"lo_m": [0.0, 0.0], "hi_m": [0.06, 0.06]}],
        t_end=0.05,
        n_frames=2,
        mu=mu,
    )


def test_second_call_does_not_recompile():
    """Changing a traced parameter (viscosity, gravity) must not recompile.

    Counted two ways: the jit cache of a wrapper (one entry after two calls), and the
    backend-compile events reported by jax.monitoring (zero during the second call,
    including through ``mpmjax.run`` with a scene rebuilt from a config that differs
    only in viscosity: the viscosity is not part of the static Scene).
    """
    s = m.build(_small_cfg(1.0))
    f = jax.jit(lambda p: m.simulate(s.scene, s.state, p)[0].x)
    # explicit dtype: jnp.asarray(7.0) would be weakly typed, a different abstract
    # signature from the strongly typed float64 built by make_params (a recompile that
    # is the caller's doing, not the engine's)
    f64 = jnp.float64
    p2 = s.params._replace(
        material=s.params.material._replace(mu=jnp.asarray(7.0, f64)), gravity=jnp.asarray([0.5, -9.0], f64)
    )
    x1 = f(s.params)
    x2 = f(p2)
    assert f._cache_size() == 1
    assert float(jnp.max(jnp.abs(x1 - x2))) > 0  # the parameters really changed the result

    compiles = []

    def listener(event, duration, **kw):
        if event == "/jax/core/compile/backend_compile_duration":
            compiles.append(duration)

    m.run(s.scene, s.state, s.params)  # warm mpmjax.run's cache for this scene
    s_b = m.build(_small_cfg(3.0))
    assert s_b.scene == s.scene and hash(s_b.scene) == hash(s.scene)
    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        f(s_b.params)
        m.run(s_b.scene, s_b.state, s_b.params)
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert compiles == [], f"{len(compiles)} recompilation(s)"


def test_vmap_over_viscosities_equals_separate_runs(allclose):
    """vmap of simulate over 4 viscosities equals 4 separate runs (rtol 1e-10, float64).

    The batched and unbatched programs do the same arithmetic per member; 1e-10 allows
    for a different reduction order in batched kernels (~1e-14 per step over ~50 steps)
    with margin.  The 4 results must differ from each other (the viscosity matters).
    """
    s = m.build(_small_cfg(1.0))
    mus = jnp.asarray([0.5, 2.0, 8.0, 32.0], jnp.float64)
    params_b = jax.tree.map(lambda a: jnp.broadcast_to(a, (4,) + jnp.shape(a)), s.params)
    params_b = params_b._replace(material=params_b.material._replace(mu=mus))
    batched = jax.jit(jax.vmap(lambda p: m.simulate(s.scene, s.state, p)))(params_b)
    runs = []
    for i in range(4):
        p = s.params._replace(material=s.params.material._replace(mu=mus[i]))
        runs.append(m.run(s.scene, s.state, p))
    single = jax.tree.map(lambda *a: jnp.stack(a), *runs)
    assert allclose(batched, single, rtol=1e-10, atol=1e-13)
    xs = np.asarray(batched[0].x)
    assert np.max(np.abs(xs[0] - xs[3])) > 1e-3  # viscosity changes the flow by > 1 mm
