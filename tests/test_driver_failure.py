"""Runs that go wrong stop with a reason (mpmjax._health, docs/output.md "Failed runs").

The unstable scene is a legitimate input: a block dropped from 2.4 m with the time step
computed for a stated speed of 1 cm/s (numerics.velocity_scale_m_s = 0.01, cfl = 1), so the
step is right for the wave speed c = 4.35 m/s but not for the free fall.  In free fall the
MPM update is exact (uniform grid velocity, partition of unity): after n steps every
particle moves at v = n dt g, and |v| dt/h first exceeds 1 at step n* = floor(h/(g dt^2)) + 1.
"""

import json
import math

import numpy as np
import pytest

import mpmjax as m
from mpmjax import _health, cli
from mpmjax._io import read_result

G = 9.81
FALL = """
name = "unstable-fall"
description = "A block dropped from 2.4 m with the wave-speed time step computed for a stated speed of 1 cm/s."
[domain]
dim = 2
lo_m = [0.0, 0.0]
hi_m = [1.0, 3.0]
cell_size_m = 0.05
[numerics]
pressure = "explicit"  # the sound speed's time step, which the stated speed of 1 cm/s undercuts
cfl = 1.0
velocity_scale_m_s = 0.01
[time]
t_end_s = 1.0
n_frames = 10
[material]
model = "newtonian"
density_kg_m3 = 1850.0
bulk_modulus_pa = 15000.0
viscosity_pa_s = 1.0
[[bodies]]
type = "box"
lo_m = [0.3, 2.4]
hi_m = [0.7, 2.6]
"""


def test_cfl_violation_stops_the_run_with_step_time_particle_and_cause(tmp_path, capsys):
    scene = tmp_path / "fall.toml"
    scene.write_text(FALL)
    out = tmp_path / "run"
    setup = m.build(m.load_scene(scene))
    dt, h = setup.scene.dt, setup.scene.h
    assert dt == pytest.approx(1.0 / 90.0, rel=1e-12)  # 10 frames of 9 steps; the limit is h/c = 0.0115 s
    n_star = math.floor(h / (G * dt * dt)) + 1  # 42: t = 0.467 s, inside frame 5 (steps 37..45)

    assert cli.main(["run", str(scene), "--out", str(out), "--quiet"]) == cli.FAILED == 3
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert f"run failed at step {n_star} (frame 5), t = {n_star * dt:.6g} s: CFL violated" in err
    assert "lower numerics.cfl" in err and "numerics.velocity_scale_m_s" in err

    summ = json.loads((out / "summary.json").read_text())
    f = summ["failure"]
    assert summ["status"] == "failed" and summ["error"] in err and not summ["complete"]
    assert f["kind"] == "cfl" and f["step"] == n_star and (f["first_step"], f["last_step"]) == (37, 45)
    assert f["t_s"] == pytest.approx(n_star * dt, rel=1e-6)
    i = f["particle"]
    assert 0 <= i < setup.scene.n_particles and f"at particle {i} (x = " in err
    # the reported speed is the free-fall speed at that step, |v| = n* dt g = 4.58 m/s
    speed = float(f["message"].split("|v| = ")[1].split(" m/s")[0])
    assert speed == pytest.approx(n_star * dt * G, rel=1e-3)
    # the particle's reported position: its start, fallen g t^2/2 (the MPM free fall is the
    # symplectic sum dt^2 g n(n+1)/2, 0.5 % above g t^2/2 at n = 42)
    y0 = np.asarray(setup.state.x)[i, 1]
    assert f["position_m"][1] == pytest.approx(y0 - G * dt * dt * n_star * (n_star + 1) / 2, abs=1e-4)

    # frames 0..4 (before the failing frame) are on disk, readable and physical
    res = read_result(out / "result.h5")
    assert res["attrs"]["status"] == "failed" and "CFL violated" in res["attrs"]["error"]
    fr = res["frames"]
    np.testing.assert_allclose(fr["t_s"], [0.0, 0.1, 0.2, 0.3, 0.4], rtol=1e-6)
    assert fr["active"].all() and np.isfinite(fr["x_m"]).all()
    # free fall: every particle moves at -g t (float32 sums of 36 increments: 1e-5 relative)
    np.testing.assert_allclose(
        fr["v_m_s"][:, :, 1], -G * fr["t_s"][:, None] * np.ones((1, fr["v_m_s"].shape[1])), rtol=1e-5
    )
    assert summ["times_s"] == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4]) and summ["frames_written"] == 4


def test_blow_up_with_lost_particles_is_a_failure(tmp_path, capsys):
    # linear shape functions at the wave-speed limit itself (cfl = 1, the speed scale ignored):
    # the dam break goes unstable at the block's foot and the step removes a particle
    over = [
        "time.t_end_s=0.2",
        "time.n_frames=20",
        "domain.cell_size_m=0.02",
        "numerics.cfl=1",
        "numerics.velocity_scale_m_s=0.001",
        "material.bulk_modulus_pa=100000",
        "numerics.shape=linear",
        "numerics.pressure=explicit",  # the particles' pressure at its wave-speed limit
    ]
    with pytest.raises(_health.RunFailure) as e:
        m.run_scene("dambreak-lab", tmp_path, over, quiet=True)
    f = e.value.info
    assert (
        f["kind"] == "lost" and "particle(s) lost" in str(e.value) and f"first particle {f['particle']}" in str(e.value)
    )
    assert f["step"] is not None and f["first_step"] <= f["step"] <= f["last_step"]
    res = read_result(tmp_path / "result.h5")
    dt = res["attrs"]["dt_s"]
    assert f["t_s"] == pytest.approx(f["step"] * dt, rel=1e-5)
    # every frame before the failing one is on disk, and in them nothing was lost yet
    assert len(res["frames"]["t_s"]) == f["frame"] and res["frames"]["active"].all()
    # the particle was last seen within a few cells of where the last good frame had it
    last = res["frames"]["x_m"][-1][f["particle"]]
    assert np.linalg.norm(np.asarray(f["position_m"]) - last) < 3 * 0.02
    assert json.loads((tmp_path / "summary.json").read_text())["status"] == "failed"


def test_outflow_through_an_open_face_is_not_a_failure(tmp_path):
    # 3 m/s towards the open x face, no gravity: the front reaches x = 0.8 m > 0.6 m in 0.1 s
    scene = tmp_path / "out.toml"
    scene.write_text(
        """
name = "outflow"
[domain]
dim = 2
lo_m = [0.0, 0.0]
hi_m = [0.6, 0.3]
cell_size_m = 0.02
[boundary]
x_hi = "open"
[time]
t_end_s = 0.1
n_frames = 4
[material]
model = "newtonian"
density_kg_m3 = 1000.0
bulk_modulus_pa = 20000.0
[gravity]
g_m_s2 = 0.0
[[bodies]]
type = "box"
lo_m = [0.3, 0.0]
hi_m = [0.5, 0.2]
velocity_m_s = [3.0, 0.0]
"""
    )
    s = m.run_scene(str(scene), tmp_path / "run", [], quiet=True)
    assert s["status"] == "complete"
    assert 0 < s["n_outflow"] == s["n_lost"] < s["n_particles"]


def _state(n=4):
    x = np.tile([[0.5, 0.5]], (n, 1))
    return m.State(
        x=x,
        v=np.zeros((n, 2)),
        C=np.zeros((n, 2, 2)),
        tau=np.zeros((n, 2, 2)),
        J=np.ones(n),
        vol0=np.ones(n),
        mu=np.ones(n),
        internal={"lam": np.ones(n)},
        active=np.ones(n, bool),
        gate=np.ones(n, bool),
        t=np.float64(0.1),
        n_lost=np.int32(0),
    )


def test_checks_name_nonfinite_stress_and_absurd_jacobian():
    cfg = m.load_scene("dambreak-lab", ["domain.cell_size_m=0.02"])
    sc = m.build(cfg).scene
    prev = _state()
    cur = prev._replace(tau=prev.tau.copy(), J=prev.J.copy())
    cur.tau[2, 0, 1] = np.nan
    cur.J[1] = 0.05
    probs, _ = _health.check(sc, cfg, prev, cur)
    assert [p["kind"] for p in probs] == ["nonfinite", "jacobian"]
    assert "non-finite tau (NaN/inf) at particle 2" in probs[0]["message"]
    assert "absurd Jacobian J = 0.05 at particle 1" in probs[1]["message"]
    # inactive particles are not checked
    mask = np.array([True, False, False, True])
    probs, _ = _health.check(sc, cfg, prev._replace(active=mask), cur._replace(active=mask))
    assert probs == []


def test_a_particle_removed_inside_the_domain_is_lost_but_at_an_open_face_it_is_outflow():
    cfg = m.load_scene("dambreak-lab", ["domain.cell_size_m=0.02", "boundary.x_hi=open"])
    sc = m.build(cfg).scene
    prev = _state()
    x = prev.x.copy()
    x[3] = [1.995, 0.1]  # within one cell of the open face x = 2 m
    mask = np.array([True, True, False, False])
    probs, outflow = _health.check(sc, cfg, prev._replace(x=x), prev._replace(x=x, active=mask))
    assert outflow.tolist() == [3]
    assert [p["kind"] for p in probs] == ["lost"] and probs[0]["particle"] == 2
    assert "1 particle(s) lost" in probs[0]["message"] and "x = 0.5 m, y = 0.5 m" in probs[0]["message"]
