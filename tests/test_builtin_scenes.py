"""Every built-in scene runs, coarsely and briefly, within physics-derived bounds.

Each scene of ``mpmjax.builtin_scenes()`` is run through ``mpmjax.run_scene`` at a coarse
cell size and a short end time (overrides below; each well under 20 s on 2 CPU cores) and
its summary is checked against bounds that need no reference run:

* mass: particles carry fixed masses, so the active mass at the end equals the mass at
  the start, no particle is lost, and the start mass is rho x (sum of body areas/volumes);
* runout never recedes by more than half a particle spacing (the front is the furthest
  particle plus half a spacing, so a particle settling or a wall splash can move it back
  by at most that much without the front itself retreating);
* the front is no faster than the inviscid dry-bed (Ritter) front: a shallow-water front
  moves at 2 sqrt(g' h0) (g' = g cos(slope), h0 the initial column height), which is larger
  than the free-fall speed sqrt(2 g h0) of any particle of the column; on a slope the
  along-slope gravity g sin(slope) can add at most g sin(slope) t to the speed. So
  ``r(t) <= r(0) + 2 t sqrt(g' h0) + g sin(slope) t^2 / 2 + h`` and the same bound on the
  advance between frames. Tolerance h (one cell): the front is the position of a discrete
  particle, whose GIMP domain spans a cell and whose position jitters by O(h) in the first
  steps while the pressure of the released column is set up; viscosity, yield stress, the
  no-slip base and the numerical dissipation only slow the front further;
* for water (the only near-inviscid scene) the Ritter front ``x0 + 2 t sqrt(g h0)`` is
  checked on its own, with the end time chosen so the front has not reached the far wall;
* the column does collapse: the final front is at least one cell beyond the initial one
  (every scene's driving stress rho g h0 is far above its yield or structure stress).

Full-resolution runs are not part of the suite; their measured runouts and wall times are
recorded in docs/scenarios.md.
"""

import math

import numpy as np
import pytest

import mpmjax
from mpmjax import _bodies

# Coarse, short CI runs. The cell size must divide the domain on every axis.
CI_OVERRIDES = {
    # 2 m x 0.24 m; 0.2 m block, BASE Coussot; 1 s of the 15 s collapse
    "dambreak-lab": ["domain.cell_size_m=0.02", "time.t_end_s=1.0", "time.n_frames=10"],
    # 0.42 m x 0.44 m; Ritter front at 0.12 s: 0.114 + 0.254 = 0.368 m < 0.42 m (no wall impact)
    "dambreak-water": ["domain.cell_size_m=0.01", "time.t_end_s=0.12", "time.n_frames=6"],
    "dambreak-shampoo": ["domain.cell_size_m=0.01", "time.t_end_s=0.2", "time.n_frames=5"],
    # 2 m x 0.24 m flume
    "bingham-dambreak": ["domain.cell_size_m=0.02", "time.t_end_s=1.0", "time.n_frames=10"],
    # 3000 m x 24 m; 6 m cells -> 500 x 4 cells, 100 x 6 particles; first 60 s of ~330 s
    "field-dambreak-2d": ["domain.cell_size_m=6.0", "time.t_end_s=60.0", "time.n_frames=6"],
    # 3000 m x 300 m x 24 m half valley; 12 m cells -> 250 x 25 x 2 cells, 50 x 8 x 3 particles; first 30 s
    "field-dambreak-3d": ["domain.cell_size_m=12.0", "time.t_end_s=30.0", "time.n_frames=3"],
    # depth-averaged Wanji: 8000 m x 300 m plan; 10 m cells -> 800 x 30 cells, the block 120 x 20 columns; first 40 s
    "field-dambreak-da": ["domain.cell_size_m=10.0", "time.t_end_s=40.0", "time.n_frames=4"],
    # quarter cylinder of 100 mm x 100 mm; 12.5 mm cells -> 4 cells across the radius, 8 up; the first 0.2 s
    "slump-test": ["domain.cell_size_m=0.0125", "time.t_end_s=0.2", "time.n_frames=4"],
}

SCENES = sorted(mpmjax.builtin_scenes())
# Dam breaks: the Ritter bound and body-mass checks below apply to them.  Pipe-inflow scenes
# (no initial body; material enters by a schedule) are run coarse in tests/test_boundary_inflow.py, breach
# releases on a DEM (no body box; a pond filled to the terrain) in tests/test_boundary_terrain_dem.py.
DAMBREAKS = [
    n for n, cfg in ((n, mpmjax.load_scene(n)) for n in SCENES)
    if cfg["inflow.point_m"] is None and cfg["release.region_map_m"] is None
]


def _fallback_overrides(name: str) -> list[str]:
    """A scene added without a CI entry: double the cell size where that still divides the
    domain, and run a tenth of its time in 5 frames."""
    cfg = mpmjax.load_scene(name)
    h = cfg["domain.cell_size_m"]
    size = np.asarray(cfg["domain.hi_m"]) - np.asarray(cfg["domain.lo_m"])
    n = size / (2 * h)
    if np.all(np.abs(n - np.round(n)) < 1e-6 * np.maximum(n, 1)) and np.all(np.round(n) >= 2):
        h *= 2
    return [f"domain.cell_size_m={h!r}", f"time.t_end_s={cfg['time.t_end_s'] / 10!r}", "time.n_frames=5"]


def _overrides(name):
    return CI_OVERRIDES.get(name) or _fallback_overrides(name)


def test_every_builtin_scene_is_valid_and_described():
    assert {"dambreak-lab", "dambreak-water", "dambreak-shampoo", "bingham-dambreak", "field-dambreak-2d"} <= set(
        SCENES
    )
    for name in SCENES:
        cfg = mpmjax.load_scene(name)  # validates, including cell size dividing the domain
        assert cfg["name"] == name
        assert len(cfg["description"]) > 80 and "thesis" in cfg["description"].lower()
        setup = mpmjax.build(cfg)  # default resolution builds (time step, particle count)
        assert setup.scene.n_particles > 0 and setup.scene.dt > 0


def test_thesis_parameters():
    w = mpmjax.load_scene("dambreak-water")
    assert (w["material.viscosity_pa_s"], w["material.density_kg_m3"], w["time.t_end_s"]) == (0.001, 1000.0, 1.2)
    assert w["domain.hi_m"] == [0.42, 0.44] and w["bodies"][0]["hi_m"] == [0.114, 0.114]
    # weakly compressible: c = sqrt(kappa/rho) about 10x the free-fall speed sqrt(2 g H)
    ratio = math.sqrt(w["material.bulk_modulus_pa"] / 1000.0) / math.sqrt(2 * 9.81 * 0.114)
    assert 9.5 < ratio < 11
    s = mpmjax.load_scene("dambreak-shampoo")
    assert (s["material.viscosity_pa_s"], s["material.density_kg_m3"], s["time.t_end_s"]) == (8.0, 1042.0, 1.0)
    assert s["bodies"][0]["hi_m"] == [0.114, 0.228] and s["boundary.y_lo"] == "slip"
    b = mpmjax.load_scene("bingham-dambreak")
    assert (b["material.model"], b["material.yield_stress_pa"], b["material.viscosity_pa_s"]) == ("bingham", 36.0, 0.65)
    assert b["bodies"][0]["hi_m"] == [0.2, 0.2]
    f = mpmjax.load_scene("field-dambreak-2d")
    assert (
        f["material.mu0_pa_s"],
        f["material.alpha"],
        f["material.T_s"],
        f["material.n"],
        f["material.mu_max_pa_s"],
        f["material.bulk_modulus_pa"],
    ) == (50.0, 0.36, 1.0, 1.25, 25000.0, 50000.0)
    assert f["bodies"][0]["hi_m"] == [600.0, 16.67]
    assert math.tan(math.radians(f["gravity.slope_deg"])) == pytest.approx(0.026, rel=1e-9)
    assert f["domain.hi_m"][0] >= 1750.0 + 250.0  # room for the thesis's 2D runout


@pytest.mark.parametrize("name", DAMBREAKS)
def test_builtin_scene_coarse_run_is_physical(name, tmp_path):
    over = _overrides(name)
    cfg = mpmjax.load_scene(name, over)
    s = mpmjax.run_scene(name, tmp_path, over, quiet=True)
    assert s["complete"]

    # mass: fixed particle masses, none lost; start mass = rho x body volume (per metre in 2D); a shaped
    # body's volume is that of its lattice points (mpmjax._bodies; against the exact volume: test_bodies.py)
    vol = sum(
        float(np.prod(np.subtract(b["hi_m"], b["lo_m"])))
        if _bodies.kind(b) == "box"
        else len(_bodies.lattice(cfg, b)) * (cfg["domain.cell_size_m"] / cfg["numerics.ppc"]) ** cfg["domain.dim"]
        for b in cfg["bodies"]
    )
    assert s["n_lost"] == 0
    assert s["mass_final_kg"] == s["mass_initial_kg"]
    assert s["mass_initial_kg"] == pytest.approx(cfg["material.density_kg_m3"] * vol, rel=1e-5)

    t = np.asarray(s["times_s"])
    r = np.asarray(s["runout_m"])
    assert np.all(np.isfinite(r))
    h = cfg["domain.cell_size_m"]
    spacing = h / cfg["numerics.ppc"]

    # runout monotonic non-decreasing within half a particle spacing
    assert np.all(np.diff(r) >= -0.5 * spacing - 1e-9), r

    # front speed bounded by the Ritter front (plus along-slope acceleration), tolerance one cell
    g, th = cfg["gravity.g_m_s2"], math.radians(cfg["gravity.slope_deg"])
    h0 = max(np.subtract(*_bodies.bounds(b, cfg["domain.dim"])[::-1])[-1] for b in cfg["bodies"])
    c_ritter = 2.0 * math.sqrt(g * math.cos(th) * h0)
    a_slope = max(g * math.sin(th), 0.0)
    bound = r[0] + c_ritter * t + 0.5 * a_slope * t**2 + h
    assert np.all(r <= bound), (r, bound)
    step_bound = (c_ritter + a_slope * t[1:]) * np.diff(t) + h
    assert np.all(np.diff(r) <= step_bound), (np.diff(r), step_bound)

    # the column collapses
    assert r[-1] > r[0] + h, r

    if name == "dambreak-water":
        # Ritter dry-bed front x0 + 2 t sqrt(g h0) as an upper bound; the run ends before it
        # reaches the far wall, so the wall cannot hold the front back artificially
        x0 = cfg["bodies"][0]["hi_m"][0]
        ritter = x0 + 2.0 * t * math.sqrt(g * h0)
        assert ritter[-1] < cfg["domain.hi_m"][0]
        # Ritter bounds the tip: the farthest particle; the headline front (thickness >= 10 % of
        # the thickest point) lies behind the tip, but reads a vertical edge 1.28 h beyond it
        # (docs/output.md "Runout"), so at t = 0 it may sit up to 1.28 h past x0
        tip = np.asarray(s["runout_farthest_particle_m"])
        assert np.all(tip <= ritter + h), (tip, ritter)
        assert np.all(r <= ritter + 1.3 * h), (r, ritter)
        # and it is a fast, inertial flow: measured 0.46 of the Ritter advance at 0.12 s (h = 0.01 m;
        # a real front lags Ritter's, which is hydrostatic from t = 0); the viscous and yield-stress
        # scenes reach 0.1-0.4 of theirs. Require 0.3: a collapse slowed by spurious friction fails.
        assert r[-1] - x0 > 0.3 * (ritter[-1] - x0), (r, ritter)
