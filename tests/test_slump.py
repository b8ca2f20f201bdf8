"""The slump test (``output.slump_test``, ``mpmjax._slump``, docs/slump-test.md): the Pashias
relation and its inverse, the measurements on synthetic particle sets, the scene's checks, and a
coarse run of the built-in ``slump-test`` scene at three yield stresses."""

import json
import math

import numpy as np
import pytest

import mpmjax as m
from mpmjax import _slump
from mpmjax._build import seed_bodies


def test_pashias_relation_and_its_inverse():
    assert _slump.pashias_slump(0.0) == 1.0 and _slump.pashias_slump(0.5) == pytest.approx(0.0, abs=1e-15)
    ts = np.linspace(1e-4, 0.5, 400)
    s = np.array([_slump.pashias_slump(t) for t in ts])
    assert np.all(np.diff(s) < 0)  # monotone: the bisection is well posed
    for t in (1e-3, 0.0566, 0.1133, 0.2265, 0.45):
        assert _slump.pashias_tau(_slump.pashias_slump(t)) == pytest.approx(t, abs=1e-11)
    assert (
        _slump.pashias_tau(1.2) == 0.0 and _slump.pashias_tau(-0.1) == 0.5 and math.isnan(_slump.pashias_tau(math.nan))
    )
    # Pashias et al. 1996's worked range: tau' = 0.1 slumps about 48 % of H
    assert _slump.pashias_slump(0.1) == pytest.approx(1 - 0.2 * (1 - math.log(0.2)))
    with pytest.raises(ValueError):
        _slump.pashias_slump(0.6)


def test_coussot_critical_stress_is_the_flow_curve_minimum():
    mu0, alpha, T, n = 4.0, 1.0, 0.5, 2.5
    g = np.logspace(-3, 3, 200001)
    curve = mu0 * g * (1 + (alpha * T * g) ** -n)
    assert _slump.coussot_critical_stress(mu0, alpha, T, n) == pytest.approx(curve.min(), rel=1e-6)
    assert _slump.coussot_critical_stress(mu0, alpha, T, 0.8) is None


def test_measurements_on_the_initial_cylinder():
    cfg = m.load_scene("slump-test")
    x, vol, _ = seed_bodies(cfg)
    got = _slump.measure(x, vol, np.ones(len(x), bool), cfg)
    h = cfg["domain.cell_size_m"]
    assert got["height_m"] == pytest.approx(0.1, abs=1e-12)  # the top particle + half a spacing
    assert got["mirror"] == 4
    assert got["spread_radius_m"] == pytest.approx(0.05 + 0.4 * h, abs=0.1 * h)  # a vertical edge (docstring)


def test_measurements_on_a_synthetic_cone_deposit():
    """A cone of height 40 mm and radius 120 mm on the lattice: centre height within a particle
    spacing of the apex (the bins within 2 h average the slope), spread radius within h of
    the radius where the thickness is 10 % of the centre's (0.9 x 120 mm)."""
    cfg = m.load_scene("slump-test", ["domain.cell_size_m=0.005"])
    cone = {
        "type": "cone",
        "base_m": [0.0, 0.0, 0.0],
        "radius_m": 0.12,
        "top_radius_m": 0.0,
        "height_m": 0.04,
        "axis": 2,
    }
    cfg = dict(cfg, bodies=[cone])
    x, vol, _ = seed_bodies(cfg)
    got = _slump.measure(x, vol, np.ones(len(x), bool), cfg)
    h = cfg["domain.cell_size_m"]
    slope = 0.04 / 0.12
    assert got["height_m"] == pytest.approx(0.04 - slope * 1.1 * h, abs=h)
    assert got["spread_radius_m"] == pytest.approx(0.9 * 0.12, abs=h)


@pytest.mark.parametrize(
    "override, words",
    [
        (
            "bodies=[{type='cone', base_m=[0.0, 0.0, 0.0], radius_m=0.05, top_radius_m=0.02, height_m=0.1}]",
            ["cylinder"],
        ),
        ("gravity.slope_deg=5", ["output.slump_test", "gravity.slope_deg = 5"]),
        ("bodies=[{type='cylinder', base_m=[0.0, 0.0, 0.01], radius_m=0.05, height_m=0.1}]", ["not on the floor"]),
        ("bodies=[{type='box', lo_m=[0.0, 0.0, 0.0], hi_m=[0.05, 0.05, 0.1]}]", ["output.slump_test", "cylinder"]),
    ],
)
def test_slump_test_needs_one_vertical_cylinder_on_the_floor(override, words):
    with pytest.raises(m.SceneError) as e:
        m.load_scene("slump-test", [override])
    for w in words:
        assert w in str(e.value), (w, str(e.value))


def test_slump_test_is_3d_only():
    raw = {
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [0.4, 0.2], "cell_size_m": 0.01},
        "time": {"t_end_s": 0.1},
        "material": {"model": "bingham", "density_kg_m3": 1800.0, "bulk_modulus_pa": 3.5e5},
        "bodies": [{"type": "polygon", "vertices_m": [[0, 0], [0.05, 0], [0.05, 0.1], [0, 0.1]]}],
        "output": {"slump_test": True},
    }
    with pytest.raises(m.SceneError) as e:
        m.validate(raw)
    assert "output.slump_test = true is invalid with domain.dim = 2" in str(e.value)


# CI size: h = 8.33 mm (6 cells across the radius, 12 up the height), 2^3 particles per cell, 0.3 s (the
# scene's grid pressure: 618 steps, about 8 s of loop a run on 2 cores; tau_y = 100 Pa is still slumping at
# 0.3 s, 57.2 mm against 59.4 mm at 0.5 s).
CI = ["domain.cell_size_m=0.008333333333333333", "time.t_end_s=0.3", "time.n_frames=3"]
CI_TAU = (100.0, 200.0, 400.0)


def ci_tolerance(tau_prime: float, h_over_H: float) -> float:
    """The method's 30 % (docs/slump-test.md, at the documented h = H / 16) plus one cell of slump,
    s' off by h / H, carried to tau' by the relation's sensitivity d ln(tau') / ds' = 1 / (2 tau' ln 2 tau')
    (4.0 at tau' = 0.057, 3.0 at 0.11, 2.8 at 0.23: the yield stress of a small slump is the best read).
    Measured at h = H / 12 with the scene's grid pressure (2026-12-05): +29 %, -16 %, -19 % against 64 %, 55 %,
    53 % (with the particles' pressure it read +47 %, -2 %, +4 %, a slump held up by volumetric locking that
    grows with refinement: docs/slump-test.md)."""
    return 0.30 + h_over_H / abs(2 * tau_prime * math.log(2 * tau_prime))


def test_slump_test_scene_ci(tmp_path, no_result_pictures):
    slumps, backs = [], []
    for tau in CI_TAU:
        out = tmp_path / f"tau{tau:g}"
        m.run_scene("slump-test", out, CI + [f"material.yield_stress_pa={tau}"], quiet=True)
        doc = json.loads((out / "summary.json").read_text())
        st = doc["slump_test"]
        assert st["yield_stress_input_pa"] == tau and st["initial_height_m"] == 0.1
        assert st["spread_diameter_m"] > st["initial_diameter_m"]
        assert st["tau_prime"] == pytest.approx(st["yield_stress_back_calculated_pa"] / (1800 * 9.81 * 0.1))
        slumps.append(st["slump_m"])
        backs.append(st["yield_stress_back_calculated_pa"])
    assert slumps[0] > slumps[1] > slumps[2] > 0, slumps
    for tau, back in zip(CI_TAU, backs):
        tol = ci_tolerance(tau / (1800 * 9.81 * 0.1), 1 / 12)
        assert back == pytest.approx(tau, rel=tol), (tau, back, tol)


@pytest.mark.slow
@pytest.mark.parametrize("tau", [100.0, 200.0, 400.0])
def test_slump_test_scene_full(tmp_path, tau):
    """The documented resolution (docs/slump-test.md): back-calculated within 30 % of the input."""
    st = m.run_scene("slump-test", tmp_path / "r", [f"material.yield_stress_pa={tau}"], quiet=True)["slump_test"]
    assert st["yield_stress_back_calculated_pa"] == pytest.approx(tau, rel=0.30)
