#!/usr/bin/env bash
# Quick start, command 1: set up, then run the default scene (thesis lab dam break).
# Extra arguments go to `mpmjax run`, e.g. `bash scripts/run.sh --set time.t_end_s=5`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/mpmjax run "$@"
