"""`field-breach-da` with and without column splitting, at two cell sizes and two column densities: which
answer the thin layer on the basin's counter-slope converges to.  Reads run folders written by `mpmjax run`
and prints one JSON line per folder (the headline front, the deposit raster's extents at four thicknesses,
its areas and volume, the sparse volume fraction and depth, the split pool's use, the time loop's wall time and,
where a file FOLDER.time from `/usr/bin/time -f "%e s wall %U user %S sys" -o FOLDER.time mpmjax run ...` exists,
the whole run's).

    for c in "0 1" "1 1" "1 2" "2 3"; do set -- $c
      .venv/bin/mpmjax run field-breach-da --set numerics.split_levels=$1 --set numerics.split_pool=$2 \
          --out runs/breach-L$1P$2 --quiet --no-animation; done
    .venv/bin/mpmjax run field-breach-da --set numerics.ppc=4 --set numerics.split_levels=0 --out runs/breach-ppc4L0 ...
    .venv/bin/mpmjax run field-breach-da --set domain.cell_size_m=2.5 --set numerics.split_levels=0 --out runs/breach-h25L0 ...
    .venv/bin/mpmjax run field-breach-da --set domain.cell_size_m=2.5 --out runs/breach-h25L1 ...
    .venv/bin/mpmjax run field-breach-da --out runs/breach-default ...   # the scene as committed (one level)
    .venv/bin/python benchmarks/accuracy/da_breach_split.py runs/breach-* >> benchmarks/accuracy/da_breach_split.jsonl

Map x is read from the raster's transform less the DEM's west edge (350 000 m), as in docs/scenarios.md.
The lines of stop 58 (2026-12-06/07) are docs/depth-averaged.md's table ("The field breach with splitting").
"""

import json
import sys

import numpy as np
import rasterio

THICKNESS_M = (0.1, 0.5, 1.0, 2.0)  # the deposit raster's extents and areas at these thicknesses
BASIN_X_M = 1600.0  # where the valley opens into the basin (data/README.md)


def _whole_run_wall(folder: str):
    """The whole run's wall time [s] from FOLDER.time (GNU time's "%e s wall ..."), None without one."""
    try:
        return float(open(f"{folder}.time").read().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def record(folder: str) -> dict:
    s = json.load(open(f"{folder}/summary.json"))
    with rasterio.open(f"{folder}/hazard_deposit_thickness_m.tif") as r:
        a = np.nan_to_num(r.read(1).astype(float))
        t = r.transform
    cell = abs(t.a * t.e)
    x = t.a * (np.arange(a.shape[1]) + 0.5)  # from the DEM's west edge [m]
    out = {
        "folder": folder,
        "overrides": s.get("overrides"),
        "cell_size_m": s["cell_size_m"],
        "n_particles": s["n_particles"],
        "front_600s_m": s["final_runout_m"],
        "front_max_m": max(s["runout_m"]),
        "farthest_column_m": s["final_runout_farthest_particle_m"],
        "sparse_volume_fraction": s.get("sparse_volume_fraction"),
        "split_columns": s.get("split_columns"),
        "time_to_rest_s": s.get("time_to_rest_s"),
        "sparse_column_depth_m": s.get("sparse_column_depth_m"),  # written since stop 58's second commit
        "wall_s": s["wall_s"],  # the time loop's
        "whole_run_wall_s": _whole_run_wall(folder),
        "deposit_volume_m3": float(a.sum() * cell),
        "deposit_max_thickness_m": float(a.max()),
        "deposit_volume_fraction_in_basin": float(a[:, x > BASIN_X_M].sum() / a.sum()),
    }
    for thr in THICKNESS_M:
        cols = np.where((a >= thr).any(axis=0))[0]
        out[f"deposit_x_far_{thr:g}m"] = float(x[cols.max()]) if len(cols) else None
        out[f"deposit_area_{thr:g}m_ha"] = float((a >= thr).sum() * cell / 1e4)
    return out


if __name__ == "__main__":
    for f in sys.argv[1:]:
        print(json.dumps(record(f)))
