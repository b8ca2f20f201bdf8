"""Stress cases (issue 6), coarse version (``mpmjax stress --size ci``): every case must stay
finite, lose no particle, keep its mass and keep its kinetic energy below what gravity released.

The criteria and their tolerances are defined (and justified) in ``mpmjax.studies.stress``; each is
checked at every step inside the scan.  The coarse cases run at h = 0.02 m for 1 s (the field
case at h = 4 m for 40 s; the 100 000-step case shortened to 2 000 steps; the depth-averaged breach at
h = 10 m for 40 s), about 75 s of CPU in all.
"""

import json
import math

import pytest

from mpmjax import build
from mpmjax.cli import main
from mpmjax.studies import stress

# Cases whose volume ratio leaves the bound, recorded and explained in docs/performance.md: with
# the thesis's kappa = 15 kPa the sound speed sqrt(kappa/rho) = 2.8 m/s is below the speeds a 1 m
# fall or a 1.2 m slide reach (Mach 0.8 to 3), far outside weak compressibility (Mach < 0.3);
# the Tait EOS caps tension at -C kappa = -1.3 kPa, so the splash/thinning layer stretches
# (sum J V0 / sum V0 up to 1.05 on the slope, 1.29 for the drop, measured at this resolution).
# At the full resolution the drop case also loses particles: the automatic time step does not
# account for the fall height (docs/performance.md); this coarse version survives it.
SUPERSONIC = {"slope-30deg", "drop-1m"}
# Lab cases whose coarse (h = 0.02 m) deposit is under-resolved across its depth at the default ppc 3:
# 1.5-2.2 cells thick (summary.json warns below 4), its particles 0.4-0.8 h above the no-slip bed sit
# at the Tait tension cutoff (J up to 2.1, p = -1.3 kPa, |tau| = 3 Pa, where hydrostatics gives
# +0.4 kPa), and sum J V0 / sum V0 reaches 1.026 (measured; docs/performance.md, "Stress cases").
# A slip bed or J-bar removes it (max 1.0003 / 1.0000), and at the full size (h = 0.01 m, 4.7 cells
# thick) alpha-10 stays at 1.0040 over 15 s: a resolution defect of the bed's first cell, not the bound.
UNDER_RESOLVED = {"alpha-10", "steps-100k"}


@pytest.fixture(scope="module")
def results():
    return {r["case"]: r for r in stress.run_stress("ci")}


@pytest.mark.parametrize("name", stress.CASE_NAMES)
def test_case_stays_finite_keeps_its_mass_and_loses_nothing(results, name):
    r = results[name]
    assert not r["nan"]
    assert r["n_lost"] == 0
    if name.startswith("da-"):  # column splitting (the depth-averaged default) may add columns in its spare slots
        assert r["n_particles"] >= r["n_active_final"] >= r["n_active_initial"] > 0
    else:
        assert r["n_active_final"] == r["n_active_initial"] == r["n_particles"]
    assert r["mass_final_kg"] == r["mass_initial_kg"] > 0  # rho V0 fixed per particle, or halved by a split: exact
    assert 0 < r["J_min"] <= 1 <= r["J_max"] and math.isfinite(r["J_max"])


@pytest.mark.parametrize("name", stress.CASE_NAMES)
def test_kinetic_energy_never_exceeds_the_energy_gravity_released(results, name):
    r = results[name]
    # E_k(t) <= E_k(0) + W_g(t) + 1 % E_avail at every step (tolerance justified in studies/stress.py);
    # measured: the excess never rises above 0 (its value at t = 0) in any coarse case
    assert r["energy_excess_over_available"] <= stress.ENERGY_TOL
    assert 0 < r["max_ke_over_available"] <= 1 + stress.ENERGY_TOL
    assert r["available_energy_J"] > 0


@pytest.mark.parametrize(
    "name",
    [
        pytest.param(n, marks=pytest.mark.xfail(strict=True, reason="supersonic for kappa = 15 kPa: see SUPERSONIC"))
        if n in SUPERSONIC
        else pytest.param(n, marks=pytest.mark.xfail(strict=True, reason="deposit under 2.2 cells: see UNDER_RESOLVED"))
        if n in UNDER_RESOLVED
        else n
        for n in stress.CASE_NAMES
        if not n.startswith("da-")
    ],
)
def test_volume_ratio_stays_within_the_tait_bound(results, name):
    r = results[name]
    lo, hi = r["volume_ratio_bound"]
    assert lo <= r["volume_ratio_min"] and r["volume_ratio_max"] <= hi, r["failures"]
    assert r["passed"], r["failures"]


def test_depth_averaged_cases_pass_every_criterion_that_applies(results):
    """Issue 33: no NaN, no loss, exact mass and the energy bound in every depth-averaged stress case
    (the lab block as columns, at the viscosity cap, down a 45 degree DEM ramp onto a floor, under a
    stiff Voellmy drag, the field breach on its DEM).  The volume bound does not apply (a column's
    volume is its own: J stays 1, asserted) and is not checked."""
    names = [n for n in stress.CASE_NAMES if n.startswith("da-")]
    assert len(names) == 5
    for n in names:
        r = results[n]
        assert r["formulation"] == "depth-averaged" and r["volume_ratio_bound"] is None
        assert r["J_min"] == r["J_max"] == 1.0
        assert r["passed"], (n, r["failures"])
    # the ramp's columns reach the floor: at least the speed of a 1 m frictionless fall, sqrt(2 g)
    assert results["da-ramp-45deg"]["max_speed_m_s"] > math.sqrt(2 * 9.81)


def test_supersonic_cases_fail_only_on_volume_and_are_supersonic(results):
    for n in SUPERSONIC:
        r = results[n]
        assert r["mach_max"] > 0.3
        assert len(r["failures"]) == 1 and r["failures"][0].startswith("V/V0"), r["failures"]


def test_under_resolved_cases_fail_only_on_expansion_and_by_little(results):
    """They keep the lower (compression) bound and exceed the upper one by under 1 % of V0 (measured
    1.026 against 1.02): a bound an instability would pass by far, as the drop's 1.36 does."""
    for n in UNDER_RESOLVED:
        r = results[n]
        assert len(r["failures"]) == 1 and r["failures"][0].startswith("V/V0"), r["failures"]
        assert r["volume_ratio_bound"][0] <= r["volume_ratio_min"]
        assert r["volume_ratio_max"] < 1 + stress.EXPANSION_TOL + 0.01


def test_the_100k_case_is_shortened_in_ci_and_the_size_is_checked():
    ci = stress.case_config(next(c for c in stress.CASES if c.name == "steps-100k"), "ci")
    full = stress.case_config(next(c for c in stress.CASES if c.name == "steps-100k"), "full")

    assert build(ci).scene.n_steps == 2000
    assert build(full).scene.n_steps == 100_000
    with pytest.raises(ValueError, match="--size"):
        stress.case_config(stress.CASES[0], "huge")


def test_cli_writes_stress_json_and_exits_2_on_a_bad_case(tmp_path, capsys):
    out = tmp_path / "stress.json"
    assert main(["stress", "--case", "lambda0-10", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["all_passed"] and doc["size"] == "ci" and [c["case"] for c in doc["cases"]] == ["lambda0-10"]
    assert "| lambda0-10 | PASS |" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        main(["stress", "--case", "nope"])
    assert e.value.code == 2
