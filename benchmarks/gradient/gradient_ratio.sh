#!/usr/bin/env bash
# The gradient/forward ratio of a git revision against the working tree's, side by side: per
# round a fresh process each (benchmarks/gradient/gradient_ratio.py), the revision first, alternating.
# usage: benchmarks/gradient/gradient_ratio.sh REV [ROUNDS] [STEPS] [CHUNK] [KEY=VALUE ...] > out.jsonl
# Pinned to one core with one XLA thread when ONE_CORE=1 (CPU time then that of the work alone).
set -euo pipefail
cd "$(dirname "$0")/../.."
rev="${1:?usage: gradient_ratio.sh REV [ROUNDS] [STEPS] [CHUNK]}"
rounds="${2:-3}"; steps="${3:-1000}"; chunk="${4:-50}"; shift $(( $# < 4 ? $# : 4 ))
py="${MPMJAX_PYTHON:-$PWD/.venv/bin/python}"
base="$(mktemp -d)"
trap 'git worktree remove --force "$base" >/dev/null 2>&1 || rm -rf "$base"' EXIT
git worktree add --detach "$base" "$rev" >/dev/null 2>&1
here="$PWD"
pin=()
flags="${XLA_FLAGS:-}"
if [ "${ONE_CORE:-0}" = 1 ]; then
  pin=(taskset -c 1)
  flags="$flags --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
fi
for round in $(seq 1 "$rounds"); do
  for tree in "$base" "$here"; do
    code=$([ "$tree" = "$base" ] && echo "$rev" || echo "working tree")
    (cd /tmp && CODE="$code" PYTHONPATH="$tree" XLA_FLAGS="${flags# }" "${pin[@]}" "$py" \
      "$here/benchmarks/gradient/gradient_ratio.py" "$steps" "$chunk" 2 "$@")
  done
done
