#!/usr/bin/env bash
# GPU figures for docs/performance.md ("GPU"), as run on a lent NVIDIA H100 whose python3 already
# has jax with CUDA, diffrax, optax, h5py and matplotlib (nothing is installed from the network).
# Every part writes under $OUT as it finishes, so a part cut off by its time limit loses only itself.
#   1. env.txt          the GPU, driver, python and jax
#   2. batch.jsonl      vmap batch of 16 against 16 sequential runs (benchmarks/batch/batch_sizes.py)
#   3. bench_gpu_float32.json / bench.log   `mpmjax bench --large` (1e3-1e6 particles, 2D/3D, f32/f64, with
#                           XLA's bytes and flops per particle-step and the device's STREAM triad)
#   4. side_by_side.jsonl   Taichi 1.7.4 on CUDA against our mpm88-equivalent (only if .whl/ holds
#                           the taichi and dill wheels for this python)
#   5. run_*.json       wall time and summary of `mpmjax run` on dambreak-lab and field-dambreak-3d
# usage: OUT=dir bash benchmarks/gpu/gpu.sh
cd "$(dirname "$0")/../.."
# shellcheck source=benchmarks/gpu/gpu_env.sh
source benchmarks/gpu/gpu_env.sh
mj() { "$py" -c 'import sys; from mpmjax.cli import main; sys.exit(main(sys.argv[1:]))' "$@"; }

{
  nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv
  nproc
  "$py" -c 'import sys, jax; print(sys.version.split()[0], "jax", jax.__version__, jax.devices())'
} 2>&1 | tee "$OUT/env.txt"

for a in "0.01 400" "0.005 400" "0.0025 200"; do
  # shellcheck disable=SC2086
  timeout 90 "$py" benchmarks/batch/batch_sizes.py $a 2>&1 | grep '^{' | tee -a "$OUT/batch.jsonl"
done

# --reps 2 and no batch section (batch_sizes.py above measures it): each row now also compiles one step
# for XLA's byte and flop counts (the GPU's own bytes per particle-step against its bandwidth, issue 18)
timeout 270 bash -c "$(declare -f mj); py='$py'; mj bench --large --only scenes,scaling,gradient --reps 2 \
  --out '$OUT/bench_gpu_float32.json'" > "$OUT/bench.log" 2>&1
tail -n 30 "$OUT/bench.log"

if ls .whl/taichi-*.whl > /dev/null 2>&1; then
  "$py" -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl &&
    for round in 1 2; do
      PYTHONPATH=/tmp/site:$PYTHONPATH TAICHI_ARCH=cuda timeout 60 "$py" benchmarks/speed/taichi_mlsmpm.py 2000 \
        2>&1 | grep '^{' | tee -a "$OUT/side_by_side.jsonl"
      timeout 60 "$py" - "$round" <<'PY' 2>&1 | grep '^{' | tee -a "$OUT/side_by_side.jsonl"
import json, sys
from mpmjax.studies import bench
from mpmjax import build, validate
raw = json.loads(json.dumps(bench.MPM88))
r = bench._measure(build(validate(raw)), 2000)
print(json.dumps({"round": int(sys.argv[1]), "code": "mpmjax mpm88-equivalent (float32)", **r}))
PY
    done
fi

for scene in dambreak-lab field-dambreak-3d; do
  t0=$(date +%s.%N)
  timeout 200 bash -c "$(declare -f mj); py='$py'; mj run $scene --out /tmp/run_$scene --no-animation --quiet" \
    > "$OUT/run_$scene.log" 2>&1
  rc=$?
  t1=$(date +%s.%N)
  "$py" - "$scene" "$rc" "$t0" "$t1" "/tmp/run_$scene/summary.json" > "$OUT/run_$scene.json" <<'PY'
import json, os, sys
scene, rc, t0, t1, path = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]), sys.argv[5]
s = json.load(open(path)) if os.path.exists(path) else None
print(json.dumps({"scene": scene, "rc": rc, "wall_s_including_compile": t1 - t0, "summary": s}, indent=1))
PY
  head -c 600 "$OUT/run_$scene.json"
  echo
done
