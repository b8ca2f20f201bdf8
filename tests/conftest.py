"""Strict test harness: float64 available, rank promotion raises, one tree_allclose; XLA:CPU's
older loop emitters for fusions (faster compilation, see below)."""

import os

# Most of the suite's time is XLA compilation (a test compiles its own scene's programs: the
# records CI table spends 73 % of its CPU compiling, measured with a warm persistent cache).  The
# CPU backend's newer fusion emitters compile about a third slower: tests/test_gradients.py,
# test_rheology_mpm.py and test_boundary_splines.py took 479 s of CPU with them and 314 s without
# (same 44 tests passing, 2-core VM, 2026-12-02; one float64 gradient program 19 -> 14 s, a
# forward chunk 3.9 -> 2.5 s), while a step runs within noise of the same speed.  Set before jax
# is imported, so that the subprocesses the tests start inherit it too.  The library itself keeps
# XLA's defaults (docs/performance.md, "Test suite").
# For the same reason the backend compiles at LLVM's optimisation level 1 with its expensive passes off:
# 14 % less compile CPU on three of the suite's programs (a float64 gradient, the lab's grid-pressure and
# explicit chunks; three alternating rounds, 2026-12-07), their run time within the VM's noise.
TEST_XLA_FLAGS = (
    "--xla_cpu_use_fusion_emitters=false",
    "--xla_backend_optimization_level=1",
    "--xla_llvm_disable_expensive_passes=true",
)
_flags = os.environ.get("XLA_FLAGS", "")
os.environ["XLA_FLAGS"] = " ".join(
    [_flags] + [f for f in TEST_XLA_FLAGS if f.split("=")[0] not in _flags]
).strip()

import jax  # noqa: E402
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

from mpmjax.studies.validate import LAB_COUSSOT  # noqa: E402  (after the configuration above)


# Thesis Table 8 BASE Coussot material (Annex 2 cap mu_max = 5000 Pa s), as a scene [material] table: the one
# mpmjax validate's Coussot cases use
COUSSOT_BASE = LAB_COUSSOT


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
    large part of a coarse CI run (``tests/test_studies_records.py``: 105 s of 266 s CPU in
    ``plotting.plot_result``, 18 runs).  Every kind of picture is still drawn by the suite:
    ``tests/test_builtin_scenes.py`` runs every built-in dam break and ``tests/test_boundary_inflow.py`` the
    pipe scenes through ``run_scene`` with pictures, and ``tests/test_plotting.py`` checks them."""
    from mpmjax import plotting

    mp.setattr(plotting, "plot_result", lambda *a, **k: None)
    mp.setattr(plotting, "plot_3d_overview", lambda *a, **k: [])


@pytest.fixture
def no_result_pictures(monkeypatch):
    """``stub_result_pictures`` for one test."""
    stub_result_pictures(monkeypatch)


# shared by test_engine.py and test_engine_shapes.py
# Round-off budget for conservation identities in float64: each step sums O(10^3)
# terms of similar magnitude (error ~ sqrt(N) eps ~ 1e-14 relative); over 100-300
# steps that accumulates to ~1e-13, so 1e-12 leaves an order of magnitude of margin.
ROUNDOFF = 1e-12
SHAPES = ("linear", "gimp", "quadratic", "cubic")  # the 1-D shape functions without a boundary modification


def signal_in_compile_script(signame: str) -> str:
    """Python source for ``python -c``: the ``mpmjax`` program (argv after ``-c``), whose run sends itself
    ``signal.<signame>`` on entering its compile step.  Deterministic where a signal timed from the parent
    could land after a small scene had compiled (0.8 s on the CI machine)."""
    return f"""
import os, signal, sys
from mpmjax._driver import run as driver_run
real = driver_run.compile_advance
def compile_advance(*a, **kw):
    os.kill(os.getpid(), signal.{signame})
    return real(*a, **kw)
driver_run.compile_advance = compile_advance
from mpmjax.cli import main
sys.exit(main())  # as the mpmjax program: it ends the process itself
"""
