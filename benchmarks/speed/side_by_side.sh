#!/usr/bin/env bash
# The speed target of issue 6, measured side by side: Taichi's CPU backend running MLS-MPM on the
# mpm88 configuration (benchmarks/speed/taichi_mlsmpm.py) and mpmjax's mpm88-equivalent
# (mpmjax.studies.bench.MPM88: the same grid, particle block, shape function and transfer, through this
# package's general step), one after the other, alternating, under the same load: per round Taichi on
# 2 threads, then mpmjax on one device, then mpmjax with the particles split over 2 host devices
# (numerics.devices = 2, the replicated grid: each core runs its half of the particles; issue 18 item 4);
# with MLS=1 each mpmjax run is followed by one with numerics.force = "mls", Taichi's own algorithm.
# usage: TAICHI_PYTHON=/path/to/venv-with-taichi/bin/python benchmarks/speed/side_by_side.sh [STEPS] [ROUNDS] > out.jsonl
set -euo pipefail
cd "$(dirname "$0")/../.."
steps="${1:-2000}"
rounds="${2:-2}"
tpy="${TAICHI_PYTHON:?set TAICHI_PYTHON to a python with taichi installed (python -m venv tv && tv/bin/pip install taichi)}"
jpy="${MPMJAX_PYTHON:-.venv/bin/python}"
for round in $(seq 1 "$rounds"); do
  "$tpy" benchmarks/speed/taichi_mlsmpm.py "$steps" 2 | grep '^{' | sed "s/^{/{\"round\": $round, \"load\": \"$(cut -d' ' -f1 /proc/loadavg)\", /"
  for run in 1 2 $([ "${MLS:-0}" = 1 ] && echo 1m 2m); do
    "$jpy" - "$steps" "$round" "$run" <<'PY'
import json, os, sys
import jax
steps, rnd, devices, mls = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3][0]), sys.argv[3].endswith("m")
jax.config.update("jax_num_cpu_devices", devices)  # before JAX starts its backends
from mpmjax.studies import bench
from mpmjax import build, validate
for dtype in ("float32",):
    raw = json.loads(json.dumps(bench.MPM88))
    raw["numerics"]["dtype"] = dtype
    raw["numerics"]["devices"] = devices
    if mls:
        raw["numerics"]["force"] = "mls"
    r = bench._measure(build(validate(raw)), steps)
    code = f"mpmjax mpm88-equivalent ({dtype})" + (f", {devices} host devices" if devices > 1 else "")
    code += ", force = mls" if mls else ""
    print(json.dumps({"round": rnd, "load": f"{os.getloadavg()[0]:.2f}", "code": code, **r}))
PY
  done
done
