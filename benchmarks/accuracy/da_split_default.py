"""The depth-averaged split defaults (``numerics.split_levels``, ``numerics.split_pool``) on the cases that chose
them (stop 65, 2026-12-07): one JSON line per run on stdout, float32 as the command line runs.

* ``huppert LEVELS POOL [PPC]``: ``mpmjax validate``'s ``da-huppert`` scene (0.1 m x 0.1 m, nu = 0.01 m^2/s, h = 1 cm,
  2 columns a cell unless PPC, 10 s; ``mpmjax.studies.validate._huppert_cfgs``), 40 frames: the farthest column
  against Huppert's front 1.411 (g q^3 t / (3 nu))^(1/5), the time the spare slots ran out, the columns at the end;
* ``lab LEVELS POOL``: ``dambreak-lab`` as columns (``mpmjax run`` with model.formulation = depth-averaged, 15 s,
  60 frames): final runout, sparse volume, slots used, loop wall.

    for c in "1 1.0" "2 1.0" "2 1.5" "2 3.0" "3 1.5" "3 3.0"; do
        .venv/bin/python benchmarks/accuracy/da_split_default.py huppert $c
        .venv/bin/python benchmarks/accuracy/da_split_default.py lab $c
    done >> benchmarks/accuracy/da_split_default.jsonl
    .venv/bin/python benchmarks/accuracy/da_split_default.py huppert 0 1.0 >> benchmarks/accuracy/da_split_default.jsonl
    .venv/bin/python benchmarks/accuracy/da_split_default.py huppert 1 1.0 8 >> benchmarks/accuracy/da_split_default.jsonl

docs/validate-depth-averaged.md, "The split's pool" has the table.
"""

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mpmjax import run_scene
from mpmjax._split import spare_slots
from mpmjax.studies import lubrication
from mpmjax.studies import validate as V

case, levels, pool = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
split = {"numerics.split_levels": levels, "numerics.split_pool": pool}
line = {"case": case, "split_levels": levels, "split_pool": pool, "date": time.strftime("%Y-%m-%d")}
if case == "huppert":
    ppc = int(sys.argv[4]) if len(sys.argv) > 4 else 2
    base = dict(split, **{"numerics.ppc": ppc, "time.n_frames": 40})
    spent = []

    def each(setup, state):
        if not spent and not bool(np.any(np.asarray(spare_slots(state)))):
            spent.append(float(state.t))

    rec: dict = {}
    s, final, _, times = V._run_frames(V._huppert_cfgs("full", base)[0], rec, each=each)
    act = np.asarray(final.active, bool)
    far = float(np.asarray(final.x)[act, 0].max())
    exact = lubrication.HUPPERT_ETA * (V.G * V.HUPPERT_Q**3 * times[-1] / (3 * V.HUPPERT_NU)) ** 0.2
    line.update(ppc=ppc, t_s=times[-1], front_exact_m=exact, farthest_m=far, farthest_error=far / exact - 1,
                columns_end=int(act.sum()), slots=int(s.scene.n_particles - np.sum(np.asarray(s.state.active))),
                pool_spent_at_s=spent[0] if spent and levels > 0 else None, loop_cpu_s=rec["cpu_s"])
elif case == "lab":
    sets = ["model.formulation=depth-averaged", "time.n_frames=60"] + [f"{k}={v}" for k, v in split.items()]
    with tempfile.TemporaryDirectory() as d:
        s = run_scene("dambreak-lab", Path(d) / "run", sets, quiet=True)
    line.update(final_runout_m=s["final_runout_m"], sparse_volume_fraction=s["sparse_volume_fraction"],
                split_columns=s["split_columns"], time_to_rest_s=s["time_to_rest_s"], loop_wall_s=s["wall_s"])
else:
    raise SystemExit(f"case {case!r}: huppert or lab")
print(json.dumps(line))
