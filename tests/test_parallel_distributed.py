"""Sweeps and multi-start fits beyond one process (issue 18 item 5): two local CPU processes
joined by ``jax.distributed`` (gloo collectives over TCP on 127.0.0.1), one process with the batch
split over 2 host devices (``--devices 2``), the ``--shard I/N`` parts of a job array and their
merge, and the options' errors."""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from calibration.sweep import merge_parts, sweep, write_part
from mpmjax.cli import main

ROOT = Path(__file__).resolve().parents[1]
TWIN = str(ROOT / "data" / "twin-small-dambreak.toml")
# 35 particles, 78 steps: the cost is compilation (~7 s CPU per process), not the run
SMALL = ["domain.cell_size_m=0.06", "time.t_end_s=0.3", "time.n_frames=3"]
VARY = {"mu0": [2.0, 6.0], "n": [2.0, 3.0]}
PER_CASE = ("final_runout_m", "runout_m", "runout_farthest_particle_m", "kinetic_energy_J", "profile_h_m", "n_lost")
PROCESS_TIMEOUT_S = 240  # a process that does not finish by then is killed and the test fails (no hang)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _sweep_cli(out, *extra):
    args = [a for k, v in VARY.items() for a in ("--vary", f"{k}={','.join(map(str, v))}")]
    args += [a for o in SMALL for a in ("--set", o)]
    cli = [sys.executable, "-m", "mpmjax.cli", "sweep", TWIN]
    return cli + args + ["--chunk", "2", "--quiet", "--out", str(out), *extra]


def _same(a, b):
    """Every per-case result equal to float rounding: each lane is the same computation on its own
    inputs, whichever process or device runs it (measured: bit for bit equal), so rtol 1e-12 only
    leaves room for a different summation order in another build."""
    for k in PER_CASE:
        np.testing.assert_allclose(np.asarray(a[k], float), np.asarray(b[k], float), rtol=1e-12, atol=1e-15, err_msg=k)
    ta, tb = (np.asarray([np.nan if v is None else v for v in r["time_to_rest_s"]], float) for r in (a, b))
    np.testing.assert_allclose(ta, tb, rtol=1e-12, equal_nan=True)
    assert [dict(c) for c in a["cases"]] == [dict(c) for c in b["cases"]]


def test_sweep_on_two_processes_equals_one_process(tmp_path):
    """Two local processes joined by jax.distributed split the four cases (one lane per process
    and batch); process 0 gathers and writes sweep.json, process 1 leaves its --out alone, and the
    result equals the one-process sweep.  The --shard parts of a job array merge to the same."""
    port = _free_port()
    # one CPU device per process: no host-device count (the harness's other XLA flags are kept)
    flags = " ".join(f for f in os.environ.get("XLA_FLAGS", "").split() if "device_count" not in f)
    env = dict(os.environ, XLA_FLAGS=flags)
    env.update(JAX_PLATFORMS="cpu", PYTHONPATH=str(ROOT) + os.pathsep + env.get("PYTHONPATH", ""))
    procs = [
        subprocess.Popen(
            _sweep_cli(
                tmp_path / ("dist" if i == 0 else "unused"),
                "--coordinator", f"127.0.0.1:{port}", "--num-processes", "2", "--process-id", str(i),
                # process 0 also holds 2 host devices: --devices combines with jax.distributed (3 devices in all)
                *(["--devices", "2"] if i == 0 else []),
            ),
            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )
        for i in range(2)
    ]
    # and one process that splits the batch over 2 host devices of its own (--devices 2)
    procs.append(
        subprocess.Popen(
            _sweep_cli(tmp_path / "devices", "--devices", "2"),
            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )
    )
    try:
        # meanwhile, in this process: the one-process sweep, and the two shares of a job array
        # (the second and third sweeps reuse the first one's compilation)
        ref = sweep(TWIN, VARY, overrides=SMALL, chunk=2, progress=False)
        for i in range(2):
            write_part(sweep(TWIN, VARY, overrides=SMALL, chunk=2, progress=False, shard=(i, 2)), tmp_path / "parts")
        logs = []
        for p in procs:
            logs.append(p.communicate(timeout=PROCESS_TIMEOUT_S)[0])
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    assert [p.returncode for p in procs] == [0, 0, 0], "\n".join(lg[-3000:] for lg in logs)
    dist = json.loads((tmp_path / "dist" / "sweep.json").read_text())
    assert (dist["n_processes"], dist["n_devices"], ref["n_processes"], ref["n_devices"]) == (2, 3, 1, 1)
    assert not (tmp_path / "unused").exists()  # only process 0 writes
    _same(dist, ref)
    local = json.loads((tmp_path / "devices" / "sweep.json").read_text())
    assert (local["n_processes"], local["n_devices"]) == (1, 2)
    _same(local, ref)
    assert (tmp_path / "dist" / "sweep.csv").exists() and (tmp_path / "dist" / "sweep_runout.png").exists()
    merged = merge_parts(tmp_path / "parts")
    assert merged["parts"] == 2 and merged["n_cases"] == 4
    _same(merged, ref)
    # physics, as a check that the cases were not mixed up: the more viscous material runs out less far
    r = {(c["mu0"], c["n"]): dist["final_runout_m"][i] for i, c in enumerate(dist["cases"])}
    assert r[(6.0, 2.0)] < r[(2.0, 2.0)] and r[(6.0, 3.0)] < r[(2.0, 3.0)]


def test_sweep_merge_cli_joins_parts_and_names_missing_ones(tmp_path, capsys):
    """``mpmjax sweep-merge`` writes sweep.csv from complete parts and, with a part missing or from
    another sweep, exits 2 naming it (parts made from a fake result: the merge does no simulation)."""
    base = {
        "scene": "twin", "overrides": [], "vary": {"mu0": [1.0, 2.0, 3.0]}, "n_cases": 3, "dt_s": 1e-3,
        "times_s": np.array([0.0, 0.5]), "profile_x_m": np.array([0.0, 1.0]), "n_particles": 10, "n_steps": 500,
        "dim": 2, "runout_definition": "farthest particle", "chunk": 1, "n_devices": 1, "n_processes": 1,
        "wall_s": 1.0,
    }

    def part(i, cases, **change):
        k = len(cases)
        res = dict(base, **change, shard=[i, 2], cases=[{"mu0": c} for c in cases])
        res.update(
            case_index=np.arange(k) + (0 if i == 0 else 1), runout_m=np.ones((k, 2)), final_runout_m=np.ones(k),
            runout_farthest_particle_m=np.ones((k, 2)), final_runout_farthest_particle_m=np.ones(k),
            kinetic_energy_J=np.zeros((k, 2)), time_to_rest_s=np.full(k, np.nan), n_lost=np.zeros(k, int),
            profile_h_m=np.zeros((k, 2)),
        )
        return res

    write_part(part(0, [1.0]), tmp_path)
    assert main(["sweep-merge", str(tmp_path), "--quiet"]) == 2
    assert "1 of 2 parts missing (jobs 1); rerun them with --shard I/2" in capsys.readouterr().err
    write_part(part(1, [2.0, 3.0], dt_s=2e-3), tmp_path)
    assert main(["sweep-merge", str(tmp_path), "--quiet"]) == 2
    assert "part-1-of-2.npz differs from part-0-of-2.npz in dt_s" in capsys.readouterr().err
    write_part(part(1, [2.0, 3.0]), tmp_path)
    assert main(["sweep-merge", str(tmp_path), "--quiet"]) == 0
    rows = (tmp_path / "sweep.csv").read_text().splitlines()
    assert rows[0].startswith("mu0,final_runout_m") and [r.split(",")[0] for r in rows[1:]] == ["1", "2", "3"]


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--coordinator", "node1"], "--coordinator = 'node1' is invalid; allowed: HOST:PORT"),
        (["--coordinator", "node1:70000", "--num-processes", "2", "--process-id", "0"], "TCP port 1 .. 65535"),
        (["--coordinator", "h:1234", "--num-processes", "0", "--process-id", "0"], "--num-processes = 0 is invalid"),
        (
            ["--coordinator", "h:1234", "--num-processes", "2", "--process-id", "2"],
            "--process-id = 2 is invalid; allowed range: 0 .. 1",
        ),
        (["--coordinator", "h:1234"], "--num-processes, --process-id missing"),
        (["--shard", "2/2"], "--shard = '2/2' is invalid; allowed: I/N with N >= 1 jobs and 0 <= I <= N - 1"),
        (["--shard", "0/2", "--coordinator", "h:1234", "--num-processes", "2", "--process-id", "0"], "--shard and"),
        (["--devices", "0"], "--devices = 0 is invalid: allowed range: integer >= 1"),
        (["--devices", "100000"], "--devices = 100000 is invalid; allowed range: integer 1 .. "),
    ],
)
def test_distributed_options_bad_input_exits_2(tmp_path, capsys, extra, needle):
    """Bad distributed options stop before anything runs, with exit status 2 and a message naming
    the option, its value and the allowed range (on sweep and calibrate alike)."""
    assert main(["sweep", TWIN, "--vary", "mu0=1", "--out", str(tmp_path / "o"), *extra]) == 2
    assert needle in capsys.readouterr().err
    if "--shard" not in extra and "--devices" not in extra:  # calibrate has no --devices: its starts run per process
        data = str(ROOT / "data" / "synthetic_twin_small_profiles.csv")
        assert main(["calibrate", data, "--scene", TWIN, "--fit", "mu0", "--out", str(tmp_path / "c"), *extra]) == 2
        assert needle in capsys.readouterr().err
    assert not (tmp_path / "o").exists() and not (tmp_path / "c").exists()
