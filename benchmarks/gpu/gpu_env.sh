# Shared set-up of the GPU scripts (sourced by gpu.sh and gpu_pipe.sh, run from the repository
# root): $OUT for the returned files, the package on PYTHONPATH, and $py, the python with jax.
set -uo pipefail
OUT="${OUT:-/tmp/gpu_out}"
mkdir -p "$OUT"
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 MPLBACKEND=Agg
py="${PYTHON:-python3}"
