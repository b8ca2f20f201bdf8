#!/usr/bin/env bash
# Quick start, command 2: set up, then run the test suite (CI calls this via .ci/run).
# Extra arguments go to pytest, e.g. `bash scripts/test.sh -m slow` for full-resolution validations.
set -uo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh || exit 1
.venv/bin/python -m pytest -q "$@"
rc=$?
if [ "$rc" -eq 5 ]; then
  echo "pytest collected no tests (exit 5): treated as success" >&2
  exit 0
fi
exit "$rc"
