"""Input the loader used to accept silently, and the user surface (issue 17, items 3, 4, 6, 10,
11, 12).  Each item has a direct test and, for items 3 and 4, a hypothesis property.

* 3: overlapping bodies are seeded as their union (two boxes overlapping by half used to hold
  148 kg/m where their union holds 111);
* 4: refused with exit 2, naming key, value and range: Coussot mu_max < mu0, an explicit NaN for
  a derived default, a 3D-only key in 2D, a material key the law does not read, calibration data
  whose x lies outside the domain;
* 6: messages print plain numbers; ``scenes --keys`` prints (required) unquoted;
* 10: the progress estimate excludes compilation;
* 11: a float64 run is stored in float64;
* 12: ``mpmjax stress`` exits 3 when a case fails (docs/performance.md, README).
"""

from __future__ import annotations

import copy
import io
import math
import re
import time
import tomllib
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import mpmjax
from mpmjax import _bodies, _rheology, builtin_scenes, cli
from mpmjax._build import seed_bodies
from mpmjax._driver import Progress
from mpmjax._schema import SCHEMA, _NAN_DEFAULT

ROOT = Path(__file__).resolve().parent.parent
TWIN = str(ROOT / "data" / "twin-small-dambreak.toml")
BASE = tomllib.loads(builtin_scenes()["dambreak-lab"].read_text())
PROP = settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))
NUMPY_REPR = re.compile(r"np\.\w+\(|array\(")


def small(dim=2, **material):
    raw = copy.deepcopy(BASE)
    raw["time"] = {"t_end_s": 0.05, "n_frames": 2}
    if dim == 2:
        raw["domain"] = {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [0.4, 0.12], "cell_size_m": 0.04}
        raw["bodies"] = [{"type": "box", "lo_m": [0.0, 0.0], "hi_m": [0.12, 0.08]}]
    else:
        raw["domain"] = {"dim": 3, "lo_m": [0.0] * 3, "hi_m": [0.2, 0.08, 0.08], "cell_size_m": 0.04}
        raw["bodies"] = [{"type": "box", "lo_m": [0.0] * 3, "hi_m": [0.08] * 3}]
        raw["boundary"].update(z_lo="noslip", z_hi="slip")
    raw["material"].update(material)
    return raw


def refused(raw) -> str:
    with pytest.raises(mpmjax.SceneError) as e:
        mpmjax.validate(raw)
    msg = str(e.value)
    assert not NUMPY_REPR.search(msg), msg
    return msg


# ------------------------------------------------------------------ item 3: union of bodies


def test_two_overlapping_boxes_hold_the_mass_of_their_union():
    """The issue's case: two 0.2 m boxes overlapping by half hold 0.06 m^2 x 1850 kg/m^3 = 111 kg/m
    (they held 148 = 2 x 74).  Aligned lattices: the overlap's particles of the second box are
    exactly those dropped, so the union's mass is exact to rounding."""
    cfg = mpmjax.load_scene(
        "dambreak-lab",
        ['bodies=[{type = "box", lo_m = [0.0, 0.0], hi_m = [0.2, 0.2]}, '
         '{type = "box", lo_m = [0.1, 0.0], hi_m = [0.3, 0.2]}]'],
    )  # fmt: skip
    setup = mpmjax.build(cfg)
    mass = float(np.sum(np.asarray(setup.state.vol0, float))) * cfg["material.density_kg_m3"]
    assert mass == pytest.approx(0.06 * 1850.0, rel=1e-6)  # float32 volumes
    x = np.asarray(setup.state.x, float)
    assert len(np.unique(np.round(x / 1e-6), axis=0)) == len(x)  # no particle seeded twice
    assert setup.scene.n_particles == 3600 + 1800  # ppc 3: (0.2 / (0.01 / 3))^2 + the half not overlapped


def test_builtin_scenes_particle_counts_are_unchanged():
    """No built-in scene has overlapping bodies: each seeds the sum of its bodies' lattices."""
    for name in builtin_scenes():
        cfg = mpmjax.load_scene(name)
        dx = cfg["domain.cell_size_m"] / cfg["numerics.ppc"]
        want = sum(
            int(np.prod(np.maximum(np.round((np.asarray(b["hi_m"]) - np.asarray(b["lo_m"])) / dx), 1)))
            if _bodies.kind(b) == "box"
            else len(_bodies.lattice(cfg, b))  # a shaped body: its lattice points (mpmjax._bodies)
            for b in cfg["bodies"]
        )
        assert len(seed_bodies(cfg)[0]) == want, name


@st.composite
def lattice_boxes(draw):
    """1-4 boxes in a 2D or 3D domain, corners on the particle lattice (dx = 0.02 m)."""
    dim = draw(st.sampled_from([2, 3]))
    n = 10 if dim == 2 else 6  # lattice points per axis
    boxes = []
    for _ in range(draw(st.integers(1, 4))):
        lo = [draw(st.integers(0, n - 1)) for _ in range(dim)]
        hi = [a + draw(st.integers(1, n - a)) for a in lo]
        boxes.append((lo, hi))
    return dim, n, boxes


@PROP
@given(lattice_boxes())
def test_property_seeded_volume_is_the_union_volume(case):
    """For boxes on the particle lattice the seeded volume equals the union's volume (counted on
    the lattice), every particle lies in some box, none twice, and each keeps its own box's
    particle volume."""
    dim, n, boxes = case
    dx = 0.02
    raw = small(dim)
    raw["domain"]["hi_m"] = [n * dx] * dim
    raw["domain"]["cell_size_m"] = 2 * dx
    raw["numerics"] = {"ppc": 2}  # the lattice spacing dx is half a cell
    raw["bodies"] = [{"type": "box", "lo_m": [a * dx for a in lo], "hi_m": [b * dx for b in hi]} for lo, hi in boxes]
    cfg = mpmjax.validate(raw)
    x, vol, _ = seed_bodies(cfg)
    cover = np.zeros((n,) * dim, bool)
    for lo, hi in boxes:
        cover[tuple(slice(a, b) for a, b in zip(lo, hi))] = True
    assert float(np.sum(vol)) == pytest.approx(cover.sum() * dx**dim, rel=1e-9)
    assert len(np.unique(np.round(x / dx - 0.5).astype(int), axis=0)) == len(x)
    assert np.all(vol == pytest.approx(dx**dim, rel=1e-9))


# ------------------------------------------------------------------ item 4: silent acceptance


def test_mu_max_below_mu0_is_refused():
    msg = refused(small(mu_max_pa_s=3.0, mu0_pa_s=5.0))
    assert msg.startswith("material.mu_max_pa_s = 3.0 is invalid with material.mu0_pa_s = 5.0: allowed range: >="), msg
    mpmjax.validate(small(mu_max_pa_s=5.0, mu0_pa_s=5.0))  # equal: the cap binds at rest only


@PROP
@given(st.floats(1e-3, 1e4), st.floats(1e-3, 1e4))
def test_property_coussot_cap_order(mu0, mu_max):
    raw = small(mu0_pa_s=mu0, mu_max_pa_s=mu_max)
    if mu_max < mu0:
        msg = refused(raw)
        assert "material.mu_max_pa_s" in msg and "material.mu0_pa_s" in msg
    else:
        mpmjax.validate(raw)


@pytest.mark.parametrize("key", _NAN_DEFAULT)
def test_explicit_nan_for_a_derived_default_is_refused(key):
    for text in ("nan", "-nan", "+nan"):
        with pytest.raises(mpmjax.SceneError, match=rf"^{re.escape(key)} = nan is invalid: must be finite"):
            mpmjax.load_scene("dambreak-lab", [f"{key}={text}"])
    assert math.isnan(mpmjax.load_scene("dambreak-lab")[key])  # the default stays "derived"


@PROP
@given(st.sampled_from(_NAN_DEFAULT), st.sampled_from([math.nan, -math.nan, math.inf, -math.inf]))
def test_property_non_finite_derived_keys_are_refused(key, val):
    raw = small()
    sec, k = key.split(".")
    raw.setdefault(sec, {})[k] = val
    assert key in refused(raw)


ONLY_3D = [k for k, s in SCHEMA.items() if s.only_3d]


def test_3d_only_keys_are_refused_in_2d():
    assert set(ONLY_3D) == {"boundary.z_lo", "boundary.z_hi", "gravity.transverse_slope_deg"}
    raw = small()
    raw["gravity"]["transverse_slope_deg"] = 5.0
    msg = refused(raw)
    assert msg.startswith("gravity.transverse_slope_deg = 5.0 is invalid in a 2D scene (domain.dim = 2)"), msg
    raw = small(3)
    raw["gravity"]["transverse_slope_deg"] = 5.0
    assert mpmjax.validate(raw)["gravity.transverse_slope_deg"] == 5.0


@PROP
@given(st.sampled_from(ONLY_3D), st.sampled_from([2, 3]))
def test_property_3d_only_keys(key, dim):
    raw = small(dim)
    sec, k = key.split(".")
    raw.setdefault(sec, {})[k] = 0.0 if SCHEMA[key].type is float else SCHEMA[key].default
    if dim == 2:
        msg = refused(raw)
        assert key in msg and "domain.dim" in msg
    else:
        mpmjax.validate(raw)


MATERIAL_KEYS = sorted(k for k in SCHEMA if k.startswith("material.") and k != "material.model")


def _law_keys(model):
    law = _rheology.MODELS[model]
    return {d.key for d in law.params + law.options} | {"material.shear_measure"}


def test_a_key_the_law_does_not_read_is_refused():
    msg = refused(small(viscosity_pa_s=2.0))  # Newtonian / Bingham viscosity in a Coussot scene
    assert msg.startswith("material.viscosity_pa_s = 2.0 is invalid with material.model = 'coussot'"), msg
    assert "material.mu0_pa_s" in msg and "bingham" in msg  # what is allowed, and whose key it is


@PROP
@given(st.sampled_from(sorted(_rheology.MODELS)), st.sampled_from(MATERIAL_KEYS))
def test_property_material_keys_belong_to_the_law(model, key):
    raw = small()
    raw["material"] = {"model": model, "density_kg_m3": 1850.0, "bulk_modulus_pa": 15000.0}
    spec = SCHEMA[key]
    val = spec.choices[0] if spec.choices else (spec.default if isinstance(spec.default, float) else 1.0)
    raw["material"][key.split(".", 1)[1]] = val
    if key in _law_keys(model):
        mpmjax.validate(raw)
    else:
        msg = refused(raw)
        assert key in msg and "material.model" in msg


def test_switching_the_law_with_set_drops_the_files_old_law_keys():
    """dambreak-lab is Coussot; --set material.model=newtonian drops its Coussot keys (they
    described the old law), while a --set key the new law does not read is still refused."""
    cfg = mpmjax.load_scene("dambreak-lab", ["material.model=newtonian", "material.viscosity_pa_s=4.0"])
    assert cfg["material.model"] == "newtonian" and cfg["material.mu0_pa_s"] == SCHEMA["material.mu0_pa_s"].default
    with pytest.raises(mpmjax.SceneError, match="material.alpha = 2.0 is invalid with material.model = 'newtonian'"):
        mpmjax.load_scene("dambreak-lab", ["material.model=newtonian", "material.alpha=2.0"])


def _profile_csv(path, xs):
    path.write_text("x_m,h_m\n" + "".join(f"{x!r},0.01\n" for x in xs))
    return path


def test_calibration_data_outside_the_domain_exits_2(tmp_path, capsys):
    data = _profile_csv(tmp_path / "p.csv", [0.1, 0.5, 2.5])  # the twin's domain: 0 .. 0.9 m
    rc = cli.main(["calibrate", str(data), "--scene", TWIN, "--fit", "mu0", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "x_m = 2.5 (station 3 of the final profile; 1 station(s) outside) lies outside the scene's domain" in err
    assert "allowed range: 0 .. 0.9 m" in err and "Traceback" not in err


@PROP
@given(st.lists(st.floats(-0.5, 1.5), min_size=2, max_size=6, unique=True).map(sorted))
def test_property_calibration_x_within_the_domain(xs):
    from calibration.data import Profile
    from calibration.experiments import ProfileExperiment

    setup = _twin_setup()
    lo, hi = setup.scene.lo[0], setup.scene.hi[0]
    prof = Profile(np.asarray(xs), np.full(len(xs), 0.01), None)
    if all(lo <= x <= hi for x in xs):
        ProfileExperiment(setup, [prof])
    else:
        with pytest.raises(ValueError, match=r"x_m = .* lies outside the scene's domain: allowed range"):
            ProfileExperiment(setup, [prof])


_TWIN_SETUP = []


def _twin_setup():
    if not _TWIN_SETUP:
        _TWIN_SETUP.append(mpmjax.build(mpmjax.load_scene(TWIN, ["domain.cell_size_m=0.05", "time.n_frames=3"])))
    return _TWIN_SETUP[0]


# ------------------------------------------------------------------ item 6: plain numbers


def test_messages_print_plain_numbers():
    raw = small()
    raw["bodies"] = [{"type": "box", "lo_m": [0.0, 0.0], "hi_m": [0.12, 0.5]}]  # numpy arrays inside
    msg = refused(raw)
    assert "[0.12, 0.5]" in msg, msg
    raw = small()
    raw["bodies"] = [{"type": "box", "lo_m": [0.1, 0.0], "hi_m": [0.05, 0.08]}]
    assert "hi_m = [0.05, 0.08] must exceed lo_m = [0.1, 0.0]" in refused(raw)


def test_scenes_keys_prints_required_unquoted(capsys):
    assert cli.main(["scenes", "--keys"]) == 0
    out = capsys.readouterr().out
    assert "default=(required)" in out and "'(required)'" not in out
    assert "default='gimp'" in out and not NUMPY_REPR.search(out)
    # a key with no default value says what it is, as docs/scenes.md does: optional (None) or worked out (NaN)
    assert "default=None" not in out and "default=nan" not in out
    line = next(ln for ln in out.splitlines() if ln.startswith("material.bulk_modulus_pa "))
    assert "default=(none)" in line
    line = next(ln for ln in out.splitlines() if ln.startswith("output.runout_origin_m "))
    assert "default=(derived)" in line


# ------------------------------------------------------------------ item 10: progress estimate


class _Stream(io.StringIO):
    def isatty(self):
        return False


def test_progress_estimate_excludes_compilation():
    """A bar created before a 0.5 s "compilation": update(0) restarts its clock, so after 5 of
    10 frames of 0.02 s the time left is ~0.1 s, not ~0.6 s (0.5 s of compilation / 5 x 5)."""
    s = _Stream()
    bar = Progress(10, "run", s)
    time.sleep(0.5)
    bar.update(0)
    for k in range(1, 6):
        time.sleep(0.02)
        bar.update(k)
    left = float(re.findall(r"left ~\s*([\d.]+) s", s.getvalue())[-1])
    assert left < 0.35, s.getvalue()  # 0.1 s plus scheduling noise on a loaded machine


# ------------------------------------------------------------------ item 11: float64 stored


def test_float64_run_is_stored_in_float64(tmp_path):
    mpmjax.run_scene(
        "dambreak-lab",
        tmp_path / "r",
        ["domain.cell_size_m=0.04", "time.t_end_s=0.1", "time.n_frames=1", "numerics.dtype=float64"],
        quiet=True,
    )
    with h5py.File(tmp_path / "r" / "result.h5") as f:
        assert f.attrs["dtype"] == "float64"
        for name in ("x_m", "v_m_s", "J", "mu_pa_s", "lambda"):
            assert f["frames"][name].dtype == np.float64, name
        assert f["frames/active"].dtype == np.uint8


# ------------------------------------------------------------------ item 12: stress exit status


def test_stress_exits_3_when_a_case_fails(tmp_path, capsys):
    """drop-1m fails the volume bound at both sizes (docs/performance.md): exit 3 and a line
    naming it; README and docs/performance.md say so."""
    assert cli.main(["stress", "--case", "drop-1m", "--out", str(tmp_path / "s.json")]) == 3
    assert "1 of 1 case(s) failed a criterion: drop-1m" in capsys.readouterr().err
    readme = (ROOT / "README.md").read_text()
    perf = (ROOT / "docs" / "performance.md").read_text()
    assert "exits 3" in readme and "exits 3" in perf and "1 when one fails" not in perf


def test_a_release_region_with_an_integer_too_large_for_a_float_is_refused_by_name():
    # TOML integers are unbounded; math.isfinite raised OverflowError on one (found by test_fuzz_garbage_scenes)
    from mpmjax._release import region_error

    assert "finite" in region_error([0, 0, 0, 10**400], 3)
    assert "finite" in region_error([0, 10**400], 2)
    assert "finite" in region_error([[0, 0], [1, 0], [10**400, 1]], 3)
    assert region_error([0.0, 0.0, 1.0, 1.0], 3) is None
