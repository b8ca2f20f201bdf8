#!/usr/bin/env bash
# Resolution and grid-volume-check runs of the pipe scenes on a lent NVIDIA GPU (docs/scenarios.md):
#   field-pipe-3d at h = 0.25 m (the pipe 1.1 cells across) without and with numerics.grid_density_cap,
#   the thin flume deposit at h = 2 cm after 300 s (benchmarks/accuracy/thin_deposit.py), and the lab dam break
#   at h = 2.5 mm with the cap (against the float64 reference runout of `mpmjax pareto`).
# Each run appends one JSON line to $OUT/results.jsonl as it ends; logs go to $OUT/log.txt.
# Part "refine": field-pipe-3d in the scene's own box at h = 0.25 and 0.125 m, no cap (recorded when that box
# was 40 m x 25 m; it is now 40 m x 24 m, whose nodes coincide with it: docs/scenarios.md).
# usage: OUT=dir bash benchmarks/gpu/gpu_pipe.sh [all|refine]
cd "$(dirname "$0")/../.."
# shellcheck source=benchmarks/gpu/gpu_env.sh
source benchmarks/gpu/gpu_env.sh
log="$OUT/log.txt"

run_scene() { # limit_s scene tag --set ... : `mpmjax run`, then one JSON line from its summary
  local limit=$1 scene=$2 tag=$3
  shift 3
  local t0 rc
  t0=$(date +%s.%N)
  timeout "$limit" "$py" -c 'import sys; from mpmjax.cli import main; sys.exit(main(sys.argv[1:]))' \
    run "$scene" --out "/tmp/run_$tag" --no-animation --quiet --checkpoint-every 0 "$@" >> "$log" 2>&1
  rc=$?
  "$py" - "$tag" "$rc" "$t0" "$(date +%s.%N)" "/tmp/run_$tag/summary.json" "$@" >> "$OUT/results.jsonl" <<'PY'
import json, os, sys
tag, rc, t0, t1, path, sets = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]), sys.argv[5], sys.argv[6:]
s = json.load(open(path)) if os.path.exists(path) else {}
keep = ("status", "failure", "t_end_s", "n_particles", "n_steps", "dt_s", "cell_size_m", "wall_s", "compile_s",
        "particle_steps_per_s", "final_runout_m", "beach_slope", "time_to_rest_s", "n_lost", "lobe_width_m",
        "mass_final_kg", "jax_backend")
print(json.dumps({"tag": tag, "rc": rc, "wall_s_including_compile": t1 - t0, "sets": sets,
                  **{k: s[k] for k in keep if k in s}}))
PY
  tail -n 1 "$OUT/results.jsonl"
}

nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee -a "$log"
if [ "${1:-all}" = refine ]; then
  run_scene 100 field-pipe-3d fp3d_box40_h025 --set domain.cell_size_m=0.25
  run_scene 200 field-pipe-3d fp3d_box40_h0125 --set domain.cell_size_m=0.125
  exit 0
fi
# the thesis's 150 m x 50 m box (the scene's box when these runs were recorded)
big=(--set "domain.lo_m=[0.0, -25.0, 0.0]" --set "domain.hi_m=[150.0, 25.0, 2.0]")
run_scene 130 field-pipe-3d fp3d_h025_cap0 "${big[@]}" --set domain.cell_size_m=0.25
run_scene 130 field-pipe-3d fp3d_h025_cap01 "${big[@]}" --set domain.cell_size_m=0.25 --set numerics.grid_density_cap=0.1
for cap in 0 0.1; do
  timeout 60 "$py" benchmarks/accuracy/thin_deposit.py flume-deposition 300 domain.cell_size_m=0.02 \
    numerics.grid_density_cap=$cap 2>> "$log" | grep '^{' | tee -a "$OUT/results.jsonl"
done
run_scene 100 dambreak-lab lab_h00025_cap01 --set domain.cell_size_m=0.0025 --set numerics.grid_density_cap=0.1
run_scene 150 field-pipe-3d fp3d_h0125_cap0 "${big[@]}" --set domain.cell_size_m=0.125
