"""``mpmjax bench --quick``: the output's schema and sanity (a benchmark measures; no speed is asserted).

The quick mode shrinks every measurement (1e3 particles, a few steps, one repetition); its
figures are not benchmarks, only evidence that each measurement ran and produced a number.
"""

import json
import math

import pytest


@pytest.fixture(scope="module")
def doc(tmp_path_factory):
    from mpmjax.cli import main

    out = tmp_path_factory.mktemp("bench") / "bench.json"
    assert main(["bench", "--quick", "--out", str(out)]) == 0
    return json.loads(out.read_text())


def _pos(x):
    return isinstance(x, (int, float)) and math.isfinite(x) and x > 0


def test_top_level_keys_and_meta(doc):
    assert set(doc) == {"meta", "results", "scaling", "gradient", "batch", "complete"}
    # the file is rewritten after every section; the last write marks it complete
    assert doc["complete"] is True
    m = doc["meta"]
    assert m["quick"] is True and m["backend"] and m["jax"] and m["cpus"] >= 1
    assert m["scaling_sizes"] == [1e3] and "1e6" in m["note_1e6"]
    bw = m["memory_bandwidth"]
    assert _pos(bw["numpy_add_gb_s"]) and _pos(bw["xla_triad_gb_s"])
    # the XLA triad reused its donated buffer: no fresh (page-faulting) allocation was timed
    assert bw["xla_output_donated"] is True
    assert m["reps"] == 1 and m["only"] == "scenes,scaling,gradient,batch"
    assert m["quick_overrides"] == {"domain.cell_size_m": 0.02, "numerics.pressure": "explicit"}


def test_default_scene_and_mpm88_entries_are_kept(doc):
    r = doc["results"]
    assert set(r) == {"default-scene", "mpm88-equivalent"}
    assert r["mpm88-equivalent"]["n_particles"] == 8192
    assert r["default-scene"]["n_particles"] == 3600  # 0.2 m block, h = 0.01 m, ppc 3
    for e in r.values():
        for k in ("best_wall_s", "compile_s", "particle_steps_per_s"):
            assert _pos(e[k]), (k, e[k])
        assert e["n_lost"] == 0
        # particle-steps/s is what it says: particles x steps / wall
        assert e["particle_steps_per_s"] == pytest.approx(e["n_particles"] * e["steps"] / e["best_wall_s"])


def test_scaling_rows_cover_both_dims_and_dtypes(doc):
    rows = doc["scaling"]
    assert {r["dim"] for r in rows} == {2, 3} and {r["dtype"] for r in rows} == {"float32", "float64"}
    for r in rows:
        # the block [0, 0.5]^dim at 2 per cell per axis holds k^dim particles, k = 1/h
        assert r["n_particles"] == pytest.approx(r["n_target"], rel=0.1)
        assert r["grid_nodes"] > r["n_particles"] / 2 ** r["dim"]
        assert r["n_lost"] == 0
        assert _pos(r["particle_steps_per_s"]) and _pos(r["best_wall_s"]) and r["steps"] >= 5


def test_traffic_per_particle_step(doc):
    """The bytes figures the scaling floor is read from (docs/performance.md, "Scaling")."""
    for r in list(doc["results"].values()) + doc["scaling"]:
        fl = 4 if r.get("dtype", "float32") == "float32" else 8
        dim = r.get("dim", 2)
        # the state read and written once: x, v (dim each), C, tau (dim^2 each), J, mu read and
        # written, vol0 read, active and gate 1 byte each way, at least
        floor = fl * (2 * (2 * dim + 2 * dim * dim + 2) + 1)
        assert r["state_bytes_per_particle_step"] >= floor
        # XLA materialises the stencil arrays (S = 3^dim nodes, 2 dim + 1 channels) at least once
        assert r["xla_bytes_per_particle_step"] > fl * 3**dim * (2 * dim + 1)
        assert r["xla_gb_s"] == pytest.approx(r["xla_bytes_per_particle_step"] * r["particle_steps_per_s"] / 1e9)
        assert _pos(r["best_cpu_s"]) and _pos(r["xla_flops_per_particle_step"])


def test_gradient_rows(doc):
    for r in doc["gradient"]:
        for k in ("forward_s", "gradient_s", "gradient_over_forward", "compile_forward_s", "compile_gradient_s"):
            assert _pos(r[k]), (k, r[k])
        for k in ("jvp_s", "jvp_over_forward", "compile_jvp_s"):
            assert _pos(r[k]), (k, r[k])
        assert r["gradient_over_forward"] == pytest.approx(r["gradient_s"] / r["forward_s"])
        assert math.isfinite(r["d_centroid_d_mu0_m_per_pa_s"]) and math.isfinite(r["centroid_x_m"])
        # forward and reverse mode give the same derivative (float32, 10 steps: round-off only)
        assert r["d_centroid_d_mu0_jvp_m_per_pa_s"] == pytest.approx(
            r["d_centroid_d_mu0_m_per_pa_s"], rel=1e-3, abs=1e-9
        )
        for mem in (r["forward_memory"], r["gradient_memory"], r["jvp_memory"]):
            assert set(mem) == {"temp_bytes", "argument_bytes", "output_bytes"}
            assert mem["temp_bytes"] is None or mem["temp_bytes"] >= 0


def test_batch_entry(doc):
    b = doc["batch"]
    assert b["batch"] == 16
    for k in ("sequential_s", "batched_s", "sequential_over_batched"):
        assert _pos(b[k]), (k, b[k])
    # the batch member and the single run compute the same thing (float32 round-off)
    assert b["max_abs_diff_batched_vs_single_m"] < 1e-4


def test_bad_steps_is_a_usage_error(tmp_path):
    from mpmjax.cli import main

    assert main(["bench", "--steps", "0", "--out", str(tmp_path / "b.json")]) == 2


def test_only_runs_the_sections_named(tmp_path):
    from mpmjax.cli import main

    out = tmp_path / "b.json"
    assert main(["bench", "--quick", "--only", "batch", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert set(doc) == {"meta", "results", "batch", "complete"} and doc["results"] == {}


@pytest.mark.parametrize("argv", [["--only", "scaling,speed"], ["--only", ","], ["--reps", "0"]])
def test_bad_only_or_reps_is_a_usage_error(tmp_path, argv, capsys):
    from mpmjax.cli import main

    assert main(["bench", *argv, "--out", str(tmp_path / "b.json")]) == 2
    err = capsys.readouterr().err
    assert argv[0] in err and "allowed" in err
