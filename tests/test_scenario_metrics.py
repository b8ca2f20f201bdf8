"""Plan-view metrics of 3D runs (lobe width, viscosity map, self-forming channels) on synthetic
particle sets with known answers."""

import json
import math

import numpy as np
import pytest

from mpmjax import _metrics as M


def _lattice(x0, x1, y0, y1, z0, z1, s):
    """Particle centres of a simple cubic lattice of spacing s filling the box (cell-centred)."""
    ax = [np.arange(a + s / 2, b, s) for a, b in ((x0, x1), (y0, y1), (z0, z1))]
    return np.stack(np.meshgrid(*ax, indexing="ij"), -1).reshape(-1, 3)


def test_plan_view_mean_exact_bins_counts_and_exclusions():
    x = np.array(
        [
            [0.5, 0.5, 0.1],  # bin (0, 0)
            [0.7, 0.2, 0.3],  # bin (0, 0)
            [1.5, 0.5, 0.1],  # bin (1, 0)
            [1.5, 1.5, 0.1],  # bin (1, 1), inactive
            [5.0, 0.5, 0.1],  # outside the x edges
            [0.5, 1.5, 0.1],  # bin (0, 1), non-finite value: left out
        ]
    )
    vals = np.array([2.0, 4.0, 7.0, 100.0, 100.0, np.nan])
    act = np.array([True, True, True, False, True, True])
    mean, count = M.plan_view_mean(x, vals, act, [0.0, 1.0, 2.0], [0.0, 1.0, 2.0])
    np.testing.assert_array_equal(count, [[2, 0], [1, 0]])
    assert mean[0, 0] == 3.0 and mean[1, 0] == 7.0
    assert np.isnan(mean[0, 1]) and np.isnan(mean[1, 1])
    mean2, _ = M.plan_view_mean(x, vals, act, [0.0, 1.0, 2.0], [0.0, 1.0, 2.0], min_count=2)
    assert mean2[0, 0] == 3.0 and np.isnan(mean2[1, 0])  # one particle < min_count
    with pytest.raises(ValueError, match="x_edges"):
        M.plan_view_mean(x, vals, act, [1.0, 0.0], [0.0, 1.0])
    with pytest.raises(ValueError, match="3D"):
        M.plan_view_mean(x[:, :2], vals, act, [0.0, 1.0], [0.0, 1.0])


def test_thickness_of_a_particle_lattice_is_its_height():
    # h = 1 m bins, spacing 0.5 m (ppc 2): a 4 x 3 m footprint, 3 layers = 1.5 m thick
    s = 0.5
    x = _lattice(1.0, 5.0, 0.0, 3.0, 0.0, 1.5, s)
    th = M.thickness_map(x, s**3, np.ones(len(x), bool), np.arange(0.0, 7.0), np.arange(0.0, 4.0))
    np.testing.assert_allclose(th[1:5], 1.5, rtol=1e-12)
    assert np.all(th[0] == 0) and np.all(th[5] == 0)
    # particles of 80 % of the volume: 1.2 m
    th2 = M.thickness_map(x, 0.8 * s**3, np.ones(len(x), bool), np.arange(0.0, 7.0), np.arange(0.0, 4.0))
    np.testing.assert_allclose(th2[1:5], 1.2, rtol=1e-12)


def test_lobe_width_threshold_and_symmetry_plane():
    s = 0.5
    ye = np.arange(-6.0, 6.5, 1.0)
    xe = np.arange(0.0, 11.0, 1.0)
    core = _lattice(0.0, 10.0, -3.0, 3.0, 0.0, 1.0, s)  # 6 m wide, 1 m (2 layers) thick
    fringe = _lattice(2.0, 4.0, 3.0, 5.0, 0.0, 0.5, s)  # one 0.5 m layer out to y = 5 m at x in 2..4
    x = np.concatenate([core, fringe])
    th = M.thickness_map(x, s**3, np.ones(len(x), bool), xe, ye)
    # threshold 0.75 m (1.5 layers): only the core counts -> 6 m in every section
    w, k, ws = M.lobe_width(th, ye, 0.75)
    assert w == 6.0 and k == 0
    np.testing.assert_array_equal(ws, 6.0)
    # threshold 0.25 m: the fringe counts; sections at x in 2..4 reach from -3 to +5 -> 8 m
    w, k, ws = M.lobe_width(th, ye, 0.25)
    assert w == 8.0 and k == 2
    np.testing.assert_array_equal(ws, [6, 6, 8, 8, 6, 6, 6, 6, 6, 6])
    # a gap inside the section still counts as width (outer edges)
    th_gap = th.copy()
    th_gap[:, 6] = 0.0
    assert M.lobe_width(th_gap, ye, 0.75)[0] == 6.0
    # half model: material from the symmetry plane y = 0 to y = 3 is a 6 m wide lobe
    half = _lattice(0.0, 10.0, 0.0, 3.0, 0.0, 1.0, s)
    ye_h = np.arange(0.0, 6.5, 1.0)
    th_h = M.thickness_map(half, s**3, np.ones(len(half), bool), xe, ye_h)
    assert M.lobe_width(th_h, ye_h, 0.75, symmetry_y_m=0.0)[0] == 6.0
    assert M.lobe_width(th_h, ye_h, 0.75)[0] == 3.0
    # nothing covered
    assert M.lobe_width(np.zeros_like(th), ye, 0.1)[:2] == (0.0, -1)
    with pytest.raises(ValueError, match="min_thickness_m"):
        M.lobe_width(th, ye, -1.0)


def test_channel_sections_contrast_cv_and_channel_flag():
    nan = np.nan
    lm = np.array(
        [
            [4.0, 4.0, 0.0, 4.0, 4.0],  # fluid lane in the middle: channel at bin 2, 4 decades
            [0.0, 4.0, 4.0, 4.0, nan],  # fluid bin at the edge: no levee on one side
            [4.0, 3.5, 3.2, 3.5, 4.0],  # 0.8 decades < 1: no channel
            [4.0, 4.0, 0.0, 4.0, 4.0],  # fluid but not faster: no channel
            [4.0, nan, nan, nan, 4.0],  # 2 occupied bins < min_bins
        ]
    )
    sp = np.array(
        [
            [0.1, 0.1, 1.0, 0.1, 0.1],
            [1.0, 0.1, 0.1, 0.1, nan],
            [0.1, 1.0, 1.0, 1.0, 0.1],
            [1.0, 1.0, 1.5, 1.0, 1.0],
            [0.1, nan, nan, nan, 0.1],
        ]
    )
    cs = M.channel_sections(lm, sp)
    np.testing.assert_array_equal(cs.channel, [True, False, False, False, False])
    np.testing.assert_array_equal(cs.channel_bin, [2, -1, -1, -1, -1])
    np.testing.assert_allclose(cs.viscosity_contrast_decades[:4], [4.0, 4.0, 0.8, 4.0], rtol=1e-12)
    assert math.isnan(cs.viscosity_contrast_decades[4])
    # speeds 0.1, 0.1, 1, 0.1, 0.1: mean 0.28, std = sqrt((4 * 0.18^2 + 0.72^2) / 5) = 0.36
    assert cs.speed_cv[0] == pytest.approx(0.36 / 0.28, rel=1e-12)
    assert cs.speed_ratio[0] == pytest.approx(10.0, rel=1e-12)
    # the edge lane of row 1 is a channel of a half model mirrored about its low-y end
    cm = M.channel_sections(lm, sp, mirror="low")
    np.testing.assert_array_equal(cm.channel, [True, True, False, False, False])
    assert cm.channel_bin[1] == 0
    # a stricter speed ratio (> 10) rejects row 0; a lower contrast (0.5) accepts row 2
    assert not M.channel_sections(lm, sp, speed_ratio=11.0).channel[0]
    c5 = M.channel_sections(lm, sp, contrast_decades=0.5)
    assert c5.channel[2] and c5.channel_bin[2] == 2  # 0.8 decades below both banks, 10x faster
    sp2 = sp.copy()
    sp2[2] = [1.0, 1.0, 1.0, 1.0, 1.0]  # the banks move as fast as the lane: not a channel
    assert not M.channel_sections(lm, sp2, contrast_decades=0.5).channel[2]
    # at rest (below min_speed) nothing is a channel
    assert not M.channel_sections(lm, sp * 1e-3).channel.any()
    with pytest.raises(ValueError, match="mirror"):
        M.channel_sections(lm, sp, mirror="left")
    with pytest.raises(ValueError, match="contrast_decades"):
        M.channel_sections(lm, sp, contrast_decades=0.0)


def _synthetic_result(cfg, frames_x, frames_v, frames_mu):
    from mpmjax._io import _jsonable

    n = frames_x[0].shape[0]
    s = cfg["domain.cell_size_m"] / cfg["numerics.ppc"]
    return {
        "attrs": {"scene_config_json": json.dumps(_jsonable(cfg))},
        "frames": {
            "t_s": np.arange(len(frames_x), dtype=float) * 10.0,
            "x_m": np.stack(frames_x),
            "v_m_s": np.stack(frames_v),
            "mu_pa_s": np.stack(frames_mu),
            "J": np.ones((len(frames_x), n)),
            "active": np.ones((len(frames_x), n), np.uint8),
        },
        "particles": {"vol0_m3": np.full(n, s**3)},
    }


# the thesis's 150 m x 50 m x 2 m box (field-pipe-3d's own box is smaller): the bins below are laid out in it
_THESIS_BOX = ["domain.lo_m=[0.0, -25.0, 0.0]", "domain.hi_m=[150.0, 25.0, 2.0]"]


def test_plan_view_summary_lobe_and_channel_of_a_synthetic_pipe_lobe(tmp_path):
    """A 6 m wide, 2 m thick lobe in the field-pipe-3d domain (h = 1 m, ppc 2) and one stray
    particle 5 m off the axis: at rest and uniform in frame 0; in frame 1 a 1 m wide lane on the
    axis (|y| < 0.5 m) at 1 Pa s and 1 m/s between banks at 1000 Pa s and 0.05 m/s."""
    from mpmjax import load_scene

    cfg = load_scene("field-pipe-3d", ["domain.cell_size_m=1.0", *_THESIS_BOX])
    x = np.concatenate([_lattice(2.0, 12.0, -3.0, 3.0, 0.0, 2.0, 0.5), [[5.25, 5.25, 0.25]]])
    lane = np.abs(x[:, 1]) < 0.5
    v0 = np.zeros_like(x)
    v1 = np.zeros_like(x)
    v1[:, 0] = np.where(lane, 1.0, 0.05)
    mu0 = np.full(len(x), 1000.0)
    mu1 = np.where(lane, 1.0, 1000.0)
    res = _synthetic_result(cfg, [x, x], [v0, v1], [mu0, mu1])
    res["frames"]["J"][:] = 3.0  # the thickness uses rest volumes: a drifted J changes nothing
    s = M.plan_view_summary(res, tmp_path / "plan_view.h5")
    # uniform 2 m thickness over y in -3..3; threshold 10 % of the thickest bin = 0.2 m; the
    # stray particle's bin (0.125 m^3 on 1 m^2: 0.125 m) is below it and does not widen the lobe
    assert s["lobe_width_threshold_m"] == pytest.approx(0.2) and not s["lobe_width_mirrored"]
    assert s["lobe_width_m_per_frame"] == [6.0, 6.0] and s["lobe_width_m"] == 6.0
    pv = s["plan_view"]
    assert pv["bin_m"] == 1.0 and pv["x_edges_m"] == [0.0, 150.0, 150] and pv["y_edges_m"] == [-25.0, 25.0, 50]
    assert pv["final_covered_area_m2"] == 60.0 and pv["final_max_thickness_m"] == pytest.approx(2.0)
    # bins y in [-1, 0) and [0, 1) each hold half lane, half bank: mean log10 mu = 1.5
    assert pv["final_log10_mu_min"] == pytest.approx(1.5) and pv["final_log10_mu_max"] == pytest.approx(3.0)
    ch = s["channels"]
    assert ch["n_channel_sections"] == [0, 10] and ch["detected"] and ch["first_time_s"] == 10.0
    assert ch["channel_x_range_m"] == [None, [2.5, 11.5]]
    assert ch["viscosity_contrast_decades_max"] == [0.0, pytest.approx(1.5)]
    # maps on disk
    d = M.read_plan_view(tmp_path)
    assert d["log10_mu"].shape == (2, 150, 50) and d["count"][1].sum() == len(x)
    np.testing.assert_allclose(d["thickness_m"][1].sum(), 120.125, rtol=1e-6)  # volume [m^3] over 1 m^2 bins
    assert d["count"][1][5, 30] == 1 and np.isnan(d["log10_mu"][1][5, 30])  # one particle < min_count 2
    assert d["attrs"]["lobe_threshold_fraction"] == 0.1


def test_plan_view_summary_half_model_mirrors_width():
    from mpmjax import load_scene

    cfg = load_scene("field-dambreak-3d", ["domain.cell_size_m=12.0"])  # y_lo is a symmetry plane
    x = _lattice(0.0, 120.0, 0.0, 60.0, 0.0, 12.0, 6.0)
    v = np.zeros_like(x)
    res = _synthetic_result(cfg, [x], [v], [np.full(len(x), 50.0)])
    s = M.plan_view_summary(res)
    assert s["lobe_width_mirrored"] and s["lobe_width_m"] == 120.0
    assert s["plan_view"]["file"] is None and not s["channels"]["detected"]


def test_3d_pictures_and_capped_animation_of_a_synthetic_run(tmp_path):
    """plan_view.png / sections.png of a synthetic two-frame 3D result, the plan map showing the
    stored bin means, and a GIF capped at 2 of 5 frames (first and last)."""
    import matplotlib

    matplotlib.use("Agg")
    from PIL import Image

    from mpmjax import load_scene, plotting

    cfg = load_scene("field-pipe-3d", ["domain.cell_size_m=1.0", *_THESIS_BOX])
    x = _lattice(2.0, 8.0, -2.0, 2.0, 0.0, 1.0, 0.5)
    v = np.zeros_like(x)
    mu = np.where(np.abs(x[:, 1]) < 0.5, 1.0, 100.0)
    res = _synthetic_result(cfg, [x] * 5, [v] * 5, [mu] * 5)
    s = M.plan_view_summary(res, tmp_path / "plan_view.h5")
    paths = plotting.plot_3d_overview(res, tmp_path, s, tmp_path)
    assert [p.name for p in paths] == ["plan_view.png", "sections.png"] and all(p.stat().st_size > 1000 for p in paths)
    ax = plotting.plan_map(tmp_path / "plan_view.h5", -1, "log10_mu")
    shown = np.ma.filled(ax.collections[0].get_array(), np.nan).reshape(50, 150)  # (ny, nx): the map transposed
    np.testing.assert_allclose(shown[23:27, 2:8], np.repeat([[2.0], [1.0], [1.0], [2.0]], 6, axis=1), rtol=1e-6)
    ax = plotting.section(res, -1, "mu", along="y", at_m=5.0, half_width_m=0.3)
    assert len(ax.collections[0].get_offsets()) == 2 * 8 * 2  # x-rows 4.75 and 5.25 (of |x - 5| <= 0.3), 8 across, 2 up
    calls = []
    gif = plotting.animate(
        res, tmp_path / "a.gif", view="plan", max_frames=2, dpi=30, progress=lambda i, _: calls.append(i)
    )
    assert Image.open(gif).n_frames == 2 and calls == [0, 1]
    with pytest.raises(ValueError, match="max_frames"):
        plotting.animate(res, tmp_path / "b.gif", max_frames=0)
