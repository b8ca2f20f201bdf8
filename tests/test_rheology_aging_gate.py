"""Aging gate (thesis §3.4.2 'x < 0 does not age', generalised to any plane)."""

import numpy as np
import pytest
from conftest import COUSSOT_BASE

import mpmjax as m


def _scene(gate):
    raw = {
        "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [0.4, 0.2], "cell_size_m": 0.02},
        # the particles' pressure, pinned: a box at rest without gravity has no flow speed, which the grid
        # pressure's time step needs (its build asks for numerics.velocity_scale_m_s); the subject is the gate
        "numerics": {"dtype": "float64", "pressure": "explicit"},
        "time": {"t_end_s": 1.0, "n_frames": 4},
        "material": dict(COUSSOT_BASE),
        "gravity": {"g_m_s2": 0.0},
        "bodies": [{"lo_m": [0.04, 0.04], "hi_m": [0.36, 0.16]}],
    }
    if gate:
        # plane through x = 0.2 m, normal along the diagonal: a non-axis-aligned gate
        raw["gate"] = {"point_m": [0.2, 0.1], "normal": [1.0, 1.0]}
    return m.build(m.validate(raw))


def test_material_ages_only_past_the_gate():
    s = _scene(gate=True)
    final, frames = m.run(s.scene, s.state, s.params)
    lam = np.asarray(final.internal["lam"])
    x = np.asarray(final.x)
    past = (x - [0.2, 0.1]) @ np.array([1.0, 1.0]) > 0
    assert past.sum() > 10 and (~past).sum() > 10
    # at rest (no gravity, no motion) gdot = 0 exactly, so lam(t) = lam0 + t/T (REFERENCE.md)
    t = float(final.t)
    np.testing.assert_allclose(lam[past], 1.5 + t / 0.5, rtol=1e-10)
    np.testing.assert_allclose(lam[~past], 1.5, rtol=0, atol=0)
    # viscosity follows mu = mu0 (1 + lam^n): unaged particles keep mu(lam0)
    np.testing.assert_allclose(np.asarray(final.mu)[~past], 4.0 * (1 + 1.5**2.5), rtol=1e-12)


def test_without_gate_everything_ages():
    s = _scene(gate=False)
    final, _ = m.run(s.scene, s.state, s.params)
    np.testing.assert_allclose(np.asarray(final.internal["lam"]), 1.5 + float(final.t) / 0.5, rtol=1e-10)


def test_gate_requires_point_and_normal():
    raw = {
        "domain": {"dim": 2, "lo_m": [0, 0], "hi_m": [1, 1], "cell_size_m": 0.1},
        "time": {"t_end_s": 1.0},
        "material": {"density_kg_m3": 1000.0, "bulk_modulus_pa": 1e4},
        "bodies": [{"lo_m": [0, 0], "hi_m": [0.5, 0.5]}],
        "gate": {"point_m": [0.0, 0.0]},
    }
    with pytest.raises(m.SceneError, match="gate"):
        m.validate(raw)
