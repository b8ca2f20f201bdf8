"""Pipe inflow: a pool of inactive particles released in layers by a schedule (jit, scan)."""

import math

import numpy as np
import pytest

from mpmjax import load_scene, run_scene
from mpmjax import SceneError, build, validate
from mpmjax._simulate import run

Q = 0.02  # m^2/s (2D, per metre of depth)
W = 0.04  # m, pipe width -> exit speed Q / W = 0.5 m/s
T0, T1 = 0.2, 1.4  # s


def _raw(**inflow):
    spec = {
        "point_m": [0.1, 0.04],
        "direction": [1.0, 0.0],
        "width_m": W,
        "flow_rate_m3_s": Q,
        "t_start_s": T0,
        "t_stop_s": T1,
    }
    spec.update(inflow)
    return {
        "domain": {"lo_m": [0.0, 0.0], "hi_m": [2.0, 0.4], "cell_size_m": 0.02},
        # the per-particle (Tait) pressure: the volume checks below read J, which the grid pressure keeps at 1
        "numerics": {"ppc": 2, "dtype": "float64", "pressure": "explicit"},
        "time": {"t_end_s": 1.8, "n_frames": 18},
        "material": {"model": "newtonian", "density_kg_m3": 1000.0, "bulk_modulus_pa": 2e4, "viscosity_pa_s": 0.5},
        "bodies": [],
        "inflow": spec,
    }


@pytest.fixture(scope="module")
def flow():
    s = build(validate(_raw()))
    final, fr = run(s.scene, s.state, s.params)
    return s, final, fr


def test_pool_is_sized_from_q_and_the_schedule(flow):
    s, _, _ = flow
    inf = s.scene.inflow
    # pool volume = Q (t_stop - t_start) exactly (each layer carries Q * layer_dt)
    assert s.info["inflow_volume_m3"] == pytest.approx(Q * (T1 - T0), rel=1e-12)
    assert inf.speed == pytest.approx(Q / W, rel=1e-15)
    assert inf.t_stop == pytest.approx(T1, rel=1e-12)
    # layers are one particle spacing thick (0.01 m) at 0.5 m/s: 0.02 s each, 60 layers of 4
    assert (inf.n_layers, inf.n_per_layer) == (60, 4)
    assert not np.asarray(s.state.active).any()


def test_released_volume_follows_q_t_and_nothing_outside_the_schedule(flow):
    s, final, fr = flow
    t = np.asarray(fr.t)
    act = np.asarray(fr.active)
    vol0 = np.asarray(s.state.vol0)
    J = np.asarray(fr.J)
    released = (act * vol0).sum(axis=1)
    expected = Q * np.clip(t - T0, 0.0, T1 - T0)
    layer = Q * s.scene.inflow.layer_dt
    # nothing before the start, everything after the stop (frames at 0.1 s spacing)
    assert np.all(released[t < T0 - 1e-9] == 0.0)
    after = t > T1 + 1e-9
    assert np.allclose(released[after], Q * (T1 - T0), rtol=1e-12)
    # in between the released volume lags Q (t - t0) by less than one layer (the layer
    # emerging at t is switched on when it starts to leave the pipe): 0.0004 m^2 vs Q t
    assert np.all(np.abs(released - expected) <= layer + 1e-12)
    # deposited volume (current volumes J V0 of the material in the flume) equals Q t within 1 %
    # once the inflow has stopped; the Tait EOS (kappa = 2e4 Pa) compresses a 5 cm deep
    # layer by rho g H / kappa ~ 2.5 %, measured -0.3 % on average -> 1 % bound
    dep = (act * vol0 * J).sum(axis=1)
    assert np.all(np.abs(dep[after] / (Q * (T1 - T0)) - 1.0) < 0.01)
    mid = (t > T0 + 0.3) & (t < T1)
    assert np.all(np.abs(dep[mid] / expected[mid] - 1.0) < 0.01 + layer / expected[mid])
    assert int(final.n_lost) == 0


def test_released_material_moves_with_the_pipe_speed_and_no_splash(flow):
    s, _, fr = flow
    x = np.asarray(fr.x)
    act = np.asarray(fr.active)
    # frame at t = 0.3 s: material has only just left the pipe, front ~ 0.1 + 0.5 * 0.1 = 0.15 m
    k = int(np.argmin(np.abs(np.asarray(fr.t) - 0.3)))
    front = x[k][act[k], 0].max()
    assert 0.12 < front < 0.2, front
    # no splash: nothing rises more than 2 cm above the pipe top (0.06 m) at any frame
    assert x[..., 1][act].max() < 0.08


def test_gate_holds_pipe_material_until_it_leaves_the_exit():
    raw = _raw()
    raw["material"] = {
        "model": "coussot",
        "density_kg_m3": 1000.0,
        "bulk_modulus_pa": 2e4,
        "mu0_pa_s": 0.5,
        "alpha": 1.0,
        "T_s": 0.05,
        "n": 1.5,
        "lambda0": 0.0,
        "mu_max_pa_s": 50.0,
    }
    raw["time"] = {"t_end_s": 0.4, "n_frames": 40}
    s = build(validate(raw))
    assert s.scene.gate is not None and s.scene.gate.point == (0.1, 0.04)
    final, fr = run(s.scene, s.state, s.params)
    # frames every 0.01 s, half a layer time: some frames hold a layer still in the pipe end
    x = np.asarray(fr.x)[..., 0]
    act = np.asarray(fr.active)
    lam = np.asarray(fr.internal["lam"])
    behind = act & (x < 0.1 - 1e-9)
    past = act & (x > 0.11)
    assert behind.sum() >= 4 and past.any()
    # behind the exit the structure is held at lambda0 = 0 (no aging in the pipe); past it the
    # material restructures (T = 0.05 s, so lambda ~ t/T at low shear) and lambda grows
    assert np.all(lam[behind] == 0.0)
    assert lam[-1][past[-1]].max() > 0.1
    gate = np.asarray(final.gate)
    assert np.all(gate[np.asarray(final.active) & (np.asarray(final.x)[:, 0] > 0.1 + 1e-9)])


def test_inflow_3d_disc_cross_section_volume():
    raw = _raw(point_m=[0.1, 0.1, 0.06], direction=[1.0, 0.0, 0.0], width_m=0.06, flow_rate_m3_s=0.002)
    raw["domain"] = {"dim": 3, "lo_m": [0.0, 0.0, 0.0], "hi_m": [0.4, 0.2, 0.2], "cell_size_m": 0.04}
    raw["time"] = {"t_end_s": 0.2, "n_frames": 1}
    raw["inflow"]["t_start_s"] = 0.0
    raw["inflow"]["t_stop_s"] = 0.2
    s = build(validate(raw))
    inf = s.scene.inflow
    assert inf.speed == pytest.approx(0.002 / (math.pi * 0.03**2), rel=1e-12)
    assert s.info["inflow_volume_m3"] == pytest.approx(0.002 * 0.2, rel=1e-12)
    off = np.asarray(inf.offsets)
    assert np.all(np.linalg.norm(off, axis=1) <= 0.03 + 1e-12) and np.allclose(off[:, 0], 0.0)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"t_stop_s": 0.1}, "inflow.t_stop_s"),
        ({"direction": [0.0, 0.0]}, "inflow.direction"),
        ({"point_m": [3.0, 0.1]}, "inflow.point_m"),
        ({"flow_rate_m3_s": -1.0}, "inflow.flow_rate_m3_s"),
        ({"width_m": 0.001}, "inflow.width_m"),
    ],
)
def test_bad_inflow_is_a_scene_error(change, match):
    with pytest.raises(SceneError, match=match):
        validate(_raw(**change))
    raw = _raw()
    del raw["inflow"]["direction"]
    with pytest.raises(SceneError, match="together"):
        validate(raw)


def test_flume_deposition_scene_coarse(tmp_path):
    """The built-in Mizani flume at 8 cm cells for its first 30 s, through the CLI runner."""
    over = ["domain.cell_size_m=0.08", "time.t_end_s=30.0", "time.n_frames=6"]
    cfg = load_scene("flume-deposition", over)
    # 773 L over 1277 s through a 0.59 m wide flume, per metre of width
    assert cfg["inflow.flow_rate_m3_s"] == pytest.approx(0.773 / 1277.0 / 0.59, rel=1e-4)
    s = run_scene("flume-deposition", tmp_path, over, quiet=True)
    assert s["complete"] and s["n_lost"] == 0
    rho, q = cfg["material.density_kg_m3"], cfg["inflow.flow_rate_m3_s"]
    # released mass = rho Q t within one layer (layer_dt ~ 1.95 s at 8 cm cells: 6.5 %)
    t = np.asarray(s["times_s"])
    assert s["mass_initial_kg"] == 0.0
    assert s["mass_final_kg"] == pytest.approx(rho * q * t[-1], rel=0.07)
    r = np.asarray(s["runout_m"])
    # material spreads along the flume, monotonically within half a spacing, and slower than
    # the 2 cm/s exit speed would carry a plug (it spreads by gravity, not by inertia)
    assert r[-1] > 0.2 and np.all(np.diff(r) >= -0.02)
    # the pipe is still running: never at rest
    assert s["time_to_rest_s"] is None
    z = np.array([np.nan if a is None else a for a in s["surface_profile_z_m"]])
    assert np.isfinite(z).sum() >= 3 and np.nanmax(z) < 0.3


def test_field_pipe_3d_scene_coarse(tmp_path):
    """The thesis's field pipe deposition (3D) at 1 m cells for its first 12 s."""
    over = ["domain.cell_size_m=1.0", "time.t_end_s=12.0", "time.n_frames=3"]
    cfg = load_scene("field-pipe-3d", over)
    s = run_scene("field-pipe-3d", tmp_path, over, quiet=True)
    assert s["complete"] and s["n_lost"] == 0
    # released mass = rho Q t within one layer (0.5 m spacing at 1.6 m/s: 0.31 s, 2.6 % of 12 s)
    rho, q = cfg["material.density_kg_m3"], cfg["inflow.flow_rate_m3_s"]
    assert s["mass_final_kg"] == pytest.approx(rho * q * s["times_s"][-1], rel=0.03)
    # the material leaves the pipe at 1.6 m/s and spreads downslope: the front is ahead of the
    # exit and behind the distance a free particle at 1.6 m/s plus g sin(slope) t^2 / 2 would go
    r = np.asarray(s["runout_m"])
    a = 9.81 * 0.03
    assert 1.0 < r[-1] < 1.6 * 12.0 + 0.5 * a * 12.0**2 + 1.0
