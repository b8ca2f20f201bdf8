#!/usr/bin/env bash
# The speed target of issue 6, measured side by side: Taichi's CPU backend running MLS-MPM on the
# mpm88 configuration (docs/bench/taichi_mlsmpm.py) and mpmjax's mpm88-equivalent
# (mpmjax.studies.bench.MPM88: the same grid, particle block, shape function and transfer, through this
# package's general step), one after the other, twice, alternating, under the same load.
# usage: TAICHI_PYTHON=/path/to/venv-with-taichi/bin/python docs/bench/side_by_side.sh [STEPS] > out.jsonl
set -euo pipefail
cd "$(dirname "$0")/../.."
steps="${1:-2000}"
tpy="${TAICHI_PYTHON:?set TAICHI_PYTHON to a python with taichi installed (python -m venv tv && tv/bin/pip install taichi)}"
jpy="${MPMJAX_PYTHON:-.venv/bin/python}"
for round in 1 2; do
  "$tpy" docs/bench/taichi_mlsmpm.py "$steps" 2 | grep '^{' | sed "s/^{/{\"round\": $round, \"load\": \"$(cut -d' ' -f1 /proc/loadavg)\", /"
  "$jpy" - "$steps" "$round" <<'PY'
import json, os, sys
from mpmjax.studies import bench
from mpmjax import build, validate
steps, rnd = int(sys.argv[1]), int(sys.argv[2])
for dtype in ("float32",):
    raw = json.loads(json.dumps(bench.MPM88))
    raw["numerics"]["dtype"] = dtype
    r = bench._measure(build(validate(raw)), steps)
    print(json.dumps({"round": rnd, "load": f"{os.getloadavg()[0]:.2f}", "code": f"mpmjax mpm88-equivalent ({dtype})", **r}))
PY
done
