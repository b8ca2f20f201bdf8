"""Scene files, validation, the command line and the output files."""

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

import mpmjax as m
from mpmjax import cli
from mpmjax._schema import schema_markdown

ROOT = Path(__file__).resolve().parents[1]


def test_public_names():
    for name in m.__all__:
        assert hasattr(m, name), name


def test_builtin_default_scene_is_thesis_base():
    cfg = m.load_scene("dambreak-lab")
    # thesis Table 8 BASE and Annex 2 (mu_max 5000), block 0.2 x 0.2 m in a 2 m enclosure
    assert cfg["material.model"] == "coussot"
    assert (
        cfg["material.mu0_pa_s"],
        cfg["material.n"],
        cfg["material.alpha"],
        cfg["material.T_s"],
        cfg["material.lambda0"],
    ) == (4.0, 2.5, 1.0, 0.5, 1.5)
    assert (cfg["material.bulk_modulus_pa"], cfg["material.density_kg_m3"], cfg["material.mu_max_pa_s"]) == (
        15000.0,
        1850.0,
        5000.0,
    )
    assert cfg["domain.hi_m"][0] - cfg["domain.lo_m"][0] == 2.0
    assert cfg["bodies"][0]["hi_m"] == [0.2, 0.2] and cfg["time.t_end_s"] == 15.0


def test_time_step_respects_both_limits():
    # the particles' pressure: kappa's sound speed in the wave limit (the grid pressure's: tests/test_pressure.py)
    s = m.build(m.load_scene("dambreak-lab", ["numerics.pressure=explicit"]))
    info = s.info
    rho, kappa, G, h = 1850.0, 15000.0, info["maxwell_G_pa"], 0.01
    c = np.sqrt((kappa + 4 * G / 3) / rho)
    v = np.sqrt(2 * 9.81 * (0.2))  # free-fall bound from the block height (+ half a spacing)
    assert info["dt_wave_s"] == pytest.approx(0.4 * h / (c + info["velocity_scale_m_s"]), rel=1e-12)
    assert info["velocity_scale_m_s"] == pytest.approx(v, rel=0.02)
    assert info["dt_viscous_s"] == pytest.approx(0.5 * rho * h * h / (2 * 2 * 5000.0), rel=1e-12)
    assert s.scene.dt <= info["dt_wave_s"]
    # explicit viscous update must honour the viscous limit too
    se = m.build(m.load_scene("dambreak-lab", ["numerics.viscous_update=explicit", "time.t_end_s=0.01", "numerics.pressure=explicit"]))
    assert se.scene.dt <= se.info["dt_viscous_s"] * (1 + 1e-12)
    # the grid pressure: the sound speed leaves the limit (only the Maxwell shear waves, G >= rho v^2), so
    # kappa does not set the step
    dts = []
    for kappa in (15e3, 1.5e6):
        gi = m.build(m.load_scene("dambreak-lab", ["numerics.pressure=incompressible", f"material.bulk_modulus_pa={kappa}"]))
        vi, Gi = gi.info["velocity_scale_m_s"], gi.info["maxwell_G_pa"]
        assert Gi >= rho * vi**2 * (1 - 1e-12)
        assert gi.info["dt_wave_s"] == pytest.approx(0.4 * h / (np.sqrt(4 * Gi / 3 / rho) + vi), rel=1e-12)
        dts.append(gi.scene.dt)
    assert dts[0] == dts[1] > s.scene.dt  # measured 0.94 ms, against 0.63 ms with the particles' pressure at 15 kPa


@pytest.mark.parametrize(
    "override, words",
    [
        ("material.mu0_pa_s=-1", ["material.mu0_pa_s", "-1", "> 0"]),
        ("material.bogus=1", ["material.bogus", "unknown"]),
        ("numerics.shape=spline7", ["numerics.shape", "spline7", "gimp"]),
        ("domain.cell_size_m=0.03", ["domain.cell_size_m", "whole number"]),
        ("numerics.dt_s=0.1", ["numerics.dt_s", "0.1", "<="]),
        ("time.n_frames=0", ["time.n_frames", ">= 1"]),
        ("domain.hi_m=[0.1, 0.24]", ["bodies[0]", "outside the domain"]),
        ("material.density_kg_m3=abc", ["material.density_kg_m3", "abc", "number"]),
    ],
)
def test_bad_input_names_key_value_and_range(override, words):
    with pytest.raises(m.SceneError) as e:
        m.build(m.load_scene("dambreak-lab", [override]))
    for w in words:
        assert w in str(e.value), (w, str(e.value))


def test_cli_bad_input_exit_2(tmp_path, capsys):
    rc = cli.main(["run", "dambreak-lab", "--out", str(tmp_path), "--set", "material.alpha=-3", "--quiet"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "material.alpha" in err and "Traceback" not in err
    assert cli.main(["run", str(tmp_path / "missing.toml"), "--quiet"]) == 2


def test_scene_docs_current():
    text = (ROOT / "docs" / "scenes.md").read_text()
    assert schema_markdown() in text, "regenerate docs/scenes.md from mpmjax._schema.schema_markdown()"


def test_cli_run_writes_results(tmp_path):
    out = tmp_path / "run"
    rc = cli.main(
        [
            "run",
            "dambreak-lab",
            "--out",
            str(out),
            "--quiet",
            "--set",
            "time.t_end_s=0.5",
            "--set",
            "time.n_frames=5",
            "--set",
            "domain.cell_size_m=0.02",
        ]
    )
    assert rc == 0
    summ = json.loads((out / "summary.json").read_text())
    for k in (
        "scene",
        "dim",
        "n_particles",
        "n_steps",
        "dt_s",
        "t_end_s",
        "wall_s",
        "particle_steps_per_s",
        "mass_initial_kg",
        "mass_final_kg",
        "times_s",
        "runout_m",
        "final_runout_m",
    ):
        assert k in summ, k
    # mass = rho * block area per metre of depth = 1850 * 0.04 = 74 kg/m (float32 volumes)
    assert summ["mass_initial_kg"] == pytest.approx(74.0, rel=1e-6)
    assert summ["mass_final_kg"] == summ["mass_initial_kg"]
    assert len(summ["times_s"]) == len(summ["runout_m"]) == 6
    assert summ["times_s"][-1] == pytest.approx(0.5, rel=1e-9)
    # the block starts at its own width (farthest particle) and the front only advances in a
    # collapse; the headline free-surface front reads the block's vertical edge 1.28 kernel
    # bandwidths (one cell, 0.02 m) beyond it (tests/test_runout_front.py), within 10 % of b
    assert summ["runout_farthest_particle_m"][0] == pytest.approx(0.2, abs=1e-6)
    assert summ["runout_m"][0] == pytest.approx(0.2 + 1.2816 * 0.02, abs=0.002)
    assert np.all(np.diff(summ["runout_m"]) >= -1e-3)
    assert np.all(np.diff(summ["runout_farthest_particle_m"]) >= -1e-3)
    assert summ["runout_capped_by_wall"] is False
    with h5py.File(out / "result.h5") as f:
        assert f.attrs["complete"]
        assert f["frames/x_m"].shape == (6, summ["n_particles"], 2)
        assert f["frames/lambda"].shape == (6, summ["n_particles"])
        assert json.loads(f.attrs["scene_config_json"])["material.model"] == "coussot"
        assert f["particles/mass_kg"][()].sum() == pytest.approx(74.0, rel=1e-6)
    assert (out / "result.png").stat().st_size > 10_000
