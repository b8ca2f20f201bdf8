#!/usr/bin/env bash
# Quick start, command 2: set up, then run the test suite (CI calls this via .ci/run).
# Extra arguments go to pytest, e.g. `bash scripts/test.sh -m slow` for full-resolution validations.
set -uo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh || exit 1
# pytest-xdist: one worker per core (MPMJAX_TEST_WORKERS overrides; 0 runs in this process).  Most
# of a test's time is XLA compilation and serial scatter-adds, one core each; measured on the idle
# 2-core VM: 431 tests in 22 min with 2 workers, where 367 tests took 23 min in one process;
# 2026-12-01: 473 tests in 20.3 min (1219 s) with 2 workers on the idle VM; 2026-12-02, with the
# tests compiling through XLA:CPU's older fusion emitters (tests/conftest.py): 490 tests in 15.3 min
# (917 s); the slowest tests are listed in docs/performance.md, "Test suite".
# worksteal evens out the long tests.
# One persistent XLA compilation cache per run, shared by the workers and the CLI subprocesses the
# tests start (tests compile some programs more than once: the same coarse scene in several CLI
# tests, one calibration program in several fits).  Fresh and removed at the end, so that CI's
# figure is a cold run's; a developer who sets JAX_COMPILATION_CACHE_DIR keeps theirs.
if [ -z "${JAX_COMPILATION_CACHE_DIR:-}" ]; then
  cache_dir=$(mktemp -d "${TMPDIR:-/tmp}/mpmjax-xla-cache.XXXXXX") || exit 1
  trap 'rm -rf "$cache_dir"' EXIT
  export JAX_COMPILATION_CACHE_DIR="$cache_dir"
fi
export JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="${JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS:-0.2}"
.venv/bin/python -m pytest -q -n "${MPMJAX_TEST_WORKERS:-auto}" --dist worksteal "$@"
rc=$?
if [ "$rc" -eq 5 ]; then
  echo "pytest collected no tests (exit 5): treated as success" >&2
  exit 0
fi
exit "$rc"
