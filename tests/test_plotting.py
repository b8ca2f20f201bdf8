"""mpmjax.plotting on a coarse dam break run once through the CLI runner (``mpmjax.run_scene``).

The checks compare what is drawn with what is stored in result.h5: one scatter point per
active particle at its stored position, colour values equal to the stored field, profiles
equal to ``mpmjax._metrics.surface_profile``, the runout curve equal to summary.json's
``runout_m``, one GIF image per saved frame, and labelled axes with units."""

import json

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from PIL import Image  # noqa: E402

from calibration.data import Profile  # noqa: E402
from mpmjax import _metrics, plotting, run_scene  # noqa: E402
from mpmjax._io import read_result  # noqa: E402

# 2 m x 0.24 m; 0.2 m BASE Coussot block at 2 cm cells (400 particles); 0.5 s of the collapse, 5 frames
OVERRIDES = ["domain.cell_size_m=0.02", "time.t_end_s=0.5", "time.n_frames=5", "numerics.ppc=2"]  # figures measured at ppc 2


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("plot")
    summary = run_scene("dambreak-lab", out, OVERRIDES, quiet=True)
    return out, summary, read_result(out / "result.h5")


@pytest.fixture(autouse=True)
def _close():
    yield
    plt.close("all")


def _colorbar_label(ax):
    cbs = [a for a in ax.figure.axes if a is not ax]
    assert len(cbs) == 1
    return cbs[0].get_ylabel()


@pytest.mark.parametrize("field", ["mu", "lambda", "J", "speed"])
def test_particles_scatter_is_the_stored_field(run, field):
    out, _, res = run
    fr = res["frames"]
    k = 3
    # hide a third of the particles: only active ones may be drawn
    res = {**res, "frames": {**fr, "active": fr["active"].copy()}}
    res["frames"]["active"][k, ::3] = 0
    act = res["frames"]["active"][k].astype(bool)
    ax = plotting.particles(res, k, field)
    sc = ax.collections[0]
    assert sc.get_offsets().shape == (int(act.sum()), 2) and act.sum() < act.size
    np.testing.assert_array_equal(np.asarray(sc.get_offsets()), fr["x_m"][k][act])
    stored = {
        "mu": fr["mu_pa_s"][k],
        "lambda": fr["lambda"][k],
        "J": fr["J"][k],
        "speed": np.linalg.norm(fr["v_m_s"][k].astype(float), axis=-1),
    }[field][act]
    np.testing.assert_allclose(np.asarray(sc.get_array()), stored, rtol=1e-6)
    assert ax.get_xlabel() == "x [m]" and ax.get_ylabel() == "y [m]"
    unit = {"mu": "[Pa·s]", "lambda": "[-]", "J": "[-]", "speed": "[m/s]"}[field]
    assert _colorbar_label(ax).endswith(unit)
    # mu on a log colour scale spanning the frame's values
    if field == "mu":
        assert isinstance(sc.norm, matplotlib.colors.LogNorm)
        assert sc.norm.vmin == pytest.approx(stored.min()) and sc.norm.vmax == pytest.approx(stored.max())
    # a path to the run folder reads the same data
    ax2 = plotting.particles(out, k, field)
    assert ax2.collections[0].get_offsets().shape[0] == act.size


def test_unknown_field_and_frame_are_named(run):
    _, _, res = run
    with pytest.raises(ValueError, match="allowed: mu, lambda, speed, vx, vz, J, displacement"):
        plotting.particles(res, 0, "viscosity")
    with pytest.raises(ValueError, match="allowed range -6..5"):
        plotting.particles(res, 6, "mu")
    bingham = {**res, "frames": {k: v for k, v in res["frames"].items() if k != "lambda"}}
    with pytest.raises(ValueError, match=r"Coussot scenes only\); allowed: mu, speed"):
        plotting.particles(bingham, 0, "lambda")
    with pytest.raises(ValueError, match="allowed: mu, lambda"):
        plotting.animate(res, "x.gif", field="tau")
    with pytest.raises(ValueError, match="'plan' needs a 3D result"):
        plotting.particles(res, 0, "mu", view="plan")


def test_runout_vs_time_matches_summary(run):
    _, summary, res = run
    ax = plotting.runout_vs_time(res)
    t, front = ax.lines[0].get_data()
    np.testing.assert_allclose(t, summary["times_s"], rtol=1e-6)
    np.testing.assert_allclose(front, summary["runout_m"], rtol=1e-6)
    # the 0.2 m block's edge reads 1.28 kernel bandwidths (one 0.02 m cell) beyond 0.2 m
    # (tests/test_runout_front.py) and the front only advances
    assert front[0] == pytest.approx(0.2 + 1.2816 * 0.02, abs=0.002) and np.all(np.diff(front) > 0)
    _, far = plotting.runout(res, farthest=True)
    np.testing.assert_allclose(far, summary["runout_farthest_particle_m"], rtol=1e-6)
    assert far[0] == pytest.approx(0.2, abs=1e-6)
    assert ax.get_xlabel() == "time t [s]" and ax.get_ylabel() == "runout [m]"


def test_profiles_with_measured_data(run, tmp_path):
    _, summary, res = run
    data = [
        Profile(np.array([0.05, 0.15, 0.25]), np.array([0.2, 0.2, 0.0]), t_s=0.0),
        Profile(np.array([0.1, 0.3, 0.5]), np.array([0.08, 0.05, 0.02]), t_s=0.5, sigma_m=np.full(3, 0.01)),
    ]
    ax = plotting.profiles(res, data=data)  # times taken from the data: 0 s and 0.5 s
    assert ax.get_xlabel() == "x [m]" and ax.get_ylabel() == "surface elevation [m]"
    model = [ln for ln in ax.lines if ln.get_label().startswith("model")]
    assert [ln.get_label() for ln in model] == ["model t = 0 s", "model t = 0.5 s"]
    # the last frame's line is summary.json's final surface profile (same _metrics.surface_profile)
    xc, hc = model[1].get_data()
    np.testing.assert_allclose(xc, summary["surface_profile_x_m"], atol=1e-9)
    z = np.array([np.nan if v is None else v for v in summary["surface_profile_z_m"]])
    np.testing.assert_allclose(hc, z, rtol=1e-6, equal_nan=True)
    # initial block: 0.2 m high over its 0.2 m width (top particle + half a spacing), empty beyond
    x0, h0 = model[0].get_data()
    assert np.allclose(h0[x0 < 0.2], 0.2, atol=1e-6) and np.all(np.isnan(h0[x0 > 0.2]))
    # measured points drawn: plain markers at t = 0, error bars (3 points) at 0.5 s
    assert any(np.array_equal(ln.get_xdata(), [0.05, 0.15, 0.25]) for ln in ax.lines)
    assert len(ax.containers) == 1
    # kernel method: the line is mpmjax.height_profile on 201 stations, bandwidth h
    axk = plotting.profiles(res, [0.5], (np.array([0.1, 0.3]), np.array([0.05, 0.03])), method="kernel")
    xk, hk = axk.lines[0].get_data()
    np.testing.assert_allclose(hk, plotting.profile_at(res, -1, method="kernel")[1])
    assert axk.get_ylabel() == "height h [m]"
    # with stations past the x = 0 wall it integrates to the released area, 0.2 m x 0.2 m per metre
    xw, hw = plotting.profile_at(res, -1, method="kernel", x_m=np.linspace(-0.2, 2.2, 2401))
    assert np.trapezoid(hw, xw) == pytest.approx(0.04, rel=1e-4)
    with pytest.raises(ValueError, match="outside the saved frames; allowed range 0..0.5 s"):
        plotting.profiles(res, [2.0])
    with pytest.raises(ValueError, match="allowed: 'surface', 'kernel'"):
        plotting.profiles(res, [0.5], method="max")
    with pytest.raises(ValueError, match=r"data\[0\]: x_m has shape \(2,\) and h_m \(3,\)"):
        plotting.profiles(res, [0.5], [(np.zeros(2), np.zeros(3))])
    # the elevation helper is _metrics.surface_profile on the run's cell-wide bins
    edges = np.arange(0.0, 2.0 + 0.01, 0.02)
    act = res["frames"]["active"][-1].astype(bool)
    ref = _metrics.surface_profile(res["frames"]["x_m"][-1], act, edges, 0.01)
    np.testing.assert_allclose(plotting.profile_at(res, -1)[1], ref[1], equal_nan=True)


def test_animate_writes_one_image_per_frame(run, tmp_path):
    _, _, res = run
    path = plotting.animate(res, tmp_path / "run.gif", field="speed", fps=4)
    with Image.open(path) as im:
        assert im.n_frames == res["frames"]["t_s"].shape[0] == 6
        assert im.info.get("duration") == pytest.approx(250, abs=10)  # 4 frames per second [ms]
    path = plotting.animate(res, tmp_path / "sub" / "two.gif", field="lambda", frames=[0, -1])
    with Image.open(path) as im:
        assert im.n_frames == 2
    assert not list(tmp_path.glob("**/*.tmp.gif"))
    with pytest.raises(ValueError, match="expected a .gif"):
        plotting.animate(res, tmp_path / "run.mp4")


def _result_3d():
    """A hand-made 3D result (2 frames, 8 particles of a 0.2 m cube on 0.1 m spacing), as read_result gives it."""
    cfg = {
        "name": "cube-3d",
        "domain.dim": 3,
        "domain.lo_m": [0.0, 0.0, 0.0],
        "domain.hi_m": [1.0, 0.4, 0.4],
        "domain.cell_size_m": 0.2,
        "numerics.ppc": 2,
        "bodies": [{"type": "box", "lo_m": [0.1, 0.0, 0.0], "hi_m": [0.3, 0.2, 0.2]}],
        "inflow.point_m": None,
        "output.runout_axis": 0,
        "output.runout_origin_m": None,
    }
    g = np.arange(2) * 0.1 + 0.05
    x0 = np.stack(np.meshgrid(g + 0.1, g, g, indexing="ij"), -1).reshape(-1, 3)
    x1 = x0 + np.array([0.25, 0.0, -0.01]) * (x0[:, 2:] < 0.1)  # the bottom layer slides 0.25 m
    v = np.zeros((2, 8, 3))
    v[1, :, 2] = -0.1
    frames = {
        "t_s": np.array([0.0, 1.0]),
        "x_m": np.stack([x0, x1]).astype("f4"),
        "v_m_s": v.astype("f4"),
        "J": np.ones((2, 8), "f4"),
        "mu_pa_s": np.full((2, 8), 4.0, "f4"),
        "active": np.ones((2, 8), "u1"),
    }
    attrs = {"scene_config_json": json.dumps(cfg), "dim": 3}
    return {"attrs": attrs, "frames": frames, "particles": {"vol0_m3": np.full(8, 1e-3)}}


def test_3d_views_and_runout():
    res = _result_3d()
    x1 = res["frames"]["x_m"][1]
    side = plotting.particles(res, 1, "vz")
    np.testing.assert_array_equal(np.asarray(side.collections[0].get_offsets()), x1[:, [0, 2]])
    assert (side.get_xlabel(), side.get_ylabel()) == ("x [m]", "z [m]")
    assert _colorbar_label(side) == "vertical velocity v_z [m/s]"
    np.testing.assert_allclose(np.asarray(side.collections[0].get_array()), -0.1, rtol=1e-6)
    plan = plotting.particles(res, 1, "displacement", view="plan")
    np.testing.assert_array_equal(np.asarray(plan.collections[0].get_offsets()), x1[:, :2])
    assert (plan.get_xlabel(), plan.get_ylabel()) == ("x [m]", "y [m]")
    # the bottom layer moved by |(0.25, 0, -0.01)| m, the top layer not at all
    d = np.sort(np.asarray(plan.collections[0].get_array()))
    np.testing.assert_allclose(d, [0, 0, 0, 0] + [np.hypot(0.25, 0.01)] * 4, atol=1e-6)
    # farthest-particle runout from the back of the body (x = 0.1 m): the last particle at 0.25
    # (+0.25) plus half of 0.1 m
    t, far = plotting.runout(res, farthest=True)
    np.testing.assert_allclose(far, [0.25 + 0.05 - 0.1, 0.5 + 0.05 - 0.1], atol=1e-6)
    # free-surface front on 0.2 m plan bins: frame 0 thicknesses 0.1, 0.1, 0 ... m, the threshold
    # 10 % of 0.1 m is crossed 0.9 of a bin past the last full bin's centre (0.3 m): 0.48 m; frame 1
    # (bottom layer in the bin at 0.4-0.6 m): 0.05, 0.05, 0.1, 0 ... m: 0.5 + 0.18 = 0.68 m
    t, front = plotting.runout(res)
    np.testing.assert_allclose(front, [0.48 - 0.1, 0.68 - 0.1], atol=1e-6)
    with pytest.raises(ValueError, match="for 2D results; this one is 3D"):
        plotting.profiles(res, method="kernel")
    with pytest.raises(ValueError, match="allowed: 'side', 'plan'"):
        plotting.particles(res, 0, "mu", view="top")


# --- result.png: the one-page report (issue 17 item 8) ---------------------------------------


def _panels(fig, label):
    return [a for a in fig.axes if a.get_label() == label]


def test_result_report_panels(run):
    out, summary, res = run
    assert (out / "result.png").stat().st_size > 20_000
    assert isinstance(summary["warnings"], list)
    fig = plotting.result_figure(res, summary, "lab")
    fr = res["frames"]
    # 0.5 s run: the ~1 s and ~5 s snapshots fall after the end, so one viscosity side view (the end)
    (side,) = _panels(fig, "side")
    act = fr["active"][-1].astype(bool)
    np.testing.assert_array_equal(np.asarray(side.collections[0].get_offsets()), fr["x_m"][-1][act])
    # Coussot: λ of the last frame on its own panel, the stored values
    (lam,) = _panels(fig, "lambda")
    np.testing.assert_allclose(np.asarray(lam.collections[0].get_array()), fr["lambda"][-1][act], rtol=1e-6)
    # thickness profiles: kernel height profiles (rest volumes, bandwidth one cell) at several
    # times in time order; on stations reaching 4 bandwidths past both walls each integrates to
    # the released area 0.2 m x 0.2 m (the Gaussian's mass beyond 4 bandwidths is 3e-5; volumes
    # are float32: 1e-3 is generous), and matches mpmjax.height_profile via profile_at
    (prof,) = _panels(fig, "profiles")
    curves = [ln for ln in prof.lines if ln.get_label().startswith("t = ")]
    assert len(curves) >= 3 and curves[0].get_label() == "t = 0 s" and curves[-1].get_label() == "t = 0.5 s"
    for ln in curves:
        xp, hp = (np.asarray(a, float) for a in ln.get_data())
        assert xp[0] <= -0.08 + 1e-9 and xp[-1] >= 2.08 - 1e-9
        assert np.trapezoid(hp, xp) == pytest.approx(0.04, rel=1e-3)
    xk, hk = plotting.profile_at(res, -1, method="kernel", x_m=np.asarray(curves[-1].get_xdata()))
    np.testing.assert_allclose(curves[-1].get_ydata(), hk, rtol=1e-4, atol=1e-7)
    assert prof.get_ylabel() == "thickness [m]" and prof.get_xlabel() == "x [m]"
    # runout against time: summary.json's series, the final value written on the panel
    (axr,) = _panels(fig, "runout")
    t, front = axr.lines[0].get_data()
    np.testing.assert_allclose(front, summary["runout_m"])
    assert f"final {summary['final_runout_m']:.3f} m" in [x.get_text() for x in axr.texts]
    assert f"final runout {summary['final_runout_m']:.3f} m" in axr.get_title(loc="left")
    assert "domain wall at 2 m" in axr.get_title(loc="left")
    assert axr.yaxis.get_major_formatter().get_useOffset() is False
    # the viscosity colour bar says how its range was chosen
    assert any("log scale" in a.get_ylabel() and "at the top" in a.get_ylabel() for a in fig.axes)
    # a Bingham result (no lambda dataset) has no λ panel
    bingham = {**res, "frames": {k: v for k, v in fr.items() if k != "lambda"}}
    assert not _panels(plotting.result_figure(bingham, summary), "lambda")
    # warnings are on the page
    fig = plotting.result_figure(res, {**summary, "warnings": ["bodies[0] is thin", "another"]})
    (axw,) = _panels(fig, "warnings")
    assert "2 warning(s)" in axw.texts[0].get_text() and "bodies[0] is thin" in axw.texts[0].get_text()


def test_viscosity_norm_keeps_contrast_when_most_material_is_at_mu_max():
    rng = np.random.default_rng(0)
    # 95 % at mu_max = 5000 Pa s, 5 % flowing between 0.1 and 1000 Pa s, one stray particle at 1e-6
    mu = np.concatenate([np.full(1900, 5000.0), 10 ** rng.uniform(-1, 3, 100), [1e-6]])
    norm, note = plotting.viscosity_norm(mu)
    assert norm.vmax == pytest.approx(5000.0)
    # the flowing material's 4 decades are shown (the 2nd percentile of the 100 flowing values)...
    assert np.log10(norm.vmax / norm.vmin) >= 4.0 and norm.vmin < 0.2
    # ... but not the stray particle's 9 (a min-max scale would spend 9.7 decades on it)
    assert norm.vmin > 1e-3
    assert "95 % at the top" in note and "below the range" in note
    # everything at mu_max: one decade below it
    norm, note = plotting.viscosity_norm(np.full(50, 5000.0))
    assert np.log10(norm.vmax / norm.vmin) == pytest.approx(1.0) and "100 % at the top" in note
    # a narrow spread is widened to one decade, without clipping anything
    norm, note = plotting.viscosity_norm(np.array([100.0, 150.0, 200.0]))
    assert np.log10(norm.vmax / norm.vmin) == pytest.approx(1.0) and "below" not in note


def test_result_report_3d_side_view_and_plan_thickness():
    res = _result_3d()
    summary = {"times_s": [0.0, 1.0], "runout_m": [0.38, 0.58], "final_runout_m": 0.58, "runout_wall_m": 0.9}
    fig = plotting.result_figure(res, summary)
    (side,) = _panels(fig, "side")
    x1 = res["frames"]["x_m"][1]
    np.testing.assert_array_equal(np.asarray(side.collections[0].get_offsets()), x1[:, [0, 2]])
    assert side.get_ylabel() == "z [m]" and not _panels(fig, "lambda")
    # thickness per 0.2 m bin along x, largest across y: frame 0 holds 0.1 m in the bins at
    # 0.1-0.3 m (x centre 0.2 m; edges at 0, 0.2, ..: bins 0 and 1 take 4 particles each)
    (prof,) = _panels(fig, "profiles")
    curves = [ln for ln in prof.lines if ln.get_label().startswith("t = ")]
    xc, h0 = (np.asarray(a) for a in curves[0].get_data())
    np.testing.assert_allclose(xc, [0.1, 0.3, 0.5, 0.7, 0.9])
    np.testing.assert_allclose(h0, [0.1, 0.1, 0, 0, 0], atol=1e-9)
    _, h1 = curves[-1].get_data()
    np.testing.assert_allclose(h1, [0.05, 0.05, 0.1, 0, 0], atol=1e-9)
