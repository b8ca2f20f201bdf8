"""The depth-averaged formulation (``model.formulation = "depth-averaged"``, ``mpmjax._shallow``,
issue 33) against exact solutions, in float64 on the 1-D plan (domain.dim = 2: a profile along x).

Each test asserts a physical number; the tolerances and why (docs/depth-averaged.md has the
measured figures):

* Ritter dam break (frictionless; H0 = 0.1 m, t = 0.4 s, h = 1 cm, 8 particles per cell): the depth
  at the dam site is the exact 4/9 H0 for all t; the depth profile over the rarefaction has an L1
  error against the exact parabola; the point where the depth falls to H0 / 5 (where particles are
  still at most about a cell apart: a column of volume H0 h / 8 spreads over h at depth H0 / 8) is
  at the exact position.  All within 2 % (of 4/9 H0, of the exact profile's integral, of the front's
  travel 2 c0 t).  The thinner tip is under-resolved by the finite particle volumes (the farthest
  particle lags the exact 2 c0 t front by 13 %: asserted as a bound, documented);
* a Bingham layer on a 10 degree incline: a long uniform layer 3 % under the critical depth
  h_c = tau_y / (rho g sin(theta)) stays at rest (zero velocity in its middle: the capped yield
  friction), one 3 % over it flows; a finite layer released at 2 h_c comes to rest with its
  deepest point within 5 % of h_c (the static profile of a Bingham deposit on an incline never
  exceeds h_c; the remaining excess is the slow final drainage);
* mass: the particles carry their volumes, so the total is conserved exactly (to round-off: 1e-12);
  depths are never negative;
* the gradient of the runout (the volume centroid's advance) with respect to the yield stress,
  by reverse mode through ``lax.scan``, against a central finite difference (float64; 1 %);
* ``vmap`` over yield stresses equals the separate runs (1e-12 relative);
* a viscous gravity current against Huppert's (1982) similarity solution (5 %);
* a twin back-analysis of the yield stress from a dam break's outline (5 %, the issue's target; measured
  -2.6 %: the fit resolution's bias);
* an inertia-free Bingham slump comes to rest at the lubrication static front (5 %; measured -1.5 % with 3 levels of
  column splitting, the default since 2026-12-07; -1.6 % at one level, -0.34 % unsplit).
* a Bingham dam break's front against the full (vertical-section) MPM with the grid pressure (5 % at
  every frame, 3 % at the end; measured 4.75 % and -1.8 % with 3 split levels, the default since 2026-12-07; 3.9 %
  and -0.5 % at one level).
* a fast (inertial) Bingham slump stays at rest after arrest where its tip columns stay within a cell
  of each other (under 1e-6 m/s; measured 3.5e-8 m/s at 4 s), and a strict xfail for the same slump
  with an under-resolved tip, which creeps (docs/depth-averaged.md, "Creep after arrest").
"""

from __future__ import annotations

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mpmjax._build import build, start_warnings
from mpmjax._schema import SceneError, validate
from mpmjax._shallow import plan_depth
from mpmjax._simulate import simulate

G = 9.81


@pytest.fixture(autouse=True, scope="module")
def _x64():
    prev = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", prev)


def _scene(material, body, t_end, h=0.01, ppc=8, length=2.0, slope=0.0, n_frames=4, x_lo="slip"):
    return {
        "model": {"formulation": "depth-averaged"},
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [length, 0.2], "cell_size_m": h},
        "boundary": {"x_lo": x_lo, "x_hi": "open"},
        "numerics": {"shape": "quadratic", "ppc": ppc, "dtype": "float64"},
        "gravity": {"slope_deg": slope},
        "material": dict(material, density_kg_m3=1000.0, bulk_modulus_pa=1e5),
        "time": {"t_end_s": t_end, "n_frames": n_frames},
        "bodies": [{"type": "box", "lo_m": body[0], "hi_m": body[1]}],
    }


_run = jax.jit(simulate, static_argnums=(0, 3))


def _final(raw):
    s = build(validate(raw))
    fin, frames = _run(s.scene, s.state, s.params)
    return s, fin, frames


# ------------------------------------------------------------------------------------------ Ritter

H0, X0, T_R = 0.1, 1.0, 0.4


@pytest.fixture(scope="module")
def ritter():
    inviscid = {"model": "newtonian", "viscosity_pa_s": 1e-12}
    return _final(_scene(inviscid, ([0.0, 0.0], [X0, H0]), T_R))


def test_ritter_dam_break_depth_and_front(ritter):
    s, fin, _ = ritter
    H, xn = plan_depth(s.scene, fin)
    H, xn = np.asarray(H), xn[:, 0]
    c0 = math.sqrt(G * H0)
    xi = (xn - X0) / T_R
    exact = np.clip(np.where(xi < -c0, H0, (2 * c0 - xi) ** 2 / (9 * G)), 0.0, H0)
    exact = np.where(xi > 2 * c0, 0.0, exact)
    # the dam site: 4/9 H0 at all t
    assert np.interp(X0, xn, H) == pytest.approx(4 / 9 * H0, rel=0.02)
    # the rarefaction, L1: where the exact depth is at least H0 / 5 (resolved by the particles) within 2 %;
    # the whole wave, to the exact front, within 3 % (the thin tip's clumped particles: docstring)
    wave = (xi > -c0) & (xi < 2 * c0)
    resolved = wave & (exact >= 0.2 * H0)
    assert np.abs(H - exact)[resolved].sum() / exact[resolved].sum() < 0.02
    assert np.abs(H - exact)[wave].sum() / exact[wave].sum() < 0.03
    # where the depth falls to H0 / 5: x = x0 + c0 t (2 - 3 sqrt(1/5))
    i = np.nonzero(H >= 0.2 * H0)[0][-1]
    x_num = xn[i] + (H[i] - 0.2 * H0) / (H[i] - H[i + 1]) * s.scene.h
    x_ex = X0 + c0 * T_R * (2 - 3 * math.sqrt(0.2))
    assert abs(x_num - x_ex) < 0.02 * 2 * c0 * T_R
    # the farthest particle: near the exact front.  With one level of column splitting (the default until 2026-12-07)
    # it stayed behind it (the under-resolved tip: -6.1 %); with the default 3 levels it runs +1.4 % of the travel
    # ahead (measured 2026-12-07; more levels run it further: docs/depth-averaged.md, "Column splitting").  Bound:
    # within the 2 % of the travel on either side of the front, and not 20 % short
    far = float(np.asarray(fin.x[:, 0]).max()) - X0
    assert 0.8 * 2 * c0 * T_R < far <= 1.02 * 2 * c0 * T_R


def test_the_map_of_a_ritter_dam_break_reads_the_exact_depth(tmp_path):
    """The depth-averaged run's plan-view maps (hazard rasters, deposit thickness, front; ``_hazard.bins``
    with the scene as ``HazardGrid.plan``: the mean of each cell's corner nodes of the step's own depth)
    on the Ritter dam break in the map (domain.dim = 3, 4 cells wide between slip walls, H0 = 0.1 m,
    0.4 s, h = 1 cm, 2 x 2 columns a cell as in the field scenes), against the exact depth at the cell
    centres where it is at least H0 / 5.  Measured: L1 3.4 % (3.3 % at one split level); the rest volumes binned by
    particle position (the maps before 2026-12-06) read 29.6 %, single cells off by up to 136 %, as the columns
    drift in and out of the bins.  Bound 5 % (2 % is the 2D test's at 8 columns a cell); the volume is
    the run's to round-off.  The domain runs to 2.2 m: the fastest tip columns of this inviscid run are 0.16 m past
    the exact front (1.79 m) by 0.4 s with one level of splitting, and about 2.0 m with three (2026-12-07), where
    they left the 2 m domain's cells for its ghost layer and the map's volume read 3e-5 short."""
    from mpmjax._hazard import HazardGrid, bins

    raw = {
        "model": {"formulation": "depth-averaged"},
        "domain": {"dim": 3, "lo_m": [0.0, 0.0, 0.0], "hi_m": [2.2, 0.04, 0.2], "cell_size_m": 0.01},
        "boundary": {"x_lo": "slip", "x_hi": "open", "y_lo": "slip", "y_hi": "slip"},
        "numerics": {"shape": "quadratic", "ppc": 2, "dtype": "float64"},
        "material": {"model": "newtonian", "viscosity_pa_s": 1e-12, "density_kg_m3": 1000.0, "bulk_modulus_pa": 1e5},
        "time": {"t_end_s": T_R, "n_frames": 1},
        "output": {"hazard_maps": True},
        "bodies": [{"type": "box", "lo_m": [0.0, 0.0, 0.0], "hi_m": [X0, 0.04, H0]}],
    }
    cfg = validate(raw)
    s = build(cfg)
    fin, _ = _run(s.scene, s.state, s.params)
    grid = HazardGrid.of(s.scene, cfg)
    assert grid.plan is s.scene
    depth = np.asarray(bins(fin, grid)[0]).reshape(grid.shape)
    c0 = math.sqrt(G * H0)
    xi = (grid.lo[0] + grid.cell * (np.arange(grid.shape[0]) + 0.5) - X0) / T_R
    exact = np.where(xi > 2 * c0, 0.0, np.where(xi < -c0, H0, (2 * c0 - xi) ** 2 / (9 * G)))
    exact = exact[:, None] * np.ones(grid.shape)
    resolved = (xi[:, None] > -c0) & (exact >= 0.2 * H0)
    assert np.abs(depth - exact)[resolved].sum() / exact[resolved].sum() < 0.05
    assert depth.sum() * grid.cell**2 == pytest.approx(float(np.sum(np.asarray(fin.vol0 * fin.active))), rel=1e-12)
    # plan_view.h5 takes the same depth (it binned the columns by position until 2026-12-06)
    from mpmjax._io import _jsonable
    from mpmjax._metrics import plan_view_summary, read_plan_view

    n = int(fin.x.shape[0])
    frames = {"x_m": np.asarray(fin.x)[None], "v_m_s": np.asarray(fin.v)[None], "active": np.asarray(fin.active)[None],
              "mu_pa_s": np.full((1, n), 1e-12), "t_s": np.array([T_R])}
    res = {"attrs": {"scene_config_json": json.dumps(_jsonable(cfg))}, "frames": frames,
           "particles": {"vol0_m3": np.asarray(fin.vol0)}}
    summary = plan_view_summary(res, tmp_path / "plan_view.h5", plan=s.scene)
    pv = read_plan_view(tmp_path / "plan_view.h5")
    np.testing.assert_allclose(pv["thickness_m"][-1], depth, rtol=1e-6, atol=1e-9)  # stored as float32
    assert "depth-averaged step" in pv["attrs"]["thickness"]
    assert summary["plan_view"]["final_max_thickness_m"] == pytest.approx(float(depth.max()), abs=1e-6)  # 6 decimals
    # a saved run's runout series (mpmjax.plotting.runout, rebuilt from the saved scene) is summary.json's: the
    # step's depth, not the columns binned by position (2540.3 against 2538.0 m on field-breach-da before 2026-12-06)
    from mpmjax._metrics import RunoutGauge
    from mpmjax.plotting import runout

    want = RunoutGauge.of(s.scene, s.info).front(fin.x, fin.vol0, fin.active)
    assert runout(res)[1][-1] == pytest.approx(want, abs=1e-9)
    # a file written before a key existed (here the column-splitting keys of 2026-12-06) reads the same
    old = {k: v for k, v in _jsonable(cfg).items() if not k.startswith("numerics.split_")}
    res_old = dict(res, attrs={"scene_config_json": json.dumps(old)})
    assert runout(res_old)[1][-1] == pytest.approx(want, abs=1e-9)


def test_mass_exact_and_depth_never_negative(ritter):
    s, fin, frames = ritter
    v0 = np.asarray(s.state.vol0)
    assert int(fin.n_lost) == 0
    for i in range(frames.x.shape[0]):
        state = fin._replace(x=frames.x[i], active=frames.active[i])
        assert float(np.sum(v0 * np.asarray(state.active))) == pytest.approx(float(v0.sum()), rel=1e-12)
        H, _ = plan_depth(s.scene, state)
        assert float(jnp.min(H)) >= 0.0
        assert bool(jnp.all(jnp.isfinite(frames.x[i])))


# -------------------------------------------------------------------------- viscous gravity current


def test_viscous_gravity_current_follows_the_similarity_solution():
    """Huppert (1982): a fixed area q of viscous fluid spreading from a wall on a horizontal plane
    has its front at x_N = 1.411 (g q^3 t / (3 nu))^(1/5) once inertia is negligible (the constant:
    (10 / (3 I^3))^(1/5), I = int_0^1 (1 - s^2)^(1/3) ds, for the one-sided planar current; the
    closure's 3 mu U / h is the lubrication basal stress, so the depth-averaged equations reduce to
    Huppert's).  q = 0.1 m x 0.1 m, nu = 0.01 m^2/s (Reynolds number ~0.02 at 10 s); the box's
    virtual time origin is 6 ms.  Front: the farthest particle + half a spacing (the similarity
    front is steep, h ~ (x_N - x)^(1/3)).  5 % (the issue's target); measured -2.2 % at 10 s (-2.3 %
    at one split level), -2.9 % at 2 s (approaching)."""
    s, fin, frames = _final(
        _scene({"model": "newtonian", "viscosity_pa_s": 10.0}, ([0.0, 0.0], [0.1, 0.1]), 10.0, length=1.0, n_frames=2)
    )
    q, nu = 0.01, 0.01
    x_n = float(jnp.max(fin.x[:, 0])) + 0.5 * s.scene.h / 8
    assert x_n == pytest.approx(1.411 * (G * q**3 * 10.0 / (3 * nu)) ** 0.2, rel=0.05)


# ------------------------------------------------------------------------------- Bingham on an incline

THETA, TAU_Y, MU_B = 10.0, 50.0, 1.0
H_C = TAU_Y / (1000.0 * G * math.sin(math.radians(THETA)))
BINGHAM = {"model": "bingham", "viscosity_pa_s": MU_B, "yield_stress_pa": TAU_Y}


@pytest.mark.parametrize("factor, moves", [(0.97, False), (1.03, True)])
def test_bingham_uniform_layer_yields_at_the_critical_depth(factor, moves):
    """A layer over the whole 4 m slope (open at its lower end, a slip wall at its upper): its middle
    is uniform, so it flows if and only if rho g sin(theta) h > tau_y."""
    raw = _scene(BINGHAM, ([0.0, 0.0], [4.0, factor * H_C]), 0.2, h=0.02, ppc=4, length=4.0, slope=THETA)
    s, fin, _ = _final(raw)
    x = np.asarray(s.state.x[:, 0])
    mid = (x > 1.5) & (x < 2.5)
    u = np.abs(np.asarray(fin.v[:, 0]))[mid]
    if moves:  # it accelerates: (g sin(theta) - tau_y / (rho h)) t minus the viscous drag, > 1 mm/s at 0.2 s
        assert u.min() > 1e-3
    else:
        assert u.max() == 0.0


def test_bingham_layer_stops_at_the_critical_depth():
    raw = _scene(BINGHAM, ([0.2, 0.0], [0.7, 2 * H_C]), 10.0, h=0.02, ppc=4, length=4.0, slope=THETA, n_frames=10)
    s, fin, frames = _final(raw)
    H, _ = plan_depth(s.scene, fin)
    assert float(H.max()) == pytest.approx(H_C, rel=0.05)
    # draining slowly: the fastest particle below 5 % of the gravity-wave speed sqrt(g h_c) of the critical layer
    assert float(jnp.abs(fin.v).max()) < 0.05 * math.sqrt(G * H_C)


def test_a_scene_with_an_unsupported_option_is_refused():
    raw = _scene(BINGHAM, ([0.2, 0.0], [0.7, 0.05]), 1.0)
    raw["numerics"]["volume_averaging"] = "jbar"
    with pytest.raises(SceneError, match="numerics.volume_averaging = 'jbar'.*depth-averaged.*allowed: 'none'"):
        validate(raw)
    raw = _scene(BINGHAM, ([0.2, 0.0], [0.7, 0.05]), 1.0, x_lo="periodic")
    with pytest.raises(SceneError, match="boundary.x_lo = 'periodic'"):
        validate(raw)


def test_the_thin_body_warning_counts_plan_cells_only():
    """A depth-averaged body's depth is carried by its columns, not resolved by cells, so a 5 cm deep
    block at h = 2 cm (2.5 cells) draws no thickness warning; one 5 cm long in plan (2.5 cells) still
    does, naming the plan axis x (``_build.start_warnings``)."""
    deep = build(validate(_scene(BINGHAM, ([0.0, 0.0], [0.3, 0.05]), 0.1, h=0.02, ppc=4, length=1.0)))
    assert not [w for w in start_warnings(deep) if "thick" in w]
    short = build(validate(_scene(BINGHAM, ([0.0, 0.0], [0.05, 0.1]), 0.1, h=0.02, ppc=4, length=1.0)))
    assert [w for w in start_warnings(short) if "2.5 cells along x" in w]


# ------------------------------------------------------------------------------ gradient and vmap


@pytest.fixture(scope="module")
def slump():
    """A Bingham dam break on the flat (tau_y = 20 Pa, mu = 0.5 Pa s, 0.1 m x 0.3 m), 0.3 s."""
    mat = {"model": "bingham", "viscosity_pa_s": 0.5, "yield_stress_pa": 20.0}
    s = build(validate(_scene(mat, ([0.0, 0.0], [0.3, 0.1]), 0.3, h=0.02, ppc=4, length=1.0, n_frames=2)))
    return s


def _runout(s, tau_y):
    params = s.params._replace(material=s.params.material._replace(tau_y=tau_y))
    fin, _ = simulate(s.scene, s.state, params)
    v = fin.vol0 * fin.active
    return jnp.sum(v * fin.x[:, 0]) / jnp.sum(v)  # the volume centroid [m]


def test_gradient_of_runout_wrt_yield_stress_matches_finite_difference(slump):
    f = jax.jit(lambda t: _runout(slump, t))
    tau = jnp.asarray(20.0)
    g = float(jax.jit(jax.grad(lambda t: _runout(slump, t)))(tau))
    d = 0.5
    fd = (float(f(tau + d)) - float(f(tau - d))) / (2 * d)
    assert g < 0  # a stronger material runs less far
    assert g == pytest.approx(fd, rel=0.01)


def test_vmap_equals_separate_runs(slump):
    taus = jnp.asarray([10.0, 20.0, 40.0])
    batched = jax.jit(jax.vmap(lambda t: _runout(slump, t)))(taus)
    single = jax.jit(lambda t: _runout(slump, t))
    for i, t in enumerate(taus):
        assert float(batched[i]) == pytest.approx(float(single(t)), rel=1e-12)
    assert float(batched[0]) > float(batched[1]) > float(batched[2])


# ------------------------------------------------------------------------ Bingham slump vs lubrication


def test_bingham_slump_follows_the_lubrication_solution_to_its_static_front():
    """Issue 33: the Bingham 1-D dam break against lubrication theory.  The geometry and numbers of
    mpmjax.studies.validate's slump-lubrication-B0.05-a1 case: a block H0 = L = 0.1 m against a wall,
    B = tau_y L / (rho g H0^2) = 0.05 (tau_y = 49.05 Pa), Galileo number rho^2 g H0^3 / mu^2 = 1
    (mu = 99 Pa s: inertia-free).  Its static front x_inf = (9 rho g H0^2 L^2 / (8 tau_y))^(1/3) =
    0.2823 m (B <= 1/3; Balmforth et al. 2006, Matson & Hogg 2007) is the critical profile
    rho g H dH/dx = -tau_y holding the block's area, which is also the depth-averaged model's static
    state.  At a Galileo number of 1 the approach to it is slow: the lubrication solution in time
    (``mpmjax.studies.lubrication``, the same block) is still 3.9 % short of x_inf at 100 s.
    Measured at h = 5 mm, 4 columns a cell, with one level of column splitting (the default until 2026-12-07): the
    headline front (free_surface_front, 10 % of the deepest) at 100 s -1.60 % of x_inf, ahead of the
    lubrication solution by 2.3 % of x_inf, its fastest column at 5.1e-5 m/s (the lubrication front's
    mean speed over 90-100 s: 9.1e-5 m/s); at 20 / 40 / 60 / 80 s -9.5 / -4.7 / -3.0 / -1.9 % against the lubrication
    solution's -11.2 / -7.2 / -5.5 / -4.5 % (docs/depth-averaged.md, "Column splitting").  Without
    splitting the same run reached x_inf by 75 s in bursts of its sparse tip and was at rest at 100 s.
    Bounds: 5 % of x_inf against each reference (the issue's target for the other benchmarks, and the
    3D model's figure for this case), and the run not behind the lubrication solution by more than
    a cell (its inertia-free limit cannot be outrun by much, but a run that lags it is too stiff)."""
    from mpmjax._observables import free_surface_front
    from mpmjax.studies import lubrication

    rho, h0, length, bingham, t_end = 1000.0, 0.1, 0.1, 0.05, 100.0
    tau = bingham * rho * G * h0**2 / length
    mu = math.sqrt(rho**2 * G * h0**3)
    mat = {"model": "bingham", "viscosity_pa_s": mu, "yield_stress_pa": tau}
    xinf = (9 * rho * G * h0**2 * length**2 / (8 * tau)) ** (1 / 3)
    raw = _scene(mat, ([0.0, 0.0], [length, h0]), t_end, h=0.005, ppc=4, length=0.4, n_frames=2)
    raw["boundary"]["x_hi"] = "slip"
    s, fin, frames = _final(raw)
    assert s.scene.split_levels == 3  # the default
    front = float(free_surface_front(fin.x, fin.vol0, fin.active, bandwidth=0.005, x_lo=0.0, x_hi=0.4))
    x, hs, _ = lubrication.slump_profiles(length, h0, tau, mu, [t_end - 10.0, t_end], density_kg_m3=rho, g_m_s2=G)
    lub_before, lub = (lubrication.headline_front(x, h) for h in hs)
    assert front == pytest.approx(xinf, rel=0.05)
    assert abs(front - lub) < 0.05 * xinf
    assert front > lub - s.scene.h
    # nearer rest than the lubrication solution: no column faster than its front's mean speed over the last 10 s
    assert float(jnp.abs(fin.v).max()) < (lub - lub_before) / 10.0


# ------------------------------------------------------------------------------ twin back-analysis


def test_twin_back_analysis_recovers_the_yield_stress():
    """Issue 33: a twin back-analysis recovers tau_y within 5 % from a runout outline.

    Truth: the Bingham dam break of ``slump`` (tau_y = 20 Pa, mu = 0.5 Pa s, 0.3 m x 0.1 m against
    a slip wall) run to t = 1 s at h = 5 mm; its outline at 1 s (the kernel height profile at
    2 cm stations where it is over 2 mm, bandwidth 2 cm, sigma 2 mm) and its headline runout
    (``free_surface_front``).  Fit: the same scene at h = 10 mm (not the truth's discretisation:
    no inverse crime), Levenberg-Marquardt through ``calibration.fit`` (forward-mode Jacobian through
    ``simulate``), from tau_y = 40 Pa (a factor 2 off).  Measured: 19.48 Pa (-2.6 %), the same to
    1e-5 from 10 Pa, so the error is the coarser model's resolution bias, not the optimiser.
    5 % is the issue's target.  At 1 s the front is slowing (0.85 m; it arrests at about 0.94 m
    near 1.5 s, then creeps): the forward sensitivities through the arrest are not usable yet (at
    2 s the Jacobian of the outline is at cosine 0.24 to a finite difference; at 1 s, 0.994),
    so the fit is to the outline before arrest (docs/depth-averaged.md)."""
    from calibration.data import Profile
    from calibration.experiments import ProfileExperiment
    from calibration.fit import fit
    from calibration.params import ParameterSet
    from mpmjax._observables import free_surface_front, height_profile

    mat = {"model": "bingham", "viscosity_pa_s": 0.5, "yield_stress_pa": 20.0}

    def setup(h):
        return build(validate(_scene(mat, ([0.0, 0.0], [0.3, 0.1]), 1.0, h=h, ppc=4, length=1.2, n_frames=1)))

    truth = setup(0.005)
    fin, _ = _run(truth.scene, truth.state, truth.params)
    xs = np.arange(0.01, 1.2, 0.02)
    hp = np.asarray(height_profile(fin.x, fin.vol0, fin.active, jnp.asarray(xs), bandwidth=0.02))
    on = hp > 0.002
    runout = float(free_surface_front(fin.x, fin.vol0, fin.active, bandwidth=0.01, x_lo=0.0, x_hi=1.2))
    assert 0.8 < runout < 0.9  # 0.85 m: the outline is of a flow that has spread, not of the initial block

    coarse = setup(0.01)
    exp = ProfileExperiment(coarse, [Profile(x_m=xs[on], h_m=hp[on])], bandwidth_m=0.02, sigma_m=0.002, runout_m=runout)
    ps = ParameterSet.from_names(["tau_y"], coarse.params.material, init={"tau_y": 40.0})
    r = fit([exp], ps, method="lm", max_iter=10, progress=False)
    assert r.params["tau_y"] == pytest.approx(20.0, rel=0.05), r.params
    assert r.loss_final < 1e-3 * r.loss_initial


# ------------------------------------------------------------------ cross-check against the full MPM


def test_bingham_dam_break_front_agrees_with_the_full_mpm():
    """Issue 33's cross-check on a lab case both models resolve: a Bingham block (H0 = 0.1 m,
    L = 0.3 m, tau_y = 20 Pa, mu = 0.5 Pa s, rho = 1000) against a wall on a no-slip bed, 2 s,
    h = 6.25 mm (16 cells over H0) in both; the full model is the vertical section (plane strain)
    with the grid pressure (``numerics.pressure = "incompressible"``), the reference here.  Measured
    (benchmarks/accuracy/da_vs_full.py, docs/depth-averaged.md): the depth-averaged front is within
    3.9 % of the full one at every 0.2 s frame (largest at 0.4 s, while the block still collapses and
    the hydrostatic assumption is worst) and -0.5 % at 2 s at one split level; 4.75 % and -1.8 % with
    the 3 levels that are the default since 2026-12-07 (this test's run, not in da_vs_full.py's raw
    lines).  With h halved the full front moves +1.3 %, the depth-averaged one +0.0 %: the converged
    models differ by about 2 %.  Asserted: 5 % at every
    frame, 3 % at the end (that 2 % and the full model's remaining resolution error)."""
    from mpmjax._observables import free_surface_front

    h, box = 0.00625, 1.2
    fronts = {}
    for formulation in ("full", "depth-averaged"):
        raw = {
            "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [box, 0.15], "cell_size_m": h},
            "time": {"t_end_s": 2.0, "n_frames": 10},
            "bodies": [{"lo_m": [0.0, 0.0], "hi_m": [0.3, 0.1]}],
            "material": {"model": "bingham", "density_kg_m3": 1000.0, "bulk_modulus_pa": 5e4,
                         "viscosity_pa_s": 0.5, "yield_stress_pa": 20.0},
            "numerics": {"dtype": "float32"},
        }  # fmt: skip
        if formulation == "full":
            raw["material"]["papanastasiou_m_s"] = 1e4
            raw["boundary"] = {"x_lo": "symmetry", "x_hi": "slip", "y_lo": "noslip", "y_hi": "slip"}
            raw["numerics"]["pressure"] = "incompressible"
        else:
            raw["model"] = {"formulation": "depth-averaged"}
            raw["boundary"] = {"x_lo": "slip", "x_hi": "slip"}
            raw["numerics"].update(shape="quadratic", ppc=4)
        s, fin, frames = _final(raw)
        fronts[formulation] = np.array(
            [float(free_surface_front(x, fin.vol0, a, bandwidth=h, x_lo=0.0, x_hi=box))
             for x, a in zip(frames.x, frames.active)]  # fmt: skip
        )
    rel = fronts["depth-averaged"] / fronts["full"] - 1.0
    assert fronts["full"][-1] > 0.9  # the block ran three times its length
    assert np.all(np.abs(rel) < 0.05), rel
    assert abs(rel[-1]) < 0.03, rel


# ------------------------------------------------------------------ a fast Bingham slump after arrest


def _fast_slump(tau_y, ppc, split_levels):
    """The twin's dam break (0.3 m x 0.1 m against a slip wall, mu = 0.5 Pa s: inertial, arrests
    within about 2 s) at h = 5 mm, frames at 1, 2, 3, 4 s."""
    from mpmjax._observables import free_surface_front

    mat = {"model": "bingham", "viscosity_pa_s": 0.5, "yield_stress_pa": tau_y}
    raw = _scene(mat, ([0.0, 0.0], [0.3, 0.1]), 4.0, h=0.005, ppc=ppc, length=1.2, n_frames=4)
    raw["numerics"]["split_levels"] = split_levels
    s, fin, frames = _final(raw)
    fronts = [
        float(free_surface_front(frames.x[i], frames.vol0[i] if frames.vol0 is not None else fin.vol0,
                                 frames.active[i], bandwidth=0.01, x_lo=0.0, x_hi=1.2))
        for i in range(4)
    ]  # fmt: skip
    xs = np.sort(np.asarray(fin.x[fin.active, 0]))
    tip_spacing = float(np.diff(xs[-10:]).mean()) / s.scene.h  # the last ten columns' spacing [cells]
    return fin, fronts, tip_spacing


def test_fast_bingham_slump_stays_at_rest_after_arrest_where_its_tip_is_resolved():
    """After arrest the capped yield friction holds the deposit exactly (docs/depth-averaged.md,
    "Creep after arrest").  tau_y = 40 Pa at 8 columns a cell without column splitting (the subject is
    the cap, not the split): the front stops at 0.744 m by 3 s with the last columns 0.95 cells apart
    (depth >= V_p / h everywhere: the grid's depth of the tip is smooth), and the largest speed then
    decays geometrically (6e-6 m/s at 3 s, 4e-8 at 4 s).  Bounds: 1e-6 m/s at 4 s (the creep this
    guards against runs at 5e-2 m/s, and the yield cap removes dt tau_y / (rho H) ~ 1e-3 m/s of speed a
    step, so a node still above 1e-6 m/s is driven past yield), and the headline front moving less than
    0.1 mm between 3 s and 4 s (the creep moved it 5 mm)."""
    fin, fronts, tip = _fast_slump(40.0, 8, 0)
    assert tip < 1.0
    assert float(jnp.abs(fin.v).max()) < 1e-6
    assert abs(fronts[3] - fronts[2]) < 1e-4
    assert 0.7 < fronts[3] < 0.8


@pytest.mark.xfail(
    strict=True,
    reason="an under-resolved tip creeps after arrest without column splitting (docs/depth-averaged.md, 'Creep after arrest')",
)
def test_fast_bingham_slump_with_an_under_resolved_tip_stays_at_rest_without_splitting():
    """The same slump at 4 columns a cell with ``numerics.split_levels = 0`` (the default before
    2026-12-06): its tip columns spread to 1.9-2 cells apart (thinner than V_p / h = 25 mm), the grid's
    depth there alternates from node to node, and the pressure of those bumps (on the 20 Pa twin slump:
    20-30 % depth jumps, 9-15 times the yield friction a node can hold, sign alternating) keeps the tip
    creeping at 5-9 cm/s: front 0.774 m at 3 s, 0.780 m at 4 s.  With the default one level the same
    slump is at rest: tests/test_column_splitting.py."""
    fin, fronts, tip = _fast_slump(40.0, 4, 0)
    assert float(jnp.abs(fin.v).max()) < 1e-6
    assert abs(fronts[3] - fronts[2]) < 1e-4


# ----------------------------------------------------------------------------------- memory estimate


def test_the_memory_estimate_counts_columns_and_the_plan_grid():
    """``memory_estimate`` (the run's refusal check, before anything is built) counts the depth-averaged
    formulation's particles as columns and its grid as the plan's: for field-breach-da exactly the
    14 384 columns it seeds with as many spare slots for column splitting (since stop 58), and 567 x 107 plan nodes (before 2026-12-05: 36 125 particles, the pond's
    volume over dx^3, and 1.5 M nodes with the vertical: 354 MB instead of 45 MB of device memory)."""
    import mpmjax as m
    from mpmjax._build import memory_estimate

    cfg = m.load_scene("field-breach-da", [])
    est = memory_estimate(cfg)
    s = build(cfg)
    assert est["particles"] == s.scene.n_particles
    assert est["grid_nodes"] == float(np.prod(s.scene.grid_shape[:-1]))
