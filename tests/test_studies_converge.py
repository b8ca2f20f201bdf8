"""``mpmjax converge``: the convergence benchmark's arithmetic (observed order, Richardson
extrapolate) on sequences with a known answer, the exact slump profile it measures against,
and a tiny sweep through the command (figures of the full sweep: docs/validation.md,
"Convergence benchmark")."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from mpmjax.studies import converge


def test_richardson_recovers_order_and_limit_of_a_power_law():
    # q(h) = 1 + 0.3 h^p at h = 1, 1/2, 1/4, 1/8: order p exactly and the limit 1
    for p in (1.0, 1.5, 2.0):
        q = [1 + 0.3 * (0.5**i) ** p for i in range(4)]
        r = converge.richardson(q)
        assert r["order"] == pytest.approx(p, rel=1e-12)
        assert r["extrapolate"] == pytest.approx(1.0, abs=1e-12)
        assert r["ratios"] == pytest.approx([2**p, 2**p], rel=1e-12)


def test_richardson_refuses_oscillating_and_non_asymptotic_sequences():
    osc = converge.richardson([1.0, 1.2, 1.1, 1.15])
    assert osc["extrapolate"] is None and "sign" in osc["reason"]
    grow = converge.richardson([1.0, 1.01, 1.03, 1.07])  # differences grow: order -1
    assert grow["order"] == pytest.approx(-1.0) and grow["extrapolate"] is None
    assert converge.richardson([1.0, 1.1])["reason"] == "fewer than 3 levels"


def test_exact_slump_profile_holds_the_released_area():
    # A = (2/3) sqrt(k) x_f^(3/2) over [0, x_f]; the profile is mirrored about x = 0 and
    # smoothed, so its integral over x >= 0 is A up to the kernel's spill past x = 0 (symmetric: none)
    x_f, k = converge._slump_exact(0.04)
    assert (2 / 3) * math.sqrt(k) * x_f**1.5 == pytest.approx(0.04, rel=1e-12)
    xs = np.arange(0.0, 1.0, 0.001)
    h = converge.exact_slump_profile(xs, x_f, k, 0.02)
    assert np.trapezoid(h, xs) == pytest.approx(0.04, rel=5e-3)
    # the front by definition on the exact profile: ~1 % short of x_f plus the smoothing
    assert converge._exact_front_by_definition(x_f, k, 0.005) == pytest.approx(0.99 * x_f, abs=0.005)


def test_tiny_sweep_writes_a_table_that_reopens(tmp_path):
    doc = converge.run_converge(
        ("water",), size="ci", out=tmp_path, ppcs=(1, 2), shapes=("gimp",), volumes=("none",), log=lambda m: None
    )
    on_disk = json.loads((tmp_path / "bench" / "converge.json").read_text())
    rows = on_disk["cases"]["water"]["rows"]
    # series default and ppc=1, 3 levels each, all finished
    assert {(r["series"], r["level"]) for r in rows} == {(s, i) for s in ("default", "ppc=1") for i in range(3)}
    assert all(r["status"] == "ok" and r["cpu_s"] > 0 for r in rows)
    # the water surge moved off the column edge (0.114 m) by 0.05 s and stays behind Ritter's
    # front x0 + 2 t sqrt(g h0) = 0.22 m (plus the front's 1.28-cell reading of a steep edge)
    for r in rows:
        h = on_disk["cases"]["water"]["levels_m"][r["level"]]
        assert 0.114 < r["runout_m"] < 0.114 + 2 * 0.05 * math.sqrt(9.81 * 0.114) + 1.3 * h
    an = doc["analysis"]["water"]
    assert set(an["convergence"]) == {"default", "ppc=1"}
    assert an["ppc_spread"] and all(v["n_ppc"] == 2 for v in an["ppc_spread"].values())
    assert (tmp_path / "img" / "converge.png").stat().st_size > 10_000
    assert "| default |" in (tmp_path / "bench" / "converge.md").read_text()
    # a rerun reuses every finished run
    again = converge.run_converge(
        ("water",), size="ci", out=tmp_path, ppcs=(1, 2), shapes=("gimp",), volumes=("none",), log=lambda m: None
    )
    assert all(r.get("reused") for r in again["cases"]["water"]["rows"])
