#!/bin/bash
# `mpmjax sweep --devices 1` against `--devices 2` end to end (issue 18): the default scene at ppc 2
# (1600 particles), 16 cases (8 values of mu0 x 2 of n), 2 s of flow (3168 steps), alternating, 3 rounds.
# One JSON line per command: its wall time (start-up and compilation included) and sweep.json's
# wall_s (the sweep itself, its compilation included).
#   bash benchmarks/devices/sweep_devices.sh > benchmarks/devices/sweep_devices.jsonl
cd "$(dirname "$0")/../.." || exit 2
out=$(mktemp -d)
for r in 1 2 3; do for d in 1 2; do
  t0=$(date +%s.%N)
  .venv/bin/mpmjax sweep dambreak-lab --set numerics.ppc=2 --set time.t_end_s=2 --set time.n_frames=4 \
    --vary mu0=2,2.4,2.8,3.2,3.6,4,4.4,4.8 --vary n=1.5,2.5 --devices $d --quiet --out "$out/d$d" > /dev/null 2>&1
  t1=$(date +%s.%N)
  .venv/bin/python -c "import json, sys; d = json.load(open('$out/d$d/sweep.json')); print(json.dumps({'round': $r,
    'devices': $d, 'command_wall_s': $t1 - $t0, 'sweep_wall_s': d['wall_s'], 'n_steps': d['n_steps'],
    'n_cases': d['n_cases'], 'n_particles': d['n_particles'], 'load_avg': float(open('/proc/loadavg').read().split()[0])}))"
done; done
rm -rf "$out"
