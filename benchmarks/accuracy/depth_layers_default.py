"""The change of ``numerics.depth_layers``' default from 1 to 16 (stop 64; docs/depth-layers.md, "The default"):
what it moves where it is chosen and in the lab records of the depth-averaged formulation.

* ``mpmjax validate``'s ``coussot-film-da`` (the lab layer from rest as columns against the film, at 2 and 1.5
  tau_c) at 1, 8, 16 and 32 layers: the errors and the loop's CPU;
* ``dambreak-lab`` as columns (``model.formulation=depth-averaged``) at the columns a cell and levels of splitting
  of docs/depth-averaged.md's resolution table ("Creep after arrest"), with 1 and 16 layers one after the other:
  the front at 15 s, the time to rest, the sparse volume and the loop's CPU.

One JSON line a run; float32 (the scenes' dtype), 2 shared cores.

    .venv/bin/python benchmarks/accuracy/depth_layers_default.py > benchmarks/accuracy/depth_layers_default.jsonl
"""

import json
import tempfile
import time
from pathlib import Path

from mpmjax import run_scene
from mpmjax.studies.validate import run_validate

LAB = (  # (columns a cell, split levels, split pool): the resolution table's runs
    (3, 1, 1.0),
    (3, 2, 2.0),
    (3, 3, 3.0),
    (8, 1, 1.0),
    (8, 3, 4.0),
)


def validate_case(layers: int, out: Path) -> dict:
    rec = run_validate(["coussot-film-da"], size="full", out=out, base={"numerics.depth_layers": layers},
                       fresh=True, log=lambda m: None)["cases"]["coussot-film-da"]
    return {"what": "coussot-film-da", "layers": layers, "pass": rec["pass"],
            "errors_pct": {c["name"]: round(100 * c["error"], 3) for c in rec["checks"]},
            "loop_cpu_s": round(rec["cpu_s"], 3), "n_steps": rec["n_steps"]}


def lab(ppc: int, levels: int, pool: float, layers: int, out: Path) -> dict:
    sets = ["model.formulation=depth-averaged", f"numerics.ppc={ppc}", f"numerics.split_levels={levels}",
            f"numerics.split_pool={pool}", f"numerics.depth_layers={layers}"]
    c0 = time.process_time()
    s = run_scene("dambreak-lab", out, sets, quiet=True)
    return {"what": "dambreak-lab as columns", "ppc": ppc, "split_levels": levels, "split_pool": pool,
            "layers": layers, "runout_m": round(s["final_runout_m"], 4), "time_to_rest_s": s["time_to_rest_s"],
            "sparse_volume_fraction": round(s["sparse_volume_fraction"], 4), "wall_s": round(s["wall_s"], 2),
            "process_cpu_s": round(time.process_time() - c0, 2),
            "warnings": [w[:120] for w in s["warnings"]]}


if __name__ == "__main__":
    date = time.strftime("%Y-%m-%d")
    with tempfile.TemporaryDirectory() as tmp:
        for k in (1, 8, 16, 32):
            print(json.dumps(dict(validate_case(k, Path(tmp) / f"v{k}"), date=date)), flush=True)
        for ppc, levels, pool in LAB:
            for k in (1, 16):
                out = Path(tmp) / f"lab-{ppc}-{levels}-{k}"
                print(json.dumps(dict(lab(ppc, levels, pool, k, out), date=date)), flush=True)
