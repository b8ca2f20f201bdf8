"""How the joint twin's observables move with the cell size (docs/calibration-coverage.md, "Three levels").

The dam break of ``calibration.synthetic.joint_twin`` (``data/twin-small-dambreak.toml``) at the twin's truth
``JOINT_TRUTH`` (or the parameters given as JSON), with the scene's settings or ``KEY=VALUE`` overrides, run at
h = 0.03, 0.015, 0.0075 and 0.00375 m: the
free-surface front every 0.1 s to 0.6 s (the front-series experiment's model, kernel bandwidth 0.06 m), and the
successive differences between halvings; at the end of the run also the volume centroid and the farthest
particle (``final``), which read the bulk and the thin tip where the front reads the profile.  An observable in
its asymptotic range of order p changes by 2^-p less
per halving; a change that does not shrink says that the fits' levels (0.03 -> 0.015 -> 0.0075 m) cannot
estimate the error of their finest one.  One JSON line per cell size.

    .venv/bin/python benchmarks/calibration/twin_h_convergence.py ['{"mu0": 4.8, ...}'] [KEY=VALUE ...]

``TWIN_FRAMES=N`` in the environment runs N frames of 0.1 s instead of 6 (15: the whole 1.5 s of the scene).
"""

import json
import os
import sys
import time

import jax
import numpy as np

import mpmjax
from mpmjax._simulate import simulate
from calibration.experiments import RunoutSeriesExperiment
from calibration.synthetic import JOINT_SCENE, JOINT_TRUTH

KEYS = {"mu0": "material.mu0_pa_s", "alpha": "material.alpha", "T": "material.T_s", "n": "material.n",
        "lambda0": "material.lambda0"}
FRAMES = int(os.environ.get("TWIN_FRAMES", "6"))


def fronts(truth, h, extra=()):
    over = [f"{KEYS[k]}={v!r}" for k, v in truth.items()] + list(extra)
    over += [f"time.t_end_s={0.1 * FRAMES!r}", f"time.n_frames={FRAMES}", f"domain.cell_size_m={h!r}"]
    s = mpmjax.build(mpmjax.load_scene(JOINT_SCENE, over))
    t = np.arange(1, FRAMES + 1) * 0.1
    c0 = time.process_time()
    f = RunoutSeriesExperiment(s, t, np.full(FRAMES, 0.3), bandwidth_m=0.06).model_fronts({})
    cpu = time.process_time() - c0
    fin, _ = jax.jit(simulate, static_argnums=(0, 3))(s.scene, s.state, s.params)
    x, vol = np.asarray(fin.x[:, 0]), np.asarray(fin.vol0 * fin.J * fin.active)
    bulk = {"centroid_m": float(np.sum(x * vol) / np.sum(vol)), "farthest_m": float(x[np.asarray(fin.active)].max())}
    return np.asarray(f, float), cpu, int(s.scene.n_steps), bulk


if __name__ == "__main__":
    truth = dict(JOINT_TRUTH)
    if len(sys.argv) > 1:
        truth = {k: float(v) for k, v in json.loads(sys.argv[1]).items()}
    extra = sys.argv[2:]
    prev = None
    for h in (0.03, 0.015, 0.0075, 0.00375):
        f, cpu, steps, bulk = fronts(truth, h, extra)
        line = {"truth": truth, "overrides": extra, "h_m": h, "steps": steps, "fronts_m": [round(v, 5) for v in f],
                "final": {k: round(v, 5) for k, v in bulk.items()}, "cpu_s": round(cpu, 1),
                "date": time.strftime("%Y-%m-%d")}
        if prev is not None:
            line["change_from_coarser_m"] = [round(a - b, 5) for a, b in zip(f, prev)]
        prev = f
        print(json.dumps(line), flush=True)
