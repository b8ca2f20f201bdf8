"""Hostile input to ``mpmjax sweep`` and ``sweep-merge`` (issue 35's table): an unusable ``--out`` is
refused before the sweep runs (it used to fail only after the whole sweep, losing it), a folder held
by another command is refused, a sweep that cannot fit in memory is refused before anything is built,
``--shard`` jobs share their folder without a lock, and a damaged part names its file."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import mpmjax
from mpmjax import cli
from mpmjax._driver import LOCK_NAME, OutputLock

ROOT = Path(__file__).resolve().parents[1]
TWIN = str(ROOT / "data" / "twin-small-dambreak.toml")
SWEEP = ["sweep", TWIN, "--vary", "n=2,3", "--quiet", "--set", "domain.cell_size_m=0.06"]


@pytest.fixture
def no_sweep(monkeypatch):
    """The sweep itself fails the test if it starts: every refusal comes first."""
    monkeypatch.setattr("mpmjax.cli._sweep.run_sweep", lambda *a, **k: pytest.fail("the sweep ran"))


def _refused(capsys, argv, *words):
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, (w, err)


@pytest.mark.parametrize(
    "out,words",
    [
        ("{tmp}/afile", ("--out", "is an existing file")),
        ("{tmp}/afile/sub", ("--out", "not a folder")),
        ("/proc/mpmjax-none/o", ("--out", "cannot be created")),
        ("", ("--out ''", "empty")),
    ],
)
def test_an_unusable_out_is_refused_before_the_sweep_runs(capsys, tmp_path, no_sweep, out, words):
    (tmp_path / "afile").write_text("keep me")
    _refused(capsys, [*SWEEP, "--out", out.format(tmp=tmp_path)], *words)
    assert (tmp_path / "afile").read_text() == "keep me"


def test_a_held_folder_is_refused(capsys, tmp_path, no_sweep):
    out = tmp_path / "o"
    out.mkdir()
    lock = OutputLock(out)
    lock.acquire()
    try:
        _refused(capsys, [*SWEEP, "--out", str(out)], f"process {os.getpid()}")
    finally:
        lock.release()


def test_shard_jobs_share_their_folder(capsys, tmp_path, monkeypatch):
    """Jobs of one --shard array write one folder together: no lock is taken for them."""
    out = tmp_path / "o"
    out.mkdir()
    lock = OutputLock(out)
    lock.acquire()
    seen = []
    monkeypatch.setattr("mpmjax.cli._sweep.run_sweep", lambda *a, **k: seen.append(k["shard"]))
    try:
        assert cli.main([*SWEEP, "--out", str(out), "--shard", "0/2"]) == 0
    finally:
        lock.release()
    assert seen == [(0, 2)]


def test_a_sweep_that_cannot_fit_is_refused_before_it_is_built(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("MPMJAX_MEMORY_LIMIT_GB", "1e-6")
    monkeypatch.setattr(mpmjax, "build", lambda *a: pytest.fail("built"))
    _refused(capsys, [*SWEEP, "--out", str(tmp_path / "o")], "the run needs about", "MPMJAX_MEMORY_LIMIT_GB")
    assert not (tmp_path / "o").exists()  # the folder made for the lock is removed again


@pytest.mark.parametrize("content", [b"PK\x03\x04garbage", b"", b"\x93NUMPY not an npz"])
def test_a_damaged_part_names_its_file(capsys, tmp_path, content):
    parts = tmp_path / "parts"
    parts.mkdir()
    (parts / "part-0-of-1.npz").write_bytes(content)
    _refused(capsys, ["sweep-merge", str(parts), "--quiet"], "part-0-of-1.npz", "not a readable part", "--shard 0/1")
    assert sorted(p.name for p in parts.iterdir()) == [LOCK_NAME, "part-0-of-1.npz"]


def test_parts_that_are_a_file_are_refused(capsys, tmp_path):
    (tmp_path / "afile").write_text("x")
    _refused(capsys, ["sweep-merge", str(tmp_path / "afile"), "--quiet"], "afile: not a folder")


def test_a_basal_coefficient_on_a_scene_without_one_is_refused_before_it_is_built(capsys, tmp_path, monkeypatch):
    """``friction`` / ``turbulence`` vary only on a depth-averaged scene with a coulomb or voellmy terrain
    (``mpmjax.fit_parameters``); elsewhere the refusal lists what can vary, before any scene is built."""
    monkeypatch.setattr(mpmjax, "build", lambda *a, **k: pytest.fail("a scene was built"))
    argv = ["sweep", TWIN, "--vary", "friction=0.1,0.2", "--quiet", "--out", str(tmp_path / "o")]
    # kappa is listed only where the scene's pressure reads it (the explicit one), so it is not checked here
    _refused(capsys, argv, "--vary friction", "allowed: rho, ", "mu0", "depth-averaged scene")


def test_the_bulk_modulus_of_a_grid_pressure_scene_is_refused_before_it_is_built(capsys, tmp_path, monkeypatch):
    """With the pressure solved on the grid the bulk modulus does not enter the step (bit-identical runs,
    tests/test_pressure.py), so every case of a kappa sweep would be the same: refused, saying why and how
    to vary it (``mpmjax.unused_parameters``), and no longer listed as a parameter that can vary."""
    monkeypatch.setattr(mpmjax, "build", lambda *a, **k: pytest.fail("a scene was built"))
    grid = ["--set", "numerics.pressure=incompressible"]
    argv = ["sweep", TWIN, "--vary", "kappa=1e4,1e5", "--quiet", "--out", str(tmp_path / "o"), *grid]
    _refused(capsys, argv, "--vary kappa", "not used by scene", "set numerics.pressure=explicit")
    argv = ["sweep", TWIN, "--vary", "friction=0.1,0.2", "--quiet", "--out", str(tmp_path / "o"), *grid]
    _refused(capsys, argv, "--vary friction", "allowed: rho, mu0")
    cfg = mpmjax.load_scene(TWIN, ["numerics.pressure=incompressible"])
    assert "kappa" not in mpmjax.fit_parameters(mpmjax.make_params(cfg), cfg)
    assert "kappa" in mpmjax.fit_parameters(mpmjax.make_params(cfg))
    da = mpmjax.load_scene("field-dambreak-da")  # the depth-averaged step has no bulk modulus either
    assert "kappa" in mpmjax.unused_parameters(da) and "kappa" not in mpmjax.fit_parameters(mpmjax.make_params(da), da)
