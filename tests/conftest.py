"""Strict test harness: float64 available, rank promotion raises, one tree_allclose."""

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")


# Thesis Table 8 BASE Coussot material (Annex 2 cap mu_max = 5000 Pa s), as a scene [material] table.
COUSSOT_BASE = {
    "model": "coussot",
    "density_kg_m3": 1850.0,
    "bulk_modulus_pa": 15000.0,
    "mu0_pa_s": 4.0,
    "alpha": 1.0,
    "T_s": 0.5,
    "n": 2.5,
    "lambda0": 1.5,
    "mu_max_pa_s": 5000.0,
}


def tree_allclose(a, b, rtol=1e-7, atol=0.0):
    la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
    if len(la) != len(lb):
        return False
    return all(np.allclose(np.asarray(x), np.asarray(y), rtol=rtol, atol=atol) for x, y in zip(la, lb))


@pytest.fixture
def allclose():
    return tree_allclose


def stub_result_pictures(mp: pytest.MonkeyPatch) -> None:
    """``run_scene`` without its pictures (result.png, and plan_view.png / sections.png in 3D).

    For tests that check a run's numbers and files other than the pictures: drawing them is a
    large part of a coarse CI run (``tests/test_records.py``: 105 s of 266 s CPU in
    ``plotting.plot_result``, 18 runs).  Every kind of picture is still drawn by the suite:
    ``tests/test_builtin_scenes.py`` runs every built-in dam break and ``tests/test_inflow.py`` the
    pipe scenes through ``run_scene`` with pictures, and ``tests/test_plotting.py`` checks them."""
    from mpmjax import plotting

    mp.setattr(plotting, "plot_result", lambda *a, **k: None)
    mp.setattr(plotting, "plot_3d_overview", lambda *a, **k: [])


@pytest.fixture
def no_result_pictures(monkeypatch):
    """``stub_result_pictures`` for one test."""
    stub_result_pictures(monkeypatch)
