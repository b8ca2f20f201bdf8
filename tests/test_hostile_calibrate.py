"""Hostile input to ``mpmjax calibrate`` (issue 35's table): the output folder (a file, a path under a
file, an uncreatable path, ``--out ""``, a folder another command holds), the data files (a folder, a
FIFO, binary and Latin-1 bytes, NaN, profiles all at t = 0, an empty flow curve), the options whose
refusal used to blame the data file or another option (``--sigma``, ``--init``, ``--runout-m``), data
times no run can reach and a scene that cannot fit in memory.  Every one is exit status 2 with one
line naming the culprit, before a scene is built (``mpmjax.build`` fails the test if called); valid
data that used to be refused (a runout series past the last profile) gives plain numbers."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import numpy as np
import pytest

import mpmjax
from calibration.run import _scene_overrides
from mpmjax import cli
from mpmjax._driver import OutputLock

ROOT = Path(__file__).resolve().parents[1]
TWIN = str(ROOT / "data" / "twin-small-dambreak.toml")
SETS = ["--set", "domain.cell_size_m=0.06", "--set", "time.t_end_s=0.3", "--set", "time.n_frames=3"]
PROFILE = "x_m,h_m,t_s\n0.0,0.1,0.3\n0.1,0.08,0.3\n0.2,0.05,0.3\n0.3,0.02,0.3\n0.4,0.0,0.3\n"


@pytest.fixture
def nothing_built(monkeypatch):
    def build(*a, **k):
        raise AssertionError("a scene was built for input that should have been refused")

    monkeypatch.setattr(mpmjax, "build", build)


@pytest.fixture
def data(tmp_path) -> Path:
    p = tmp_path / "p.csv"
    p.write_text(PROFILE)
    return p


def _calibrate(capsys, tmp_path, data, *extra, words=(), out=None):
    argv = ["calibrate", str(data), "--scene", TWIN, "--fit", "mu0", "--levels", "1", "--quiet", *SETS]
    argv += ["--out", str(tmp_path / "o") if out is None else out, *extra]
    old = signal.signal(signal.SIGALRM, lambda *a: pytest.fail("calibrate hung"))
    signal.alarm(60)  # a FIFO must not hang the test
    try:
        assert cli.main(argv) == 2
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, (w, err)
    return err


@pytest.mark.parametrize(
    "out,words",
    [
        ("{tmp}/afile", ("--out", "is an existing file")),
        ("{tmp}/afile/sub", ("--out", "afile is a file, not a folder")),
        ("/proc/mpmjax-none/o", ("--out", "cannot be created")),
        ("", ("--out ''", "empty")),
    ],
)
def test_an_unusable_out_is_refused_and_the_file_kept(capsys, tmp_path, data, nothing_built, out, words):
    (tmp_path / "afile").write_text("keep me")
    _calibrate(capsys, tmp_path, data, out=out.format(tmp=tmp_path), words=words)
    assert (tmp_path / "afile").read_text() == "keep me"


def test_a_second_command_into_a_held_folder_is_refused(capsys, tmp_path, data, nothing_built):
    out = tmp_path / "o"
    out.mkdir()
    lock = OutputLock(out)
    lock.acquire()  # as a running calibrate holds it (flock: a second open of the file conflicts)
    try:
        _calibrate(capsys, tmp_path, data, words=("--out", f"process {os.getpid()}", "choose another --out"))
    finally:
        lock.release()


def test_a_refused_command_leaves_no_folder_behind(capsys, tmp_path, data, nothing_built):
    _calibrate(capsys, tmp_path, data, "--sigma", "runout=0", words=("--sigma",))
    assert not (tmp_path / "o").exists()


def _fifo(p):
    os.mkfifo(p)


@pytest.mark.parametrize(
    "name,make,words",
    [
        ("d.csv", lambda p: p.mkdir(), ("is a folder",)),
        ("f.csv", _fifo, ("is a FIFO",)),
        ("b.csv", lambda p: p.write_bytes(b"\x00\xff\xfe\x89PNG\r\n" * 20), ("line 1", "not UTF-8")),
        ("l.csv", lambda p: p.write_bytes("x_m,h_m\n0,0.1\n# H\xf6he\n".encode("latin-1")), ("line 3", "not UTF-8")),
        ("n.csv", lambda p: p.write_text(PROFILE.replace("0.08", "nan")), ("h_m (line 3) = nan",)),
        ("z.csv", lambda p: p.write_text(PROFILE.replace(",0.3\n", ",0\n")), ("t_s = 0 in every row",)),
    ],
)
def test_a_hostile_profile_file_is_named(capsys, tmp_path, nothing_built, name, make, words):
    make(tmp_path / name)
    _calibrate(capsys, tmp_path, tmp_path / name, words=(name, *words))


@pytest.mark.parametrize(
    "option,name,make,words",
    [
        ("--flow-curve", "fc.csv", lambda p: p.write_text(""), ("no header line",)),
        ("--flow-curve", "fc.csv", lambda p: p.write_text("gamma_dot_1_s,tau_pa\n"), ("no data rows",)),
        ("--flow-curve", "fc", lambda p: p.mkdir(), ("is a folder",)),
        ("--flow-curve", "fc.csv", lambda p: p.write_text("gamma_dot_1_s,tau_pa\n1,-5\n"), ("tau_pa = -5.0",)),
        ("--rest-times", "r.csv", lambda p: p.write_text("t_rest_s,t_s,x_front_m\n0,0.1,0.3\n0,0.2,nan\n"),
         ("line 3", "x_front_m = nan")),
        ("--runout-series", "rs.csv", _fifo, ("is a FIFO",)),
    ],
)
def test_a_hostile_second_data_file_is_named(capsys, tmp_path, data, monkeypatch, option, name, make, words):
    make(tmp_path / name)
    if option != "--flow-curve":  # the flow curve is read after the coarse scene is built
        monkeypatch.setattr(mpmjax, "build", lambda *a: pytest.fail("built"))
    _calibrate(capsys, tmp_path, data, option, str(tmp_path / name), words=(name, *words))


@pytest.mark.parametrize(
    "extra,words",
    [
        (["--sigma", "runout=0"], ("--sigma runout=0", "unknown experiment kind")),
        (["--sigma", "profiles=0"], ("--sigma profiles=0", "> 0")),
        (["--sigma-m", "0"], ("--sigma-m = 0.0", "> 0")),
        (["--bandwidth-m", "0"], ("--bandwidth-m = 0.0", "> 0")),
        (["--init", "mu0=1e9"], ("error: --init mu0=1000000000.0: ", "needs mu0 <= mu_max")),
        (["--runout-m", "-1"], ("--runout-m = -1.0", ">= 0")),
        (["--bounds", "mu0=5:1"], ("--bounds 'mu0=5:1'", "finite LO < HI")),
        (["--bounds", "mu0=nan:1"], ("--bounds 'mu0=nan:1'", "finite LO < HI")),
        (["--profile-points", "4"], ("--profile-points = 4", "odd integer >= 3")),  # without --profile too
        # a basal coefficient on a scene without a frictional depth-averaged bed, named with what it needs
        (["--init", "friction=0.2"], ("--init friction", "allowed: rho, kappa, mu0", "depth-averaged scene")),
        # the bulk modulus where the pressure is solved on the grid: a fit of it would meet a flat loss
        (["--init", "kappa=1e5", "--set", "numerics.pressure=incompressible"],
         ("--init kappa", "not used by scene", "set numerics.pressure=explicit")),
    ],
)
def test_an_option_is_blamed_on_itself(capsys, tmp_path, data, nothing_built, extra, words):
    err = _calibrate(capsys, tmp_path, data, *extra, words=words)
    assert "p.csv" not in err and "--levels" not in err


def test_runout_beyond_the_domain_is_refused(capsys, tmp_path, data):
    _calibrate(capsys, tmp_path, data, "--runout-m", "100", words=("--runout-m = 100.0", "allowed range: 0 .. 0.9 m"))


def test_data_times_no_run_can_reach_are_refused(capsys, tmp_path):
    far = tmp_path / "far.csv"
    far.write_text(PROFILE.replace(",0.3\n", ",1e6\n"))
    argv = ["calibrate", str(far), "--scene", TWIN, "--fit", "mu0", "--levels", "1", "--quiet",
            "--set", "domain.cell_size_m=0.06", "--out", str(tmp_path / "o")]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "far.csv: t_s = 1e+06 s needs" in err and "steps" in err and "time.t_end_s" in err, err


def test_a_scene_that_cannot_fit_is_refused_before_it_is_built(capsys, tmp_path, data, nothing_built, monkeypatch):
    monkeypatch.setenv("MPMJAX_MEMORY_LIMIT_GB", "1e-6")
    _calibrate(capsys, tmp_path, data, words=("the run needs about", "MPMJAX_MEMORY_LIMIT_GB"))


def test_data_times_past_the_profiles_give_plain_numbers():
    """A runout series past the last profile time stretched the run with an np.float64 repr that the
    scene refused (``time.t_end_s = 'np.float64(0.45)' is invalid``, blamed on --levels)."""
    _, overrides = _scene_overrides(TWIN, [], [0.3, np.float64(0.1), np.float64(0.45)], {})
    assert "time.t_end_s=0.45" in overrides
    assert mpmjax.load_scene(TWIN, overrides)["time.t_end_s"] == 0.45


def test_a_fit_whose_model_turns_non_finite_ends_with_status_3_and_one_line(capsys, tmp_path, data, monkeypatch):
    """A FloatingPointError from the fit (a non-finite loss or Jacobian, calibration.uncertainty) is the
    model failing, not a bug: status 3 (as a failed run) and one line naming it, never a traceback (it
    was a traceback until 2026-12-06, found by a float32 friction fit)."""

    def nan_fit(*a, **k):
        raise FloatingPointError("profiles.csv: non-finite Jacobian at {'friction': 0.283}")

    monkeypatch.setattr("mpmjax.cli._calibrate.calibrate", nan_fit)
    argv = ["calibrate", str(data), "--scene", TWIN, "--fit", "mu0", "--quiet", "--out", str(tmp_path / "o")]
    assert cli.main(argv) == 3
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err, err
    assert err.splitlines()[0] == "mpmjax: profiles.csv: non-finite Jacobian at {'friction': 0.283}", err
