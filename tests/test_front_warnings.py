"""The warnings a run's end adds about its front (``mpmjax._driver.summary``): a front still advancing when the run
ends (final_runout_m is then a moving front's), and in the depth-averaged model a tip that creeps after the bulk has
come to rest, which column splitting holds (docs/depth-averaged.md, 'Creep after arrest')."""

import json

import math

import pytest

from mpmjax import run_scene
from mpmjax._driver.summary import _front_at_the_end

DA = ["model.formulation=depth-averaged", "time.n_frames=60"]


def test_depth_averaged_tip_creep_is_named_and_splitting_holds_it(tmp_path, capsys):
    """``dambreak-lab`` in the depth-averaged model, 15 s: its kinetic energy is below 1 % of its peak from 2-3 s,
    but without splitting (``split_levels = 0``) its tip creeps on at about 0.16 m/s into the wall at 2 m (measured
    2026-12-06).  With one level and a pool of 1 (the defaults until 2026-12-07) it rested at 1.196 m with 22 % of its
    volume in columns still sparser than the grid; with the defaults since (3 levels, a pool of 3) at 1.347 m in
    float32, the runout of the resolved tip (8 columns a cell: 1.29-1.35 m, docs/depth-averaged.md), using 163 of
    its 180 spare slots.  Asserted: the creep warning, the capped runout and more than 0.5 m of advance after rest;
    with the default splitting no front or sparse warning, the runout within one cell (1 cm) of 1.347 m, the front's
    end speed below 1 mm/s and the pool not exhausted."""
    s = run_scene("dambreak-lab", tmp_path / "creep", DA + ["numerics.split_levels=0"], quiet=True)
    (w,) = [w for w in s["warnings"] if "front" in w]
    assert "creep of a tip" in w and "(numerics.split_levels = 3, the default this run turned off) holds it" in w
    assert s["runout_capped_by_wall"] and s["final_runout_m"] > 1.9 and s["time_to_rest_s"] <= 3.0
    k = s["times_s"].index(s["time_to_rest_s"])
    assert s["runout_m"][-1] - s["runout_m"][k] > 0.5
    held = run_scene("dambreak-lab", tmp_path / "held", DA, quiet=True)
    assert not [w for w in held["warnings"] if "front" in w or "sparse" in w or "slots" in w]
    assert held["final_runout_m"] == pytest.approx(1.347, abs=0.01)
    assert abs(held["final_front_speed_m_s"]) < 1e-3
    doc = json.loads((tmp_path / "held" / "summary.json").read_text())
    assert doc["final_front_speed_m_s"] == held["final_front_speed_m_s"]
    # 60 seeded columns, 180 spare slots; about 163 used (float32), none left wanting one
    assert held["split_columns"]["spare_slots"] == 180 and 120 < held["split_columns"]["slots_used"] < 180
    assert held["split_columns"]["sparse_unsplit_at_end"] == 0
    # the tip resolved: under the 5 % the sparse-volume warning starts at (float32: 0.4 %)
    assert held["sparse_volume_fraction"] < 0.05


def test_the_sparse_volume_warning_holds_its_tongue_where_the_tip_is_resolved():
    """``_sparse_volume_fraction`` on the lab block as columns before it moves: none sparse (3 columns a cell of a
    0.2 m deep block); with every other column removed, those left are 2/3 of a cell apart and still dense; spread
    to 3 cells apart (depth on the grid below V_p / h), all sparse: 1.  The warning starts above 5 %."""
    import jax.numpy as jnp

    from mpmjax import _shallow, load_scene
    from mpmjax._build import build
    from mpmjax._driver.summary import (
        SPARSE_VOLUME_WARN,
        _sparse_column_depth,
        _sparse_volume_fraction,
        _sparse_warning,
    )

    s = build(load_scene("dambreak-lab", DA))
    st = s.state
    depth = lambda state: _shallow.column_depth(s.scene, state)  # noqa: E731
    assert _sparse_volume_fraction(s.scene, st, depth(st)) == 0.0
    seeded = st.active & (st.vol0 > 0)
    half = st._replace(active=seeded & (jnp.arange(st.active.shape[0]) % 2 == 0))
    assert _sparse_volume_fraction(s.scene, half, depth(half)) == 0.0
    spread = st._replace(x=st.x.at[:, 0].multiply(9.0), active=seeded)  # 3 cells apart over 1.8 m of the 2 m box
    assert _sparse_volume_fraction(s.scene, spread, depth(spread)) == pytest.approx(1.0)
    assert _sparse_warning(SPARSE_VOLUME_WARN, 1, 3) is None and _sparse_warning(0.06, 1, 3).startswith("6 %")
    # the depth they resolve: the seeded columns' own V_p / h (0.2 m over 3 columns a cell), spread or not
    assert _sparse_column_depth(s.scene, st, depth(st)) is None
    assert _sparse_column_depth(s.scene, spread, depth(spread)) == pytest.approx(0.2 / 3, rel=1e-5)
    # a hazard map's threshold thinner than that is named (field-breach-da: 0.447 m against 0.1 m), a deeper one not
    w = _sparse_warning(0.084, 1, 2, depth=0.447, per_level=4, hazard_depth=0.1)
    assert "about 0.447 m" in w and "divides that by 4" in w and "output.hazard_depth_m = 0.1 m, is thinner" in w
    assert "hazard" not in _sparse_warning(0.084, 1, 2, depth=0.447, per_level=4, hazard_depth=0.5)


def test_a_pool_too_small_for_the_columns_that_want_to_split_is_named(tmp_path):
    """The same run with 3 spare slots (split_pool 0.05): sparse columns are left unsplit at the end, and the
    warning names how many and the remedy."""
    s = run_scene("dambreak-lab", tmp_path / "small", DA + ["numerics.split_levels=1", "numerics.split_pool=0.05"],
                  quiet=True)
    n = s["split_columns"]["sparse_unsplit_at_end"]
    assert s["split_columns"]["slots_used"] == 3 and n > 0
    (w,) = [w for w in s["warnings"] if "slots" in w]
    assert f"{n} column(s) sparse at the end, " in w and "were left unsplit" in w and "raise numerics.split_pool" in w
    # their share of the volume, named with them: part of the volume the sparse-volume fraction counts (columns the
    # pool left unsplit are sparse; sparse columns at the smallest volume are not in it)
    share = s["split_columns"]["sparse_unsplit_volume_fraction"]
    assert 0.0 < share <= s["sparse_volume_fraction"] + 1e-12
    assert f"{100 * share:.2g} % of the volume" in w
    # and the volume left sparse is named, with what one more level would resolve: nearly all of it here (the
    # pool let three of the 60 seeded columns split), each column at its seeded 0.2 m x h/3, alone on the grid
    # V_p / h = 0.2 / 3 m deep, which one more level halves (a 1-D plan)
    assert s["sparse_volume_fraction"] > 0.9
    assert s["sparse_column_depth_m"] == pytest.approx(0.2 / 3, rel=1e-5)
    (w,) = [w for w in s["warnings"] if "sparse_volume_fraction" in w]
    assert "raise numerics.split_levels (= 1)" in w
    assert "resolve layers down to about 0.0667 m" in w and "divides that by 2" in w
    assert "hazard" not in w  # no hazard maps in this run


def test_a_run_ended_while_its_front_still_moves_says_so(tmp_path, capsys):
    """The lab dam break (full model) stopped at 0.6 s, in its collapse: over the last quarter of the run its front
    moves at about 1 m/s, many cells; the warning says so and is printed at the end."""
    s = run_scene("dambreak-lab", tmp_path / "cut", ["domain.cell_size_m=0.02", "time.t_end_s=0.6", "time.n_frames=8"])
    err = capsys.readouterr().err
    (w,) = [w for w in s["warnings"] if "front" in w]
    assert w.startswith("the runout front was still advancing at the end of the run") and "raise time.t_end_s" in w
    assert s["final_front_speed_m_s"] > 0.5
    assert f"warning: {w}" in err


def test_the_front_check_needs_two_frames_in_the_last_quarter_and_a_front_off_the_wall():
    """One frame (times 0 and t_end): nothing is measured, rather than the whole run's mean speed; two frames in the
    last quarter: 1 m in 1 s, warned; the same front within a cell of the wall: measured, not warned; a NaN front
    earlier in the run does not matter; a front moving by exactly one bin (h) is not 'more than a cell'."""
    assert _front_at_the_end([0.0, 30.0], [0.2, 1.5], 0.01, 2.0) == (None, None)
    speed, w = _front_at_the_end([0.0, 1.0, 2.0, 3.0, 4.0], [math.nan, 0.5, 0.8, 1.0, 2.0 - 0.5], 0.01, 2.0)
    assert speed == pytest.approx(0.5) and w.startswith("the runout front was still advancing")
    speed, w = _front_at_the_end([0.0, 1.0, 2.0, 3.0, 4.0], [0.2, 0.5, 0.8, 1.0, 1.995], 0.01, 2.0)
    assert speed == pytest.approx(0.995) and w is None
    assert _front_at_the_end([0.0, 1.0, 2.0, 3.0, 4.0], [0.2, 0.5, 0.8, 1.0, 1.01], 0.01, 2.0)[1] is None
