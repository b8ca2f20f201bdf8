"""Warnings at run start (issue 17 item 5): ``mpmjax._build.start_warnings`` on constructed
scenes (built, not run), and one short run that prints them and keeps them, with the final
deposit's resolution warning, in summary.json's ``warnings``."""

import json

import pytest

import mpmjax as m
from mpmjax import run_scene
from mpmjax._build import STEPS_WARN, estimate_run_time_s, start_warnings


def _warnings(*overrides):
    setup = m.build(m.load_scene("dambreak-lab", list(overrides)))
    return setup, start_warnings(setup)


def test_default_scene_has_no_start_warning():
    # the 0.2 m block at 2 cm cells: 10 cells across, dt at the stable limit, 11 880 steps
    assert _warnings("domain.cell_size_m=0.02")[1] == []


def test_thin_body_names_the_body_the_axis_and_the_cell_size():
    # 0.2 m block at 8 cm cells: 2.5 cells along x and y
    _, w = _warnings("domain.cell_size_m=0.08", "time.t_end_s=0.1")
    (msg,) = w
    assert msg.startswith("bodies[0] is fewer than 4 cells of domain.cell_size_m = 0.08 m thick")
    assert "2.5 cells along x (bodies[0].lo_m[0] = 0, hi_m[0] = 0.2)" in msg
    assert "2.5 cells along y" in msg and "set domain.cell_size_m <= 0.05 m" in msg
    # a thin layer (0.06 m = 3 cells of 2 cm) only along its thin axis
    layer = "bodies=[{type='box', lo_m=[0, 0], hi_m=[1.0, 0.06]}]"
    _, w = _warnings("domain.cell_size_m=0.02", "time.t_end_s=0.1", layer)
    (msg,) = w
    assert "3 cells along y" in msg and "along x" not in msg and "domain.cell_size_m <= 0.015 m" in msg


def test_n_frames_forcing_a_small_step_says_so_with_the_run_time():
    # a frame every 0.1 ms against a stable step of 1.26 ms: each frame one step of 0.1 ms
    # the particles' pressure: its sound speed sets the stable step
    explicit = "numerics.pressure=explicit"
    setup, w = _warnings("domain.cell_size_m=0.02", "time.t_end_s=0.5", "time.n_frames=5000", explicit)
    (msg,) = w
    assert setup.scene.dt == pytest.approx(1e-4) and setup.scene.steps_per_frame == 1
    assert msg.startswith("time.n_frames = 5000 forces dt = 0.0001 s, 12.6x below the stable time step")
    assert "time.t_end_s = 0.5 s" in msg and "estimated run time" in msg
    # the fix it names brings the step back within 2x of the limit: t_end / n_frames >= dt
    assert "set time.n_frames <= 395" in msg
    ok = m.build(m.load_scene("dambreak-lab", ["domain.cell_size_m=0.02", "time.t_end_s=0.5", "time.n_frames=395", explicit]))
    assert start_warnings(ok) == [] and ok.scene.dt >= 0.5 * ok.info["dt_limit_s"]
    # 10x is the line: a frame every 0.2 ms (6.3x) is not warned about
    assert _warnings("domain.cell_size_m=0.02", "time.t_end_s=0.5", "time.n_frames=2500", explicit)[1] == []


def test_stiff_bulk_modulus_needing_over_a_million_steps():
    setup, w = _warnings("domain.cell_size_m=0.02", "material.bulk_modulus_pa=1e12", "numerics.pressure=explicit")
    locking, msg = w  # the hydrostatic strain's warning comes first (test below)
    assert locking.startswith("material.bulk_modulus_pa = 1e+12 Pa with numerics.pressure")
    assert 'set numerics.pressure = "incompressible"' in msg
    assert setup.scene.n_steps > STEPS_WARN
    assert msg.startswith(f"the run needs {setup.scene.n_steps} steps")
    assert "material.bulk_modulus_pa = 1e+12 Pa sets the step" in msg
    # the softer modulus it proposes: Mach 0.1 at the velocity scale, rho (10 v)^2
    v = setup.info["velocity_scale_m_s"]
    assert f"{1850 * (10 * v) ** 2:.3g} Pa" in msg
    est = estimate_run_time_s(setup.scene.n_particles, setup.scene.n_steps, 2)
    assert est > 3600 and f"{est / 3600:.1f} h" in msg


def test_run_prints_and_records_the_warnings(tmp_path, capsys):
    out = tmp_path / "thin"
    s = run_scene("dambreak-lab", out, ["domain.cell_size_m=0.08", "time.t_end_s=0.05", "time.n_frames=2"])
    err = capsys.readouterr().err
    doc = json.loads((out / "summary.json").read_text())
    assert doc["warnings"] == s["warnings"]
    assert doc["warnings"][0].startswith("bodies[0] is fewer than 4 cells")
    # printed before the time loop (before "compiled in"), each as "warning: ..."
    assert err.index("warning: bodies[0]") < err.index("compiled in")
    # the final deposit (0.2 m at 8 cm: 2.5 cells) joins the list, as printed at the end
    assert doc["deposit_cells_across"] < 4
    assert doc["warnings"][-1].startswith("the final deposit is") and "deposit_cells_across" in doc["warnings"][-1]
    # it names the cheapest measured remedy, uniform refinement (docs/validation.md "Depth resolution")
    assert "set domain.cell_size_m <=" in doc["warnings"][-1] and "Depth resolution" in doc["warnings"][-1]
    assert f"warning: {doc['warnings'][-1]}" in err


def test_a_yield_stress_material_under_the_particles_pressure_is_warned_where_it_locks():
    """The default scene's runout is 1.282 m at kappa = 15 kPa (rho g H / kappa = 24 %) and 0.647 m at 1.5 MPa
    (0.24 %): below ``LOCKING_STRAIN`` (5 %) the warning names the key, the strain, the depth it used and both
    remedies, with the modulus that reaches 5 %.  The grid pressure, a Newtonian material (the Cruchaga columns
    move by at most 0.9 % over kappa / 10 to kappa x 10) and the default scene are not warned about."""
    explicit = "numerics.pressure=explicit"
    _, w = _warnings("domain.cell_size_m=0.02", "material.bulk_modulus_pa=1.5e6", explicit)
    (msg,) = w
    strain = 1850 * 9.81 * 0.2 / 1.5e6
    assert msg.startswith("material.bulk_modulus_pa = 1.5e+06 Pa with numerics.pressure = \"explicit\"")
    assert f"rho g H / kappa is {100 * strain:.2g} % (H = 0.2 m" in msg and "below 5 %" in msg
    assert 'set numerics.pressure = "incompressible"' in msg
    assert f"lower material.bulk_modulus_pa to {1850 * 9.81 * 0.2 / 0.05:.3g} Pa or less" in msg
    # at that modulus the warning stops (5 % is the line); the grid pressure never gets it
    assert _warnings("domain.cell_size_m=0.02", f"material.bulk_modulus_pa={1850 * 9.81 * 0.2 / 0.051}", explicit)[1] == []
    assert _warnings("domain.cell_size_m=0.02", "material.bulk_modulus_pa=1.5e6", "numerics.pressure=incompressible")[1] == []
    water = m.build(m.load_scene("dambreak-water", ["domain.cell_size_m=0.02", "time.t_end_s=0.1"]))
    assert 1000 * 9.81 * 0.114 / 225e3 < 0.05 and start_warnings(water) == []
