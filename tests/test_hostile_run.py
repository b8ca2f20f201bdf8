"""Hostile input to ``mpmjax run`` (issue 35): ``--out ""``, a 10,000-digit scene value, and a
``--resume`` checkpoint that does not fit its scene (damaged metadata, a negative frame, arrays of
another shape).  Each is exit status 2 with one line naming the culprit, found before anything is
compiled; the checkpoint is left as it was.  One interrupted coarse run (h = 6 cm, 3 frames) gives
the checkpoint that is damaged in turn."""

from __future__ import annotations

import json
import shutil
import tomllib
from pathlib import Path

import h5py
import numpy as np
import pytest

import mpmjax
from mpmjax import cli
from mpmjax._build import start_warnings

SMALL = ["domain.cell_size_m=0.04", "time.t_end_s=0.3", "time.n_frames=3", "numerics.pressure=explicit"]
SETS = [a for s in SMALL for a in ("--set", s)]


def _refused(capsys, argv, *words) -> str:
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, (w, err)
    return err


def test_empty_out_is_refused_not_the_default_folder(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _refused(capsys, ["run", "dambreak-lab", "--out", "", *SETS], "--out ''", "empty")
    assert list(tmp_path.iterdir()) == []  # runs/dambreak-lab not created


@pytest.mark.parametrize("key", ["time.n_frames", "numerics.ppc"])
def test_a_10000_digit_integer_names_its_key(capsys, tmp_path, key):
    err = _refused(capsys, ["run", "--out", str(tmp_path / "o"), "--set", f"{key}={'9' * 10000}"], key)
    assert len(err) < 600  # the value is shortened, not printed whole


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """A run interrupted after its first frame: OUT/checkpoint.h5 at frame 1."""
    out = tmp_path_factory.mktemp("interrupted") / "r"

    def stop(i, st):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        mpmjax.run_scene("dambreak-lab", out, SMALL, quiet=True, on_frame=stop)
    assert (out / "checkpoint.h5").is_file()
    return out


def _damage(src: Path, dst: Path, how) -> bytes:
    shutil.copytree(src, dst)
    with h5py.File(dst / "checkpoint.h5", "r+") as f:
        how(f)
    return (dst / "checkpoint.h5").read_bytes()


def _meta(f):
    f.attrs["meta_json"] = "{not json"


def _frame(f):
    f.attrs["frame"] = -3


def _shape(f):
    x = f["x"][()]
    del f["x"]
    f["x"] = np.concatenate([x, x])


def _no_keys(f):
    f.attrs["meta_json"] = json.dumps({"cfg": {}})


def _past_end(f):
    f.attrs["frame"] = 99


@pytest.mark.parametrize(
    "how,words",
    [
        (_meta, ("cannot be read", "JSONDecodeError")),
        (_frame, ("damaged", "frame = -3", "allowed: >= 0")),
        (_shape, ("damaged", "state array x", "float")),
        (_no_keys, ("damaged", "'scene_source' is missing")),
        (_past_end, ("damaged", "frame = 99", "series hold 2 frames")),
    ],
)
def test_a_damaged_checkpoint_is_refused_naming_it(capsys, tmp_path, checkpoint, how, words):
    out = tmp_path / "r"
    before = _damage(checkpoint, out, how)
    _refused(capsys, ["run", "--resume", str(out), "--quiet", "--no-animation"], "checkpoint", *words)
    assert (out / "checkpoint.h5").read_bytes() == before  # left as it was


# --- a body below the DEM surface (issue 35's terrain row) -------------------------------------------
_TERRAIN_SCENE = """
name = "buried"
[domain]
lo_m = [0.0, 0.0]
hi_m = [1.6, 0.4]
cell_size_m = 0.04
[time]
t_end_s = 0.05
n_frames = 1
[material]
model = "newtonian"
density_kg_m3 = 1000.0
bulk_modulus_pa = 1e5
viscosity_pa_s = 1.0
[terrain]
type = "slip"
heights_m = [0.1, 0.2, 0.3]
spacing_m = 0.8
[[bodies]]
lo_m = [0.2, 0.0]
hi_m = [0.4, {top}]
"""


def test_a_body_wholly_below_the_terrain_is_refused_naming_it_and_the_surface(tmp_path, capsys):
    scene = tmp_path / "buried.toml"
    scene.write_text(_TERRAIN_SCENE.format(top=0.1))
    assert cli.main(["run", str(scene), "--quiet", "--no-animation", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err == (
        "mpmjax: error: bodies[0] (box, from [0.2, 0.0] to [0.4, 0.1] m) lies wholly below the terrain surface: its "
        "highest particle is at y = 0.09375 m, where the surface under the body is at y = 0.1258 to 0.1492 m "
        "(terrain.*); allowed: a body above the surface: raise bodies[0] to rest on it, or lower the terrain"
    ), err
    assert not (tmp_path / "o").exists()


def test_a_body_partly_below_the_terrain_runs_with_a_warning_giving_the_share_lifted():
    def warnings(text):
        return [w for w in start_warnings(mpmjax.build(mpmjax.validate(tomllib.loads(text)))) if "terrain" in w]

    (w,) = warnings(_TERRAIN_SCENE.format(top=0.3))
    assert w.startswith(
        "bodies[0] (box, from [0.2, 0.0] to [0.4, 0.3] m) starts 45.8 % below the terrain surface (151 of 330 "
        "particles, down to 0.142 m under it): they are lifted onto the surface at the first step"
    ), w
    assert not warnings(_TERRAIN_SCENE.format(top=0.3).replace("[0.2, 0.0]", "[0.2, 0.15]"))
