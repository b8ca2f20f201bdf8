"""Value and gradient of a calibration loss in forward and in reverse mode, in loss evaluations
(the break-even behind ``calibration.fit.FORWARD_MODE_MAX_PARAMS``); one JSON line per round.

    python benchmarks/gradient/gradient_modes.py [ROUNDS] >> benchmarks/gradient/gradient_modes.jsonl

The twin scene (data/twin-small-dambreak.toml, float64) against its synthetic profiles, as
tests/test_calibration_twin.py builds it; k = 2 (mu0, lambda0) and k = 5 (all Coussot parameters) free.
Each of value, forward mode (one jvp tangent per parameter under vmap) and reverse mode
(``jax.value_and_grad``) is compiled first, then timed in turn (wall, best of 2 calls per round).
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

import mpmjax as m
from calibration.data import load_profiles
from calibration.experiments import ProfileExperiment
from calibration.fit import forward_value_and_grad, loss_function
from calibration.params import ParameterSet

ROOT = Path(__file__).resolve().parents[2]
rounds = int(sys.argv[1]) if len(sys.argv) > 1 else 2
setup = m.build(m.load_scene(str(ROOT / "data" / "twin-small-dambreak.toml")))
exp = ProfileExperiment(setup, load_profiles(ROOT / "data" / "synthetic_twin_small_profiles.csv"), bandwidth_m=0.04)
progs = {}
for names in (["mu0", "lambda0"], ["mu0", "alpha", "T", "n", "lambda0"]):
    ps = ParameterSet.from_names(names, setup.params.material)
    loss = loss_function([exp], ps, "reverse")
    z = ps.z0(setup.state.x.dtype)
    for mode, fn in (("value", loss), ("forward", forward_value_and_grad(loss)), ("reverse", jax.value_and_grad(loss))):
        progs[(len(names), mode)] = (jax.jit(fn).lower(z).compile(), z)


def timed(f, z):
    best = float("inf")
    for _ in range(2):
        t0 = time.perf_counter()
        jax.block_until_ready(f(z))
        best = min(best, time.perf_counter() - t0)
    return best


for r in range(rounds):
    line = {"round": r + 1, "scene": "twin-small-dambreak", "dtype": str(setup.state.x.dtype),
            "n_particles": setup.scene.n_particles, "steps": setup.scene.n_frames * setup.scene.steps_per_frame}
    for k in (2, 5):
        t = {mode: timed(*progs[(k, mode)]) for mode in ("value", "forward", "reverse")}
        line[f"k{k}_value_s"] = t["value"]
        line[f"k{k}_forward_evals"] = t["forward"] / t["value"]
        line[f"k{k}_reverse_evals"] = t["reverse"] / t["value"]
    g_f = np.asarray(progs[(5, "forward")][0](progs[(5, "forward")][1])[1])
    g_r = np.asarray(progs[(5, "reverse")][0](progs[(5, "reverse")][1])[1])
    line["k5_gradient_max_rel_diff"] = float(np.max(np.abs(g_f - g_r) / np.maximum(np.abs(g_r), 1e-300)))
    line["load_avg"] = os.getloadavg()[0]
    line["time_utc"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    print(json.dumps(line), flush=True)
