#!/usr/bin/env bash
# A git revision's step against the working tree's, side by side: per round, each scene is timed in
# a fresh process by benchmarks/speed/step_speed.py, first the revision's code (a temporary worktree on
# PYTHONPATH), then the working tree's, alternating, under the same load.  One JSON line per timing.
# With ALSO_KEEP_XLA_FLAGS=1 the working tree is timed a second time per round with
# MPMJAX_KEEP_XLA_FLAGS=1 (XLA's default flags, mpmjax._fusion.prefer_xla_reductions off).
# usage: benchmarks/speed/compare_revisions.sh REV [ROUNDS] > out.jsonl
set -euo pipefail
cd "$(dirname "$0")/../.."
rev="${1:?usage: compare_revisions.sh REV [ROUNDS]}"
rounds="${2:-3}"
py="${MPMJAX_PYTHON:-$PWD/.venv/bin/python}"
base="$(mktemp -d)"
trap 'git worktree remove --force "$base" >/dev/null 2>&1 || rm -rf "$base"' EXIT
git worktree add --detach "$base" "$rev" >/dev/null 2>&1
here="$PWD"
bench="$here/benchmarks/speed/step_speed.py"
run() {  # CODE TREE SCENE STEPS [KEY=VALUE ...]
  local code="$1" tree="$2" keep=0; shift 2
  [ "$tree" = keep ] && { tree="$here"; keep=1; }
  (cd /tmp && CODE="$code" PYTHONPATH="$tree" MPMJAX_KEEP_XLA_FLAGS=$keep "$py" "$bench" "$1" "$2" 3 "${@:3}")
}
trees=("$base" "$here")
[ "${ALSO_KEEP_XLA_FLAGS:-0}" = 1 ] && trees+=(keep)
for round in $(seq 1 "$rounds"); do
  for tree in "${trees[@]}"; do
    code=$([ "$tree" = "$base" ] && echo "$rev" || echo "working tree")
    [ "$tree" = keep ] && code="working tree, XLA default flags"
    run "$code" "$tree" mpm88 500
    run "$code" "$tree" dambreak-lab 500
    run "$code" "$tree" field-dambreak-3d 100 domain.cell_size_m=12
  done
done
